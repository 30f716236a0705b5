"""`ppr-jax identify`: fit parameters to measured trajectories."""

from __future__ import annotations

import csv
import json
import os
import shlex
import time

from .._files import write_file
from .._names import (
    ACTUATIONS,
    ID_SOLVERS,
    INITIAL_STATES,
    LOSSES,
    MODEL_NAMES,
    PARAM_RANGES,
    SCENE_NAMES,
)
from ._common import (
    _log,
    _name_values,
    check_out_dir,
)


def _bounds(items):
    out = {}
    for item in items or []:
        try:
            name, rng = item.split("=", 1)
            lo, hi = (float(v) for v in rng.split(","))
        except ValueError:
            raise ValueError(f"--bound expects NAME=LO,HI, got {item!r}") from None
        out[name.strip()] = (lo, hi)
    return out


def cmd_identify(args):
    from .._data import load_experiments
    from .._params import RobotParams
    from .._scenes import SceneOptions, scene_params
    from .._studies import FitOptions, StartError, identification_figures, identify
    from ._common import model_from_args

    # before anything is fitted: a directory that cannot be written would lose the fit (it is
    # created only when there is something to write: a refused fit leaves nothing)
    check_out_dir(args.out, create=False)
    exps = load_experiments(args.data, time_unit=args.time_unit, length_unit=args.length_unit,
                            angle_unit=args.angle_unit, drop_nan=args.drop_nan)
    for e in exps:
        if e.dropped_lines:
            _log(f"{e.name}: dropped {len(e.dropped_lines)} NaN rows (lines "
                 f"{', '.join(map(str, e.dropped_lines[:10]))}"
                 f"{', ...' if len(e.dropped_lines) > 10 else ''})")
    # the paper's experiment named by --scene, or (default) the one each file describes
    params = RobotParams() if args.scene is None else scene_params(args.scene)
    if getattr(args, "params_file", None):
        from .._params_file import load_params

        params = load_params(args.params_file, params)
    params = params.replace(**_name_values(args.set, "--set"))
    fixed = _name_values(args.fix, "--fix")
    initial = _name_values(args.initial, "--initial")
    unknowns = args.unknown or ["t"]
    _log(f"identify {', '.join(unknowns)} with {args.model} from {len(exps)} experiment(s), "
         f"{sum(e.n for e in exps)} samples (compiling the simulation and its Jacobian first) ...")
    t0 = time.perf_counter()
    commands = None
    if args.commands_set:
        commands = params.replace(**_name_values(args.commands_set, "--commands-set"))
    try:
        fit = identify(exps, unknowns, model=model_from_args(args, args.model),
                       scene=args.scene, actuation=args.actuation, commands=commands,
                       params=params, fixed=fixed, initial=initial, bounds=_bounds(args.bound),
                       noise=(args.noise_pos, args.noise_phi),
                       fit_options=FitOptions(
                           solver=args.method, max_iter=args.max_iter, loss=args.loss,
                           loss_scale=args.loss_scale, starts=_starts(args.starts),
                           initial_state=args.initial_state, nuisance=tuple(args.nuisance),
                           validation=_validation(args.validation), force=args.force),
                       options=SceneOptions().updated(solver=args.solver, rtol=args.rtol,
                                                      atol=args.atol, max_steps=args.max_steps),
                       program_dir=getattr(args, "program_dir", None))
    except StartError as err:
        # the experiment's name is its file's stem: name the file as the user typed it
        msg = str(err)
        for e, path in zip(exps, args.data):
            if msg.startswith(f"{e.name}: "):
                msg = f"{path}: {msg[len(e.name) + 2:]}"
                break
        raise StartError(msg) from None
    _log(f"driven by {fit.actuation}")
    _log(f"done in {time.perf_counter() - t0:.1f} s ({fit.history.get('iterations')} iterations, "
         f"stop: {fit.history.get('stop')})")
    os.makedirs(args.out, exist_ok=True)
    summary = fit.to_dict()
    summary["data"] = [os.path.abspath(p) for p in args.data]
    with write_file(os.path.join(args.out, "estimates.json")) as f:
        json.dump(summary, f, indent=2)
    table = fit.table()
    _write_fitted(os.path.join(args.out, "fitted.csv"), fit)
    figs = identification_figures(fit, args.out)
    if args.profile:
        from .._studies import profile_figure

        _log("profile likelihood of " + ", ".join(fit.names) + " ...")
        profiles = [fit.profile(n) for n in fit.names]
        with write_file(os.path.join(args.out, "profiles.json")) as f:
            json.dump(profiles, f, indent=2)
        figs.append(profile_figure(profiles, os.path.join(args.out, "profiles.png")))
        for pr in profiles:
            ends = ["open" if x is None else f"{x:.6g}" for x in pr["ci"]]
            extra = (f" (ends where {', '.join(pr['limited_by_bounds_of'])} reaches a bound)"
                     if pr["limited_by_bounds_of"] else "")
            table += (f"\n  profile 95% interval of {pr['name']}: [{ends[0]}, {ends[1]}]"
                      + extra)
    with write_file(os.path.join(args.out, "estimates.txt")) as f:
        f.write(table + "\n")
    robot_files = _write_robot(args.out, fit)
    report = fit.report(os.path.join(args.out, "report.html"), figures=figs,
                        data_files=args.data, profiles=profiles if args.profile else None,
                        command=" ".join(["ppr-jax", *map(shlex.quote, args.argv)]))
    print(table)
    print(f"wrote {args.out}/estimates.json, estimates.txt, fitted.csv, "
          + ("profiles.json, " if args.profile else "")
          + ", ".join(os.path.basename(p) for p in figs + robot_files + [report]))
    if args.strict and not fit.quality["ok"]:
        _log("--strict: the fit cannot be trusted: " + "; ".join(fit.quality["problems"]))
        return 3
    return 0


