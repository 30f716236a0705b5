"""Static equilibria and quasi-static (L1-consistent) initial states.

Every residual here is the generalized force balance of `_dynamics.py`, solved with optimistix
Newton (differentiable by the implicit function theorem, forward and reverse mode).
"""

from __future__ import annotations

from typing import Callable, Optional

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx

from ._checks import PPRError, raise_if
from ._actuation import AbstractActuation, TorqueDriven
from ._dynamics import eom_terms, generalized_force, passive_force
from ._linalg import SmallLU, lu_factor, lu_solve
from ._models import AbstractModel
from ._robot import RobotLike, as_robot
from ._trajectory import derivatives


def _assemble(n, idx_u, zu, idx_k, zk):
    z = jnp.zeros(n, dtype=jnp.float64)
    if idx_u:
        z = z.at[jnp.array(idx_u)].set(zu)
    if idx_k:
        z = z.at[jnp.array(idx_k)].set(zk)
    return z


def _newton(resid, y0, args, rtol=1e-12, atol=1e-12, max_steps=100):
    sol = optx.root_find(
        resid, optx.Newton(rtol=rtol, atol=atol, linear_solver=SmallLU()), y0, args=args, max_steps=max_steps, throw=False
    )
    return sol.value, sol.result


def static_equilibrium(
    model: AbstractModel,
    robot: RobotLike,
    z_guess,
    *,
    locked: bool,
    tau=None,
    wrench=None,
    check: bool = True,
    return_failed: bool = False,
):
    """Static equilibrium z* of `model` near `z_guess`.

    locked=True: the actuated angles stay at their values in `z_guess` and only the other
    coordinates move (L2: the pose; L0/L1 have none left and `z_guess` is returned).
    locked=False: every coordinate is free and the actuators apply constant torques `tau`
    (default 0, "free actuators"). `wrench` (3,) is a constant platform load.
    Returns (z*, free_index) with free_index the coordinates that were free, and with
    `return_failed` a traceable bool `failed` as a third element (`check=False` then leaves the
    check to the caller: no host callback inside a compiled program)."""
    robot = as_robot(robot)
    n = model.n_dof
    tau = jnp.zeros(3) if tau is None else jnp.asarray(tau, dtype=jnp.float64)
    w = jnp.zeros(3) if wrench is None else jnp.asarray(wrench, dtype=jnp.float64)
    z_guess = jnp.asarray(z_guess, dtype=jnp.float64)
    if locked:
        if model.actuated_index is None:
            return (z_guess, (), jnp.asarray(False)) if return_failed else (z_guess, ())
        known = tuple(model.actuated_index)
    else:
        known = ()
    free = tuple(i for i in range(n) if i not in known)
    zk = z_guess[jnp.array(known)] if known else None

    def resid(zf, _):
        z = _assemble(n, free, zf, known, zk)
        eom = eom_terms(model, robot, z, jnp.zeros(n))
        return generalized_force(eom, tau, w)[jnp.array(free)]

    zf, result = _newton(resid, z_guess[jnp.array(free)], None)
    failed = result != optx.RESULTS.successful
    if check:
        zf = raise_if(
            zf, result != optx.RESULTS.successful,
            "static equilibrium not found (Newton did not converge): the load may exceed what "
            "the joints hold, or the guess is far from an equilibrium",
        )
    z = _assemble(n, free, zf, known, zk)
    return (z, free, failed) if return_failed else (z, free)


#: time step (s) of the 5-point stencil that gives the quasi-static velocity; truncation error
#: ~ dt^4 z^(5)/30, about 1e-13 relative for the scenes' motions (periods of seconds)
QS_DT = 1e-3


#: relative step of the central differences that give the chord iteration's matrix
CHORD_FD_STEP = 1e-6


def _difference_jacobian(f, y0):
    """Jacobian of f at y0 by central differences (steps CHORD_FD_STEP (1 + |y0_j|)), all
    columns in one vectorised evaluation. Error about 1e-10 relative (rounding over the step;
    truncation is 1e-12): the chord iteration only
    needs a matrix close enough to contract, and a forward-mode Jacobian here would trace the
    springs' force (itself built on the kinematics' Jacobian) under a second derivative, a
    third of the quasi-static program."""
    n = y0.shape[0]
    d = CHORD_FD_STEP * (1 + jnp.abs(y0))
    steps = jnp.concatenate([jnp.diag(d), -jnp.diag(d)])
    F = jax.vmap(f)(y0 + steps)
    return ((F[:n] - F[n:]) / (2 * d)[:, None]).T


