"""A robot's parameters in a file (TOML or JSON), as a lab keeps them beside its data."""

from __future__ import annotations

import dataclasses
import json
import math
import os
from typing import Optional, Sequence

from ._errors import PPRError
from ._files import write_file
from ._params import PARAM_RANGES, RobotParams, settable_names

#: the formats by file extension
PARAMS_FORMATS = (".toml", ".json")


def _format(path: str) -> str:
    ext = os.path.splitext(str(path))[1].lower()
    if ext not in PARAMS_FORMATS:
        raise PPRError(f"parameter file {str(path)!r}: the extension must be one of "
                       f"{', '.join(PARAMS_FORMATS)}, got {ext or 'none'!r}")
    return ext


#: the UTF-8 byte-order mark some editors write first (Windows' Notepad): not TOML, skipped
BOM = b"\xef\xbb\xbf"


def read_toml(path: str) -> dict:
    """The TOML file `path` as a dict, a UTF-8 byte-order mark before it skipped (the one place
    this library reads TOML). Raises `OSError` for a file that cannot be read, `ValueError`
    (tomllib's `TOMLDecodeError`) for text that is not TOML, and `PPRError` where no TOML
    reader is installed (Python 3.10 without tomli)."""
    try:
        import tomllib
    except ImportError:  # Python 3.10
        try:
            import tomli as tomllib
        except ImportError:
            raise PPRError("reading TOML needs Python 3.11 or the tomli package") from None
    with open(path, "rb") as f:
        raw = f.read()
    if raw.startswith(BOM):
        raw = raw[len(BOM):]
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise ValueError(f"not UTF-8 text ({err})") from None
    return tomllib.loads(text)


def check_param_values(data: dict, where: str) -> dict:
    """The values of `data` {name: value} as `RobotParams.replace` takes them, each checked for
    its kind (a number, an integer `sigma`, a string `joint_geometry`) and, for a number, for
    float64's range: a `PPRError` names `where` (the file), the name and the value. Unknown
    names are refused with the allowed ones."""
    unknown = sorted(set(data) - set(settable_names()))
    if unknown:
        raise PPRError(f"{where}: unknown name(s) {unknown}; allowed: "
                       f"{', '.join(settable_names())}")
    changes = {}
    for name, value in data.items():
        if name == "joint_geometry":
            ok = isinstance(value, str)
        elif name == "sigma":
            ok = isinstance(value, int) and not isinstance(value, bool)
        else:
            ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        if not ok:
            raise PPRError(f"{where}: {name} = {value!r} is not a "
                           f"{'string' if name == 'joint_geometry' else 'number'}")
        if name in PARAM_RANGES:
            try:
                value = float(value)
            except OverflowError:  # an integer beyond float's range (TOML reads 1e400 as inf)
                lo, hi, unit, _ = PARAM_RANGES[name]
                digits = len(str(abs(value)))
                raise PPRError(f"{where}: {name} = an integer of {digits} digits is out of "
                               f"range; allowed: [{lo:g}, {hi:g}] {unit}".rstrip()) from None
        changes[name] = value
    return changes


def load_params(path: str, base: Optional[RobotParams] = None) -> RobotParams:
    """Read a robot's parameters from a TOML or JSON file (by extension).

    The file holds `name = value` pairs (TOML) or one object (JSON) of the names `RobotParams`
    takes (`settable_names()`), in SI units: floats for the physical parameters, an integer for
    `sigma`, a string for `joint_geometry`; TOML may group them in a `[params]` table. A name not
    in the file keeps its value in `base` (default: Table 1, `RobotParams()`).

    **Arguments:**

    - `path`: the file (`.toml` or `.json`).
    - `base`: the parameters the file's values replace.

    **Returns:** the `RobotParams`, validated like the constructor (a `PPRError` names a value out
    of its range, an unknown name, or a value of the wrong kind, with the file's name).
    """
    ext = _format(path)
    try:
        if ext == ".json":
            with open(path, encoding="utf-8-sig") as f:  # a byte-order mark skipped
                data = json.load(f)
        else:
            data = read_toml(path)
    except OSError as err:
        raise PPRError(f"parameter file {str(path)!r}: {err.strerror or err}") from None
    except ValueError as err:  # json.JSONDecodeError and tomllib.TOMLDecodeError
        raise PPRError(f"parameter file {str(path)!r} is not valid {ext[1:].upper()}: "
                       f"{err}") from None
    if isinstance(data, dict) and set(data) == {"params"} and isinstance(data["params"], dict):
        data = data["params"]
    if not isinstance(data, dict):
        raise PPRError(f"parameter file {str(path)!r} must hold name = value pairs")
    changes = check_param_values(data, f"parameter file {str(path)!r}")
    base = RobotParams() if base is None else base
    try:
        return base.replace(**changes)
    except (PPRError, OverflowError) as err:
        raise PPRError(f"parameter file {str(path)!r}: {err}") from None


def save_params(params: RobotParams, path: str, *, comments: Sequence[str] = ()) -> str:
    """Write one robot's parameters to a TOML or JSON file (by extension) that `load_params`
    reads back exactly (floats in `repr`'s shortest round-trip form). Parameters left to the PRB
    table (`gamma`, `rho`, `K_theta` None) are left out. `comments`: lines written as TOML
    comments after the header (where the parameters came from, how far to trust them); JSON has
    no comments, so they need a .toml path. Returns the path."""
    ext = _format(path)
    if comments and ext == ".json":
        raise PPRError(f"save_params: {path}: comments need a .toml file (JSON has none)")
    values = {}
    for f in dataclasses.fields(params):
        v = getattr(params, f.name)
        if v is None:
            continue
        if f.name in PARAM_RANGES:
            x = float(v)
            if not math.isfinite(x):
                raise PPRError(f"save_params: {f.name} is not finite")
            values[f.name] = x
        else:
            values[f.name] = v
    if ext == ".json":
        text = json.dumps(values, indent=2) + "\n"
    else:
        lines = ["# ppr_jax robot parameters (SI units)"]
        lines += [f"# {c}" for text in comments for c in str(text).splitlines()]
        for k, v in values.items():
            lines.append(f'{k} = "{v}"' if isinstance(v, str) else f"{k} = {v!r}")
        text = "\n".join(lines) + "\n"
    with write_file(path, "w", encoding="utf-8") as fh:
        fh.write(text)
    return str(path)
