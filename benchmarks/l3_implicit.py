"""Work-precision of explicit (Tsit5) against implicit (Kvaerno5, Kvaerno3) solvers on the full L3.

paper-circle (t = 0.3 mm, `pj.scene_params("paper-circle")`, L1's centre-line torques) over the
first T seconds, with the full L3 (`pj.Beam(N, strip_loss=tau)`: strip inertia and modes kept,
stiff) at N = 8 (N = 16 is an option: not measured, its Kvaerno5 compilation alone was
out of reach of the first session's budget), undamped strips (tau = 0, the default) and
Kelvin-Voigt strips (tau = 1e-5 s: damping ratio tau omega / 2 = 0.075 for the first strip mode,
2.4 kHz at N = 8 and 2.6 kHz at N = 16, 3e-4 for the robot's 10 Hz mode). `run_scene` starts
every run from the consistent quasi-static state (`quasi_static_core`: strips in equilibrium,
velocities of the quasi-static motion), so the strip modes are excited only by the motion itself.

Error: the largest platform position distance over the n_out output times against a reference of
the same model: Dopri8 at rtol 1e-9, atol 1e-11 (`--ref-solver`, `--ref-rtol`; `--ref-check` also
runs Tsit5 at that tolerance and stores the distance between the two). Kvaerno5 at rtol 1e-10 was
the first choice but did not finish 5 ms at N = 8 in 6 minutes, and Dopri8 at rtol 1e-10 takes
9400 steps (29 s) per 2 ms: the rounding noise of the accelerations (segment inertias of
1e-9 kg m^2 beside a 0.2 kg platform) keeps the step controller busy below rtol ~1e-9.
atol = rtol / 100 for every run. Timing: `run_scene` compiles ahead of time (`compile_s`,
lowering and XLA compilation) and then times the run alone after `block_until_ready` (`run_s`);
tolerances are arrays, so one compilation serves every rtol of a solver, and a run shorter than
5 s is repeated once (the faster counts). The difference between the full and the quasi-static
L3 (`pj.QuasiStaticBeam(N)`, Tsit5 rtol 1e-10) over the window is stored per (N, tau).

Implicit solver settings: diffrax's Kvaerno5/Kvaerno3 with their default root finder, a
`VeryChord` (one Jacobian of the vector field per step, simplified Newton iterations, LU by
lineax's AutoLinearSolver) that takes its tolerances from the step-size controller. optimistix
Newton (a Jacobian per iteration) can only cost more per step, and the Jacobian (forward mode
through the equations of motion, 2n = 54 / 102 directions) dominates the cost of a step, so the
chord method was kept without a timed comparison (`--root newton` runs the alternative).

Options let the script run in parts (each part merges its rows into the JSON, a row per
(N, tau, solver, rtol, T); the reference per (N, tau, T) is kept and reused):
  python benchmarks/l3_implicit.py --elements 8 --losses 0,1e-5 --solvers kvaerno5 --rtols 1e-4,1e-6
Writes benchmarks/results/l3_implicit.json and .png (--plot-only redraws the figure).
"""

from __future__ import annotations

import argparse
import pathlib

import diffrax
import numpy as np
import optimistix as optx
from _common import label_axes, load_json, parse_or_plot, save_figure, save_json, upsert

import ppr_jax as pj

OUT = pathlib.Path(__file__).parent / "results"
JSON = OUT / "l3_implicit.json"
PNG = OUT / "l3_implicit.png"


def solver_of(name: str, root: str):
    if name.startswith("kvaerno") and root == "newton":
        cls = {"kvaerno5": diffrax.Kvaerno5, "kvaerno3": diffrax.Kvaerno3}[name]
        return cls(root_finder=optx.Newton(rtol=1e-8, atol=1e-10))
    return name


def load():
    return load_json(JSON, {"references": [], "quasi_static": [], "runs": []})


def save(db):
    save_json(JSON, db)


def run(params, model, t_end, n_out, solver, rtol, atol, max_steps):
    """(report, timing): timing = {compile_s of the first call, run_s the fastest run}."""
    kw = dict(model=model, t_end=t_end, n_out=n_out, solver=solver, rtol=rtol, atol=atol,
              max_steps=max_steps)
    r = pj.run_scene("paper-circle", params, **kw)
    timing = dict(r.timing)
    if timing["run_s"] < 5:  # warm: once more, the faster run counts
        timing["run_s"] = min(timing["run_s"], pj.run_scene("paper-circle", params, **kw)
                              .timing["run_s"])
    return r, timing


