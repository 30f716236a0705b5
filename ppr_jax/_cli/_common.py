"""Shared pieces of the commands: parameter parsing, the options every command shares (parent
parsers), output directories and JSON. The parent parsers read `_names` alone (no JAX); the
helpers that run a command import the library inside."""

from __future__ import annotations

import argparse
import csv
import json
import os
import sys

from .._names import (
    ATOL,
    DEFAULT_ELEMENTS,
    FULL_L3_ATOL,
    FULL_L3_RTOL,
    KINEMATIC_MODELS,
    MAX_STEPS,
    MODEL_NAMES,
    N_OUT,
    RTOL,
    SCENE_NAMES,
    SOLVER_NAMES,
    STRIP_DYNAMICS,
    T_END,
    settable_names,
)


def _parse_sets(items, scene, path=None):
    from .._errors import PPRError
    from .._params import RobotParams, parse_value
    from .._scenes import scene_names, scene_params

    kw = {}
    for item in items or []:
        if "=" not in item:
            raise PPRError(f"--set expects NAME=VALUE, got {item!r}")
        name, value = item.split("=", 1)
        name = name.strip()
        kw[name] = parse_value(name, value)
    # `modes` (simulate's static solve) is no scene: Table 1 as the registered scenes' base
    base = (scene_params(scene) if not isinstance(scene, str) or scene in scene_names()
            else RobotParams())
    if path:
        from .._params_file import load_params

        base = load_params(path, base)
    return base.replace(**kw)


def _params_dict(params):
    import dataclasses

    out = {}
    for f in dataclasses.fields(params):
        v = getattr(params, f.name)
        out[f.name] = None if v is None else (v if isinstance(v, (int, str)) else float(v))
    return out


def _derived_dict(params):
    import dataclasses

    from .._prb import derived_concrete

    # one compiled program (the one `Robot` uses), not one per operation
    dv = derived_concrete(params)
    return {f.name: float(getattr(dv, f.name)) for f in dataclasses.fields(dv)}


def frequencies_text(freqs, spec: str = ".6g") -> str:
    """A modes result's frequencies as printed: "f1, f2, ... Hz", or "none (no free
    coordinate)" (no unit) where there is none."""
    if len(freqs) == 0:
        return "none (no free coordinate)"
    return ", ".join(f"{x:{spec}}" for x in freqs) + " Hz"


def _log(msg):
    print(msg, file=sys.stderr, flush=True)


def _models(text, default):
    """--model: a model or a comma list (None: `default`'s), each once in the order given.
    Refuses an unknown name and a list with no name (`--model ""`)."""
    from .._errors import PPRError

    names = list(dict.fromkeys(m.strip() for m in (default if text is None else text).split(",")
                               if m.strip()))
    if not names:
        raise PPRError(f"--model {text!r} names no model; give one or a comma list of "
                       f"{', '.join(MODEL_NAMES)} (without --model: {default})")
    for m in names:
        if m not in MODEL_NAMES:
            raise PPRError(f"unknown model {m!r}; allowed: {', '.join(MODEL_NAMES)}")
    return names


def model_from_args(args, name: str):
    """The model `name` with the `model` parent parser's options (--elements, --strip-dynamics,
    --strip-loss)."""
    from .._errors import PPRError
    from .._models import get_model

    loss = getattr(args, "strip_loss", 0.0)
    if name == "beam" and loss != 0 and args.strip_dynamics != "full":
        raise PPRError(f"--strip-loss {loss:g} needs --strip-dynamics full (quasi-static "
                       "strips have no strip modes to damp)")
    # L0-L2 run beside the beam have no strips: --strip-loss is the beam's alone
    return get_model(name, args.elements, args.strip_dynamics,
                     strip_loss=loss if name == "beam" else 0.0)


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """argparse's formatter that appends "(default: ...)" to an option's help, except where
    that says nothing or says it twice: a default of None (the help says what happens without
    the option), a flag's False, and a help text that states its default itself ("(default",
    "default:", "default 0")."""

    def _get_help_string(self, action):
        text = action.help or ""
        d = action.default
        shown = f"{d:g}" if isinstance(d, float) else str(d)
        if (d is None or (d is False and action.nargs == 0) or "(default" in text
                or "default:" in text or f"default {shown}" in text):
            return text
        return super()._get_help_string(action)


