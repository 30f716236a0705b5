"""`ppr-jax simulate`: run a scene for one or more models; summary.json, trajectory.csv, figures."""

from __future__ import annotations

import csv
import os
import time

from .._files import write_file
from .._names import KINEMATIC_MODELS, MODEL_NAMES, SIMULATE_CHOICES
from ._common import (
    SceneAction,
    _derived_dict,
    _log,
    _models,
    _params_dict,
    _parse_sets,
    _write_json,
    check_commands_from_args,
    check_out_dir,
    frequencies_text,
    model_from_args,
    options_from_args,
    scene_from_args,
)


def cmd_simulate(args):
    import numpy as np

    from .._errors import PPRError
    from .._metrics import is_circle
    from .._scenes import check_scene_args, modes_scene, run_scene, scene_names

    # `modes` is a static solve, not a scene; every other choice (and --path) is a scene
    static = args.path is None and args.scene not in scene_names()
    models = _models(args.model, "reduced,double1r" if static else "rigid,reduced,double1r")
    scene = args.scene if static else scene_from_args(args)
    params = _parse_sets(args.set, scene, getattr(args, "params_file", None))
    check_out_dir(args.out)
    if static:
        res = []
        for m in models:
            for act in ("locked", "free"):
                _log(f"modes: {m}, actuators {act} ...")
                res.append(modes_scene(params, model=model_from_args(args, m),
                                       actuators=act))
        summary = {"scene": args.scene, "params": _params_dict(params), "modes": res}
        _write_json(os.path.join(args.out, "summary.json"), summary)
        for r in res:
            print(f"{r['model']:>9s} actuators {r['actuators']:>6s}: "
                  f"{frequencies_text(r['frequencies_hz'], '.4g')}")
        print(f"wrote {args.out}/summary.json")
        return 0
    options = options_from_args(args)
    results, failed = [], {}
    traj = scene.trajectory()
    circle = is_circle(traj)
    # the nominal circle as host numbers: the CSV and figures are numpy post-processing
    center, radius = ((np.asarray(traj.center), float(traj.radius)) if circle
                      else (None, None))
    # Every argument checked before the first compilation.
    objs = [model_from_args(args, m) for m in models]
    check_scene_args(args.t_end, args.n_out, args.rtol, args.atol, args.max_steps)
    # a command log's span and assembly mode: one line for the run, not one failure per model
    check_commands_from_args(scene, params, args)
    derived = _derived_dict(params)

    def write():
        # After every model: a failing or interrupted later model keeps what finished.
        summary = {
            "scene": scene.name,
            "drive": scene.drive,
            "input_model": scene.input_model.name,
            "path_file": args.path,
            "command_log": args.angles or args.torques,
            "t_end_s": args.t_end,
            "n_out": args.n_out,
            "params": _params_dict(params),
            "derived": derived,
            "models": {r.model: dict(r.metrics, solver=r.solver) for r in results},
            "beam": ({"elements": args.elements, "strip_dynamics": args.strip_dynamics,
                      "strip_loss_s": args.strip_loss}
                     if "beam" in models else None),
            "failed": failed,
            "paper_reference": dict(scene.reference) or None,
        }
        _write_json(os.path.join(args.out, "summary.json"), summary)
        if results:
            _write_csv(os.path.join(args.out, "trajectory.csv"), results, center, radius)

    for i, m in enumerate(models):
        _log(f"[{i + 1}/{len(models)}] {scene.name}: model {m} (compiling, then running) ...")
        t0 = time.perf_counter()
        try:
            r = run_scene(scene, params, model=objs[i],
                          program_dir=getattr(args, "program_dir", None), options=options)
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
        # the table first: the figures (the plotting library's import and drawing) come after
        # the answer, not before it
        _print_table(scene, results, circle)
        figs = []
        if args.figures:
            from ._figures import scene_figures

            figs = scene_figures(results, args.out, center, radius)
        print(f"wrote {args.out}/summary.json, trajectory.csv"
              + "".join(", " + os.path.basename(f) for f in figs))
    if failed:
        raise PPRError(f"{len(failed)} of {len(models)} models failed ({', '.join(failed)}); "
                       f"see above and {args.out}/summary.json")
    return 0


