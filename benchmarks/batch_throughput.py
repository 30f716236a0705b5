"""Per-robot cost of a batch against single calls: the L1 (and optionally L2) `paper-circle`.

For each batch size B the scene runs on B robots (strip thickness spread over 0.28-0.40 mm) in
one compiled vmapped call (`ppr_jax.paper_circle` with stacked parameters); the single-robot cost
is the same scene on one robot. Compilation is timed apart (first call minus fastest run); run
times are the minimum of `--repeats` runs after `block_until_ready`. Writes
benchmarks/results/batch_throughput.json.

Run: python benchmarks/batch_throughput.py [--models reduced double1r] [--sizes 1 8 64 256]
"""

from __future__ import annotations

import argparse
import json
import os
import platform

import jax
import numpy as np

import ppr_jax as pj

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="+", default=["reduced"])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1, 8, 64, 256])
    ap.add_argument("--rtols", type=float, nargs="+", default=[1e-6, 1e-8])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--t-end", type=float, default=7.54)
    args = ap.parse_args()
    os.makedirs(OUT, exist_ok=True)
    base = pj.scene_params("paper-circle")
    rows = []
    out = {"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
           "jax": jax.__version__, "backend": jax.default_backend(), "t_end_s": args.t_end,
           "rows": rows}
    for model in args.models:
        for rtol in args.rtols:
            for B in args.sizes:
                ts = np.linspace(0.28e-3, 0.40e-3, B)
                params = (base.replace(t=float(ts[0])) if B == 1 else
                          pj.stack_params([base.replace(t=float(t)) for t in ts]))
                r = pj.run_scene("paper-circle", params, model=model, rtol=rtol, atol=rtol * 1e-2,
                                 t_end=args.t_end, repeats=args.repeats, max_steps=400_000)
                row = dict(model=model, rtol=rtol, batch=B, compile_s=r.timing["compile_s"],
                           run_s=r.timing["run_s"], per_robot_ms=r.timing["run_s"] / B * 1e3,
                           trajectories_per_s=B / r.timing["run_s"])
                rows.append(row)
                print(json.dumps(row), flush=True)
                with open(os.path.join(OUT, "batch_throughput.json"), "w") as f:
                    json.dump(out, f, indent=2)


if __name__ == "__main__":
    main()