#: help of --drop-nan, an option of every command that reads a path or a command log
DROP_NAN_HELP = ("drop the rows of the --path, --angles and --torques files that hold NaN, empty "
                 "or infinite cells (otherwise such a file is refused, naming its lines)")


def parent_parsers() -> dict:
    """Options shared by several commands, as argparse parent parsers (one definition each):
    `params` (--set), `model` (--model, --elements), `solve` (solver, tolerances, step limit),
    `times` (--t-end, --n-out; `circle_times` the same for a command without --path), `files`
    (a path of one's own and its command logs), `figures` (--figures / --no-figures). A command
    takes the ones it needs with `parents=[...]`."""
    params = argparse.ArgumentParser(add_help=False)
    params.add_argument("--params-file", dest="params_file", default=None, metavar="FILE",
                        help="read the robot's parameters from a TOML or JSON file (names as "
                             "--set, SI units); --set overrides it")
    params.add_argument("--set", action="append", metavar="NAME=VALUE",
                        help="override a parameter, NAME=VALUE (SI units); repeatable; names: "
                             + ", ".join(settable_names()))
    model = argparse.ArgumentParser(add_help=False)
    model.add_argument("--elements", type=int, default=DEFAULT_ELEMENTS,
                       help="beam elements per strip (L3)")
    model.add_argument("--strip-dynamics", default=STRIP_DYNAMICS[0], choices=list(STRIP_DYNAMICS),
                       help="L3's strips: in static equilibrium for their clamp poses (9 "
                            "coordinates, fast) or with their own inertia and kHz modes (3 + 3N "
                            "coordinates, stiff: its own default solver and tolerances, about "
                            "a minute for the 7.54 s paper-circle at N = 16)")
    model.add_argument("--strip-loss", type=float, default=0.0, metavar="SECONDS",
                       help="Kelvin-Voigt material loss of L3's strips with --strip-dynamics "
                            "full: retardation time tau (s), each strip spring damped by "
                            "tau * its stiffness (damping ratio tau*omega/2; 1e-5 damps the "
                            "first strip mode by 7.5%%); default 0 (undamped); the beam's alone")
    solve = argparse.ArgumentParser(add_help=False)
    solve.add_argument("--solver", default=None, choices=[*SOLVER_NAMES, "auto"],
                       help="ODE solver (default: per model, see the docs' Which model page); "
                            "auto: Kvaerno5 where the robot's highest natural frequency makes "
                            "the explicit solver's stable steps dearer than implicit ones")
    solve.add_argument("--rtol", type=float, default=None,
                       help=f"relative tolerance of the solver (default: the model's, {RTOL:g}; "
                            f"{FULL_L3_RTOL:g} for the full L3)")
    solve.add_argument("--atol", type=float, default=None,
                       help=f"absolute tolerance of the solver (default: the model's, {ATOL:g}; "
                            f"{FULL_L3_ATOL:g} for the full L3)")
    solve.add_argument("--max-steps", type=int, default=MAX_STEPS, help="solver step limit")
    times = argparse.ArgumentParser(add_help=False)
    times.add_argument("--t-end", type=float, default=None,
                       help=f"end time (s); default {T_END:g} (one turn of the paper's circle), "
                            f"or the last time of a --path file")
    times.add_argument("--n-out", type=int, default=N_OUT, help="number of output times")
    # the paper's circle alone (a command without --path)
    circle_times = argparse.ArgumentParser(add_help=False)
    circle_times.add_argument("--t-end", type=float, default=None,
                              help=f"end time (s); default {T_END:g} (one turn of the paper's "
                                   f"circle)")
    circle_times.add_argument("--n-out", type=int, default=N_OUT,
                              help="number of output times")
    files = argparse.ArgumentParser(add_help=False)
    files.add_argument("--path", default=None, metavar="FILE.csv",
                       help="your own experiment instead of --scene: a CSV of commanded poses "
                            "(time, x, y, phi; units as the tracker files: docs' Paths page), "
                            "the nominal path, splined C2")
    files.add_argument("--angles", default=None, metavar="FILE.csv",
                       help="with --path: the actuated angles a controller commanded (time, "
                            "th_1..th_3), which drive the model (a motion drive)")
    files.add_argument("--torques", default=None, metavar="FILE.csv",
                       help="with --path: the torques a controller applied (time, "
                            "tau_1..tau_3), which drive the model (a torque drive)")
    files.add_argument("--bc", default="auto", choices=["auto", "clamped", "natural",
                                                        "not-a-knot"],
                       help="with --path: the splines' ends: clamped (at rest), natural (the "
                            "samples cut out of a motion), not-a-knot, or auto (default): what "
                            "the file's header declares (# spline: ...), else clamped when the "
                            "file is at rest at both ends, else natural")
    files.add_argument("--drop-nan", action="store_true", help=DROP_NAN_HELP)
    files.add_argument("--drive", default="torque", choices=["torque", "motion"],
                       help="with --path and no command log: the torque model's inverse-dynamics "
                            "torques along the path (torque), or its inverse-kinematics angles "
                            "(motion)")
    figures = argparse.ArgumentParser(add_help=False)
    figures.add_argument("--figures", action=argparse.BooleanOptionalAction, default=True,
                         help="draw the figures; --no-figures writes only the JSON and CSV "
                              "files and prints the summary (the plotting library is then not "
                              "imported)")
    return {"params": params, "model": model, "solve": solve, "times": times,
            "circle_times": circle_times, "files": files, "figures": figures}


