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
from typing import ClassVar, Optional

import equinox as eqx
import jax
import jax.numpy as jnp

from .._custom_types import Array, Float
from .._linalg import solve_blocks
from .._names import ATOL, RTOL  # noqa: F401 (the non-stiff levels' defaults)
from .._robot import Robot
from .fused import ChainSpec, fused_balance, fused_eom


class Kin(eqx.Module):
    """Kinematic state of a model at coordinates z.

    X (3,) platform pose; th (3, k) chain link angles (k = 3 for L1/L2: th_i1, th_i2, th_i3;
    k = 2 for L0: th_i1, th_i3; N + 2 for L3); body_p (nb, 2) body centres of mass; body_ang
    (nb,) body angles; deflection (ns,) spring deflections (rad); th_a (3,) actuated angles; margin
    (3,) reach margin of each chain's closed-form closure (<= 0: out of reach / singular);
    trig the chain angles' cosines and sines where known.
    """

    X: Array
    th: Array
    body_p: Array
    body_ang: Array
    deflection: Array
    th_a: Array
    margin: Array
    #: the chain angles' cosines and sines (`_geometry.ChainTrig`) where the closure computed
    #: them, or None: the loop residual reads them instead of evaluating them again
    trig: Optional[object] = None


class AbstractModel(eqx.Module):
    """A model level: its coordinates z and their kinematics; the dynamics are generic."""

    #: whether the equations of motion take the model's fused terms where it has them
    #: (`fused_eom`); a vmapped batch's program sets it False (`for_batch`): under `vmap` the
    #: generic projection's batched dots run faster on a CPU than the fused arithmetic (L2 x64
    #: on `paper-circle`: 6.1 against 8.9 s), while a single run is faster fused.
    fused: bool = eqx.field(static=True, default=True, kw_only=True, repr=False)
    #: whether the model runs as a member of a vmapped batch (`for_batch` sets it): such a
    #: member integrates with `diffeqsolve`, whose loop `vmap` runs faster than the lean one
    #: (`_lean.py`; L1 x256 on `paper-circle`: 652 against 530 trajectories/s)
    batch_member: bool = eqx.field(static=True, default=False, kw_only=True, repr=False)

    #: registry name (`ppr_jax.get_model(name)`, the CLI's `--model`)
    name: eqx.AbstractClassVar[str]
    #: fidelity level of MODEL.md section 5 (0 rigid ... 3 beam)
    level: eqx.AbstractClassVar[int]
    #: number of generalized coordinates
    n_dof: eqx.AbstractClassVar[int]
    #: indices of the actuated angles inside z, or None when z = X (the actuated angles are then
    #: functions of X and a motion-driven model has no free coordinate left)
    actuated_index: eqx.AbstractClassVar[Optional[tuple[int, ...]]]
    #: indices of the coordinates whose own dynamics is far faster than the robot's (kHz modes
    #: against 10-70 Hz), () for none: they make the model stiff (its default solver implicit
    #: and its default tolerances looser, `_scenes/_options.py`) and the quasi-static start
    #: moves them onto their slow path (`_statics.onto_slow_manifold`)
    fast_index: eqx.AbstractClassVar[tuple[int, ...]]
    #: how many of the last coordinates each belong to one chain alone (one per chain, in chain
    #: order; L2's actuated angles), 0 for none: the mass matrix couples each of them with the
    #: others only through the first coordinates, so the right-hand side solves it with that
    #: diagonal block eliminated first (`_linalg.solve_arrow`) and the fused terms compute
    #: their columns as one per-chain column (`_models/fused.ChainSpec.own`)
    chain_coordinates: ClassVar[int] = 0
    #: the solver a scene uses when the options name none (`SceneOptions.solver`; the names of
    #: `_simulate.get_solver`): explicit Runge-Kutta for the non-stiff levels (docs/
    #: which_model.md), an implicit one for a model with fast coordinates
    default_solver: eqx.AbstractClassVar[str]
    #: the step-size controller's tolerances when the options name none (`SceneOptions.rtol`,
    #: `atol`): rtol 1e-8 / atol 1e-10 put L2's error near 1e-8 m on the paper's scenes; the
    #: full L3 is looser (its undamped kHz strip vibration would be resolved for hours)
    default_rtol: eqx.AbstractClassVar[float]
    default_atol: eqx.AbstractClassVar[float]

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

    def fused_eom(self, robot: Robot, z, zdot):
        """(kin, M, h, Q_passive, Jth, JX) of the equations of motion at (z, z') written as
        straight-line arithmetic (`_models/fused.py`), or None (the default): `_dynamics.py`
        then takes the generic projection, which stays the reference."""
        return None

    @abc.abstractmethod
    def masses(self, robot: Robot) -> tuple[Array, Array]:
        """(m (nb,), I (nb,)): body masses (kg) and central moments of inertia (kg m^2),
        in the order of `Kin.body_p`."""

    @abc.abstractmethod
    def stiffness(self, robot: Robot) -> Array:
        """Torsion stiffness of the springs (N m/rad): a scalar, or one per entry of
        `Kin.deflection`."""

    def damping(self, robot: Robot) -> Array:
        """Viscous damping of the springs (N m s/rad): a scalar, or one per entry of
        `Kin.deflection`. `params.c_spring` on every spring (MODEL.md section 1)."""
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


