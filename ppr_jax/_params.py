"""Robot parameters (MODEL.md section 1, the paper's Table 1).

`RobotParams` is an `equinox.Module` whose fields are float64 array leaves, so a batch of robots is
one pytree with a leading axis (`stack_params`) and every field is differentiable. A value given
as a host number or numpy array stays a numpy array (JAX arrays and tracers stay JAX's): a
jitted call takes either alike, and building, checking and replacing parameters moves nothing
to the device (Table 1 with a scene's thickness: 1.8 -> 0.5 ms, a warm L1 `paper-circle` call
about 1.2 ms shorter). The elbow
orientation `sigma` is a discrete branch choice and therefore a static field.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any, Optional

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._custom_types import Array, as_f64
from ._errors import PPRError, is_traced
from ._names import PARAM_RANGES, settable_names


def _f(x):
    if isinstance(x, (str, bytes)) or x is None:
        raise PPRError(f"a parameter must be a number or an array of numbers, got {x!r}")
    if isinstance(x, int) and not isinstance(x, bool):
        try:
            x = float(x)
        except OverflowError:  # beyond float64: inf, which `check_params` names with the field
            x = math.inf if x > 0 else -math.inf
    # kept on the host: building, checking and replacing parameters moves nothing to the device
    return as_f64(x)


def _field(default):
    return eqx.field(default_factory=lambda: _f(default), converter=_f)


def _optional(x):
    return None if x is None else _f(x)


#: `sigma` (elbow orientation) is +1 or -1.
SIGMA_VALUES = (-1, 1)
#: where the PRB joint is built (MODEL.md sections 3 and 3a): on the link centre lines, as the
#: paper does, or on the actual strip (radius r, ends at the clamps on the links' inner sides)
JOINT_GEOMETRIES = ("centerline", "strip")


class RobotParams(eqx.Module):
    """Parameters of the planar 3-RRR robot with compliant joints (SI units).

    Defaults are MODEL.md section 1 (paper Table 1, strip thickness of the simulation, 0.3 mm).
    `gamma`, `rho`, `K_theta` are the PRB parameters of each half of the compliant joint
    (MODEL.md section 3). `gamma=None` / `K_theta=None` (the default) take them from the PRB table
    fitted to the elastica (`ppr_jax.prb_parameters(kappa0)`, kappa0 = theta_c/2; MODEL.md
    section 8); `rho=None` means Howell's geometric definition (the PRB link ends at the unloaded
    tip). The paper's Table-2 style values used before the fit landed were gamma = 0.81,
    K_theta = 2.50. All float fields are differentiable array leaves (scalars, or a leading batch
    axis for a batch of robots).
    """

    a: Array = _field(0.900)
    h: Array = _field(0.080)
    t_p: Array = _field(0.025)
    l1: Array = _field(0.366)
    l3: Array = _field(0.366)
    b_r: Array = _field(0.023)
    t_r: Array = _field(0.010)
    r: Array = _field(0.020)
    theta_c: Array = _field(1.88)
    w: Array = _field(0.026)
    t: Array = _field(0.3e-3)
    E: Array = _field(71.0e9)
    rho_m: Array = _field(2780.0)
    gamma: Optional[Array] = eqx.field(default=None, converter=_optional)
    K_theta: Optional[Array] = eqx.field(default=None, converter=_optional)
    rho: Optional[Array] = eqx.field(default=None, converter=_optional)
    J_rotor: Array = _field(0.0)
    c_spring: Array = _field(0.0)
    c_act: Array = _field(0.0)
    sigma: int = eqx.field(static=True, default=-1)
    joint_geometry: str = eqx.field(static=True, default="centerline")

    def __check_init__(self):
        if isinstance(self.sigma, bool) or self.sigma not in SIGMA_VALUES:
            raise PPRError(
                f"parameter 'sigma' (elbow orientation) must be -1 or +1, got {self.sigma!r}"
            )
        if self.joint_geometry not in JOINT_GEOMETRIES:
            raise PPRError(
                f"parameter 'joint_geometry' must be one of {', '.join(JOINT_GEOMETRIES)}, got "
                f"{self.joint_geometry!r}"
            )
        check_params(self)

    def replace(self, **changes: Any) -> "RobotParams":
        """A copy with some fields changed (validated like the constructor)."""
        unknown = set(changes) - {f.name for f in dataclasses.fields(self)}
        if unknown:
            raise PPRError(
                f"unknown parameter(s) {sorted(unknown)}; allowed: {sorted(settable_names())}"
            )
        for name, v in changes.items():  # named here: the converter does not know the field
            if name in PARAM_RANGES and not (v is None and name in OPTIONAL_PARAMS):
                _check_value(name, v)
        kw = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        kw.update(changes)
        return RobotParams(**kw)


@functools.lru_cache(maxsize=32)
def table1_with_thickness(t: float) -> "RobotParams":
    """Table 1 with strip thickness `t` (m), built and checked once per thickness (a scene's
    defaults, on every call that leaves the robot to the scene). Its numpy leaves are made
    read-only: the one object is shared, and `robot_of` keeps its `Robot`."""
    params = RobotParams().replace(t=t)
    for leaf in jax.tree_util.tree_leaves(params):
        if isinstance(leaf, np.ndarray):
            leaf.flags.writeable = False
    return params


#: the float parameters that may be None (the PRB table's or Howell's value)
OPTIONAL_PARAMS = ("gamma", "K_theta", "rho")


def _check_value(name: str, v) -> None:
    """Raise `PPRError` naming parameter `name` and its range where `v` is no number or array
    of numbers (a string, None, an integer beyond float64's range); a traced value passes."""
    if is_traced(v):
        return
    lo, hi, unit, meaning = PARAM_RANGES[name]
    rng = f"allowed range [{lo:g}, {hi:g}] {unit}".rstrip()
    if isinstance(v, int) and not isinstance(v, bool) and abs(v) >= 10**300:
        try:
            float(v)
        except OverflowError:
            raise PPRError(f"parameter {name!r} ({meaning}) = an integer of {len(str(abs(v)))} "
                           f"digits is beyond the range of a float ({rng})") from None
    if v is None or isinstance(v, (str, bytes, bool)):
        raise PPRError(f"parameter {name!r} ({meaning}) must be a number, got {v!r} ({rng})")
    try:
        np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        text = repr(v)
        text = text if len(text) <= 60 else text[:57] + "..."
        raise PPRError(f"parameter {name!r} ({meaning}) must be a number or an array of "
                       f"numbers, got {text} ({rng})") from None


def check_params(params: RobotParams) -> None:
    """Raise `ValueError` naming the parameter and its allowed range if a concrete value is out of
    range (or not finite). Traced values (inside jit/vmap) are skipped here and checked by
    `validate_traced` instead."""
    for name, (lo, hi, unit, meaning) in PARAM_RANGES.items():
        v = getattr(params, name)
        if v is None or is_traced(v):
            continue
        arr = np.asarray(v)
        nonfinite = ~np.isfinite(arr)
        bad = nonfinite | (arr < lo) | (arr > hi)
        if np.any(bad):
            where = "" if arr.ndim == 0 else f" at batch index {np.flatnonzero(bad).tolist()}"
            rng = f"[{lo:g}, {hi:g}] {unit}".rstrip()
            what = (("is not finite" + (" (an integer beyond the range of a float reads as "
                                         "inf)" if np.any(np.isinf(arr[bad])) else "")
                     + f" (allowed range {rng})")
                    if np.all(nonfinite[bad]) else f"is out of its allowed range {rng}")
            raise PPRError(
                f"parameter {name!r} ({meaning}) = {arr[bad].tolist() if arr.ndim else float(arr)}"
                f"{where} {what}"
            )


def params_invalid(params: RobotParams):
    """Traceable: True where a parameter is not finite or out of its range (a bool, batched like
    the parameters). For status codes inside compiled programs (no host callback)."""
    bad = jnp.asarray(False)
    for name, (lo, hi, _, _) in PARAM_RANGES.items():
        v = getattr(params, name)
        if v is None:
            continue
        bad = bad | ~jnp.isfinite(v) | (v < lo) | (v > hi)
    return bad


def stack_params(params_list: list[RobotParams]) -> RobotParams:
    """Stack robots into one batched `RobotParams` (leading axis) for `jax.vmap`. Every member is
    validated; an error names the bad member (its index in `params_list`)."""
    params_list = list(params_list)
    if not params_list:
        raise PPRError("stack_params needs at least one RobotParams")
    for i, p in enumerate(params_list):
        if not isinstance(p, RobotParams):
            raise PPRError(f"stack_params: member {i} is a {type(p).__name__}, not RobotParams")
        if np.ndim(p.a) != 0:
            raise PPRError(f"stack_params: member {i} is already a batch (stack single robots)")
        try:
            check_params(p)
        except PPRError as err:
            raise PPRError(f"stack_params: member {i}: {err}") from None
    sigma0 = params_list[0].sigma
    for i, p in enumerate(params_list):
        if p.sigma != sigma0:
            raise PPRError(
                f"stack_params: member {i} has sigma = {p.sigma}, member 0 sigma = {sigma0}: all "
                f"robots of a batch must share sigma (a static branch choice)"
            )
    for i, p in enumerate(params_list):
        if p.joint_geometry != params_list[0].joint_geometry:
            raise PPRError(
                f"stack_params: member {i} has joint_geometry = {p.joint_geometry!r}, member 0 "
                f"{params_list[0].joint_geometry!r}: a batch shares its joint geometry (static)"
            )
    for name in ("gamma", "rho", "K_theta"):
        given = [getattr(p, name) is not None for p in params_list]
        if len(set(given)) != 1:
            i = given.index(not given[0])
            raise PPRError(
                f"stack_params: member {i} {'gives' if given[i] else 'does not give'} {name} "
                f"but member 0 {'does' if given[0] else 'does not'}: either every robot of a "
                f"batch gives {name} explicitly or none does"
            )
    return jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *params_list)


