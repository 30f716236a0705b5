"""A sweep over several processes (hosts) with `jax.distributed.initialize`.

Every process runs this script. The processes agree on one design, and each one sweeps its share
of the members (member i goes to process i mod P) on its own local devices, with `shard_map` over
them when there are several. It writes OUT/sweep_process_<id>.csv, and process 0 then joins the
shares into OUT/sweep.csv once they are all there.

    # two processes on this machine (or one per host, with the coordinator's address):
    PROCESS_ID=0 NUM_PROCESSES=2 COORDINATOR=localhost:12355 python scripts/sweep_multihost.py &
    PROCESS_ID=1 NUM_PROCESSES=2 COORDINATOR=localhost:12355 python scripts/sweep_multihost.py

Without these variables it runs as one process. (On SLURM and similar clusters,
`jax.distributed.initialize()` with no arguments reads them from the environment.)
"""

import csv
import os
import time

import jax

n_proc = int(os.environ.get("NUM_PROCESSES", "1"))
if n_proc > 1:
    jax.distributed.initialize(coordinator_address=os.environ["COORDINATOR"],
                               num_processes=n_proc, process_id=int(os.environ["PROCESS_ID"]))

import numpy as np  # noqa: E402

import ppr_jax as pj  # noqa: E402

OUT = os.environ.get("OUT", "out_multihost")
T_END = float(os.environ.get("T_END", "0.5"))

members = pj.design_members({"t": np.linspace(0.25e-3, 0.45e-3, 4), "gamma": [0.80, 0.86]})
me, P = jax.process_index(), jax.process_count()
mine = {k: v[me::P] for k, v in members.items()}
devices = jax.local_devices()
r = pj.sweep("paper-circle", vary=mine, design="list", model="reduced", torque_model="rigid",
             options=pj.SceneOptions(t_end=T_END, n_out=11), chunk_size=4 * len(devices),
             devices=devices)
os.makedirs(OUT, exist_ok=True)
index = np.arange(len(members["t"]))[me::P]  # member numbers in the whole design
with open(os.path.join(OUT, f"sweep_process_{me}.csv"), "w", newline="") as f:
    w = csv.DictWriter(f, fieldnames=r.columns)
    w.writeheader()
    for row, i in zip(r.rows, index):
        w.writerow({**row, "member": int(i)})
print(f"process {me}/{P}: {len(r.ok)} ok, {len(r.failed)} failed on {len(devices)} device(s)")
if me == 0:
    parts = [os.path.join(OUT, f"sweep_process_{k}.csv") for k in range(P)]
    for _ in range(600):  # a shared file system; wait for the other processes' shares
        if all(os.path.exists(p) for p in parts):
            break
        time.sleep(1)
    rows = []
    for p in parts:
        with open(p) as f:
            rows += list(csv.DictReader(f))
    rows.sort(key=lambda row: int(row["member"]))
    with open(os.path.join(OUT, "sweep.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=r.columns)
        w.writeheader()
        w.writerows(rows)
    print(f"wrote {OUT}/sweep.csv ({len(rows)} members)")
