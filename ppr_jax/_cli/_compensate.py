"""`ppr-jax compensate`: the commands that make the model's platform follow a path, written as
the command log `simulate --path F --angles/--torques` reads back."""

from __future__ import annotations

import csv
import os

from .._files import save_figure, write_file
from .._names import MODEL_NAMES
from ._common import (
    _log,
    _params_dict,
    _parse_sets,
    _write_json,
    check_out_dir,
    model_from_args,
)

#: the columns of the written logs: what `load_commands` reads (SI units)
COLUMNS = {"angles": ["time[s]", "th_1[rad]", "th_2[rad]", "th_3[rad]"],
           "torque": ["time[s]", "tau_1[Nm]", "tau_2[Nm]", "tau_3[Nm]"]}
FILES = {"angles": "angles.csv", "torque": "torques.csv"}


def write_log(path: str, comp) -> str:
    """The compensated commands as a command log: a header naming its spline (`# spline:
    not-a-knot`, which `load_commands` follows) and how it was made, then one row a time."""
    from .._paths import SPLINE_COMMENT

    with write_file(path, "w", newline="") as f:
        f.write(f"{SPLINE_COMMENT} not-a-knot\n")
        f.write(f"# compensated {comp.kind} of the {comp.model} model ({comp.drive} drive), "
                f"by {comp.method}\n")
        w = csv.writer(f)
        w.writerow(COLUMNS[comp.kind])
        for t, u in zip(comp.ts, comp.commands):
            w.writerow([repr(float(t)), *(repr(float(v)) for v in u)])
    return path


def error_figure(path: str, comp) -> str:
    """Position and orientation error against the path, nominal and compensated commands."""
    import numpy as np

    from ._figures import _figure

    fig = _figure((8, 5))
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    for label, rep in (("nominal commands", comp.before), ("compensated", comp.after)):
        res = rep.result
        e = np.asarray(res.X) - np.asarray(res.X_nominal)
        ax1.semilogy(res.ts, np.maximum(np.linalg.norm(e[:, :2], axis=1), 1e-15), label=label)
        ax2.semilogy(res.ts, np.maximum(np.abs(e[:, 2]), 1e-15), label=label)
    ax1.set_ylabel("position error (m)")
    ax2.set_ylabel("|phi error| (rad)")
    ax2.set_xlabel("t (s)")
    ax1.set_title(f"{comp.model}, {comp.drive} drive: tracking error before and after")
    ax1.legend()
    fig.tight_layout()
    return save_figure(fig, path, dpi=120)


def cmd_compensate(args):
    from .._errors import PPRError
    from .._paths import load_path
    from .._scenes import SceneOptions
    from .._studies import compensate

    if (args.path is None) == (args.scene is None):
        raise PPRError("give the path to follow: --path FILE.csv or --scene paper-circle|"
                       "servo-circle (one of them)")
    if args.path is not None:
        target = load_path(args.path, bc=args.bc, drop_nan=args.drop_nan)
        if float(target.ts[0]) != 0.0:
            raise PPRError(f"{args.path}: the path's first time is {float(target.ts[0]):g} s; "
                           f"the scenes start at t = 0 (shift the file's times)")
        t_end = float(target.ts[-1]) if args.t_end is None else args.t_end
        from .._scenes import PathScene

        # the robot `simulate --path` takes, so that its replay runs the same one
        params = _parse_sets(args.set, PathScene(target), getattr(args, "params_file", None))
    else:
        target = args.scene
        t_end = 7.54 if args.t_end is None else args.t_end
        params = _parse_sets(args.set, args.scene, getattr(args, "params_file", None))
    check_out_dir(args.out)
    limits = {k: v for k, v in (("angle", args.max_angle), ("rate", args.max_rate),
                                ("torque", args.max_torque)) if v is not None}
    options = SceneOptions().updated(t_end=t_end, solver=args.solver, rtol=args.rtol,
                                     atol=args.atol, max_steps=args.max_steps)
    _log(f"compensate: {args.model}, {args.drive or 'the scene'}'s drive (compiling the "
         f"inverse and two runs) ...")
    comp = compensate(target, model_from_args(args, args.model), params, drive=args.drive,
                      options=options, rate=args.rate, limits=limits or None,
                      method=args.method)
    log = write_log(os.path.join(args.out, FILES[comp.kind]), comp)
    summary = dict(comp.summary(), path_file=args.path, scene=args.scene,
                   params=_params_dict(params), command_log=os.path.basename(log))
    summary_path = os.path.join(args.out, "summary.json")
    _write_json(summary_path, summary)
    b, a = comp.error["before"], comp.error["after"]
    print(f"position error max {b['position_max'] * 1e3:.4g} mm -> {a['position_max'] * 1e3:.4g}"
          f" mm ({comp.improvement:.3g}x), |phi error| max {b['phi_max'] * 1e3:.4g} mrad -> "
          f"{a['phi_max'] * 1e3:.4g} mrad")
    for flag in comp.flags:
        print(f"warning: {flag}")
    # the figure after the answer (the plotting library's import and drawing)
    figs = ([error_figure(os.path.join(args.out, "tracking_error.png"), comp)]
            if args.figures else [])
    # every path as written, the folder with each
    print(f"wrote {', '.join([log, summary_path, *figs])}")
    return 2 if comp.flags else 0