def member_params(params: RobotParams, i: int) -> RobotParams:
    """Member i of a batch of parameters (`stack_params`); unbatched leaves are shared."""
    return jax.tree_util.tree_map(lambda x: x[i] if np.ndim(x) else x, params)


def unstack_params(params: RobotParams) -> list[RobotParams]:
    """Inverse of `stack_params`.

    Each batched leaf is copied to the host once and its members cut there: indexing the device
    array member by member is one dispatched operation per member and field (16 fields), which
    for a batch of 1,024 took 3 s, as long as the batch's simulation."""
    leaves, tree = jax.tree_util.tree_flatten(params)
    host = [np.asarray(x) if np.ndim(x) else None for x in leaves]
    return [tree.unflatten([x if h is None else jnp.asarray(h[i]) for x, h in zip(leaves, host)])
            for i in range(params.a.shape[0])]


def parse_value(name: str, text: str):
    """Parse a CLI ``NAME=VALUE`` value (floats; ``sigma`` int; ``gamma``/``rho``/``K_theta``
    ``=auto`` for the default source: the fitted PRB table, Howell's geometric rho)."""
    if name not in settable_names():
        raise PPRError(f"unknown parameter {name!r}; allowed: {', '.join(settable_names())}")
    if name == "joint_geometry":
        if text.strip() not in JOINT_GEOMETRIES:
            raise PPRError(f"parameter 'joint_geometry' must be one of "
                           f"{', '.join(JOINT_GEOMETRIES)}, got {text!r}")
        return text.strip()
    if name == "sigma":
        try:
            v = float(text)
        except ValueError:
            v = math.nan
        if v not in SIGMA_VALUES:  # 1.5 is not truncated to 1
            raise PPRError(f"parameter 'sigma' (elbow orientation) must be -1 or +1, got {text!r}")
        return int(v)
    if name in ("gamma", "rho", "K_theta") and text.strip().lower() in (
        "none", "auto", "table", "geometry"
    ):
        return None
    try:
        v = float(text)
    except ValueError:
        raise PPRError(f"parameter {name!r}: cannot read {text!r} as a number") from None
    if not math.isfinite(v):
        lo, hi, unit, _ = PARAM_RANGES[name]
        raise PPRError(
            f"parameter {name!r} must be finite (allowed range [{lo:g}, {hi:g}] {unit}), "
            f"got {text!r}"
        )
    return v
