"""Benchmark XLA's small-loop threshold: two settings, by default the import's
(`SMALL_LOOP_BYTES`) against `configure_cpu(derivatives=True)`'s (`DERIVATIVE_LOOP_BYTES`), on
what users run: single scenes, batches, a run of many output times, the quasi-static L3 and the
sensitivities in both modes.

Protocol: one process per setting and repetition, the settings interleaved (import, derivatives,
import, ...), each process with the threshold in `XLA_FLAGS` (the import's other setting, the
loop emitters, added as usual) and a persistent compilation cache of its own setting in a
temporary folder, so that later processes skip most compilation. In each process, warm runs:
the minimum of 15 (scenes), 10 (7,540 output times), 3 (batches) and 6 (sensitivities: the
derivative's one run a call, `Sensitivity.timing['run_s']`). Reported: every process's numbers,
and per quantity the minimum and the median over the processes. Single runs and batches are
`paper-circle` at the scenes' defaults unless named: L1 x1,024 "bench" at rtol 1e-6, atol 1e-8
(the batch benchmark's settings), L2 over 1 s with 101 output times (the sensitivities' scene),
the quasi-static L3 at N = 4 and 8 (minimum of 4). Writes benchmarks/results/loop_threshold.json;
`--bytes A B` compares two thresholds of one's choice (the second column's ratios are B / A),
`--out` elsewhere; `--quick` one short L0 run per process (the script's test).

Run: python benchmarks/loop_threshold.py [--repeats 3]
     python benchmarks/loop_threshold.py --bytes 65536 262144 --repeats 2 \
         --out benchmarks/results/loop_threshold_default.json   # the import's, before and now
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
OUT = os.path.join(HERE, "results", "loop_threshold.json")
ROOT = os.path.dirname(HERE)

_CHILD = r"""
import json, sys, time
import numpy as np, jax
import ppr_jax as pj
pj.enable_compilation_cache(sys.argv[1])

def best(f, n):
    ts = []
    for _ in range(n):
        t = time.perf_counter(); r = f(); jax.block_until_ready(r)
        ts.append(time.perf_counter() - t)
    return min(ts)

out = {}
if len(sys.argv) > 2:  # --quick: one short L0 run, that the script runs (its test)
    o = pj.SceneOptions(t_end=0.1, n_out=3)
    pj.solve_scene("paper-circle", model="rigid", options=o)
    out["rigid run, 0.1 s (s)"] = best(
        lambda: pj.solve_scene("paper-circle", model="rigid", options=o), 1)
    print(json.dumps(out))
    sys.exit(0)
for m in ("rigid", "reduced", "double1r"):
    pj.solve_scene("paper-circle", model=m)
    out[f"{m} run (s)"] = best(lambda: pj.solve_scene("paper-circle", model=m), 15)
o = pj.SceneOptions(n_out=7540)
pj.solve_scene("paper-circle", model="double1r", options=o)
out["double1r run, 7,540 outputs (s)"] = best(
    lambda: pj.solve_scene("paper-circle", model="double1r", options=o), 10)
base = pj.scene_params("paper-circle")
ps = pj.stack_params([base.replace(t=float(t)) for t in np.linspace(0.28e-3, 0.40e-3, 1024)])
o = pj.SceneOptions(rtol=1e-6, atol=1e-8, max_steps=400_000)
out["reduced x1024 bench (s)"] = best(
    lambda: pj.solve_scene("paper-circle", ps, model="reduced", options=o), 3)
out["reduced x1024 defaults (s)"] = best(
    lambda: pj.solve_scene("paper-circle", ps, model="reduced"), 3)
ps = pj.stack_params([base.replace(t=float(t)) for t in np.linspace(0.28e-3, 0.40e-3, 256)])
out["rigid x256 defaults (s)"] = best(lambda: pj.solve_scene("paper-circle", ps, model="rigid"), 3)
for N in (4, 8):
    beam = pj.QuasiStaticBeam(N)
    pj.solve_scene("paper-circle", model=beam)
    out[f"beam_qs N={N} run (s)"] = best(lambda: pj.solve_scene("paper-circle", model=beam), 4)
o = pj.SceneOptions(t_end=1.0, n_out=101)
out["double1r run, 1 s (s)"] = best(
    lambda: pj.solve_scene("paper-circle", model="double1r", options=o), 20)