class SceneAction(argparse.Action):
    """--scene's action: stores the scene and marks it given on the command line
    (`args.scene_given`), so that a --path beside it is refused (`scene_from_args`), while the
    default scene stands aside for a --path."""

    def __call__(self, parser, namespace, values, option_string=None):
        setattr(namespace, self.dest, values)
        namespace.scene_given = True


#: the shared options of a command that runs a scene (`parent_parsers`' keys)
SCENE_OPTIONS = ("params", "model", "solve", "times", "files")


def scene_command(sub, name: str, parents: dict, fmt, *, uses=SCENE_OPTIONS,
                  scene: str = "paper-circle", model_help=None, torque_help=None, **kwargs):
    """The parser of command `name` that runs a scene: the shared options `uses` (keys of
    `parent_parsers`), then --scene (default `scene`), --model (default double1r) and
    --torque-model (a kinematic model, default reduced), with their help texts; `kwargs` (help,
    description) as `add_parser`'s."""
    p = sub.add_parser(name, formatter_class=fmt, parents=[parents[k] for k in uses], **kwargs)
    p.add_argument("--scene", default=scene, choices=list(SCENE_NAMES), action=SceneAction,
                   help="the paper's scene to run (or --path: your own experiment)")
    p.add_argument("--model", default="double1r", choices=list(MODEL_NAMES), help=model_help)
    p.add_argument("--torque-model", default="reduced", choices=list(KINEMATIC_MODELS),
                   help=torque_help)
    return p


def options_from_args(args):
    """The `SceneOptions` of the shared options `solve` and `times` (`parent_parsers`): those
    given replace the defaults."""
    from .._scenes import SceneOptions

    return SceneOptions().updated(t_end=args.t_end, n_out=args.n_out, solver=args.solver,
                                  rtol=args.rtol, atol=args.atol, max_steps=args.max_steps)


