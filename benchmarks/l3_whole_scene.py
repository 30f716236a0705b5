"""The full L3 (strips with their own inertia) over a whole scene, against the quasi-static L3.

paper-circle (7.54 s, `pj.scene_params("paper-circle")`, L1's torques) or servo-circle (the
angles of L1's inverse kinematics, `--scene servo-circle`) with `pj.Beam(N, strip_loss=tau)`
from the library's start (the quasi-static state with the strips moved onto their slow path,
`quasi_static_state`), by the stiff solvers (`kvaerno5-kept`, the full L3's default,
`kvaerno5` and `ros34pw2`), against the quasi-static L3 (`pj.QuasiStaticBeam(N)`, its default
Dopri8 at rtol 1e-8). Per run: the run and compile times (`run_scene`'s timing, the run after
compilation), steps and rejected steps, the largest relative change of a trajectory metric
against the quasi-static L3 (the metrics of `benchmarks/l3_validation.py`), and the largest
platform distance between the two. The figure shows what the strips' own dynamics adds: the
full L3's platform position and phi minus the quasi-static L3's over the scene (at rtol 1e-4
each solver's own error is part of it: the two solvers differ by about half the distance).

    python benchmarks/l3_whole_scene.py --elements 16 --solvers kvaerno5,ros34pw2 --rtols 1e-4

Writes benchmarks/results/l3_whole_scene.json and
l3_whole_scene.png (--plot-only redraws it from the saved traces); rows are merged per (scene,
N, tau, solver, rtol).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from _common import parse_or_plot, upsert  # noqa: E402

import ppr_jax as pj  # noqa: E402
from benchmarks.l3_validation import METRICS  # noqa: E402
from benchmarks.run import machine  # noqa: E402

OUT = pathlib.Path(__file__).parent / "results"
JSON = OUT / "l3_whole_scene.json"
PNG = OUT / "l3_whole_scene.png"
SCENE = "paper-circle"
T_END = 7.54
N_OUT = 755


def load() -> dict:
    db = json.loads(JSON.read_text()) if JSON.exists() else {"quasi_static": [], "runs": []}
    for row in db["quasi_static"] + db["runs"]:
        row.setdefault("scene", "paper-circle")
    return db


def metrics(report) -> dict:
    return {k: float(report.metrics[k]) for k in METRICS}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default=SCENE, choices=["paper-circle", "servo-circle"])
    ap.add_argument("--elements", default="16")
    ap.add_argument("--losses", default="0")
    ap.add_argument("--solvers", default="ros34pw2,kvaerno5")
    ap.add_argument("--rtols", default="1e-4")
    ap.add_argument("--max-steps", type=int, default=400_000)
    args, db = parse_or_plot(ap, load, plot)
    if args is None:
        return
    db["machine"] = machine(False)
    scene = args.scene
    params = pj.scene_params(scene)
    for N in (int(n) for n in args.elements.split(",")):
        # the baseline's run is short and its timing noisy: the fastest of three
        qs = pj.run_scene(
            scene,
            params,
            model=pj.QuasiStaticBeam(N),
            repeats=3,
            options=pj.SceneOptions(t_end=T_END, n_out=N_OUT),
        )
        qrow = dict(scene=scene, N=N, solver=qs.solver["name"], rtol=qs.solver["rtol"],
                    run_s=qs.timing["run_s"], compile_s=qs.timing["compile_s"],
                    steps=int(qs.result.num_steps), metrics=metrics(qs),
                    X=np.asarray(qs.X).tolist(), end_rot=np.asarray(qs.end_rot).tolist())
        upsert(db["quasi_static"], qrow, ["scene", "N"])
        print(f"quasi-static N={N}: run {qrow['run_s']:.2f} s, {qrow['steps']} steps",
              flush=True)
        for tau in (float(v) for v in args.losses.split(",")):
            for s in args.solvers.split(","):
                for rtol in (float(v) for v in args.rtols.split(",")):
                    opts = pj.SceneOptions(t_end=T_END, n_out=N_OUT, solver=s, rtol=rtol,
                                           atol=rtol / 100, max_steps=args.max_steps)
                    r = pj.run_scene(scene, params, model=pj.Beam(N, strip_loss=tau),
                                     options=opts)
                    m = metrics(r)
                    dev = max(abs(m[k] - qrow["metrics"][k]) / abs(qrow["metrics"][k])
                              for k in METRICS)
                    dX = np.asarray(r.X) - np.asarray(qs.X)
                    row = dict(scene=scene, N=N, strip_loss_s=tau, solver=s, rtol=rtol,
                               atol=rtol / 100,
                               run_s=r.timing["run_s"], compile_s=r.timing["compile_s"],
                               steps=int(r.result.num_steps),
                               rejected=int(r.result.num_rejected),
                               run_over_quasi_static=r.timing["run_s"] / qrow["run_s"],
                               metrics=m, metrics_max_relative_deviation=dev,
                               platform_distance_max_m=float(np.max(np.hypot(*dX[:, :2].T))),
                               phi_difference_max_rad=float(np.max(np.abs(dX[:, 2]))),
                               X=np.asarray(r.X).tolist(),
                               end_rot=np.asarray(r.end_rot).tolist())
                    upsert(db["runs"], row, ["scene", "N", "strip_loss_s", "solver", "rtol"])
                    OUT.mkdir(parents=True, exist_ok=True)
                    JSON.write_text(json.dumps(db, indent=1))
                    print(f"  {scene} full N={N} tau={tau:g} {s} rtol {rtol:g}: "
                          f"run {row['run_s']:.1f} s"
                          f" ({row['run_over_quasi_static']:.1f} x quasi-static), compile "
                          f"{row['compile_s']:.0f} s, {row['steps']} steps "
                          f"({row['rejected']} rejected), metrics within {100 * dev:.3g} %, "
                          f"platform within {row['platform_distance_max_m']:.2e} m", flush=True)
    plot(db)


def plot(db):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ts = np.linspace(0.0, T_END, N_OUT)
    fig, (a1, a2, a3) = plt.subplots(3, 1, figsize=(7.5, 7.5), sharex=True)
    for r in db["runs"]:
        q = next(q for q in db["quasi_static"]
                 if (q["scene"], q["N"]) == (r["scene"], r["N"]))
        dX = np.asarray(r["X"]) - np.asarray(q["X"])
        label = (f"{r['scene']}, N = {r['N']}, tau = {r['strip_loss_s']:g} s, {r['solver']} "
                 f"rtol {r['rtol']:g}")
        (line,) = a1.plot(ts, 1e6 * np.hypot(*dX[:, :2].T), lw=0.8, label=label)
        a2.plot(ts, 1e6 * dX[:, 2], lw=0.8, color=line.get_color())
        if "end_rot" in r and "end_rot" in q:
            # the strips' own bending where it shows: chain 1's joint-end rotations
            dE = np.asarray(r["end_rot"]) - np.asarray(q["end_rot"])
            a3.plot(ts, 1e3 * (dE[:, 0] - dE[:, 1]), lw=0.8, color=line.get_color())
    a1.set_ylabel("platform distance (um)")
    a2.set_ylabel("phi difference (urad)")
    a3.set_ylabel("end-rotation difference,\nchain 1 (mrad)")
    a3.set_xlabel("t (s)")
    a1.set_title("full L3 minus quasi-static L3: what the strips' own dynamics adds")
    a1.legend(fontsize=7)
    for a in (a1, a2, a3):
        a.grid(True, alpha=0.3)
    fig.tight_layout()
    OUT.mkdir(parents=True, exist_ok=True)
    fig.savefig(PNG, dpi=120)


if __name__ == "__main__":
    main()
