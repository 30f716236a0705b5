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
    MAX_STEPS,
    MODEL_NAMES,
    N_OUT,
    RTOL,
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
    base = scene_params(scene) if scene in scene_names() else RobotParams()
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


def _log(msg):
    print(msg, file=sys.stderr, flush=True)


def _models(text, default):
    names = [m.strip() for m in (text or default).split(",") if m.strip()]
    for m in names:
        if m not in MODEL_NAMES:
            from .._errors import PPRError

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


def parent_parsers() -> dict:
    """Options shared by several commands, as argparse parent parsers (one definition each):
    `params` (--set), `model` (--model, --elements), `solve` (solver, tolerances, step limit,
    times), `out` (--out). A command takes the ones it needs with `parents=[...]`."""
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
                       help=f"relative tolerance of the solver (default {RTOL:g}; "
                            f"{FULL_L3_RTOL:g} for the full L3 in simulate)")
    solve.add_argument("--atol", type=float, default=None,
                       help=f"absolute tolerance of the solver (default {ATOL:g}; "
                            f"{FULL_L3_ATOL:g} for the full L3 in simulate)")
    solve.add_argument("--max-steps", type=int, default=MAX_STEPS, help="solver step limit")
    times = argparse.ArgumentParser(add_help=False)
    times.add_argument("--t-end", type=float, default=T_END, help="end time (s)")
    times.add_argument("--n-out", type=int, default=N_OUT, help="number of output times")
    return {"params": params, "model": model, "solve": solve, "times": times}


def check_out_dir(path: str) -> str:
    """Make sure the output directory can be written before a long run starts (`PPRError`)."""
    from .._errors import PPRError

    if os.path.exists(path) and not os.path.isdir(path):
        raise PPRError(f"--out {path!r} is a file, not a directory")
    try:
        os.makedirs(path, exist_ok=True)
    except OSError as err:
        raise PPRError(f"--out {path!r}: cannot create the directory ({err.strerror})") from None
    if not os.access(path, os.W_OK):
        raise PPRError(f"--out {path!r}: the directory is not writable")
    return path


def _write_json(path, obj):
    with open(path, "w") as f:
        json.dump(obj, f, indent=2)


def _out_dir(path):
    """Create the output directory (or check it) before a long run."""
    if os.path.exists(path) and not os.path.isdir(path):
        raise ValueError(f"--out {path!r} is a file, not a directory")
    os.makedirs(path, exist_ok=True)
    if not os.access(path, os.W_OK):
        raise ValueError(f"--out {path!r} is not writable")


def _write_rows(path, rows, columns):
    with open(path, "w", newline="") as f:
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
