"""A design's specification in a TOML file (`ppr-jax design --spec`): plain Python, read before
anything is compiled.

```toml
[variables]            # name = [lo, hi], SI units
t = [1e-4, 1e-3]
r = [0.01, 0.04]

[objective]            # maximize = NAME or minimize = NAME
maximize = "pivot_frequency_hz"

[[constraints]]        # metric and upper and/or lower, in the metric's unit
metric = "pivot_stress_Pa"
upper = 1e8

[[constraints]]        # or a band the metric must stay out of: avoid = [lo, hi]
metric = "pivot_frequency_hz"
avoid = [4.0, 6.0]

[settings]             # design()'s keywords; a scene's t_end, n_out, solver, rtol, atol,
stroke = 0.3           # max_steps; params_file (relative to this file)
optimizer = "slsqp"

[params]               # the base robot's values, names as --set (optional)
w = 0.026
```
"""

from __future__ import annotations

import os

from ..._errors import DesignError, PPRError
from ..._params import RobotParams
from ..._params_file import check_param_values, read_toml
from ..._scenes import SceneOptions
from ._goals import as_constraints, as_objective
from ._variables import check_variables

#: the [settings] keys that are `design`'s keywords
DESIGN_KEYS = ("stroke", "scene", "model", "torque_model", "frequency_model", "optimizer",
               "mode", "starts", "candidates", "max_iter", "grid", "grid_rtol", "fd_rtol",
               "seed", "pose", "strip_load", "l3_elements")
#: the [settings] keys that are `SceneOptions`' fields
OPTION_KEYS = ("t_end", "n_out", "solver", "rtol", "atol", "max_steps")
SECTIONS = ("variables", "objective", "constraints", "settings", "params")


def load_design_spec(path: str) -> dict:
    """Read a design specification (module docstring).

    **Arguments:**

    - `path`: the `.toml` file.

    **Returns:** {variables, objective, constraints, settings (design's keywords), options
    ({SceneOptions field: value}), params ({name: value}), params_file (a path or None)}.
    A `DesignError` names the file and what is wrong in it.
    """
    from ._arguments import check_keywords

    where = f"design specification {str(path)!r}"
    try:
        data = read_toml(path)
    except OSError as err:
        raise DesignError(f"{where}: {err.strerror or err}") from None
    except PPRError as err:
        raise DesignError(f"{where}: {err}") from None
    except ValueError as err:
        raise DesignError(f"{where} is not valid TOML: {err}") from None
    unknown = sorted(set(data) - set(SECTIONS))
    if unknown:
        raise DesignError(f"{where}: unknown section(s) {unknown}; allowed: {', '.join(SECTIONS)}")
    for sec in ("variables", "objective"):
        if not isinstance(data.get(sec), dict) or not data[sec]:
            raise DesignError(f"{where}: a [{sec}] table is required")
    variables = {}
    for name, b in data["variables"].items():
        if not isinstance(b, list) or len(b) != 2:
            raise DesignError(f"{where}: variable {name} must be [lo, hi], got {b!r}")
        variables[name] = tuple(b)
    cons = data.get("constraints", [])
    if not isinstance(cons, list) or not all(isinstance(c, dict) for c in cons):
        raise DesignError(f"{where}: constraints must be [[constraints]] tables")
    try:  # every field checked here, so that the error names the file
        check_variables(variables)
        as_objective(dict(data["objective"]))
        as_constraints(cons)
    except DesignError as err:
        raise DesignError(f"{where}: {err}") from None
    settings = dict(data.get("settings", {}))
    params_file = settings.pop("params_file", None)
    if params_file is not None:
        params_file = os.path.join(os.path.dirname(os.path.abspath(path)), str(params_file))
    options = {k: settings.pop(k) for k in OPTION_KEYS if k in settings}
    unknown = sorted(set(settings) - set(DESIGN_KEYS))
    if unknown:
        raise DesignError(f"{where}: unknown setting(s) {unknown}; allowed: "
                          f"{', '.join(DESIGN_KEYS + OPTION_KEYS + ('params_file',))}")
    try:
        check_keywords(settings)
    except DesignError as err:
        raise DesignError(f"{where}: [settings] {err}") from None
    try:
        SceneOptions().updated(**options).check()
    except PPRError as err:
        raise DesignError(f"{where}: [settings] {err}") from None
    params = data.get("params", {})
    if not isinstance(params, dict):
        raise DesignError(f"{where}: [params] must be a table of name = value")
    try:  # the kinds and ranges of the values, each alone (the base robot is not known yet)
        params = check_param_values(params, f"{where}: [params]")
        for name, value in params.items():
            RobotParams().replace(**{name: value})
    except PPRError as err:
        msg = str(err)
        raise DesignError(msg if msg.startswith(where) else f"{where}: [params] {msg}") \
            from None
    return {"variables": variables, "objective": dict(data["objective"]), "constraints": cons,
            "settings": settings, "options": options, "params": params,
            "params_file": params_file}
