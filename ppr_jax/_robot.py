"""`Robot`: the parameters, their derived quantities and the static structural choices, built once.

As MJX builds its `Model` once from an MJCF, a `Robot` is built once from `RobotParams` and then
passed to every model, solver and scene: the derived joint quantities (`Derived`, MODEL.md
sections 1 and 3, including the PRB-table spline) are not recomputed inside the ODE right-hand
side, and the structural choices that change the *program* (not just its numbers) are decided in
plain Python before tracing, so that a batch of robots compiles to the same branch-free program
as one robot (under `vmap` a `lax.cond` on traced data turns into a select that runs both
branches for every member).

Static structural choices:
- `sigma` (elbow orientation, +1 or -1) from `RobotParams.sigma`;
- `equal_links`: r1 == r3 (l1 == l3), for every member of a batch. The L1 inverse kinematics is
  then closed form (MODEL.md section 4) and needs a single Newton step, whose update is zero but
  whose derivative is the implicit-function derivative (so gradients with respect to l1 or l3
  alone stay exact); otherwise Newton's method from the closed-form guess, to a step of 1e-15 rad,
  then three differentiable Newton steps (derivatives exact to third order).
  Decided from the concrete values; with traced parameters (a `Robot` built inside `jit`,
  `grad` or `vmap`) it cannot be known and is False, the general path, which is exact for
  equal links too.

Gradients: a `Robot` is a pytree whose leaves are the parameters and the derived quantities.
To differentiate with respect to the parameters, build the robot inside the differentiated
function (`jax.grad(lambda p: f(Robot(p)))`), as the public functions that take `RobotParams` do.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Optional, Union

import equinox as eqx
import jax
import numpy as np

from ._errors import PPRError, is_traced
from ._params import RobotParams, table1_with_thickness
from ._prb import Derived, derived, derived_concrete


def equal_links_of(params: RobotParams) -> bool:
    if not (not is_traced(params.l1) and not is_traced(params.l3)):
        return False
    return bool(np.all(np.asarray(params.l1) == np.asarray(params.l3)))


class Robot(eqx.Module):
    """A robot built once (module docstring): `params` (`RobotParams`), `dv` (`Derived`, every
    derived quantity of MODEL.md sections 1 and 3) and the static structural choices
    `equal_links` (bool) and `sigma` (+1 or -1, from `params.sigma`).

    `Robot(params)` decides `equal_links` from the values; pass `equal_links=False` to force the
    general (Newton) inverse kinematics, or `equal_links=True` inside a trace (`jax.grad` over
    the parameters) when you know l1 == l3 there: the fast path, with derivatives in l1 and l3
    that stay exact (tests/test_kinematics.py). Concrete unequal lengths with `True` raise. A batch
    of robots (`stack_params`) gives one `Robot` with a leading axis on every leaf."""

    params: RobotParams
    dv: Derived
    equal_links: bool = eqx.field(static=True)

    def __init__(self, params: RobotParams, equal_links: Optional[bool] = None):
        if not isinstance(params, RobotParams):
            raise TypeError(f"Robot needs RobotParams, got {type(params).__name__}")
        self.params = params
        concrete = all(not is_traced(x) for x in jax.tree_util.tree_leaves(params))
        self.dv = derived_concrete(params) if concrete else derived(params)
        auto = equal_links_of(params)
        if equal_links is None:
            equal_links = auto
        elif equal_links and not auto and not is_traced(params.l1) and not is_traced(params.l3):
            raise PPRError(
                "equal_links=True needs l1 == l3 (drive and connecting links of equal length) "
                "for every robot of the batch"
            )
        self.equal_links = bool(equal_links)

    @property
    def sigma(self) -> int:
        """Elbow orientation (+1 or -1), static."""
        return self.params.sigma

    def replace(self, **changes) -> "Robot":
        """The robot with some parameters changed (rebuilt: derived quantities and choices)."""
        return Robot(self.params.replace(**changes))


def _forward(container: str, name: str):
    def get(self):
        return getattr(getattr(self, container), name)

    get.__name__ = name
    get.__doc__ = (f"`{container}.{name}` "
                   f"(see `{'Derived' if container == 'dv' else 'RobotParams'}`).")
    return property(get)


# Flat, read-only access to every quantity, `robot.r1`, `robot.l1`, `robot.K`, as MJX's `Model`
# holds its arrays: the derived value first, so that `robot.gamma`, `robot.rho` and
# `robot.K_theta` are the PRB parameters in use (the table's where `RobotParams` leaves them None).
for _name in (f.name for f in dataclasses.fields(Derived)):
    setattr(Robot, _name, _forward("dv", _name))
for _name in (f.name for f in dataclasses.fields(RobotParams)):
    if not hasattr(Robot, _name):
        setattr(Robot, _name, _forward("params", _name))
del _name


@functools.lru_cache(maxsize=32)
def table1_robot(t: float) -> Robot:
    """`Robot` of Table 1 with strip thickness `t` (m) (`table1_with_thickness`), built once:
    a scene's default robot, on every call that leaves the robot to the scene."""
    return Robot(table1_with_thickness(t))


#: what the public functions accept: a built `Robot`, or `RobotParams` to build one from
RobotLike = Union[Robot, RobotParams]


def as_robot(robot: RobotLike) -> Robot:
    """`robot` itself, or a `Robot` built from `RobotParams`."""
    if isinstance(robot, Robot):
        return robot
    if isinstance(robot, RobotParams):
        return Robot(robot)
    raise TypeError(f"expected Robot or RobotParams, got {type(robot).__name__}")