class Motion(eqx.Module):
    """First- and second-order kinematics at (z, z'): `kin` at z; `jac`, a `Kin` whose fields
    are the Jacobians d(field)/dz (trailing axis n; `margin`'s is meaningless); `acc_p` (nb, 2)
    and `acc_a` (nb,), the bodies' convective accelerations (their second derivative along z'
    with z'' = 0), or None when not asked for."""

    kin: Kin
    jac: Kin
    acc_p: Optional[Array]
    acc_a: Optional[Array]


class AbstractClosedLoop(AbstractModel):
    """A model whose chains close in closed form: besides the independent coordinates z (n,) it
    has dependent chain coordinates u (3, k), found from z by `dependent`, with the loop
    closures Phi(z, u) = 0 (3, k) (`closure_residual`; chain i's rows depend on u[i] alone).

    Its velocity and acceleration kinematics (`motion`) come from implicit differentiation of the
    closures instead of derivatives of the closed form (whose arccos, atan2 and square roots under
    two nested forward-mode derivatives made most of a right-hand side): with Phi_u the 3 k x k
    blocks d Phi_i / d u_i,

        u_z = -Phi_u^-1 Phi_z,     u''_conv = -Phi_u^-1 D2 Phi[(z', u'), (z', u')],

    and every body, spring and actuated angle is a plain trigonometric function `kin_at` of
    (z, u), differentiated along (e_j, u_z e_j) and twice along (z', u'). Both need only the
    simple functions Phi and `kin_at`; `tests/test_dynamics.py` checks the result against
    autodiff of the closed form. Derivatives with respect to the parameters are unaffected: u
    carries them through `dependent`, and u_z through Phi_u and Phi_z."""

    @abc.abstractmethod
    def dependent(self, robot: Robot, z: Float[Array, " n"]) -> tuple[Array, Array]:
        """(u (3, k), margin (3,)): the dependent chain coordinates at z and the reach margin of
        each chain's closure (<= 0: out of reach or singular)."""

    @abc.abstractmethod
    def closure_residual(self, robot: Robot, z, u) -> Float[Array, "3 k"]:
        """Phi(z, u): chain i's k closure equations in row i, zero on the closed loop."""

    def dependent_trig(self, robot: Robot, z: Float[Array, " n"]) -> tuple[Array, Array, object]:
        """(u, margin, trig): `dependent`, and the chain angles' cosines and sines
        (`_geometry.ChainTrig`) where the closure computes them without evaluating sines (L1's
        closed form), else None (the default). `kinematics` and the fused terms hand them on
        to `kin_at` and `chain_spec`."""
        u, margin = self.dependent(robot, z)
        return u, margin, None

    @abc.abstractmethod
    def kin_at(self, robot: Robot, z, u, margin, trig=None) -> Kin:
        """`Kin` from (z, u) on the closed loop (plain trigonometry, no closure solve); `trig`
        the chain angles' `ChainTrig` where known (`dependent_trig`)."""

    def kinematics(self, robot, z):
        return self.kin_at(robot, z, *self.dependent_trig(robot, z))

    def chain_spec(self, robot: Robot, z, u, trig=None) -> Optional[ChainSpec]:
        """The chains as sums of links (`_models/fused.ChainSpec`) at (z, u) (`trig` as in
        `kin_at`), for the fused equations of motion; None (the default) keeps the generic
        projection."""
        return None

    def fused_eom(self, robot, z, zdot):
        u, margin, trig = self.dependent_trig(robot, z)
        spec = self.chain_spec(robot, z, u, trig)
        if spec is None:
            return None
        kin = self.kin_at(robot, z, u, margin, trig)
        return (kin, *fused_eom(spec, robot, z, zdot, kin, self.stiffness(robot),
                                self.damping(robot)))

    def fused_balance(self, robot, z, zdot, zdd, once=None):
        """(kin, Q_passive - M z'' - h, Jth, JX) at (z, z', z'') as straight-line arithmetic
        (`_models/fused.fused_balance`), or None where the model has no `chain_spec`."""
        u, margin, trig = self.dependent_trig(robot, z)
        spec = self.chain_spec(robot, z, u, trig)
        if spec is None:
            return None
        kin = self.kin_at(robot, z, u, margin, trig)
        return (kin, *fused_balance(spec, robot, z, zdot, zdd, kin, self.stiffness(robot),
                                    self.damping(robot), once=once))

    def motion(self, robot: Robot, z, zdot, convective: bool = True) -> Motion:
        """`Motion` at (z, z') by implicit differentiation of the closures (class docstring)."""
        u, margin = self.dependent(robot, z)
        n, k = z.shape[0], u.shape[-1]
        res = lambda z, u: self.closure_residual(robot, z, u)  # noqa: E731
        # Chain i's residual depends on u[i] only: one JVP along column j of every chain's u at
        # once gives column j of all three k x k blocks.
        Phi_u = jax.vmap(
            lambda d: jax.jvp(lambda u: res(z, u), (u,), (jnp.broadcast_to(d, u.shape),))[1],
            out_axes=-1,
        )(jnp.eye(k))  # (3, k, k)
        Phi_z = jax.vmap(
            lambda d: jax.jvp(lambda z: res(z, u), (z,), (d,))[1], out_axes=-1
        )(jnp.eye(n))  # (3, k, n)
        u_z = -solve_blocks(Phi_u, Phi_z)  # (3, k, n)
        kin_of = lambda z, u: self.kin_at(robot, z, u, margin)  # noqa: E731
        kin = kin_of(z, u)
        jac = jax.vmap(
            lambda dz, du: jax.jvp(kin_of, (z, u), (dz, du))[1], in_axes=(1, 2), out_axes=-1
        )(jnp.eye(n), u_z)
        if not convective:
            return Motion(kin=kin, jac=jac, acc_p=None, acc_a=None)
        ud = u_z @ zdot

        def second(f):
            # second derivative of f along (z', u') with u'' = 0
            return jax.jvp(lambda z, u: jax.jvp(f, (z, u), (zdot, ud))[1], (z, u), (zdot, ud))[1]

        udd = -solve_blocks(Phi_u, second(res)[..., None])[..., 0]
        bodies = lambda z, u: (lambda k: (k.body_p, k.body_ang))(kin_of(z, u))  # noqa: E731
        acc2 = second(bodies)
        acc1 = jax.jvp(bodies, (z, u), (jnp.zeros_like(z), udd))[1]
        return Motion(kin=kin, jac=jac, acc_p=acc2[0] + acc1[0], acc_a=acc2[1] + acc1[1])


def rotor_inertia(robot: Robot):
    """Drive link central inertia plus the reflected rotor inertia (both turn with th_i1)."""
    return robot.I1 + robot.J_rotor
