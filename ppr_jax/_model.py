"""The interface every model level implements (L0 `rigid`, L1 `reduced`, L2 `double1r`).

A model is a stateless `equinox.Module` (so it is static under `eqx.filter_jit`) that maps its
generalized coordinates z to the positions and angles of its rigid bodies, its spring deflections
and its actuated angles. The equations of motion of every level then follow from one generic
projection (Kane's form of Lagrange's equations, `_dynamics.py`): the constraint forces of the
closed loops never appear because z is a set of independent coordinates and the loop closures hold
exactly (to rounding) for every z.
"""

from __future__ import annotations

import abc
from typing import ClassVar, Optional

import equinox as eqx
import jax.numpy as jnp

from ._custom_types import Array, Float
from ._kinematics import base_points, e, loop_residual
from ._params import RobotParams
from ._prb import Derived


class Kin(eqx.Module):
    """Kinematic state of a model at coordinates z.

    X (3,) platform pose; th (3, k) chain link angles (k = 3 for L1/L2: th_i1, th_i2, th_i3;
    k = 2 for L0: th_i1, th_i3); body_p (nb, 2) body centres of mass; body_ang (nb,) body angles;
    defl (ns,) spring deflections (rad); th_a (3,) actuated angles; margin (3,) reach margin of each
    chain's closed-form closure (<= 0: out of reach / singular).
    """

    X: Array
    th: Array
    body_p: Array
    body_ang: Array
    defl: Array
    th_a: Array
    margin: Array


class AbstractModel(eqx.Module):
    """A model level. Subclasses define the coordinates and kinematics; dynamics are generic."""

    name: ClassVar[str]
    level: ClassVar[int]
    #: number of generalized coordinates
    n_dof: ClassVar[int]
    #: indices of the actuated angles inside z, or None when z = X (the actuated angles are then
    #: functions of X and a motion-driven model has no free coordinate left)
    actuated_index: ClassVar[Optional[tuple[int, ...]]] = None

    @abc.abstractmethod
    def kinematics(self, params: RobotParams, dv: Derived, z: Float[Array, " n"]) -> Kin:
        """Bodies, deflections and actuated angles at coordinates z."""

    @abc.abstractmethod
    def masses(self, params: RobotParams, dv: Derived) -> tuple[Array, Array]:
        """(m (nb,), I (nb,)): body masses (kg) and central moments of inertia (kg m^2),
        in the order of `Kin.body_p`."""

    @abc.abstractmethod
    def stiffness(self, params: RobotParams, dv: Derived) -> Array:
        """Torsion stiffness of the springs (N m/rad): a scalar, or one per entry of `Kin.defl`."""

    @abc.abstractmethod
    def coords_from_pose(self, params: RobotParams, dv: Derived, X: Float[Array, "3"]):
        """Coordinates z at platform pose X on the model's quasi-static (L1-consistent) manifold."""

    def loop_residual(self, params: RobotParams, dv: Derived, kin: Kin) -> Float[Array, "3 2"]:
        """Loop-closure residual of each chain (eq 12) (m)."""
        return loop_residual(params, dv, kin.th, kin.X)

    def joint_end_rotations(self, params: RobotParams, dv: Derived, kin: Kin) -> Float[Array, "3 2"]:
        """Rotations of the two ends of each compliant joint relative to the joint's chord
        (the pseudo-link BD), i.e. the two pivot deflections (d_i1, d_i2) (rad); eq 28 says they
        are equal under the quasi-static assumption. Models with one pin split it in half."""
        return kin.defl.reshape(3, 2)


def rotor_inertia(params: RobotParams, dv: Derived):
    """Drive link central inertia plus the reflected rotor inertia (both turn with th_i1)."""
    return dv.I1 + params.J_rotor


def chain_bodies_double1r(params: RobotParams, dv: Derived, th, X):
    """Bodies of the double-1R chains and the platform: for each chain the drive link (COM at l1/2
    from A_i), the pseudo-link (COM at its middle, r_bc = r2/2) and the connecting link (COM at
    l3/2 from E_i, i.e. r_dc = s + l3/2 from D_i); then the platform. Returns (p (10, 2), ang (10,))."""
    A = base_points(params)
    B = A + dv.r1 * e(th[:, 0])
    p1 = A + (params.l1 / 2) * e(th[:, 0])
    p2 = B + (dv.r2 / 2) * e(th[:, 1])
    D = B + dv.r2 * e(th[:, 1])
    p3 = D + (dv.s + params.l3 / 2) * e(th[:, 2])
    p = jnp.concatenate([p1, p2, p3, X[None, :2]], axis=0)
    ang = jnp.concatenate([th[:, 0], th[:, 1], th[:, 2], X[2:3]])
    return p, ang


def masses_double1r(params: RobotParams, dv: Derived):
    one = jnp.ones(3, dtype=jnp.float64)
    m = jnp.concatenate([dv.m1 * one, dv.m2 * one, dv.m3 * one, dv.m4[None]])
    I = jnp.concatenate([rotor_inertia(params, dv) * one, dv.I2 * one, dv.I3 * one, dv.I4[None]])
    return m, I
