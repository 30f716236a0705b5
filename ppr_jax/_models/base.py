"""The interface every model level implements (MODEL.md section 5).

A model is a stateless `equinox.Module` (so it is static under `eqx.filter_jit`) that maps its
generalized coordinates z to the positions and angles of its rigid bodies, its spring deflections
and its actuated angles. The equations of motion of every level then follow from one generic
projection (Kane's form of Lagrange's equations, `_dynamics.py`): the constraint forces of the
closed loops never appear because z is a set of independent coordinates and the loop closures hold
exactly (to rounding) for every z.

The levels follow equinox's abstract/final pattern: `AbstractModel` declares what a level must
say (abstract class variables and abstract methods), concrete classes are final and implement
only abstract methods, and what several levels share lives in an intermediate abstract class
(`AbstractDouble1R` for L1 and L2). Adding a level is one file in this package and one line in
its registry (`ppr_jax/_models/__init__.py`).
"""


import abc
from typing import Optional

import equinox as eqx

from .._custom_types import Array, Float
from .._robot import Robot


class Kin(eqx.Module):
    """Kinematic state of a model at coordinates z.

    X (3,) platform pose; th (3, k) chain link angles (k = 3 for L1/L2: th_i1, th_i2, th_i3;
    k = 2 for L0: th_i1, th_i3; N + 2 for L3); body_p (nb, 2) body centres of mass; body_ang
    (nb,) body angles; deflection (ns,) spring deflections (rad); th_a (3,) actuated angles; margin (3,)
    reach margin of each chain's closed-form closure (<= 0: out of reach / singular).
    """

    X: Array
    th: Array
    body_p: Array
    body_ang: Array
    deflection: Array
    th_a: Array
    margin: Array


class AbstractModel(eqx.Module):
    """A model level: its coordinates z and their kinematics; the dynamics are generic."""

    #: registry name (`ppr_jax.get_model(name)`, the CLI's `--model`)
    name: eqx.AbstractClassVar[str]
    #: fidelity level of MODEL.md section 5 (0 rigid ... 3 beam)
    level: eqx.AbstractClassVar[int]
    #: number of generalized coordinates
    n_dof: eqx.AbstractClassVar[int]
    #: indices of the actuated angles inside z, or None when z = X (the actuated angles are then
    #: functions of X and a motion-driven model has no free coordinate left)
    actuated_index: eqx.AbstractClassVar[Optional[tuple[int, ...]]]

    @abc.abstractmethod
    def kinematics(self, robot: Robot, z: Float[Array, " n"]) -> Kin:
        """Bodies, deflections and actuated angles at coordinates z."""

    def bodies(self, robot: Robot, z: Float[Array, " n"]) -> tuple[Array, Array, Array, Array]:
        """(`Kin.body_p`, `Kin.body_ang`, `Kin.th_a`, `Kin.X`) alone: with `spring_force` this is
        all the equations of motion differentiate, so a model whose springs cost more than its
        bodies (L3 with quasi-static strips) overrides both to keep the derivatives of its strip
        shapes out of every right-hand side."""
        k = self.kinematics(robot, z)
        return k.body_p, k.body_ang, k.th_a, k.X

    def spring_force(self, robot: Robot, z, zdot, kin: Kin) -> Optional[Array]:
        """Generalized force (n,) of the springs and their viscous damping at (z, z'), with `kin`
        the kinematics at z; or None (the default): `_dynamics.py` then takes it from the Jacobian
        of `Kin.deflection`. A model whose deflections are implicit functions of z (the
        quasi-static L3) overrides this with something cheaper than that Jacobian."""
        return None

    @abc.abstractmethod
    def masses(self, robot: Robot) -> tuple[Array, Array]:
        """(m (nb,), I (nb,)): body masses (kg) and central moments of inertia (kg m^2),
        in the order of `Kin.body_p`."""

    @abc.abstractmethod
    def stiffness(self, robot: Robot) -> Array:
        """Torsion stiffness of the springs (N m/rad): a scalar, or one per entry of `Kin.deflection`."""

    def damping(self, robot: Robot) -> Array:
        """Viscous damping of the springs (N m s/rad): a scalar, or one per entry of `Kin.deflection`.
        `params.c_spring` on every spring (MODEL.md section 1)."""
        return robot.c_spring

    @abc.abstractmethod
    def coords_from_pose(self, robot: Robot, X: Float[Array, "3"]) -> Float[Array, " n"]:
        """Coordinates z at platform pose X on the model's quasi-static (L1-consistent) manifold."""

    @abc.abstractmethod
    def loop_residual(self, robot: Robot, kin: Kin) -> Float[Array, "3 2"]:
        """Loop-closure residual of each chain (eq 12): the chain's E_i minus the platform's (m)."""

    @abc.abstractmethod
    def joint_end_rotations(self, robot: Robot, kin: Kin) -> Float[Array, "3 2"]:
        """Rotations (rad) of the two ends of each compliant joint relative to its chord (the
        pseudo-link BD), from their rest values; eq 28 says they are equal under the
        quasi-static assumption."""


def rotor_inertia(robot: Robot):
    """Drive link central inertia plus the reflected rotor inertia (both turn with th_i1)."""
    return robot.I1 + robot.J_rotor
