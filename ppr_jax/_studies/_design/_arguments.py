"""The argument checks of `design`, before anything is compiled: the variables, the objective and
constraints, the robot and options, and every keyword a specification's [settings] may give too
(`KEYWORD_CHECKS`), each refused with a `DesignError` naming it and what is allowed."""

from __future__ import annotations

import math

from ..._errors import (
    DesignError,
    PPRError,
    check_instance,
    check_int,
    check_number as _check_number,
    check_vector,
)
from ..._models import get_model
from ..._names import DESIGN_OPTIMIZERS
from ..._params import RobotParams
from ..._scenes import SceneOptions, get_scene
from ._goals import as_constraints, as_objective
from ._variables import check_variables


def check_number(*args, **kwargs):
    """`_errors.check_number`, its error a `DesignError`."""
    return _check_number(*args, **kwargs, error=DesignError)


def _names_check(check):
    """`check(value)`, a `PPRError` of the model or scene registries as a `DesignError`."""
    def run(name, value):
        try:
            return check(value)
        except DesignError:
            raise
        except PPRError as err:
            raise DesignError(f"{name}: {err}") from None
    return run


def _model_or_none(value):
    if value is not None:
        get_model(value)
    return value


def _scene_or_none(value):
    if value is not None:
        get_scene(value)
    return value


def _model(value):
    get_model(value)
    return value


#: `design`'s keywords that a specification's [settings] may give, each with its check
#: (name, value) -> the value normalised, raising a `DesignError` naming it and what is allowed
#: (before anything is compiled: `check_keywords`)
KEYWORD_CHECKS = {
    "stroke": lambda n, v: None if v is None else check_number(n, v, 0.0, math.pi, "rad",
                                                                open_lo=True),
    "scene": _names_check(_scene_or_none),
    "model": _names_check(_model),
    "torque_model": _names_check(_model_or_none),
    "frequency_model": _names_check(_model),
    "optimizer": lambda n, v: _choice(n, v, DESIGN_OPTIMIZERS),
    "mode": lambda n, v: None if v is None else _choice(n, v, ("fwd", "rev")),
    "starts": lambda n, v: check_number(n, v, 1, 1000, integer=True),
    "candidates": lambda n, v: check_number(n, v, 1, 100_000, integer=True),
    "max_iter": lambda n, v: check_number(n, v, 1, 100_000, integer=True),
    "grid": lambda n, v: check_number(n, v, 1, 10_000_000, integer=True),
    "grid_rtol": lambda n, v: check_number(n, v, 0.0, 1.0),
    "fd_rtol": lambda n, v: None if v is None else check_number(n, v, 0.0, 1.0),
    "seed": lambda n, v: check_int(n, v, 0, 2**63 - 1, error=DesignError),
    "pose": lambda n, v: None if v is None else check_vector(
        n, v, 3, error=DesignError, what="(x, y, phi) (m, m, rad)"),
    "strip_load": lambda n, v: None if v is None else check_vector(
        n, v, 3, error=DesignError, what="(fx, fy, m) (N, N, N m)"),
    "l3_elements": lambda n, v: None if v is None else check_number(n, v, 1, 64,
                                                                     integer=True),
}


def _choice(name, value, allowed):
    if not isinstance(value, str) or value not in allowed:
        raise DesignError(f"{name} must be one of {', '.join(allowed)}, got {value!r}")
    return value


def check_keywords(keywords: dict) -> dict:
    """`design`'s keywords `keywords` {name: value} checked (`KEYWORD_CHECKS`) and normalised;
    the names not checked there are refused. A `DesignError` names the keyword, its value and
    what is allowed."""
    unknown = sorted(set(keywords) - set(KEYWORD_CHECKS))
    if unknown:
        raise DesignError(f"unknown design setting(s) {unknown}; allowed: "
                          f"{', '.join(KEYWORD_CHECKS)}")
    return {k: KEYWORD_CHECKS[k](k, v) for k, v in keywords.items()}


def check_arguments(variables, objective, constraints, params, options, keywords: dict) -> tuple:
    """`design`'s arguments checked: (names, lo, hi) of the variables (`check_variables`), the
    objective and the constraints as objects (`as_objective`, `as_constraints`), the keywords
    normalised (`check_keywords`); `params` a `RobotParams` and `options` a `SceneOptions`
    where given. Returns (names, lo, hi, objective, constraints, keywords)."""
    names, lo, hi = check_variables(variables)
    obj = as_objective(objective)
    cons = as_constraints(constraints)
    kw = check_keywords(keywords)
    if params is not None:
        check_instance("params", params, RobotParams, error=DesignError, what="a RobotParams")
    if options is not None:
        check_instance("options", options, SceneOptions, error=DesignError,
                       what="a SceneOptions")
    return names, lo, hi, obj, cons, kw
