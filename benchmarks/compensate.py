"""Compensation's cost and effect: 6 s of a figure eight at 100 Hz (601 command times), L2 at
0.5 mm strips, both drives (and the quasi-static L3 with `--models`).

For each model and drive, in one fresh process (so "cold" is what a user's first call waits,
compilation included): `compensate` whole (the inversion, the nominal and the compensated runs),
then warm: the inversion alone (`_studies._compensate._invert`, minimum of repeats), one forward
run of the compensated scene (`run_scene`'s run time, minimum of repeats), their ratio (the
issue's goal: at most 10 forward runs' time), and the tracking error before and after. Writes
benchmarks/results/compensate.json.

    python benchmarks/compensate.py [--models double1r,beam] [--t-end 6] [--repeats 3] [--optimise]

With `--optimise`, `method="optimise"` (Levenberg-Marquardt from the inversion's commands, 12
knots, 4 iterations, no replays, its default Jacobian by differences) is timed too: its first
call and a warm second one; and one Jacobian of the 36 unknowns each way, warm: by differences
(one batch of 37 replays) and by forward mode, with their largest difference.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
OUT = os.path.join(HERE, "results", "compensate.json")

CHILD = r"""
import json, sys, time
t0 = time.perf_counter()
import jax, jax.numpy as jnp, numpy as np
import ppr_jax as pj
from ppr_jax._robot import Robot
from ppr_jax._studies._compensate import _invert

model, drive, t_end, repeats = sys.argv[1], sys.argv[2], float(sys.argv[3]), int(sys.argv[4])
method = sys.argv[5]
path = pj.Fourier(mean=[0.45, 0.15 * np.sqrt(3), 0.0], cos=[[0.0, 0.0, 0.02], [0.0, 0.0, 0.0]],
                  sin=[[0.08, 0.0, 0.0], [0.0, 0.05, 0.0]], omega=2.0)
params = pj.scene_params("servo-circle")
opts = pj.SceneOptions(t_end=t_end)
c = pj.compensate(path, model, params, drive=drive, options=opts)
cold = time.perf_counter() - t0
ts = c.ts
m, robot = pj.get_model(model), Robot(params)
inv = []
for _ in range(repeats):
    s = time.perf_counter()
    jax.block_until_ready(_invert(m, robot, path, ts))
    inv.append(time.perf_counter() - s)
scene = pj.PathScene(path, drive=drive, command_log=c.log)
import dataclasses
o = dataclasses.replace(opts, n_out=int(c.ts.shape[0]))
rep = pj.run_scene(scene, params, model=model, options=o, repeats=repeats)
opt = None
if method == "optimise":
    s = time.perf_counter()
    co = pj.compensate(path, model, params, drive=drive, options=opts, method="optimise",
                       verify=False, max_iter=4)
    first = time.perf_counter() - s
    s = time.perf_counter()
    co = pj.compensate(path, model, params, drive=drive, options=opts, method="optimise",
                       verify=False, max_iter=4)
    opt = {"first_s": first, "warm_s": time.perf_counter() - s, "iterations": co.fit["iterations"],
           "cost_start_m2": co.fit["cost_start"], "cost_m2": co.fit["cost"],
           "knots": 12, "max_iter": 4, "jacobian": "differences"}
    # one Jacobian each way at the inversion's commands, warm (minimum of 2 after a first call)
    from ppr_jax._studies import _compensate_fit as F
    import diffrax
    tk = np.linspace(ts[0], ts[-1], 12)
    basis = jax.vmap(pj.Waypoints(tk, np.eye(12), bc="not-a-knot"))(jnp.asarray(ts))
    u0 = c.commands
    fit = F._Fit(path=path, u0=jnp.asarray(u0), basis=basis, ts=tuple(float(t) for t in ts),
                 drive=drive, kind=c.kind, model=m,
                 options=dataclasses.replace(o, adjoint=diffrax.ForwardMode()))
    z = jnp.zeros((12, 3))
    h = F.FD_STEP * float(np.max(np.abs(u0)))
    jac = {}
    for how, fn in (("differences", lambda: F._differences(fit, z, params, jnp.asarray(h))[0]),
                    ("forward", lambda: F._jacobian(fit, z, params))):
        jax.block_until_ready(fn())
        w = []
        for _ in range(2):
            s = time.perf_counter()
            J = jax.block_until_ready(fn())
            w.append(time.perf_counter() - s)
        jac[how] = (min(w), np.asarray(J).reshape(-1, 36) if how == "forward" else np.asarray(J))
    opt["jacobian_s"] = {k: v[0] for k, v in jac.items()}
    Jd, Jf = jac["differences"][1], jac["forward"][1]
    opt["jacobian_rel_diff"] = float(np.abs(Jd - Jf).max() / np.abs(Jf).max())
print(json.dumps({"model": model, "drive": drive, "t_end_s": t_end, "optimise": opt,
                  "commands": int(c.ts.shape[0]), "cold_s": cold,
                  "inversion_warm_s": min(inv), "forward_run_s": rep.timing["run_s"],
                  "inversion_over_forward_run": min(inv) / rep.timing["run_s"],
                  "steps": int(rep.metrics["num_steps"]),
                  "error_before": c.error["before"], "error_after": c.error["after"],
                  "inversion_change_rad": c.change, "flags": list(c.flags)}))
"""


def main(argv=None):
    from latency import machine

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", default="double1r")
    ap.add_argument("--drives", default="motion,torque")
    ap.add_argument("--t-end", type=float, default=6.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--optimise", action="store_true",
                    help="also time method='optimise' (4 iterations, 12 knots), first and warm")
    ap.add_argument("--out", default=OUT)
    a = ap.parse_args(argv)
    rows = []
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    for model in a.models.split(","):
        for drive in a.drives.split(","):
            out = subprocess.run([sys.executable, "-c", CHILD, model, drive, str(a.t_end),
                                  str(a.repeats), "optimise" if a.optimise else "inversion"],
                                 capture_output=True, text=True, env=env,
                                 check=True)
            row = json.loads(out.stdout.strip().splitlines()[-1])
            print(f"{model} {drive}: cold {row['cold_s']:.1f} s, inversion "
                  f"{row['inversion_warm_s'] * 1e3:.0f} ms = "
                  f"{row['inversion_over_forward_run']:.1f} forward runs "
                  f"({row['forward_run_s'] * 1e3:.0f} ms); error "
                  f"{row['error_before']['position_max']:.3g} -> "
                  f"{row['error_after']['position_max']:.3g} m", flush=True)
            rows.append(row)
    goals = {"inversion_over_forward_run_max": 10.0, "cold_s_max": 180.0}
    goals["optimise_warm_s_max"] = 30.0
    for row in rows:
        row["met"] = {"inversion_within_10_runs": row["inversion_over_forward_run"] <= 10.0,
                      "cold_within_3_min": row["cold_s"] <= 180.0}
        if row.get("optimise"):
            row["met"]["optimise_within_30_s"] = row["optimise"]["warm_s"] <= 30.0
    with open(a.out, "w") as f:
        json.dump({"machine": machine(), "goals": goals, "rows": rows}, f, indent=1)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    sys.path.insert(0, HERE)
    main()