for mode in ("fwd", "rev"):
    runs = [pj.sensitivity("paper-circle", model="double1r", mode=mode, options=o)
            for _ in range(6)]
    out[f"sensitivity {mode}, L2 1 s, 19 parameters (s)"] = min(
        s.timing["run_s"] for s in runs)
print(json.dumps(out))
"""


def _size(n: int) -> str:
    return f"{n >> 20} MiB" if n % (1 << 20) == 0 else f"{n >> 10} KiB"


def _settings(pair=None) -> dict:
    """{label: bytes}: the two settings compared, the first the reference."""
    if pair is not None:
        return {_size(int(b)): int(b) for b in pair}
    sys.path.insert(0, ROOT)
    from ppr_jax._devices import DERIVATIVE_LOOP_BYTES, SMALL_LOOP_BYTES

    return {f"import ({_size(SMALL_LOOP_BYTES)})": SMALL_LOOP_BYTES,
            f"derivatives ({_size(DERIVATIVE_LOOP_BYTES)})": DERIVATIVE_LOOP_BYTES}


def _jax_version() -> str:
    from importlib.metadata import version

    return version("jax")


def _process(threshold: int, cache: str, quick: bool = False) -> dict:
    env = dict(os.environ, PYTHONPATH=ROOT, EQX_ON_ERROR="nan", JAX_ENABLE_X64="1",
               XLA_FLAGS=("--xla_backend_extra_options="
                          f"xla_cpu_small_while_loop_byte_threshold={threshold}"))
    env.pop("PPR_JAX_CACHE_DIR", None)
    p = subprocess.run([sys.executable, "-c", _CHILD, cache, *(["quick"] if quick else [])],
                       capture_output=True, text=True,
                       env=env, timeout=1800, cwd=ROOT)
    if p.returncode != 0:
        return {"failed": (p.stderr.strip().splitlines() or ["?"])[-1]}
    return json.loads(p.stdout.strip().splitlines()[-1])


def main(repeats: int, pair=None, out: str = OUT, quick: bool = False):
    settings = _settings(pair)
    raw = {name: [] for name in settings}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(repeats):
            for name, threshold in settings.items():
                raw[name].append(_process(threshold, os.path.join(tmp, str(threshold)), quick))
                print(name, raw[name][-1], flush=True)
    names = list(settings)
    rows = []
    for q in raw[names[0]][0]:
        row = {"quantity": q}
        for name in names:
            vals = [r[q] for r in raw[name] if q in r]
            row[name] = {"min": min(vals), "median": statistics.median(vals)}
        row["second / first (min)"] = row[names[1]]["min"] / row[names[0]]["min"]
        row["second / first (median)"] = row[names[1]]["median"] / row[names[0]]["median"]
        rows.append(row)
    db = {"what": f"XLA's small-loop threshold: {names[1]} against {names[0]}, interleaved "
                  "processes (module docstring of benchmarks/loop_threshold.py)",
          "machine": {"system": platform.platform(), "cpus": os.cpu_count(),
                      "jax": _jax_version(), "date": time.strftime("%Y-%m-%d")},
          "settings": settings, "repeats": repeats, "rows": rows, "raw": raw,
          "wall_s": time.perf_counter() - t0,
          "command": "python benchmarks/loop_threshold.py --repeats " + str(repeats)
                     + (f" --bytes {pair[0]} {pair[1]}" if pair else "")
                     + ("" if out == OUT else f" --out {os.path.relpath(out, ROOT)}")}
    os.makedirs(os.path.dirname(out), exist_ok=True)
    with open(out, "w") as f:
        json.dump(db, f, indent=1)
    for r in rows:
        print(f"{r['quantity']:48s} {r['second / first (min)']:.2f} "
              f"{r['second / first (median)']:.2f}")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--bytes", nargs=2, default=None, metavar=("A", "B"),
                    help="two thresholds (bytes) instead of the import's and derivatives'")
    ap.add_argument("--quick", action="store_true",
                    help="one short L0 run per process: checks that the script runs, measures "
                         "nothing of interest")
    ap.add_argument("--out", default=OUT)
    a = ap.parse_args()
    main(a.repeats, a.bytes, os.path.abspath(a.out), a.quick)