def dist(Xa, Xb):
    Xa, Xb = np.asarray(Xa), np.asarray(Xb)
    return float(np.max(np.hypot(*(Xa[:, :2] - Xb[:, :2]).T)))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--elements", default="8")
    ap.add_argument("--t-end", type=float, default=0.01)
    ap.add_argument("--n-out", type=int, default=101)
    ap.add_argument("--losses", default="0,1e-5")
    ap.add_argument("--solvers", default="tsit5,kvaerno5")
    ap.add_argument("--rtols", default="1e-5,1e-6,1e-7,1e-8")
    ap.add_argument("--root", default="verychord", choices=["verychord", "newton"])
    ap.add_argument("--ref-solver", default="dopri8")
    ap.add_argument("--ref-rtol", type=float, default=1e-9)
    ap.add_argument("--ref-check", action="store_true",
                    help="also run Tsit5 at the reference tolerance and compare")
    ap.add_argument("--no-quasi-static", action="store_true")
    ap.add_argument("--max-steps", type=int, default=4_000_000)
    args, db = parse_or_plot(ap, load, plot)
    if args is None:
        return
    params = pj.scene_params("paper-circle")
    T, n_out = args.t_end, args.n_out
    for N in (int(n) for n in args.elements.split(",")):
        for tau in (float(v) for v in args.losses.split(",")):
            model = pj.Beam(N, strip_loss=tau)
            key = dict(N=N, strip_loss_s=tau, t_end_s=T, n_out=n_out)
            ref = next((r for r in db["references"]
                        if all(r.get(k) == v for k, v in key.items())), None)
            if ref is None:
                r, tm = run(params, model, T, n_out, args.ref_solver, args.ref_rtol,
                              args.ref_rtol / 100, args.max_steps)
                ref = dict(key, solver=args.ref_solver, rtol=args.ref_rtol,
                           X=np.asarray(r.result.X).tolist(), run_s=tm["run_s"],
                           compile_s=tm["compile_s"], steps=int(r.result.num_steps))
                upsert(db["references"], ref, list(key))
                save(db)
                print(f"reference N={N} tau={tau:g}: {ref['steps']} steps, run "
                      f"{ref['run_s']:.1f} s, compile {ref['compile_s']:.1f} s", flush=True)
            Xref = np.asarray(ref["X"])
            if args.ref_check:
                r, tm = run(params, model, T, n_out, "tsit5", args.ref_rtol,
                              args.ref_rtol / 100, args.max_steps)
                ref["tsit5_check"] = dict(rtol=args.ref_rtol, distance_m=dist(r.result.X, Xref),
                                          run_s=tm["run_s"],
                                          steps=int(r.result.num_steps))
                save(db)
                print(f"  reference check (Tsit5 rtol {args.ref_rtol:g}): distance "
                      f"{ref['tsit5_check']['distance_m']:.3g} m", flush=True)
            if not args.no_quasi_static and not any(
                    all(q.get(k) == v for k, v in key.items()) for q in db["quasi_static"]):
                r, tm = run(params, pj.QuasiStaticBeam(N), T, n_out, "tsit5", 1e-10, 1e-12,
                              args.max_steps)
                q = dict(key, full_minus_quasi_static_max_m=dist(r.result.X, Xref),
                         phi_difference_max_rad=float(np.max(np.abs(
                             np.asarray(r.result.X)[:, 2] - Xref[:, 2]))),
                         run_s=tm["run_s"], compile_s=tm["compile_s"],
                         steps=int(r.result.num_steps))
                upsert(db["quasi_static"], q, list(key))
                save(db)
                print(f"  full - quasi-static: {q['full_minus_quasi_static_max_m']:.3g} m "
                      f"(quasi-static run {q['run_s']:.2f} s)", flush=True)
            for s in args.solvers.split(","):
                for rtol in (float(v) for v in args.rtols.split(",")):
                    solver = solver_of(s, args.root)
                    try:
                        r, tm = run(params, model, T, n_out, solver, rtol, rtol / 100,
                                      args.max_steps)
                    except pj.PPRError as err:
                        print(f"  {s} rtol {rtol:g} failed: {err}", flush=True)
                        continue
                    row = dict(key, solver=s if args.root == "verychord" or s == "tsit5"
                               else f"{s}-newton", rtol=rtol, atol=rtol / 100,
                               error_m=dist(r.result.X, Xref), run_s=tm["run_s"],
                               compile_s=tm["compile_s"], steps=int(r.result.num_steps),
                               rejected=int(r.result.num_rejected))
                    upsert(db["runs"], row, list(key) + ["solver", "rtol"])
                    save(db)
                    print(f"  N={N} tau={tau:g} {row['solver']} rtol {rtol:g}: error "
                          f"{row['error_m']:.3g} m, run {row['run_s']:.2f} s, "
                          f"{row['steps']} steps, compile {row['compile_s']:.1f} s", flush=True)
    plot(db)


def plot(db):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = [r for r in db["runs"] if "run_s" in r]  # not the runs that did not finish
    Ns = sorted({r["N"] for r in runs})
    if not Ns:
        return
    fig, axes = plt.subplots(1, len(Ns), figsize=(5.5 * len(Ns), 4.2), squeeze=False)
    for ax, N in zip(axes[0], Ns):
        groups = sorted({(r["solver"], r["strip_loss_s"], r["t_end_s"]) for r in runs
                         if r["N"] == N})
        for s, tau, T in groups:
            rr = sorted((r for r in runs if (r["N"], r["solver"], r["strip_loss_s"],
                                              r["t_end_s"]) == (N, s, tau, T)),
                        key=lambda r: r["rtol"])
            x = [r["run_s"] for r in rr]
            y = [max(r["error_m"], 1e-14) for r in rr]
            ls = "-" if tau == 0 else "--"
            mk = {"tsit5": "o", "kvaerno5": "s", "kvaerno3": "^"}.get(s, "x")
            ax.loglog(x, y, ls, marker=mk, label=f"{s}, tau={tau:g} s, T={T:g} s")
            for r in rr:
                ax.annotate(f"{r['rtol']:.0e}", (r["run_s"], max(r["error_m"], 1e-14)),
                            fontsize=6, alpha=0.7)
        label_axes(ax, "run time (s, after compilation)", "max platform position error (m)",
                   f"full L3, N = {N}, paper-circle", legend_size=7)
    save_figure(fig, PNG)


if __name__ == "__main__":
    main()
