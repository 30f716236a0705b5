"""`ppr-jax simulate`: run a scene for one or more models; summary.json, trajectory.csv, figures."""

from __future__ import annotations

import csv
import os
import time

from .._names import KINEMATIC_MODELS, MODEL_NAMES, SIMULATE_CHOICES
from ._common import (
    _derived_dict,
    _log,
    _models,
    _params_dict,
    _parse_sets,
    _write_json,
    check_out_dir,
    model_from_args,
)


def _reference(scene):
    """The values the scene's paper figure reports (`AbstractScene.reference`), or None."""
    from .._scenes import get_scene

    ref = get_scene(scene).reference
    return dict(ref) if ref else None


def cmd_simulate(args):
    import numpy as np

    from .._errors import PPRError
    from .._scenes import check_scene_args, get_scene, modes_scene, run_scene
    from ._figures import scene_figures

    scene = args.scene
    params = _parse_sets(args.set, scene, getattr(args, "params_file", None))
    check_out_dir(args.out)
    if scene == "modes":
        models = _models(args.model, "reduced,double1r")
        res = []
        for m in models:
            for act in ("locked", "free"):
                _log(f"modes: {m}, actuators {act} ...")
                res.append(modes_scene(params, model=model_from_args(args, m),
                                       actuators=act))
        summary = {"scene": scene, "params": _params_dict(params), "modes": res}
        _write_json(os.path.join(args.out, "summary.json"), summary)
        for r in res:
            f = ", ".join(f"{x:.4g}" for x in r["frequencies_hz"]) or "none (no free coordinate)"
            print(f"{r['model']:>9s} actuators {r['actuators']:>6s}: {f} Hz")
        print(f"wrote {args.out}/summary.json")
        return 0
    models = _models(args.model, "rigid,reduced,double1r")
    kw = dict(t_end=args.t_end, n_out=args.n_out, solver=args.solver, rtol=args.rtol,
              atol=args.atol, max_steps=args.max_steps)
    results, failed = [], {}
    traj = get_scene(scene).trajectory()
    # the nominal circle as host numbers: the CSV and figures are numpy post-processing
    center, radius = np.asarray(traj.center), float(traj.radius)
    # Every argument checked before the first compilation.
    objs = [model_from_args(args, m) for m in models]
    check_scene_args(args.t_end, args.n_out, args.rtol, args.atol, args.max_steps)
    derived = _derived_dict(params)

    def write():
        # After every model: a failing or interrupted later model keeps what finished.
        summary = {
            "scene": scene,
            "torque_model": args.torque_model if scene == "paper-circle" else None,
            "t_end_s": args.t_end,
            "n_out": args.n_out,
            "params": _params_dict(params),
            "derived": derived,
            "models": {r.model: dict(r.metrics, solver=r.solver) for r in results},
            "beam": ({"elements": args.elements, "strip_dynamics": args.strip_dynamics,
                      "strip_loss_s": args.strip_loss}
                     if "beam" in models else None),
            "failed": failed,
            "paper_reference": _reference(scene),
        }
        _write_json(os.path.join(args.out, "summary.json"), summary)
        if results:
            _write_csv(os.path.join(args.out, "trajectory.csv"), results, center, radius)

    for i, m in enumerate(models):
        _log(f"[{i + 1}/{len(models)}] {scene}: model {m} (compiling, then running) ...")
        t0 = time.perf_counter()
        try:
            r = run_scene(scene, params, model=objs[i], torque_model=args.torque_model,
                          program_dir=getattr(args, "program_dir", None), **kw)
        except PPRError as err:
            failed[m] = " ".join(str(err).split())
            _log(f"      {m} failed: {failed[m]}")
            write()
            continue
        _log(f"      done in {time.perf_counter() - t0:.1f} s "
             f"(compile {r.timing['compile_s']:.1f} s, "
             f"run {r.timing['run_s'] * 1e3:.1f} ms, {r.metrics['num_steps']} steps)")
        results.append(r)
        write()
    if results:
        scene_figures(results, args.out, center, radius)
        _print_table(scene, results, args)
        print(f"wrote {args.out}/summary.json, trajectory.csv, trajectory.png, angle.png, "
              f"radial_error.png")
    if failed:
        raise PPRError(f"{len(failed)} of {len(models)} models failed ({', '.join(failed)}); "
                       f"see above and {args.out}/summary.json")
    return 0


