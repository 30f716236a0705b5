"""Explicit (Tsit5) vs implicit (Kvaerno5) integration of the L3 `beam` model.

Scene: the start of paper-circle (torque-driven by L1's inverse-dynamics torques from the
quasi-static state, t = 0.3 mm) over [0, T] (default T = 0.1 s), N elements per strip.
For each solver and tolerance rtol (atol = rtol/100): accepted+rejected steps, wall time
(compiled once per solver, then min of `--repeats` timed runs, block_until_ready) and the error
of the platform pose against a tight reference (Tsit5, rtol 1e-10), max over the output times.
Compare the solvers at matched error. Optionally a strip damping c_spring (MODEL.md section 1)
that damps the strips' fast modes: `--c-spring`.

Writes benchmarks/results/beam_stiffness.json and .png.
Run: python benchmarks/beam_stiffness.py [--n 8 16] [--t-end 0.1]
"""

from __future__ import annotations

import argparse
import json
import pathlib
import time

import jax
import numpy as np

import ppr_jax as pj
from ppr_jax._models.beam import Beam
from ppr_jax._simulate import get_solver

OUT = pathlib.Path(__file__).parent / "results"
#: reference tolerance (tighter makes the step controller fight the rounding noise of the
#: accelerations: segment inertias of 1e-9 kg m^2 beside a 0.2 kg platform)
REF_RTOL = 1e-10


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[8])
    ap.add_argument("--t-end", type=float, default=0.1)
    ap.add_argument("--rtols", type=float, nargs="+", default=[1e-4, 1e-6, 1e-8])
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--c-spring", type=float, default=0.0)
    ap.add_argument("--solvers", nargs="+", default=["tsit5", "kvaerno5"])
    args = ap.parse_args()
    OUT.mkdir(parents=True, exist_ok=True)
    params = pj.RobotParams(c_spring=args.c_spring)
    results = dict(t_end_s=args.t_end, c_spring=args.c_spring, device=str(jax.devices()[0]),
                   runs={})


    for N in args.n:
        m = Beam(N)
        runs = {}
        for sname in args.solvers:
            solver = get_solver(sname)

            def run(rtol):
                # The public scene (jitted once per model and solver; tolerances are arrays).
                # A solver that fails is recorded, not raised: the result code says why.
                res = pj.paper_circle(
                    params, model=m, solver=solver, rtol=rtol, atol=rtol / 100,
                    t_end=args.t_end, n_out=21, max_steps=2_000_000, throw=False,
                )
                jax.block_until_ready(res.z)
                return res, res

            t0 = time.perf_counter()
            run(1e-4)
            t_compile = time.perf_counter() - t0
            print(f"N={N} {sname}: compiled and ran once in {t_compile:.1f} s", flush=True)

            if sname == "tsit5":
                sol, out = run(REF_RTOL)
                ref = np.asarray(out.X)
                runs["reference"] = dict(solver="tsit5", rtol=REF_RTOL, steps=int(sol.num_steps),
                                         result=str(sol.result))
            runs[sname] = dict(compile_s=t_compile, rows=[])
            for rtol in args.rtols:
                times = []
                for _ in range(args.repeats):
                    t0 = time.perf_counter()
                    sol, out = run(rtol)
                    times.append(time.perf_counter() - t0)
                runs[sname]["rows"].append(dict(
                    rtol=rtol, steps=int(sol.num_steps), accepted=int(sol.num_accepted),
                    rejected=int(sol.num_rejected), wall_s=min(times),
                    result=str(sol.result), X=np.asarray(out.X),
                ))
                print(N, sname, rtol, int(sol.num_steps), min(times), flush=True)
        for sname in args.solvers:
            for r in runs[sname]["rows"]:
                X = r.pop("X")
                r["pose_error_max_m"] = float(np.abs(X[:, :2] - ref[:, :2]).max())
                r["phi_error_max_rad"] = float(np.abs(X[:, 2] - ref[:, 2]).max())
        results["runs"][f"N={N}"] = runs
        print(json.dumps(runs, indent=1), flush=True)

    (OUT / "beam_stiffness.json").write_text(json.dumps(results, indent=1))

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(11, 4.5))
    for N, runs in results["runs"].items():
        for j, sname in enumerate(args.solvers):
            rows = runs[sname]["rows"]
            err = [max(r["pose_error_max_m"], 1e-16) for r in rows]
            ax[0].loglog(err, [r["wall_s"] for r in rows], "o-", label=f"{N} {sname}")
            ax[1].loglog(err, [r["steps"] for r in rows], "o-", label=f"{N} {sname}")
    for a, lab in zip(ax, ["wall time (s)", "steps"]):
        a.set_xlabel("max platform position error vs reference (m)")
        a.set_ylabel(lab)
        a.legend(fontsize=8)
    fig.suptitle(f"L3 paper-circle start, {args.t_end} s, c_spring = {args.c_spring}")
    fig.tight_layout()
    fig.savefig(OUT / "beam_stiffness.png", dpi=110)
    print("wrote", OUT / "beam_stiffness.json")


if __name__ == "__main__":
    main()