def _chord_solve(resid, resid_stiff, y0, rtol: float = 1e-13, atol: float = 1e-13,
                 max_steps: int = 100):
    """Solve resid(y) = 0 near y0 by chord iterations with the Jacobian J0 of `resid_stiff` (the
    residual's spring/actuator part) at y0, factorised once: the fixed point of
    y -> y - J0^-1 resid(y), found by optimistix (`FixedPointIteration`, stopping when a step is
    below atol + rtol |y|, with a result code) and differentiated implicitly (a small solve at
    the root, not through the iterations). The inertial part of the residual changes the
    Jacobian by about (motion frequency / internal frequency)^2, so the iteration contracts by
    that factor per step while converging to the root of the full residual (J0 by central
    differences, `_difference_jacobian`: its 1e-10 error changes nothing of that).
    Returns (y, relative residual, optimistix result)."""
    J0 = _difference_jacobian(resid_stiff, y0)
    lu = lu_factor(J0)

    def chord(y, _):
        r = resid(y)
        return y - lu_solve(lu, r), r

    # The residual is the iteration's aux: taken at the last iterate y_k, while the value
    # returned is y_k+1, a step below the tolerance further on (a residual up to one contraction
    # factor larger: the conservative side). Evaluating resid once more at y_k+1 instead put a
    # second copy of the full equations of motion into the program, a third of the compilation
    # of L2's and L3's scenes.
    sol = optx.fixed_point(
        chord, optx.FixedPointIteration(rtol=rtol, atol=atol), y0, has_aux=True,
        max_steps=max_steps, throw=False, adjoint=optx.ImplicitAdjoint(SmallLU()),
    )
    y = sol.value
    scale = jnp.maximum(jnp.max(jnp.abs(J0)) * jnp.max(jnp.abs(y)), 1e-300)
    return y, jnp.max(jnp.abs(sol.aux)) / scale, sol.result


def quasi_static_state(
    model: AbstractModel,
    robot: RobotLike,
    trajectory: Callable,
    t,
    actuation: Optional[AbstractActuation] = None,
    *,
    motion_driven: Optional[bool] = None,
    torque: Optional[Callable] = None,
    wrench=None,
):
    """Initial state (z, z') of `model` consistent with the L1 motion along `trajectory` at t
    under `actuation` (an `AbstractActuation`; the older flags `motion_driven` and `torque`
    (a time function) say the same: one or the other). Raises `PPRError` if it is not found.

    The reference is the model's coordinates on the L1 manifold, z_ref(t) =
    coords_from_pose(X(t)), with its velocity and acceleration. Models without internal degrees of
    freedom (L0, L1) return it as is. For L2 the coordinates not fixed by the scene are put at the
    quasi-static state: their rows of M z'' + h = Q balance with the reference velocities and
    accelerations
    (torque-driven: the pose is the nominal one and every other coordinate (L2: the actuated
    angles) balances under the applied torque; motion-driven: the actuated angles are prescribed
    and the pose and any other internal coordinate balance). Models order z as (X, th_a, rest).
    Their velocity is the time derivative of that quasi-static solution (a 5-point central
    difference of step `QS_DT`, error ~1e-13), so no fast internal vibration is excited at t = 0
    beyond what the model mismatch implies.
    """
    z, zd, failed = _quasi_static_state_jit(
        model, as_robot(robot), trajectory, t, actuation, motion_driven=motion_driven,
        torque=torque, wrench=wrench,
    )
    z = raise_if(
        z, failed,
        "quasi-static initial state not found (the chord iteration did not converge): the "
        "scene's initial loads are beyond what the joints hold near the nominal pose",
    )
    return z, zd


