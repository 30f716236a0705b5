"""Equations of motion of every model level from one generic projection.

For a model with independent coordinates z (n,), bodies with COM p_b(z), angle a_b(z), mass m_b and
central inertia I_b, Lagrange's equations of T = sum_b (m_b |p_b'|^2 + I_b a_b'^2)/2 and
U = (k/2) sum_j d_j(z)^2 read (Kane's form)

    M(z) z'' + h(z, z') = Q,     M = sum_b m_b Jp_b^T Jp_b + I_b Ja_b^T Ja_b,
    h = sum_b m_b Jp_b^T (Jp_b' z') + I_b Ja_b^T (Ja_b' z'),
    Q = -k Jd^T d - c_s Jd^T Jd z' - c_a Jth^T Jth z' + Jth^T tau_a + JX^T w,

with Jp = dp/dz etc. The convective accelerations Jp' z' are second directional derivatives of the
body positions along z', so no closed-form derivation is needed and the same code serves every
level. For the closed-loop levels L0-L2 the Jacobians and convective accelerations come from
implicit differentiation of the loop closures (`AbstractClosedLoop.motion`): a right-hand side
then differentiates only plain trigonometric functions, never the closed-form closure (L2's
right-hand side 9.7 -> 5.6 microseconds, L1's 3.8 -> 2.9). L3 takes two nested forward-mode JVPs
of its body positions. For L1 (z = X) this is exactly the paper's eq 54: M = J^T M J
and h = J^T (M J' + C J) X'; `tests/test_paper_eom.py` checks it against the paper's closed form
(eqs 30-35, 41, 47). c_s is the viscous damping of each spring, c_a the viscous friction of the
actuated joints, tau_a (3,) the actuator torques (N m), w (3,) an external platform wrench
(F_x [N], F_y [N], M_z [N m]). Gravity acts normal to the plane of the robot and does no work.

`eom_terms` takes a model's fused terms where it has them (`AbstractModel.fused_eom`: L0-L2, the
same projection written out as straight-line arithmetic, `_models/fused.py`) and this generic
projection otherwise (L3); `_eom_terms` is the generic projection for every model, the reference
`tests/test_fused_eom.py` compares the fused terms with.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp

from ._custom_types import Array, Float
from ._errors import PPRError
from ._fusion import materialize, tangents_once
from ._linalg import solve, solve_arrow, solve_spd
from ._models import AbstractClosedLoop, AbstractModel, Kin
from ._robot import Robot, RobotLike, as_robot


class EOM(eqx.Module):
    """Terms of M z'' + h = Q at one state. `Jth` (3, n) = d th_a / d z, `JX` (3, n) = d X / d z."""

    M: Array
    h: Array
    Q_passive: Array  # spring, damping, friction (no actuator torque, no wrench)
    Jth: Array
    JX: Array
    kin: Kin


def eom_terms(
    model: AbstractModel,
    robot: RobotLike,
    z: Float[Array, " n"],
    zdot: Float[Array, " n"],
) -> EOM:
    """Mass matrix, velocity terms and passive generalized forces at (z, z'): the fused terms
    where the model has them (`AbstractModel.fused_eom`: L0-L2), else the generic projection
    (module docstring).

    **Arguments:**

    - `model`: a model (L0-L3).
    - `robot`: a `Robot` or `RobotParams`.
    - `z`: (n,) the model's coordinates (m, m, rad, then rad).
    - `zdot`: (n,) their rates.

    **Returns:** an `EOM`: M (n, n), h (n,), Q_passive (n,) (springs, their damping, actuator
    friction), Jth = d th_a/dz (3, n), JX = dX/dz (3, n) and the kinematics at z.
    """
    return _eom_terms_jit(model, as_robot(robot), z, zdot)


@eqx.filter_jit
def _eom_terms_jit(model, robot, z, zdot) -> EOM:
    # Jitted although mostly called inside other traces: a scene traces the equations of motion
    # several times (the quasi-static solve's shape probe and loop, the right-hand side), and a
    # cached jaxpr is traced once (tracing is a third of a scene's compilation).
    if has_fused_terms(model):
        return _fused_terms(robot, z, zdot, model=model)
    return _eom_terms(model, robot, z, zdot, implicit=True)


def has_fused_terms(model: AbstractModel) -> bool:
    """Whether `model.fused_eom` gives terms (L0-L2), decided from its class before tracing."""
    kind = type(model)
    if not model.fused or kind.fused_eom is AbstractModel.fused_eom:
        return False
    return not (isinstance(model, AbstractClosedLoop)
                and kind.fused_eom is AbstractClosedLoop.fused_eom
                and kind.chain_spec is AbstractClosedLoop.chain_spec)


def for_batch(model: AbstractModel) -> AbstractModel:
    """`model` as a vmapped batch's program takes it: with the generic projection's terms
    (`AbstractModel.fused`), which `vmap` runs faster on a CPU than the fused arithmetic, and
    marked as a batch member (`AbstractModel.batch_member`: diffrax's loop, not the lean one).
    A structural choice, made in Python before tracing."""
    if has_fused_terms(model):
        model = dataclasses.replace(model, fused=False)
    return dataclasses.replace(model, batch_member=True)


def _fused(model, robot, z, zdot) -> EOM:
    kin, M, h, Q, Jth, JX = model.fused_eom(robot, z, zdot)
    return EOM(M=M, h=h, Q_passive=Q, Jth=Jth, JX=JX, kin=kin)


@eqx.filter_custom_jvp
def _fused_terms(robot, z, zdot, *, model) -> EOM:
    """The fused terms (`AbstractModel.fused_eom`), with M, h and Q differentiated through the
    generic projection (`_fused_terms_jvp`)."""
    return _fused(model, robot, z, zdot)


@_fused_terms.def_jvp
def _fused_terms_jvp(primals, tangents, *, model):
    # M, h and Q take the generic projection's derivatives, which equal the fused terms' (tested
    # to 1e-12) at a fraction of their cost: differentiated, the fused arithmetic's sums over the
    # chains become fusions that XLA's CPU backend recomputes per element (an L2 sensitivity took
    # 1.4x the generic projection's time in forward mode and 3.3x in reverse mode).
    #
    # The primal is the fused one, and the kinematics, Jth and JX take the fused terms' own
    # derivatives: under `vmap` inside a derivative (a JVP of a batched program), JAX fixes which
    # outputs are batched from the primal function, and the rule's outputs must not be batched
    # where the primal's are not. The generic projection computes Jth from the state even where
    # the fused terms know it is constant (L2's actuated angles are coordinates), so its Jth
    # would carry a batch axis that the primal's does not. M, h and Q depend on the same inputs
    # in both formulations (`tests/test_fused_eom.py` checks every batching).
    primal, fused_tangent = eqx.filter_jvp(lambda r, q, qd: _fused(model, r, q, qd),
                                           primals, tangents)
    _, generic = eqx.filter_jvp(lambda r, q, qd: _eom_terms(model, r, q, qd, implicit=True),
                                primals, tangents)
    tangent = eqx.tree_at(lambda e: (e.M, e.h, e.Q_passive), fused_tangent,
                          (generic.M, generic.h, generic.Q_passive))
    return primal, tangent


def _has_fused_balance(model: AbstractModel) -> bool:
    """Whether the model's fused terms come from a `chain_spec` (L0-L2), which also gives the
    balance (`AbstractClosedLoop.fused_balance`); decided before tracing."""
    return (has_fused_terms(model) and isinstance(model, AbstractClosedLoop)
            and type(model).chain_spec is not AbstractClosedLoop.chain_spec)


def mass_solve(model: AbstractModel, M, b):
    """M^-1 b for a model's mass matrix M: L2's arrow structure eliminated first."""
    if model.chain_coordinates:
        # XLA fuses the mass matrix's arithmetic into every kernel that reads a block of it;
        # eliminating the diagonal block first reads fewer blocks (L2's compiled right-hand
        # side: 7,323 -> 4,859 element operations)
        return solve_arrow(M, b, model.chain_coordinates)
    return solve_spd(M, b)


def torque_driven_accelerations(model, robot, actuation, wrench, t, z, zdot):
    """(z'' (n,), tau_a (3,)) of a torque-driven model at (z, z') and time t: M z'' = Q - h
    with the actuator torques `actuation.torque_at(t, th_a, th_a')` (N m) and the platform
    wrench (3,).

    Its derivatives are those of forward dynamics through inverse dynamics: from
    M(p) z''(p) + h(p) = Q(p), M dz'' = d(Q - M a - h) at a = z'' held fixed, the tangent of
    the balance (`AbstractClosedLoop.fused_balance`: the bodies' inertial forces, no n x n
    matrix) solved with the primal's M. This is the derivative of the same equations, not an
    approximation (robotics libraries differentiate their forward dynamics the same way); it
    costs a fraction of the derivative of M, h and Q. Models without the fused balance (L3, a
    batch's members) differentiate the terms themselves."""
    if _has_fused_balance(model):
        return _torque_driven_fused(robot, actuation, wrench, t, z, zdot, model=model)
    return _torque_driven(model, robot, actuation, wrench, t, z, zdot)[:2]


def _torque_driven(model, robot, actuation, wrench, t, z, zdot):
    eom = eom_terms(model, robot, z, zdot)
    tau = actuation.torque_at(t, eom.kin.th_a, eom.Jth @ zdot)
    zdd = mass_solve(model, eom.M, generalized_force(eom, tau, wrench) - eom.h)
    return zdd, tau, eom.M


@eqx.filter_custom_jvp
def _torque_driven_fused(robot, actuation, wrench, t, z, zdot, *, model):
    return _torque_driven(model, robot, actuation, wrench, t, z, zdot)[:2]


@_torque_driven_fused.def_jvp
def _torque_driven_fused_jvp(primals, tangents, *, model):
    zdd, tau, M = _torque_driven(model, *primals)

    def balance(robot, actuation, wrench, t, z, zdot):
        # straight-line arithmetic differentiated recomputes a shared tangent in every fusion
        # that reads it (an L2 sensitivity 1.4 s against 0.11 s): `tangents_once`
        kin, r, Jth, JX = model.fused_balance(robot, z, zdot, zdd, once=tangents_once)
        tau = actuation.torque_at(t, kin.th_a, Jth @ zdot)
        for k in range(3):
            r = r + Jth[k] * tau[k] + JX[k] * wrench[k]
        return r, tau

    dr, dtau = _jvp_residuals_once(balance, primals, tangents)
    # M^-1 once (its columns by the primal's solve, through `materialize`), applied to the
    # tangent as a sum of its columns: solved with the tangent, M's elimination was recomputed
    # for every tangent entry inside the solve's kernels (L2's forward-mode sensitivity over
    # 1 s: 67.3 -> 58.9 ms)
    n = M.shape[-1]
    Minv = materialize(jax.vmap(lambda e: mass_solve(model, M, e))(jnp.eye(n, dtype=M.dtype)))
    dzdd = Minv[0] * dr[0]
    for k in range(1, n):
        dzdd = dzdd + Minv[k] * dr[k]  # M symmetric: row k of M^-1 is its column k
    return (zdd, tau), (dzdd, dtau)


def _jvp_residuals_once(fn, primals, tangents):
    """The tangent of `fn(*primals)` along `tangents` (None: zero), with every primal value the
    tangent reads computed once: `jax.linearize` splits the derivative into the primal
    values it needs (its residuals) and arithmetic linear in the tangents, and each
    residual goes through a `materialize` of its own. Straight-line arithmetic
    differentiated in one piece let XLA's CPU fusion recompute primal products inside every
    fusion of the tangents, once per tangent entry (19 parameters' tangents of L2's
    balance: 292,000 primal operations a right-hand side inside tangent kernels, against
    145,000 tangent operations)."""
    # Linearised in the inputs that carry a tangent only (a custom rule's None is a symbolic
    # zero): an input held constant, such as the robot of an `InverseDynamicsTorque` that
    # drives the model, would otherwise have its whole derivative in the program, multiplied
    # by zeros (getting_started's gradient: 37,860 -> 27,442 StableHLO lines, 6.9 -> 4.8 s of
    # tracing).
    moves = jax.tree_util.tree_map(lambda p, t: eqx.is_inexact_array(p) and t is not None,
                                   primals, tangents, is_leaf=lambda x: x is None)
    diff, nondiff = eqx.partition(primals, moves)
    _, lin = jax.linearize(lambda d: fn(*eqx.combine(d, nondiff)), diff)
    leaves, treedef = jax.tree_util.tree_flatten(lin)
    floats = [i for i, x in enumerate(leaves)
              if eqx.is_inexact_array(x) and x.dtype == jnp.float64]
    for i in floats:
        # each residual its own `materialize`: one concatenated vector (1,073 values for L2's
        # balance), read whole by every kernel that reads one of them, counted some 60 times in
        # the bytes XLA's small-loop pass weighs a loop by, and kept the loop of steps of a
        # forward-mode sensitivity out of one kernel even for one parameter (`_devices`; L2
        # over 1 s, one parameter: 34 -> 6.2 ms)
        leaves[i] = materialize(leaves[i])
    lin = jax.tree_util.tree_unflatten(treedef, leaves)
    dt = jax.tree_util.tree_map(lambda p, t: None if p is None else t, diff, tangents,
                                is_leaf=lambda x: x is None)
    return lin(dt)


#: the most coordinates whose generic equations of motion form their products as elementwise
#: sums (`_eom_terms`, outside a vmapped batch): L0-L2 and the quasi-static L3 (3-9); the full
#: L3's (tens) as dots
SUMS_MAX_DOF = 12


def _eom_terms(model, robot, z, zdot, implicit: bool) -> EOM:
    k, Q, (Jp, Ja, Jth, JX), (acc_p, acc_a) = _derivatives(
        model, robot, z, zdot, convective=True, implicit=implicit
    )
    m, I = model.masses(robot)
    # Jp (nb, 2, n), Ja (nb, n)
    if Jp.shape[-1] <= SUMS_MAX_DOF and not model.batch_member:
        # Sums of products, not einsums: XLA's CPU compiler makes an einsum a dot, and the
        # (n, n) mass matrix's dot kept the quasi-static L3's loop of steps from compiling as
        # one kernel (`_devices`); as elementwise sums it fuses (L3 `paper-circle` at N = 4 on
        # 2 cores: 606 -> 516 ms before its loop was one kernel, 182 ms after).
        M = (jnp.sum(m[:, None, None, None] * Jp[:, :, :, None] * Jp[:, :, None, :], axis=(0, 1))
             + jnp.sum(I[:, None, None] * Ja[:, :, None] * Ja[:, None, :], axis=0))
        h = (jnp.sum(m[:, None, None] * Jp * acc_p[:, :, None], axis=(0, 1))
             + jnp.sum(I[:, None] * Ja * acc_a[:, None], axis=0))
        damping = jnp.sum(Jth * jnp.sum(Jth * zdot[None, :], axis=1)[:, None], axis=0)
    else:
        # the full L3's tens of coordinates: the products as dots, which its implicit solver's
        # loop holds anyway (as sums, the full L3 at N = 16 ran 0.5 s of `paper-circle` in 3.7
        # instead of 2.3 s: the (nb, 2, n, n) products are a large temporary); and a vmapped
        # batch's members, which run diffrax's loop, not the lean one, and whose batched dots
        # are the faster (8 quasi-static L3 robots at N = 4 over 1 s: 0.63 s as sums, 0.58 s)
        M = jnp.einsum("b,bki,bkj->ij", m, Jp, Jp) + jnp.einsum("b,bi,bj->ij", I, Ja, Ja)
        h = jnp.einsum("b,bki,bk->i", m, Jp, acc_p) + jnp.einsum("b,bi,b->i", I, Ja, acc_a)
        damping = Jth.T @ (Jth @ zdot)
    Q = Q - robot.c_act * damping
    return EOM(M=M, h=h, Q_passive=Q, Jth=Jth, JX=JX, kin=k)


def _derivatives(model: AbstractModel, robot: Robot, z, zdot, convective: bool,
                 implicit: bool = True):
    """(kin, spring forces, (Jp, Ja, Jth, JX), (acc_p, acc_a) or None): the kinematics at z, the
    springs' force with their damping, the Jacobians of the bodies, actuated angles and pose, and
    (`convective`) the bodies' convective accelerations.

    A closed-loop model (L0-L2) gets all of it from implicit differentiation of its loop
    closures (`AbstractClosedLoop.motion`); `implicit=False` (for tests) and every other model
    take forward-mode derivatives of the kinematics: the convective accelerations as second
    directional derivatives (two nested JVPs), the springs' force from the model
    (`spring_force`) or else from the Jacobian of the deflections."""
    if implicit and isinstance(model, AbstractClosedLoop):
        mo = model.motion(robot, z, zdot, convective)
        k, jac = mo.kin, mo.jac
        return (k, _spring_force(model, robot, k, jac.deflection, zdot),
                (jac.body_p, jac.body_ang, jac.th_a, jac.X), (mo.acc_p, mo.acc_a))
    k = model.kinematics(robot, z)
    acc = None
    if convective:
        def vel(z):
            return jax.jvp(lambda z: model.bodies(robot, z)[:2], (z,), (zdot,))[1]

        acc = jax.jvp(vel, (z,), (zdot,))[1]
    Q = model.spring_force(robot, z, zdot, k)
    if Q is not None:
        return k, Q, jax.jacfwd(lambda z: model.bodies(robot, z))(z), acc
    jac = jax.jacfwd(lambda z: model.kinematics(robot, z))(z)
    return (k, _spring_force(model, robot, k, jac.deflection, zdot),
            (jac.body_p, jac.body_ang, jac.th_a, jac.X), acc)


def _spring_force(model, robot, k, Jd, zdot):
    """-K Jd^T d - c Jd^T Jd z': the springs and their viscous damping."""
    kk, cc = model.stiffness(robot), model.damping(robot)
    # kk and cc are scalars or one per spring (the beam's clamp half-springs differ; the full
    # beam's Kelvin-Voigt loss is proportional to each spring's stiffness).
    return -(Jd.T @ (kk * k.deflection)) - Jd.T @ (cc * (Jd @ zdot))


def passive_force(
    model: AbstractModel, robot: Robot, z, zdot, tau_a, wrench
) -> Array:
    """Q of springs, damping, friction, actuators and wrench only (first derivatives of the
    kinematics; no mass matrix): the stiffness part of the static and quasi-static balances."""
    _, Q, (_, _, Jth, JX), _ = _derivatives(model, robot, z, zdot, convective=False)
    return Q - robot.c_act * (Jth.T @ (Jth @ zdot)) + Jth.T @ tau_a + JX.T @ wrench


def generalized_force(eom: EOM, tau_a, wrench) -> Array:
    """Total generalized force Q for actuator torques tau_a (3,) and platform wrench (3,)."""
    # Jth^T tau_a + JX^T w as sums of rows, elementwise: no dot kernels on 3 x n matrices
    Q = eom.Q_passive
    for k in range(3):
        Q = Q + eom.Jth[k] * tau_a[k] + eom.JX[k] * wrench[k]
    return Q


def accelerations(eom: EOM, tau_a, wrench) -> Array:
    """Torque-driven forward dynamics: z'' = M^-1 (Q - h)."""
    return solve(eom.M, generalized_force(eom, tau_a, wrench) - eom.h)


def energy(model: AbstractModel, robot: Robot, z, zdot):
    """The kinetic and potential energy of `model` at (z, z').

    **Arguments:**

    - `model`: a model; `robot`: a `Robot`.
    - `z`, `zdot`: (n,) the coordinates and their rates.

    **Returns:** (T, U) (J): the bodies' kinetic energy and the springs' potential energy.
    """
    k, kd = jax.jvp(lambda z: model.kinematics(robot, z), (z,), (zdot,))
    return energy_of(model, robot, k, kd)


def energy_of(model: AbstractModel, robot: Robot, k, kd):
    """(kinetic, potential) energy (J) from the kinematics k and their rates kd (a JVP of
    `model.kinematics`): for callers that already hold them."""
    m, I = model.masses(robot)
    T = 0.5 * (jnp.sum(m * jnp.sum(kd.body_p**2, axis=-1)) + jnp.sum(I * kd.body_ang**2))
    return T, potential_of(model, robot, k)


def potential_of(model: AbstractModel, robot: Robot, k):
    """The springs' potential energy (J) from the kinematics k: at rest, Q_passive is its
    gradient's negative (no damping or friction without velocity)."""
    return 0.5 * jnp.sum(model.stiffness(robot) * k.deflection**2)


def lagrangian_eom(model: AbstractModel, robot: Robot, z, zdot):
    """Reference equations of motion from automatic differentiation of L = T - U (slow; for tests):
    returns (M, h + dU/dz) with M = d2T/dz'2 and h = d2T/dz'dz z' - dT/dz."""

    def T(z, zdot):
        return energy(model, robot, z, zdot)[0]

    def U(z):
        return energy(model, robot, z, jnp.zeros_like(z))[1]

    M = jax.hessian(T, argnums=1)(z, zdot)
    dTdzd_dz = jax.jacfwd(jax.grad(T, argnums=1), argnums=0)(z, zdot)
    h = dTdzd_dz @ zdot - jax.grad(T, argnums=0)(z, zdot)
    return M, h + jax.grad(U)(z)


def inverse_dynamics(
    model: AbstractModel,
    robot: Robot,
    X: Float[Array, "3"],
    Xdot: Float[Array, "3"],
    Xddot: Float[Array, "3"],
    wrench=None,
):
    """Actuator torques that move a model with z = X (L0, L1) along (X, X', X'').

    Solves S^T tau_a = M X'' + h - Q_passive - w (eq 54 solved for tau_a, S = d th_a/dX, eq 52).

    **Arguments:**

    - `model`: L0 or L1 (coordinates z = X); `robot`: a `Robot`.
    - `X`, `Xdot`, `Xddot`: (3,) the platform pose (m, m, rad) and its rates.
    - `wrench`: (3,) an external platform wrench (N, N, N m); None: none.

    **Returns:** (tau_a (3,) (N m), eom): the torques and the `EOM` at X; the caller checks
    `eom.kin.margin` and the conditioning of S.

    **Raises:** `PPRError` for a model with internal coordinates (L2, L3).
    """
    if model.actuated_index is not None:
        raise PPRError(
            f"inverse_dynamics along a platform trajectory needs a model whose coordinates are the "
            f"pose (rigid, reduced); {model.name!r} has internal degrees of freedom: simulate it "
            f"motion-driven instead"
        )
    w = jnp.zeros(3) if wrench is None else wrench
    eom = eom_terms(model, robot, X, Xdot)
    rhs = eom.M @ Xddot + eom.h - eom.Q_passive - w
    return solve(eom.Jth.T, rhs), eom