def _starts(text):
    """--starts: "auto" or an integer (anything else reaches `identify`, which names the
    allowed values)."""
    if text == "auto":
        return text
    try:
        return int(text)
    except ValueError:
        return text


def _validation(text):
    """--validation: None, a fraction, or experiment names."""
    if text is None:
        return None
    try:
        return float(text)
    except ValueError:
        return [n.strip() for n in text.split(",") if n.strip()]


def robot_file_notes(fit) -> list:
    """The lines that head the identified robot's files: where the parameters come from, and a
    WARNING line when the fit cannot be trusted (`quality["problems"]`: a poor fit, an unknown
    at a bound, a model that does not generalise) or was forced past the preflight's refusal
    (combinations not identifiable from the data)."""
    q = fit.quality or {}
    notes = [f"identified by ppr-jax identify: {', '.join(fit.names)} fitted with the "
             f"{fit.model} model to {', '.join(fit.experiment_names)}; residual scale s = "
             f"{q.get('residual_scale', float('nan')):.4g} (1 = noise as stated)"]
    if q.get("problems"):
        notes.append("WARNING: this fit cannot be trusted: " + "; ".join(q["problems"]))
    if q.get("preflight_not_identifiable"):
        notes.append("WARNING: forced past the preflight (force): not identifiable from these "
                     "data at the initial guess: " + ", ".join(q["preflight_not_identifiable"]))
    if len(notes) == 1:
        notes.append("fit quality: ok (explains the data, no unknown at a bound)")
    return notes


def _write_robot(out, fit) -> list:
    """The identified robot: `identified.toml` (every command's `--params-file` reads it) and
    `identified_l2.xml`, its L2 as MJCF (`to_mjcf`; `python -m mujoco.viewer
    --mjcf=identified_l2.xml` shows it). Both begin with `robot_file_notes` (comments): a poor
    or forced fit is marked WARNING in the files themselves."""
    import sys

    from .._errors import PPRError
    from .._mjcf import to_mjcf
    from .._params_file import save_params

    notes = robot_file_notes(fit)
    paths = [save_params(fit.params, os.path.join(out, "identified.toml"), comments=notes),
             os.path.join(out, "identified_l2.xml")]
    # an XML comment may not hold "--"
    head = "".join(f"<!-- {' '.join(n.split()).replace('--', '- -')} -->\n" for n in notes)
    try:
        xml = to_mjcf(fit.params)
    except PPRError as err:  # no assembled state for this robot: keep the rest of the fit
        print(f"ppr-jax: identified_l2.xml not written: {err}", file=sys.stderr)
        return paths[:1]
    with write_file(paths[1], "w", encoding="utf-8") as f:
        f.write(head + xml)
    return paths


def _write_fitted(path, fit):
    """Measured and fitted pose of every experiment at its sample times (SI units); the samples
    held out by --validation too (held_out 1: the fit's prediction of them)."""
    import numpy as np

    held = (np.zeros(np.shape(fit.mask), bool) if fit.held_out is None
            else np.asarray(fit.held_out))
    with write_file(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["experiment", "time", "x_measured", "y_measured", "phi_measured", "x_fitted",
                    "y_fitted", "phi_fitted", "held_out"])
        for k, name in enumerate(fit.experiment_names):
            m = np.asarray(fit.mask[k]) | held[k]
            for t, xm, xf, h in zip(np.asarray(fit.ts[k])[m], np.asarray(fit.measured[k])[m],
                                    np.asarray(fit.fitted[k])[m], held[k][m]):
                w.writerow([name, f"{t:.10g}", *(f"{v:.12g}" for v in xm),
                            *(f"{v:.12g}" for v in xf), int(h)])


def _units(p):
    p.add_argument("--time-unit", default=None, choices=["s", "ms"],
                   help="unit of the time column when the file does not declare it")
    p.add_argument("--length-unit", default=None, choices=["m", "mm"],
                   help="unit of x, y when the file does not declare it")
    p.add_argument("--angle-unit", default=None, choices=["rad", "mrad", "deg"],
                   help="unit of phi (and th_i) when the file does not declare it")


