"""Benchmark the `paper-circle` scene: compile time, run time, steps and error against a
tight-tolerance reference, for every model level and solver; and batched (vmapped) throughput.

Protocol: compile ahead of time (timed separately), warm up, then the minimum of `REPEATS` runs
with `block_until_ready`. Solvers are compared at matched error (the work-precision plot), not at
matched tolerance. Writes benchmarks/results/paper_circle.json and paper_circle_work_precision.png.

Run: python benchmarks/bench_paper_circle.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import platform

import jax
import numpy as np

import ppr_jax as pj

HERE = os.path.dirname(os.path.abspath(__file__))
OUT = os.path.join(HERE, "results")
REPEATS = 5


def run_case(model, params, solver, rtol):
    r = pj.run_scene("paper-circle", params, model=model, solver=solver, rtol=rtol,
                     atol=rtol * 1e-2, max_steps=400_000, repeats=REPEATS)
    return r.result, r.timing["compile_s"], r.timing["run_s"]


def main(quick: bool):
    os.makedirs(OUT, exist_ok=True)
    params = pj.scene_params("paper-circle")
    tols = [1e-4, 1e-6, 1e-8, 1e-10] if not quick else [1e-6, 1e-8]
    solvers = ["tsit5", "dopri8"]
    models = ["reduced", "double1r", "rigid"]
    results = {"machine": platform.processor() or platform.machine(), "jax": jax.__version__,
               "devices": [str(d) for d in jax.devices()], "cases": [], "batched": []}
    for mname in models:
        ref, _, _ = run_case(mname, params, "dopri8", 1e-13)
        compiled_once = {}
        for solver in solvers:
            for rtol in tols:
                sol, tc, tr = run_case(mname, params, solver, rtol)
                compiled_once.setdefault(solver, tc)
                err = float(np.linalg.norm(sol.X[:, :2] - ref.X[:, :2], axis=-1).max())
                case = {
                    "model": mname, "solver": solver, "rtol": rtol, "atol": rtol * 1e-2,
                    "compile_s": tc, "run_s": tr, "steps": int(sol.num_steps),
                    "rejected": int(sol.num_rejected), "error_vs_reference_m": err,
                }
                results["cases"].append(case)
                print(json.dumps(case))
    save(results)
    # Batched throughput: vmap over thickness, L1 and L2 at rtol 1e-8.
    for mname, sizes in (("reduced", [8, 64]), ("double1r", [8])):
        for B in (sizes if not quick else [8]):
            batch = pj.stack_params([params.replace(t=float(t)) for t in np.linspace(0.28e-3, 0.4e-3, B)])
            r = pj.run_scene("paper-circle", batch, model=mname, solver="tsit5", rtol=1e-8,
                             atol=1e-10, max_steps=400_000, repeats=3)
            tc, tr = r.timing["compile_s"], r.timing["run_s"]
            row = {"model": mname, "batch": B, "compile_s": tc, "run_s": tr,
                   "per_robot_ms": tr / B * 1e3}
            results["batched"].append(row)
            print(json.dumps(row))
            save(results)
    plot(results)


def save(results):
    with open(os.path.join(OUT, "paper_circle.json"), "w") as f:
        json.dump(results, f, indent=2)


def plot(results):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    for mname in sorted({c["model"] for c in results["cases"]}):
        for solver, mk in (("tsit5", "o-"), ("dopri8", "s--")):
            cs = [c for c in results["cases"] if c["model"] == mname and c["solver"] == solver]
            if cs:
                ax.loglog([max(c["error_vs_reference_m"], 1e-16) for c in cs],
                          [c["run_s"] * 1e3 for c in cs], mk, label=f"{mname} {solver}")
    ax.set_xlabel("max position error vs reference (m)")
    ax.set_ylabel("run time after compilation (ms)")
    ax.set_title("paper-circle work-precision (CPU)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(OUT, "paper_circle_work_precision.png"), dpi=120)


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    main(ap.parse_args().quick)
