"""The benchmark suite: speed against error, on whichever JAX backend is present.

    python benchmarks/run.py [--quick] [--parts work-precision contenders compile batch]

Parts (each writes `benchmarks/results/<backend>/<part>.json` with the machine, backend and
versions, and its figures next to it; `--quick` runs a few minutes in all, the full run is
documented in docs/performance.md with its duration):

- `work-precision`: error against run time for L0, L1, L2 and L3 (quasi-static strips) on
  `paper-circle` and `servo-circle` (L0/L1 need no ODE there: a single point), for Tsit5,
  Dopri5, Dopri8 and Kvaerno5 over a ladder of tolerances. The error of a run is the largest
  platform position error over the output times against the same model run with Dopri8 at
  rtol 1e-12 (the integration error of that model, at its own discretisation); compilation is
  timed apart (once per model and solver: tolerances are arrays, so they do not recompile).
- `contenders`: L2 `paper-circle` in this library, in MuJoCo (an MJCF of the same robot,
  `benchmarks/contenders/mujoco_l2.py`, skipped when MuJoCo is not installed: `pip install
  '.[bench]'`) and in scipy `solve_ivp` (DOP853, Radau, LSODA) on a NumPy right-hand side
  (`benchmarks/contenders/scipy_l2.py`), all against one reference; times compared at matched
  error by log-log interpolation of each contender's work-precision line, never at matched
  tolerance. What each timed number includes is written next to it.
- `compile`: per model, a fresh process compiling the `paper-circle` program without a
  persistent cache, then two processes sharing a fresh cache: the second one's time to its first
  simulated result is what a user waits for on the second `ppr-jax simulate`.
- `batch`: trajectories per second against batch size for L1 and L2 `paper-circle`, at rtol 1e-6
  and 1e-8, against the loop-of-singles cost.

Protocol everywhere: compile ahead of time (timed apart), warm up, then the minimum of
`--repeats` runs, each ending in `block_until_ready`.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import tempfile
import time

import jax
import numpy as np

import ppr_jax as pj

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from benchmarks import plots  # noqa: E402

REF_RTOL = 1e-12
SOLVERS = ("tsit5", "dopri5", "dopri8", "kvaerno5")
L3_ELEMENTS = 8
#: errors (m) at which the contenders' times are compared (2e-5 mm and 1e-7 mm)
MATCHED_ERRORS_M = (2e-8, 1e-10)


def machine(quick: bool) -> dict:
    """Where and with what a result was measured."""
    import diffrax
    import equinox

    return {
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "machine": platform.processor() or platform.machine(),
        "platform": platform.platform(),
        "cpus": os.cpu_count(),
        "backend": jax.default_backend(),
        "devices": [str(d) for d in jax.devices()],
        "python": platform.python_version(),
        "versions": {"jax": jax.__version__, "jaxlib": jax.lib.__version__,
                     "diffrax": diffrax.__version__, "equinox": equinox.__version__,
                     "numpy": np.__version__},
        "quick": quick,
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
    }


def _selected(args, scene, model) -> bool:
    return ((not args.models or model in args.models)
            and (not args.scenes or scene in args.scenes))


def _load(out_dir: str, part: str):
    path = os.path.join(out_dir, f"{part}.json")
    if not os.path.exists(path):
        return None
    with open(path) as f:
        return json.load(f)


def save(out_dir: str, part: str, data: dict) -> str:
    path = os.path.join(out_dir, f"{part}.json")
    with open(path, "w") as f:
        json.dump(data, f, indent=1)
    return path


def model_of(name: str):
    return pj.get_model(name, n_elements=L3_ELEMENTS) if name == "beam" else pj.get_model(name)


def position_error(X, ref_X) -> float:
    """Largest platform position error (m) over the output times."""
    return float(np.linalg.norm(np.asarray(X)[:, :2] - np.asarray(ref_X)[:, :2], axis=-1).max())


def run_point(scene, model, solver, rtol, t_end, n_out, repeats):
    r = pj.run_scene(
        scene,
        pj.scene_params(scene),
        model=model_of(model),
        repeats=repeats,
        options=pj.SceneOptions(
            solver=solver,
            rtol=rtol,
            atol=rtol * 1e-2,
            t_end=t_end,
            n_out=n_out,
            max_steps=1_000_000,
        ),
    )
    return r


# --------------------------------------------------------------------------------------------
def part_work_precision(args, out_dir) -> dict:
    if args.quick:
        t_end, n_out = 1.0, 101
        cases = {"paper-circle": ("rigid", "reduced", "double1r"), "servo-circle": ("double1r",)}
        solvers, rtols = ("tsit5", "dopri8"), (1e-5, 1e-7, 1e-9)
    else:
        t_end, n_out = 7.54, 755
        cases = {"paper-circle": ("rigid", "reduced", "double1r", "beam"),
                 "servo-circle": ("rigid", "reduced", "double1r", "beam")}
        solvers, rtols = SOLVERS, (1e-4, 1e-6, 1e-8, 1e-10)
    data = {"machine": machine(args.quick), "t_end_s": t_end, "n_out": n_out,
            "reference": f"same model, dopri8, rtol {REF_RTOL:g}, atol {REF_RTOL * 1e-2:g}",
            "error": "max over output times of the platform position error (m)",
            "l3_elements": L3_ELEMENTS, "rows": []}
    old = _load(out_dir, "work_precision")
    if (args.models or args.scenes) and old is not None and old.get("t_end_s") == t_end:
        # A run of some models or scenes only (each under the 10 minutes a run may take)
        # replaces their rows and keeps the others'.
        data["rows"] = [r for r in old["rows"] if not _selected(args, r["scene"], r["model"])]
    for scene, models in cases.items():
        for model in models:
            if not _selected(args, scene, model):
                continue
            ode = not (scene == "servo-circle" and model in ("rigid", "reduced"))
            ref = run_point(scene, model, "dopri8", REF_RTOL if ode else 1e-8, t_end, n_out, 1)
            if not ode:
                # No ODE (forward kinematics along the prescribed angles): one point, exact.
                r = run_point(scene, model, "dopri8", 1e-8, t_end, n_out, args.repeats)
                row = dict(scene=scene, model=model, solver="none (no ODE)", rtol=None,
                           compile_s=r.timing["compile_s"], run_s=r.timing["run_s"], steps=0,
                           error_m=0.0)
                data["rows"].append(row)
                print(json.dumps(row), flush=True)
                continue
            for solver in solvers:
                if model == "beam" and solver == "kvaerno5" and args.skip_l3_implicit:
                    continue
                # L3, and Kvaerno5 (an implicit solver on problems that are not stiff: many
                # rejected steps), run seconds per tolerance: a shorter ladder, one timed run.
                slow = model == "beam" or solver == "kvaerno5"
                ladder = tuple(r for r in rtols if r >= 1e-8) if slow else rtols
                for i, rtol in enumerate(ladder):
                    try:
                        r = run_point(scene, model, solver, rtol, t_end, n_out,
                                      1 if slow else args.repeats)
                    except pj.PPRError as e:  # a loose tolerance may fail: say so, keep going
                        row = dict(scene=scene, model=model, solver=solver, rtol=rtol,
                                   failed=str(e).splitlines()[0])
                    else:
                        # Dopri8 compiled with the reference run (tolerances do not recompile).
                        tc = (ref if solver == "dopri8" else r).timing["compile_s"]
                        row = dict(scene=scene, model=model, solver=solver, rtol=rtol,
                                   compile_s=tc if i == 0 else None,
                                   run_s=r.timing["run_s"], steps=int(r.result.num_steps),
                                   rejected=int(r.result.num_rejected),
                                   error_m=position_error(r.X, ref.X))
                    data["rows"].append(row)
                    print(json.dumps(row), flush=True)
                    save(out_dir, "work_precision", data)
    save(out_dir, "work_precision", data)
    plots.work_precision(data, out_dir)
    return data


# --------------------------------------------------------------------------------------------
def part_contenders(args, out_dir) -> dict:
    """L2 paper-circle in this library, MuJoCo and scipy, errors against one reference."""
    from benchmarks.contenders import scipy_l2

    try:
        from benchmarks.contenders import mujoco_l2
    except ImportError as e:  # MuJoCo is the optional `bench` extra
        mujoco_l2, why = None, str(e)
    scene, model = "paper-circle", "double1r"
    params = pj.scene_params(scene)
    t_end, n_out = (1.0, 101) if args.quick else (7.54, 755)
    ref = run_point(scene, model, "dopri8", REF_RTOL, t_end, n_out, 1)
    data = {"machine": machine(args.quick), "scene": scene, "model": model, "t_end_s": t_end,
            "n_out": n_out, "reference": f"ppr_jax L2, dopri8, rtol {REF_RTOL:g}",
            "error": "max over output times of the platform position error (m)",
            "rows": [], "matched": []}

    def add(row):
        data["rows"].append(row)
        print(json.dumps(row), flush=True)
        save(out_dir, "contenders", data)

    # from 1e-3: every method needs a point above the matched errors (2e-8 m) to interpolate
    rtols = (1e-5, 1e-7, 1e-9) if args.quick else (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10)
    for solver in ("tsit5", "dopri5", "dopri8"):
        for i, rtol in enumerate(rtols):
            r = run_point(scene, model, solver, rtol, t_end, n_out, args.repeats)
            add(dict(tool="ppr_jax", method=solver, setting=f"rtol {rtol:g}",
                     run_s=r.timing["run_s"], compile_s=r.timing["compile_s"] if i == 0 else None,
                     error_m=position_error(r.X, ref.X),
                     includes="one compiled call: initial state, torque table, "
                              "integration, output; compilation apart"))
    sp_rtols = {"DOP853": (1e-5, 1e-7, 1e-9) if args.quick else (1e-5, 1e-7, 1e-9, 1e-11),
                "Radau": (1e-5, 1e-7) if args.quick else (1e-5, 1e-7, 1e-9),
                "LSODA": (1e-5, 1e-7) if args.quick else (1e-5, 1e-7, 1e-9)}
    # Both contenders start from the library's initial state (its quasi-static L2 state), taken
    # from the reference run instead of being solved again in each call.
    z0, zd0 = np.asarray(ref.result.z[0]), np.asarray(ref.result.zdot[0])
    for method, rts in sp_rtols.items():
        for rtol in rts:
            o = scipy_l2.run(params, method=method, rtol=rtol, atol=rtol * 1e-2, t_end=t_end,
                             n_out=n_out, repeats=1 if args.quick else 2, z0=z0, zdot0=zd0)
            add(dict(tool="scipy", method=method, setting=f"rtol {rtol:g}", run_s=o["run_s"],
                     error_m=position_error(o["X"], ref.X), nfev=int(o["nfev"]),
                     includes=o["includes"]))
    if mujoco_l2 is None:
        data["skipped"] = f"MuJoCo: {why}"
    else:
        # "midpoint": torque held over a step (MuJoCo's control model), C rollout; "stages":
        # the torque at each RK4 stage through MuJoCo's control callback (a Python step loop).
        dts = {"midpoint": (2e-3, 5e-4, 1e-4) if args.quick else
               (1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 2e-4, 1e-4, 5e-5),
               "stages": (2e-3, 5e-4) if args.quick else (5e-3, 2e-3, 1e-3, 5e-4, 2e-4, 1e-4)}
        for inputs, steps in dts.items():
            for dt in steps:
                o = mujoco_l2.run(params, dt=dt, t_end=t_end, n_out=n_out, inputs=inputs,
                                  repeats=1 if args.quick else 3, initial_state=(z0, zd0))
                add(dict(tool="mujoco", method="RK4" if inputs == "midpoint" else "RK4 stages",
                         setting=f"dt {dt:g}", run_s=o["run_s"],
                         error_m=position_error(o["X"], ref.X), steps=int(o["n_steps"]),
                         includes=o["includes"]))
    data["matched"] = matched_times(data["rows"], MATCHED_ERRORS_M)
    save(out_dir, "contenders", data)
    plots.contenders(data, out_dir)
    return data


def matched_times(rows, errors) -> list:
    """Each tool's fastest time (s) at each target error: per method, log-log interpolation of
    time against error between the two points around the target (None outside its range); per
    tool, the fastest method. Ratios are against ppr_jax."""
    out = []
    for err in errors:
        best = {}
        for tool in sorted({r["tool"] for r in rows}):
            for method in sorted({r["method"] for r in rows if r["tool"] == tool}):
                pts = sorted((r["error_m"], r["run_s"]) for r in rows
                             if r["tool"] == tool and r["method"] == method and r["error_m"] > 0)
                t = _interp_time(pts, err)
                if t is not None and (tool not in best or t < best[tool][1]):
                    best[tool] = (method, t)
        ours = best.get("ppr_jax", (None, None))[1]
        for tool, (method, t) in best.items():
            out.append(dict(error_m=err, tool=tool, method=method, run_s=t,
                            ratio_to_ppr_jax=(t / ours) if ours else None))
    return out


def _interp_time(pts, err):
    """Time at error `err` on a work-precision line: the time of the cheapest point at or below
    `err`, interpolated in log-log with its neighbour above `err` where one exists."""
    below = [p for p in pts if p[0] <= err]
    if not below:
        return None
    above = [p for p in pts if p[0] > err]
    e1, t1 = max(below, key=lambda p: p[0])  # the loosest run that is accurate enough
    if not above:
        return t1
    e0, t0 = min(above, key=lambda p: p[0])
    w = (np.log(err) - np.log(e0)) / (np.log(e1) - np.log(e0))
    return float(np.exp(np.log(t0) + w * (np.log(t1) - np.log(t0))))


# --------------------------------------------------------------------------------------------
_COMPILE_SNIPPET = r"""
import json, os, sys, time
t0 = time.perf_counter()
import ppr_jax as pj
programs = None
if sys.argv[2]:  # as the command line runs: compiled and exported programs both cached
    pj.enable_compilation_cache(sys.argv[2])
    programs = os.path.join(sys.argv[2], "ppr_jax_programs")