def _print_table(scene, results, args):
    ref = _reference(scene) or {}
    hdr = (f"{'model':>10s} {'e_r max':>9s} {'e_r min':>9s} {'e_r mean':>9s} {'max|e_r|/R':>10s} "
           f"{'|dphi| max':>10s} {'d_end max':>9s} {'d_end min':>9s} {'d_end mean':>10s} "
           f"{'rel':>6s} {'resid':>8s} {'steps':>6s} {'run':>8s}")
    units = (f"{'':>10s} {'mm':>9s} {'mm':>9s} {'mm':>9s} {'%':>10s} {'mrad':>10s} {'deg':>9s} "
             f"{'deg':>9s} {'deg':>10s} {'%':>6s} {'m':>8s} {'':>6s} {'ms':>8s}")
    print(f"\nScene {scene} (t = {float(results[0].params.t) * 1e3:.2f} mm); radial error "
          f"e_r = |(x,y) - c| - R against the nominal circle (eq 55); d_end = difference of chain "
          f"1's joint end rotations")
    print(hdr)
    print(units)
    for r in results:
        m = r.metrics
        print(f"{r.model:>10s} {m['radial_error_max_m'] * 1e3:9.4f} "
              f"{m['radial_error_min_m'] * 1e3:9.4f} {m['radial_error_mean_m'] * 1e3:9.4f} "
              f"{m['radial_error_max_relative_percent']:10.4f} "
              f"{m['phi_error_max_rad'] * 1e3:10.4f} {m['end_rotation_diff_max_deg']:9.4f} "
              f"{m['end_rotation_diff_min_deg']:9.4f} {m['end_rotation_diff_mean_deg']:10.4f} "
              f"{m['end_rotation_diff_max_relative_percent']:6.2f} "
              f"{m['constraint_residual_max_m']:8.1e} {m['num_steps']:6d} "
              f"{r.timing['run_s'] * 1e3:8.2f}")
    if ref:
        print(f"{'paper':>10s} {ref['radial_error_max_m'] * 1e3:9.4f} "
              f"{ref['radial_error_min_m'] * 1e3:9.4f} "
              f"{ref['radial_error_mean_m'] * 1e3:9.4f} "
              f"{ref['radial_error_max_relative_percent']:10.4f}"
              f"   ({ref['source']})")
    for r in results:
        if r.metrics["radial_error_max_relative_percent"] > 20:
            print(f"note: {r.model} runs far off the circle "
                  f"({r.metrics['radial_error_max_relative_percent']:.0f}% "
                  f"of R): open-loop torques of another model amplify the mismatch "
                  f"(L0's pin is about half as stiff as the double-1R joint); "
                  f"use --torque-model {r.model} for its own torques")


def _write_csv(path, results, center, R):
    """trajectory.csv: every model's pose, radial error (host side, numpy: no XLA program per
    operation), torques and joint end rotations."""
    import numpy as np

    from .._metrics import radial_error

    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["model", "t", "x", "y", "phi", "e_r", "tau_1", "tau_2", "tau_3",
                    "end_rot_1", "end_rot_2"])
        r0 = results[0]
        er = radial_error(np.asarray(r0.X_nominal), center, R, xp=np)
        for k in range(len(r0.ts)):
            w.writerow(["nominal", r0.ts[k], *r0.X_nominal[k], er[k], "", "", "", "", ""])
        for r in results:
            er = radial_error(np.asarray(r.X), center, R, xp=np)
            for k in range(len(r.ts)):
                w.writerow([r.model, r.ts[k], *r.X[k], er[k], *r.tau[k], *r.end_rot[k]])


def _add_simulate(sub, parents, fmt):
    kinematic = list(KINEMATIC_MODELS)  # pose = coordinates
    s = sub.add_parser("simulate", formatter_class=fmt,
        parents=[parents[k] for k in ("params", "model", "solve", "times")],
        help="run a scene and write summary.json, trajectory.csv, figures")
    s.add_argument("--scene", default="paper-circle", choices=list(SIMULATE_CHOICES),
                   help="scene to run")
    s.add_argument("--model", default=None,
                   help="a model (" + ", ".join(MODEL_NAMES) + ") or a comma list (default: rigid, "
                        "reduced, double1r). beam is L3 with quasi-static strips (see "
                        "--elements, --strip-dynamics)")
    s.add_argument("--torque-model", default="reduced", choices=kinematic,
                   help="paper-circle: the model whose inverse dynamics gives the torques")
    s.add_argument("--out", default="out", help="output directory")
    s.set_defaults(func=cmd_simulate)