def _print_table(scene, results, circle: bool):
    ref = dict(scene.reference)
    if circle:
        head = [("e_r max", "mm", "radial_error_max_m", 1e3, 9.4),
                ("e_r min", "mm", "radial_error_min_m", 1e3, 9.4),
                ("e_r mean", "mm", "radial_error_mean_m", 1e3, 9.4),
                ("max|e_r|/R", "%", "radial_error_max_relative_percent", 1, 10.4)]
        what = "radial error e_r = |(x,y) - c| - R against the nominal circle (eq 55)"
    else:
        head = [("pos max", "mm", "position_error_max_m", 1e3, 9.4),
                ("pos rms", "mm", "position_error_rms_m", 1e3, 9.4),
                ("pos end", "mm", "position_error_end_m", 1e3, 9.4)]
        what = "position error |(x,y) - (x,y)_commanded| against the commanded path"
    head += [("|dphi| max", "mrad", "phi_error_max_rad", 1e3, 10.4),
             ("d_end max", "deg", "end_rotation_diff_max_deg", 1, 9.4),
             ("d_end min", "deg", "end_rotation_diff_min_deg", 1, 9.4),
             ("d_end mean", "deg", "end_rotation_diff_mean_deg", 1, 10.4),
             ("rel", "%", "end_rotation_diff_max_relative_percent", 1, 6.2)]
    widths = [int(f) for *_, f in head]
    print(f"\nScene {scene.name} (t = {float(results[0].params.t) * 1e3:.2f} mm); {what}; "
          f"d_end = difference of chain 1's joint end rotations")
    print(f"{'model':>10s} " + " ".join(f"{h:>{w}s}" for (h, *_), w in zip(head, widths))
          + f" {'resid':>8s} {'steps':>6s} {'run':>8s}")
    print(f"{'':>10s} " + " ".join(f"{u:>{w}s}" for (_, u, *_), w in zip(head, widths))
          + f" {'m':>8s} {'':>6s} {'ms':>8s}")
    for r in results:
        m = r.metrics
        print(f"{r.model:>10s} " + " ".join(f"{m[k] * s:{f}f}" for _, _, k, s, f in head)
              + f" {m['constraint_residual_max_m']:8.1e} {m['num_steps']:6d} "
              f"{r.timing['run_s'] * 1e3:8.2f}")
    if ref and circle:
        print(f"{'paper':>10s} " + " ".join(f"{ref[k] * s:{f}f}" for _, _, k, s, f in head[:4])
              + f"   ({ref['source']})")
    far = "radial_error_max_relative_percent" if circle else None
    for r in results:
        if far and r.metrics[far] > 20:
            print(f"note: {r.model} runs far off the circle "
                  f"({r.metrics[far]:.0f}% of R): open-loop torques of another model amplify "
                  f"the mismatch (L0's pin is about half as stiff as the double-1R joint); "
                  f"use --torque-model {r.model} for its own torques")


def _write_csv(path, results, center, R):
    """trajectory.csv: every model's pose, its error against the nominal path (the radial
    error e_r of a circle, else the position error e_pos; host side, numpy: no XLA program per
    operation), torques and joint end rotations."""
    import numpy as np

    from .._metrics import radial_error

    def err(r, X):
        if center is not None:
            return radial_error(np.asarray(X), center, R, xp=np)
        return np.linalg.norm(np.asarray(X)[:, :2] - np.asarray(r.X_nominal)[:, :2], axis=-1)

    with write_file(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["model", "t", "x", "y", "phi", "e_r" if center is not None else "e_pos",
                    "tau_1", "tau_2", "tau_3", "end_rot_1", "end_rot_2"])
        r0 = results[0]
        er = err(r0, r0.X_nominal)
        for k in range(len(r0.ts)):
            w.writerow(["nominal", r0.ts[k], *r0.X_nominal[k], er[k], "", "", "", "", ""])
        for r in results:
            er = err(r, r.X)
            for k in range(len(r.ts)):
                w.writerow([r.model, r.ts[k], *r.X[k], er[k], *r.tau[k], *r.end_rot[k]])


def _add_simulate(sub, parents, fmt):
    kinematic = list(KINEMATIC_MODELS)  # pose = coordinates
    s = sub.add_parser("simulate", formatter_class=fmt,
        parents=[parents[k] for k in ("params", "model", "solve", "times", "files", "figures")],
        help="run a scene and write summary.json, trajectory.csv, figures")
    s.add_argument("--scene", default="paper-circle", choices=list(SIMULATE_CHOICES),
                   action=SceneAction,
                   help="scene to run (or --path: your own experiment; modes: the natural "
                        "frequencies at home)")
    s.add_argument("--model", default=None,
                   help="a model (" + ", ".join(MODEL_NAMES) + ") or a comma list (default: rigid, "
                        "reduced, double1r). beam is L3 with quasi-static strips (see "
                        "--elements, --strip-dynamics)")
    s.add_argument("--torque-model", default="reduced", choices=kinematic,
                   help="paper-circle: the model whose inverse dynamics gives the torques")
    s.add_argument("--out", default="out", help="output directory")
    s.set_defaults(func=cmd_simulate)