def scene_from_args(args):
    """The scene the options name: the registered `--scene`, or your own experiment, a
    `PathScene` of the commanded poses of `--path` driven by `--angles` or `--torques` (or by
    the torque model's inverse dynamics or kinematics, `--drive`). Sets `args.t_end` where it
    is None: the path file's last time, else the scenes' `T_END`. Refuses, naming the option,
    a command log without a path, two logs at once, and a --scene given beside --path."""
    import os

    from .._errors import PPRError

    path = getattr(args, "path", None)
    angles, torques = getattr(args, "angles", None), getattr(args, "torques", None)
    if path is None:
        for opt, v in (("--angles", angles), ("--torques", torques)):
            if v is not None:
                raise PPRError(f"{opt} needs --path (the commanded poses: the nominal path the "
                               f"tracking error is measured against)")
        from .._scenes import get_scene

        if getattr(args, "t_end", T_END) is None:
            args.t_end = T_END
        return get_scene(args.scene, getattr(args, "torque_model", None))
    if getattr(args, "scene_given", False):
        raise PPRError(f"--scene {args.scene} and --path are alternatives (a scene of the "
                       f"paper's, or your own experiment): give one")
    if angles is not None and torques is not None:
        raise PPRError("give one command log: --angles (a motion drive) or --torques (a torque "
                       "drive), not both")
    from .._models import get_model
    from .._paths import check_same_rate, load_commands, load_path
    from .._scenes import PathScene

    bc, drop = getattr(args, "bc", "auto"), getattr(args, "drop_nan", False)
    traj = load_path(path, bc=bc, drop_nan=drop)
    log = (load_commands(angles, kind="angles", bc=bc, drop_nan=drop) if angles is not None
           else load_commands(torques, kind="torque", bc=bc, drop_nan=drop)
           if torques is not None else None)
    if log is not None:
        check_same_rate(traj, log)
    drive = "motion" if angles is not None else "torque" if torques is not None else args.drive
    ts = traj.ts
    if getattr(args, "t_end", None) is None:
        args.t_end = float(ts[-1] - ts[0])
    if float(ts[0]) != 0.0:
        raise PPRError(f"{path}: the path's first time is {float(ts[0]):g} s; the scenes start "
                       f"at t = 0 (shift the file's times)")
    return PathScene(traj, drive=drive, command_log=log,
                     input_model=get_model(getattr(args, "torque_model", None) or "reduced"),
                     name=os.path.splitext(os.path.basename(path))[0])


def check_commands_from_args(scene, params, args) -> None:
    """A `--path` scene's command log against the robot of the options (its span and an angle
    log's assembly mode: `check_scene_commands`), before anything is compiled or announced: a
    refusal is the command's one line."""
    if getattr(args, "path", None) is None:
        return
    from .._scenes import check_scene_commands

    check_scene_commands(scene, params, scene.trajectory(), getattr(args, "t_end", None))


def check_out_dir(path: str, create: bool = True) -> str:
    """Make sure the output directory can be written before a long run starts (`PPRError`
    naming it). It is created; with `create=False` it is not, and its nearest existing parent is
    checked instead (a run refused later then leaves nothing behind). Writable means a file can
    be created and removed there (the permission bits say nothing for root, and nothing of a
    read-only file system)."""
    import tempfile

    from .._errors import PPRError

    if os.path.exists(path) and not os.path.isdir(path):
        raise PPRError(f"--out {path!r} is a file, not a directory")
    where = path
    if create:
        try:
            os.makedirs(path, exist_ok=True)
        except OSError as err:
            raise PPRError(f"--out {path!r}: cannot create the directory "
                           f"({err.strerror})") from None
    else:
        while not os.path.isdir(where):
            if os.path.exists(where):
                raise PPRError(f"--out {path!r}: {where!r} is a file, not a directory")
            parent = os.path.dirname(os.path.abspath(where))
            if parent == os.path.abspath(where):
                break
            where = parent
    try:
        fd, probe = tempfile.mkstemp(prefix=".ppr-jax-probe-", dir=where)
        os.close(fd)
        os.remove(probe)
    except OSError as err:
        what = "the directory" if where == path else f"its parent {where!r}"
        raise PPRError(f"--out {path!r}: {what} is not writable "
                       f"({err.strerror or type(err).__name__})") from None
    return path


def _write_json(path, obj):
    from .._files import write_file

    with write_file(path) as f:
        json.dump(obj, f, indent=2)


def _out_dir(path):
    """Create the output directory (or check it) before a long run (`check_out_dir`)."""
    check_out_dir(path)


def _write_rows(path, rows, columns):
    from .._files import write_file

    with write_file(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=columns)
        w.writeheader()
        for r in rows:
            w.writerow({c: r[c] for c in columns})


def _name_values(items, what):
    from .._params import parse_value

    out = {}
    for item in items or []:
        if "=" not in item:
            raise ValueError(f"{what} expects NAME=VALUE, got {item!r}")
        name, value = (v.strip() for v in item.split("=", 1))
        out[name] = parse_value(name, value)
    return out
