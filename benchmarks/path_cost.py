"""Cost per step of a path from a file against the circle: the paper's circle, `PathScene` on
`Circle()`, and `PathScene` on the circle sampled at 100 Hz, written as a CSV file and read back
with `load_path` (a C2 cubic spline, natural ends: its input table has a panel boundary at
every knot, and the integrator steps to every knot), torque- and motion-driven, L2 (`double1r`)
and L0 (`rigid`), over the scenes' default horizon (7.54 s, 755 outputs, default tolerances).

Timed: compilation apart (ahead of time, as `run_scene` compiles), a warm-up run, then
`--repeats` rounds that run every program once each (interleaved, so that a loaded machine's
drift hits every row alike), after `block_until_ready`; `run_s` the fastest. Per step: run
seconds / accepted steps. A motion-driven L0 is forward kinematics and inverse dynamics alone
(no integrator, no steps): its row gives the run time only. `input_s`: the scene's input
alone (`AbstractScene.commands`, compiled apart and timed in the same rounds), built once per
run; `per_step_after_input_s`: (run - input) / accepted steps, what each step costs. Writes
benchmarks/results/path_cost.json.

Run: python benchmarks/path_cost.py [--repeats 5] [--models double1r rigid]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time

import jax
import jax.numpy as jnp
import numpy as np

import ppr_jax as pj

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")
#: the circle's samples in the file (Hz) and the horizon (s)
RATE_HZ = 100.0
T_END = 7.54
N_OUT = 755


def circle_file(directory: str) -> str:
    """The paper's circle sampled at RATE_HZ over [0, T_END], as a CSV file of poses (SI)."""
    ts = np.arange(0.0, T_END + 0.5 / RATE_HZ, 1.0 / RATE_HZ)
    X = np.asarray(jax.vmap(pj.Circle())(jnp.asarray(ts)))
    path = os.path.join(directory, "circle_100hz.csv")
    np.savetxt(path, np.column_stack([ts, X]), delimiter=",", header="time,x,y,phi",
               comments="", fmt="%.17g")
    return path


def scenes(directory: str) -> dict:
    """{label: {drive: scene}}."""
    f = pj.load_path(circle_file(directory), bc="natural")
    return {
        "paper circle": {"torque": "paper-circle", "motion": "servo-circle"},
        "PathScene(Circle())": {d: pj.PathScene(pj.Circle(), drive=d) for d in ("torque",
                                                                                 "motion")},
        "PathScene(load_path, 100 Hz)": {d: pj.PathScene(f, drive=d) for d in ("torque",
                                                                                "motion")},
    }


def compiled(scene, model: str):
    """(run, compile seconds): the scene's program for `model` at the horizon, compiled ahead
    of time (as `run_scene` compiles it, without a program store)."""
    from ppr_jax._programs import compiled_program
    from ppr_jax._scenes._registry import get_scene
    from ppr_jax._scenes._run import prepare

    scene = get_scene(scene)
    options = pj.SceneOptions(t_end=T_END, n_out=N_OUT)
    c = prepare(scene, scene.default_params(), model, options)
    t0 = time.perf_counter()
    fn, _ = compiled_program(c.fn, c.args, c.template(), None, scene.name)
    return (lambda: fn(*c.args)), time.perf_counter() - t0


def input_program(scene, model: str):
    """The scene's input alone (`AbstractScene.commands`: the table of the input model's
    torques or angles along the path, with its checks), compiled: a call builds it once, as
    the scene's program does at the start of every run."""
    import equinox as eqx

    from ppr_jax._models import get_model
    from ppr_jax._robot import as_robot
    from ppr_jax._scenes._options import input_panels_at
    from ppr_jax._scenes._registry import get_scene

    scene = get_scene(scene)
    mdl = get_model(model)
    robot = as_robot(scene.default_params())
    traj = scene.trajectory()
    ts = jnp.linspace(0.0, T_END, N_OUT)
    panels = input_panels_at(traj, ts)
    fn = eqx.filter_jit(lambda robot, ts: scene.commands(mdl, robot, traj, ts, panels))
    jax.block_until_ready(fn(robot, ts))
    return lambda: fn(robot, ts)


def timed(run) -> float:
    t0 = time.perf_counter()
    jax.block_until_ready(run())
    return time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--models", nargs="*", default=["double1r", "rigid"])
    ap.add_argument("--out", default="path_cost.json")
    args = ap.parse_args()
    rows, runs, inputs = [], [], []
    with tempfile.TemporaryDirectory() as d:
        for label, by_drive in scenes(d).items():
            for drive, scene in by_drive.items():
                for model in args.models:
                    run, compile_s = compiled(scene, model)
                    res = run()  # warm-up, and the steps
                    jax.block_until_ready(res)
                    steps = int(res.num_accepted)
                    rows.append({"scene": label, "drive": drive, "model": model,
                                 "ok": bool(res.result == pj.RESULTS.successful),
                                 "compile_s": compile_s, "accepted_steps": steps,
                                 "rejected_steps": int(res.num_rejected)})
                    runs.append(run)
                    inputs.append(input_program(scene, model))
                    print(rows[-1], flush=True)
    # Interleaved: every program once per round, the fastest of the rounds (a loaded machine's
    # drift hits every row alike)
    best = [float("inf")] * len(rows)
    best_input = [float("inf")] * len(rows)
    for _ in range(args.repeats):
        for k, (run, inp) in enumerate(zip(runs, inputs)):
            best[k] = min(best[k], timed(run))
            best_input[k] = min(best_input[k], timed(inp))
    for row, run_s, input_s in zip(rows, best, best_input):
        row["run_s"] = run_s
        row["input_s"] = input_s
        steps = row["accepted_steps"]
        row["per_step_s"] = run_s / steps if steps else None
        # what a step costs once the input is built (its table is built once per run)
        row["per_step_after_input_s"] = (run_s - input_s) / steps if steps else None
    for row in rows:  # the cost per step against the paper circle's, same drive and model
        base = next(r for r in rows if r["scene"] == "paper circle"
                    and r["drive"] == row["drive"] and r["model"] == row["model"])
        for key, ratio in (("per_step_s", "per_step_vs_paper"),
                           ("per_step_after_input_s", "per_step_after_input_vs_paper")):
            row[ratio] = row[key] / base[key] if row[key] and base[key] else None
        row["run_vs_paper"] = row["run_s"] / base["run_s"]
    out = {
        "machine": {"date": time.strftime("%Y-%m-%d"), "machine": platform.machine(),
                    "cpus": os.cpu_count(), "backend": jax.default_backend(),
                    "jax": jax.__version__, "load_average": os.getloadavg()},
        "t_end_s": T_END, "n_out": N_OUT, "rate_hz": RATE_HZ, "repeats": args.repeats,
        "rows": rows,
    }
    os.makedirs(OUT, exist_ok=True)
    with open(os.path.join(OUT, args.out), "w") as f:
        json.dump(out, f, indent=1)
    print("wrote", os.path.join(OUT, args.out))


if __name__ == "__main__":
    main()