def add_compensate(sub, parents, fmt):
    c = sub.add_parser(
        "compensate", formatter_class=fmt,
        parents=[parents["params"], parents["model"], parents["solve"], parents["figures"]],
        help="commands that cancel the robot's compliance along a path (model inversion)",
        description="Compute the actuated angles (--drive motion) or torques (--drive torque) "
                    "that make the model's platform follow the path, by inverting the model, "
                    "replay them and the nominal commands through the model, and write "
                    "angles.csv or torques.csv (the format `simulate --path F --angles/"
                    "--torques` reads back), summary.json and tracking_error.png. Exits 2 "
                    "with the files written when a result is flagged (a limit exceeded, an "
                    "unstable open loop, an inversion that did not settle).")
    c.add_argument("--path", default=None, metavar="FILE.csv",
                   help="the path to follow: a CSV of poses (time, x, y, phi), as simulate's")
    c.add_argument("--scene", default=None, choices=["paper-circle", "servo-circle"],
                   help="or a paper scene's circle (eq 55) with its robot")
    c.add_argument("--bc", default="auto", choices=["auto", "clamped", "natural", "not-a-knot"],
                   help="the path spline's ends (as simulate's --bc)")
    c.add_argument("--drop-nan", action="store_true",
                   help="drop the rows of the --path file that hold NaN, empty or infinite "
                        "cells (otherwise the file is refused, naming its lines)")
    c.add_argument("--drive", default=None, choices=["motion", "torque"],
                   help="motion: actuated angles; torque: torques (default: motion for a path, "
                        "the scene's own for --scene)")
    c.add_argument("--model", default="double1r", choices=list(MODEL_NAMES),
                   help="the model that is inverted and replays the commands")
    c.add_argument("--rate", type=float, default=None,
                   help="command rate (Hz); default: the path file's own samples, else 100")
    c.add_argument("--t-end", type=float, default=None,
                   help="horizon (s) for --scene (default 7.54); a path runs to its last time")
    c.add_argument("--method", default="inversion", choices=["inversion", "optimise"],
                   help="inversion (the model's inverse), or optimise: Levenberg-Marquardt on a "
                        "smooth correction of it through the simulation (docs: Compensation)")
    c.add_argument("--max-angle", type=float, default=None, metavar="RAD",
                   help="flag angles beyond this (motion drive)")
    c.add_argument("--max-rate", type=float, default=None, metavar="RAD/S",
                   help="flag angle rates beyond this (motion drive)")
    c.add_argument("--max-torque", type=float, default=None, metavar="NM",
                   help="flag torques beyond this (torque drive)")
    c.add_argument("--out", default="compensate_out", help="output directory")
    c.set_defaults(func=cmd_compensate)