t1 = time.perf_counter()
r = pj.run_scene("paper-circle", model=sys.argv[1], program_dir=programs)
t2 = time.perf_counter()
print(json.dumps(dict(import_s=t1 - t0, compile_s=r.timing["compile_s"], run_s=r.timing["run_s"],
                      program=r.timing["program"], first_result_s=t2 - t0)))
"""


def _compile_probe(model: str, cache_dir: str) -> dict:
    # As the `ppr-jax` console script runs: equinox's runtime errors as NaN (the results are
    # checked from status codes), so that diffrax's checks add no host callback, which would
    # keep the program out of the persistent cache.
    env = dict(os.environ, EQX_ON_ERROR="nan")
    p = subprocess.run([sys.executable, "-c", _COMPILE_SNIPPET, model, cache_dir],
                       capture_output=True, text=True, env=env, timeout=600)
    if p.returncode != 0:
        return {"failed": p.stderr.strip().splitlines()[-1]}
    return json.loads(p.stdout.strip().splitlines()[-1])


def part_compile(args, out_dir) -> dict:
    models = ("rigid", "reduced", "double1r") + (() if args.quick else ("beam",))
    data = {"machine": machine(args.quick), "scene": "paper-circle (7.54 s, defaults)",
            "what": "fresh processes: `cold` without a persistent cache; `first`/`second` share "
                    "a new cache directory with the compiled and the exported programs (as the "
                    "command line runs); first_result_s counts from the interpreter's import "
                    "of ppr_jax to the scene's result", "rows": []}
    for model in models:
        row = {"model": model, "cold": _compile_probe(model, "")}
        with tempfile.TemporaryDirectory() as d:
            row["first"] = _compile_probe(model, d)
            row["second"] = _compile_probe(model, d)
        data["rows"].append(row)
        print(json.dumps(row), flush=True)
        save(out_dir, "compile", data)
    return data


# --------------------------------------------------------------------------------------------
def part_batch(args, out_dir) -> dict:
    base = pj.scene_params("paper-circle")
    if args.quick:
        plan, rtols, t_end = {"reduced": (1, 8, 64)}, (1e-6,), 1.0
    else:
        plan = {"reduced": (1, 8, 64, 256, 1024), "double1r": (1, 8, 64)}
        rtols, t_end = (1e-6, 1e-8), 7.54
    if args.sizes:
        plan = {m: tuple(args.sizes) for m in (args.models or plan)}
    rtols = tuple(args.rtols) if args.rtols else rtols
    data = {
        "machine": machine(args.quick),
        "scene": "paper-circle",
        "t_end_s": t_end,
        "members": "strip thickness spread evenly over 0.28-0.40 mm",
        "rows": [],
    }
    old = _load(out_dir, "batch")
    if args.models:
        plan = {m: b for m, b in plan.items() if m in args.models}
        if old is not None and old.get("t_end_s") == t_end:
            data["rows"] = [r for r in old["rows"] if r["model"] not in args.models]
    for model, sizes in plan.items():
        for rtol in rtols:
            for B in sizes:
                ts = np.linspace(0.28e-3, 0.40e-3, B)
                params = (base.replace(t=float(ts[0])) if B == 1 else
                          pj.stack_params([base.replace(t=float(t)) for t in ts]))
                r = pj.run_scene("paper-circle", params, model=model, repeats=args.repeats,
                                 options=pj.SceneOptions(rtol=rtol, atol=rtol * 1e-2,
                                                         t_end=t_end, max_steps=400_000))
                row = dict(model=model, rtol=rtol, batch=B, compile_s=r.timing["compile_s"],
                           run_s=r.timing["run_s"], per_robot_ms=r.timing["run_s"] / B * 1e3,
                           trajectories_per_s=B / r.timing["run_s"])
                data["rows"].append(row)
                print(json.dumps(row), flush=True)
                save(out_dir, "batch", data)
    plots.batch(data, out_dir)
    return data


PARTS = {"work-precision": part_work_precision, "contenders": part_contenders,
         "compile": part_compile, "batch": part_batch}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small settings: a few minutes in all")
    ap.add_argument("--parts", nargs="+", choices=list(PARTS), default=list(PARTS))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--models", nargs="+", choices=list(pj.MODELS), default=None,
                    help="work-precision, batch: only these models (their rows replace the stored "
                         "ones)")
    ap.add_argument("--scenes", nargs="+", choices=["paper-circle", "servo-circle"],
                    default=None, help="work-precision: only these scenes")
    ap.add_argument("--skip-l3-implicit", action="store_true",
                    help="leave Kvaerno5 out for L3 (its compilation is the longest)")
    ap.add_argument("--sizes", nargs="+", type=int, default=None,
                    help="batch: these batch sizes for every model (default 1-1024 for L1, "
                         "1-64 for L2; a GPU takes 4096)")
    ap.add_argument("--rtols", nargs="+", type=float, default=None,
                    help="batch: these tolerances (default 1e-6 1e-8)")
    ap.add_argument("--out", default=None,
                    help="results directory (default benchmarks/results/<backend>)")
    ap.add_argument("--no-cpu-config", action="store_true",
                    help="leave XLA's CPU settings alone (default: ppr_jax.configure_cpu(): one "
                         "host device per core, batches split over them, no YNNPACK fusions)")
    args = ap.parse_args(argv)
    if not args.no_cpu_config:
        pj.configure_cpu()  # before JAX's first computation
    out_dir = args.out or os.path.join(HERE, "results", jax.default_backend())
    os.makedirs(out_dir, exist_ok=True)
    for part in args.parts:
        t0 = time.perf_counter()
        print(f"== {part}", flush=True)
        PARTS[part](args, out_dir)
        print(f"== {part}: {time.perf_counter() - t0:.0f} s", flush=True)


if __name__ == "__main__":
    main()