def _quasi_static_state(
    model: AbstractModel,
    robot: RobotLike,
    trajectory: Callable,
    t,
    actuation: Optional[AbstractActuation] = None,
    *,
    motion_driven: Optional[bool] = None,
    torque: Optional[Callable] = None,
    wrench=None,
):
    """`quasi_static_state` without raising: (z, z', failed), failed a traceable bool."""
    robot = as_robot(robot)
    if actuation is None:
        if motion_driven is None:
            raise PPRError("quasi_static_state needs an actuation (or motion_driven=True/False)")
        actuation = None if motion_driven else TorqueDriven(
            (lambda t: jnp.zeros(3)) if torque is None else torque
        )
        prescribed = bool(motion_driven)
    else:
        if motion_driven is not None or torque is not None:
            raise PPRError("give either an actuation or motion_driven/torque, not both")
        prescribed = actuation.prescribes_angles
    n = model.n_dof
    w = jnp.zeros(3) if wrench is None else jnp.asarray(wrench, dtype=jnp.float64)

    def ref(t):
        return model.coords_from_pose(robot, trajectory(t))

    t = jnp.asarray(t, dtype=jnp.float64)
    if model.actuated_index is None:
        z, zd, _ = derivatives(ref, t)
        return z, zd, jnp.asarray(False)
    act = tuple(model.actuated_index)
    # torque-driven: the pose is nominal and every internal coordinate balances;
    # motion-driven: the actuated angles are prescribed and everything else balances.
    unknown = tuple(i for i in range(n) if i not in act) if prescribed else tuple(range(3, n))
    known = tuple(i for i in range(n) if i not in unknown)
    iu, ik = jnp.array(unknown), jnp.array(known)

    def solve_at(t):
        z_r, zd_r, zdd_r = derivatives(ref, t)
        if prescribed:
            tau = jnp.zeros(3)
        else:
            # The torque at the reference motion (a servo's feedforward; a PD term is zero there);
            # the actuated angles are coordinates of the models that reach this line.
            ia = jnp.array(act)
            tau = actuation.torque_at(t, z_r[ia], zd_r[ia])

        def full(zu):
            z = _assemble(n, unknown, zu, known, z_r[ik])
            eom = eom_terms(model, robot, z, zd_r)
            return (eom.M @ zdd_r + eom.h - generalized_force(eom, tau, w))[iu]

        def stiff(zu):
            z = _assemble(n, unknown, zu, known, z_r[ik])
            return -passive_force(model, robot, z, zd_r, tau, w)[iu]

        return (*_chord_solve(full, stiff, z_r[iu]), z_r, zd_r)

    # The solution at t and at t +- dt, t +- 2 dt in one vmapped solve; the velocity is the
    # 5-point central difference (exact derivatives would need third derivatives of the
    # kinematics, whose compilation cost more than the whole simulation).
    offsets = jnp.array([0.0, -2.0, -1.0, 1.0, 2.0]) * QS_DT
    zus, errs, results, z_rs, zd_rs = jax.vmap(solve_at)(t + offsets)
    zu = zus[0]
    zu_dot = (zus[1] - 8 * zus[2] + 8 * zus[3] - zus[4]) / (12 * QS_DT)
    # the reference at t is the first solve's (offset 0): no second trace of its derivatives
    z_r, zd_r = z_rs[0], zd_rs[0]
    # Running out of chord steps is no failure when the residual is down to rounding: a residual
    # computed through an inner solve (L3's quasi-static strips at large N) has a noise floor
    # that the step criterion (1e-13 relative) may not reach. The residual decides.
    stalled = results == optx.RESULTS.nonlinear_max_steps_reached
    failed = ~(jnp.max(errs) < 1e-10) | jnp.any((results != optx.RESULTS.successful) & ~stalled)
    z = _assemble(n, unknown, zu, known, z_r[ik])
    zd = _assemble(n, unknown, zu_dot, known, zd_r[ik])
    # A balance found outside the chains' reach is no state: there the closed-form closure works
    # on clipped values, is locally flat, and the balance equations can hold spuriously (a strip
    # too thin to carry the loads collapses the chain).
    failed = failed | ~(jnp.min(model.kinematics(robot, z).margin) > 0)
    return z, zd, failed


# Compiled once per (model, actuation type, shapes): run op by op, the chord iteration's many
# small operations cost minutes.
_quasi_static_state_jit = eqx.filter_jit(_quasi_static_state)
