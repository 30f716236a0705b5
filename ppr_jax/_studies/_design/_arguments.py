"""The argument checks of `design`, before anything is compiled: the variables, the objective and
constraints, the robot and options, and every keyword a specification's [settings] may give too
(`KEYWORD_CHECKS`), each refused with a `DesignError` naming it and what is allowed; then the
metrics against the scene and what they need (`check_metrics`), and the base robot
(`check_base`)."""

from __future__ import annotations

import math

import numpy as np

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
from ..._scenes import SceneOptions, check_scene_commands, get_scene
from .._catalogue import CATALOGUE, SceneContext, allowed_metrics, tracking_metrics
from .._sensitivity import explicit_params
from ._constraints import with_path_margins
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


def check_metrics(objective, constraints, scene, model, torque_model, frequency_model, options,
                  keywords: dict) -> tuple:
    """The metrics of `objective` and `constraints` checked against what the design gives them:
    the scene's (a scene's metrics need one; `allowed_metrics`), a tracking error not of a
    model that follows its own input, the stroke and the strip's load where a metric needs
    them, and a `frequency_model` with free coordinates for the pose metrics. On a scene the
    path margins are bounded too (`with_path_margins`).

    **Arguments:**

    - `objective`, `constraints`: an `Objective` and a list of `Constraint`s.
    - `scene`, `model`, `torque_model`, `frequency_model`, `options`: as `design`'s.
    - `keywords`: the checked keywords (`check_keywords`), for stroke, pose and strip_load.

    **Returns:** (the `SceneContext`, the checked `SceneOptions` (None without a scene), the
    metrics (the objective's first), the constraints, the stroke (rad; 0 where unused)).
    """
    scene_ = model_ = prepared = opts = None
    if scene is not None:
        scene_, model_ = get_scene(scene, torque_model), get_model(model)
        opts = (SceneOptions() if options is None else options).check()
        prepared = opts.prepared(model_, scene_.trajectory())
    allowed = allowed_metrics(None if prepared is None else prepared.trajectory, "design")
    if scene_ is not None:
        constraints = with_path_margins(constraints)
    metrics = list(dict.fromkeys([objective.metric] + [c.metric for c in constraints]))
    for m in metrics:
        if m not in allowed:
            more = "" if scene is not None else " (a scene's metrics need scene=...)"
            raise DesignError(f"unknown design metric {m!r}; allowed: {', '.join(allowed)}{more}")
    if scene_ is not None:
        # its tracking error only: its torques, stresses and energies are the robot's
        scene_metrics = tracking_metrics(metrics)
        follows = scene_.follows_its_input(model_)
        if follows and scene_metrics:
            raise DesignError(f"{', '.join(scene_metrics)} of model {model_.name!r} in "
                              f"{scene_.name!r} measure the integrator's error, not the robot:"
                              f" {follows}. Design with another model (double1r or beam)")
    needing = {k: [m for m in metrics if k in CATALOGUE[m].requires]
               for k in ("stroke", "strip_load")}
    stroke, strip_load = keywords["stroke"], keywords["strip_load"]
    if needing["stroke"] and stroke is None:
        raise DesignError(f"{', '.join(needing['stroke'])} needs stroke= (the joint rotation, "
                          f"rad, in (0, 3.14159])")
    fmodel = get_model(frequency_model)
    if needing["strip_load"] and strip_load is None:
        raise DesignError(f"{', '.join(needing['strip_load'])} need strip_load=(fx, fy, m) "
                          f"(N, N, N m), three finite numbers, got None")
    pose_metrics = [m for m in metrics if CATALOGUE[m].needs == "pose"]
    if pose_metrics and fmodel.actuated_index is None:
        raise DesignError(f"{', '.join(pose_metrics)} need a "
                          f"frequency_model with free coordinates when the actuators are locked "
                          f"(double1r or beam), got {fmodel.name!r}")
    ctx = SceneContext(scene_, model_, prepared, fmodel, keywords["pose"],
                       strip_load if needing["strip_load"] else None)
    return ctx, opts, metrics, constraints, 0.0 if stroke is None else float(stroke)


def check_base(params, ctx: SceneContext, options, names) -> RobotParams:
    """The design's base robot: `params`, or the scene's (Table 1 without a scene); one robot,
    its PRB parameters explicit where a variable is among gamma, rho and K_theta (they follow
    theta_c otherwise), and on a scene the commands fit it (`check_scene_commands`, over the
    checked `options`' horizon)."""
    if params is None:
        base = ctx.scene.default_params() if ctx.scene is not None else RobotParams()
    else:
        base = params
    if np.ndim(base.a) != 0:
        raise DesignError("a design starts from one robot, not a batch")
    if any(n in ("gamma", "rho", "K_theta") and getattr(base, n) is None for n in names):
        base = explicit_params(base)
    if ctx.scene is not None:
        check_scene_commands(ctx.scene, base, ctx.options.trajectory, options.t_end)
    return base