def add_identify(sub, parents, fmt):
    p = sub.add_parser(
        "identify", formatter_class=fmt,
        parents=[parents[k] for k in ("params", "model", "solve")],
        help="identify parameters from measured trajectories (CSV), with 95%% intervals",
        description="Fit unknown parameters to tracker data by least squares through the "
                    "simulation; write estimates.json (estimates, 95 % intervals, correlations, "
                    "identifiability, residual statistics), estimates.txt, fitted.csv and "
                    "figures. CSV format: docs/identification.md.")
    p.add_argument("--data", action="append", required=True, metavar="FILE.csv",
                   help="tracker CSV file; repeat for several experiments (fitted jointly)")
    p.add_argument("--model", default="double1r", choices=list(MODEL_NAMES),
                   help="model to fit (beam/L3 is too slow for time-domain fits)")
    p.add_argument("--scene", default=None, choices=list(SCENE_NAMES),
                   help="the paper's experiment the files come from; default: the experiment "
                        "each file describes, its own angles th_1..th_3 (else its torques "
                        "tau_1..tau_3) driving the model along its own poses, from the state "
                        "its first samples give")
    p.add_argument("--actuation", default="auto", choices=list(ACTUATIONS),
                   help="with a motion-driven --scene: drive the model by the measured angles "
                        "th_1..th_3 of the data (auto: when every file holds them) or by the "
                        "scene's commands computed for the model named by --commands-set; "
                        "without --scene the files' own commands drive it")
    p.add_argument("--commands-set", action="append", metavar="NAME=VALUE",
                   help="a parameter of the model that computed the commands (as --set; "
                        "default: the nominal robot, never the unknowns' start values); "
                        "repeatable")
    p.add_argument("--initial-state", default="scene", choices=list(INITIAL_STATES),
                   help="estimate each experiment's initial platform pose (and velocity) "
                        "instead of starting from the scene's quasi-static state")
    p.add_argument("--unknown", action="append", metavar="NAME", choices=list(PARAM_RANGES),
                   help="parameter to identify; repeatable (default: t alone, K_theta from the "
                        "PRB table: t and K_theta act through E w t^3 K_theta, so the pair is "
                        "not identifiable from usual data and the preflight refuses it without "
                        "--force)")
    p.add_argument("--fix", action="append", metavar="NAME=VALUE",
                   help="parameter held at a known value (as --set); repeatable")
    p.add_argument("--initial", action="append", metavar="NAME=VALUE",
                   help="start value of an unknown (default: the robot's value, --set)")
    p.add_argument("--bound", action="append", metavar="NAME=LO,HI",
                   help="bounds of an unknown (default: its physical range)")
    p.add_argument("--noise-pos", type=float, default=1e-4,
                   help="tracker position noise (m): weight of x, y residuals (inf: x, y "
                        "not fitted)")
    p.add_argument("--noise-phi", type=float, default=1e-3,
                   help="platform angle noise (rad): weight of phi residuals (inf: phi not "
                        "fitted)")
    p.add_argument("--loss", default="linear", choices=list(LOSSES),
                   help="robust loss for outliers")
    p.add_argument("--loss-scale", type=float, default=3.0,
                   help="robust loss scale in noise units")
    p.add_argument("--method", default="lm", choices=list(ID_SOLVERS),
                   help="least-squares solver")
    p.add_argument("--max-iter", type=int, default=50, help="iteration limit of the fit")
    p.add_argument("--drop-nan", action="store_true", help="drop NaN rows (reported)")
    p.add_argument("--strict", action="store_true",
                   help="exit 3 when the fit cannot be trusted: it does not explain the data "
                        "(residual scale s > 3), an unknown ends at a bound, or it does not "
                        "generalise to the --validation samples")
    p.add_argument("--starts", default="auto", metavar="auto|N",
                   help="auto (default): fit from the given start, and only when that fit does "
                        "not explain the data (s > 3) or ends at a bound, refit from the 3 "
                        "cheapest of 8 Latin-hypercube points within the bounds (screened in "
                        "one vectorised call); N: fit from the given start and N - 1 more "
                        "Latin-hypercube points. The lowest cost wins, and the table says "
                        "whether the given start ended in another minimum")
    p.add_argument("--force", action="store_true",
                   help="fit even when the preflight finds a combination of the unknowns not "
                        "identifiable from the data at the initial guess (otherwise refused, "
                        "exit 2, naming the combination)")
    p.add_argument("--nuisance", action="append", default=[], choices=["bias", "delay"],
                   help="also estimate the tracker's measurement model, shared by every file: "
                        "'bias' (an offset of x, y, phi) or 'delay' (its lag behind the "
                        "actuation); repeat for both")
    p.add_argument("--validation", default=None, metavar="FRACTION|NAME[,NAME...]",
                   help="hold samples out of the fit and report how the fitted model predicts "
                        "them: a fraction in (0, 1) holds out the last part of every "
                        "experiment; experiment names (file stems) hold out those files")
    p.add_argument("--profile", action="store_true",
                   help="also profile-likelihood intervals of every unknown (a re-fit of the "
                        "others per point): profiles.json, profiles.png")
    _units(p)
    p.add_argument("--out", default="identify_out", help="output directory")
    p.set_defaults(func=cmd_identify)
