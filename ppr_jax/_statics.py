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
from ._dynamics import eom_terms, generalized_force
from ._linalg import SmallLU, solve
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
        resid, optx.Newton(rtol=rtol, atol=atol, linear_solver=SmallLU()), y0, args=args,
        max_steps=max_steps, throw=False,
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


#: relative step of the central differences that give the quasi-static Newton iteration's
#: Jacobian (error about 1e-10 relative: rounding over the step; truncation is 1e-12)
FD_STEP = 1e-6


def _fd_newton_solve(resid, y0, rtol: float = 1e-13, atol: float = 1e-13, max_steps: int = 100):
    """Solve resid(y) = 0 near y0 by Newton's iteration with the Jacobian by central
    differences (steps FD_STEP (1 + |y_j|), 1e-10 relative error, so the convergence is
    quadratic down to rounding), the residual and its 2n neighbours in one vmapped evaluation:
    the equations of motion appear once in the program. (A chord iteration with the springs'
    Jacobian from a separate evaluation of the passive forces, the previous form, put a second
    copy of the springs into the program: for L3's strips, 0.25 M of its 0.92 M characters and
    a third of its compilation.) `resid` returns (residual, aux). Found by optimistix
    (`FixedPointIteration` on y -> y - J(y)^-1 resid(y), stopping when a step is below
    atol + rtol |y|, with a result code) and differentiated implicitly (J under stop_gradient:
    at the root only resid's own derivatives enter, so the derivatives are exact whatever J's
    error).
    Returns (y, relative residual at the last iterate, optimistix result, aux of that iterate)."""
    n = y0.shape[0]

    def newton(y, _):
        d = FD_STEP * (1 + jnp.abs(y))
        pts = jnp.concatenate([y[None], y + jnp.diag(d), y - jnp.diag(d)])
        F, aux = jax.vmap(resid)(pts)
        J = jax.lax.stop_gradient(((F[1:n + 1] - F[n + 1:]) / (2 * d)[:, None]).T)
        scale = jnp.maximum(jnp.max(jnp.abs(J)) * jnp.max(jnp.abs(y)), 1e-300)
        r = F[0]
        return y - solve(J, r), (jnp.max(jnp.abs(r)) / scale, jax.tree.map(lambda a: a[0], aux))

    sol = optx.fixed_point(
        newton, optx.FixedPointIteration(rtol=rtol, atol=atol), y0, has_aux=True,
        max_steps=max_steps, throw=False, adjoint=optx.ImplicitAdjoint(SmallLU()),
    )
    err, aux = sol.aux
    return sol.value, err, sol.result, aux


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
        "quasi-static initial state not found (the Newton iteration did not converge): the "
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
            # the balance, and the chains' reach (which the balance needs: below)
            z = _assemble(n, unknown, zu, known, z_r[ik])
            eom = eom_terms(model, robot, z, zd_r)
            r = (eom.M @ zdd_r + eom.h - generalized_force(eom, tau, w))[iu]
            return r, jnp.min(eom.kin.margin)

        return (*_fd_newton_solve(full, z_r[iu]), z_r, zd_r)

    # The solution at t and at t +- dt, t +- 2 dt in one vmapped solve; the velocity is the
    # 5-point central difference (exact derivatives would need third derivatives of the
    # kinematics, whose compilation cost more than the whole simulation).
    offsets = jnp.array([0.0, -2.0, -1.0, 1.0, 2.0]) * QS_DT
    zus, errs, results, margins, z_rs, zd_rs = jax.vmap(solve_at)(t + offsets)
    zu = zus[0]
    zu_dot = (zus[1] - 8 * zus[2] + 8 * zus[3] - zus[4]) / (12 * QS_DT)
    # the reference at t is the first solve's (offset 0): no second trace of its derivatives
    z_r, zd_r = z_rs[0], zd_rs[0]
    # Running out of Newton steps is no failure when the residual is down to rounding: a residual
    # computed through an inner solve (L3's quasi-static strips at large N) has a noise floor
    # that the step criterion (1e-13 relative) may not reach. The residual decides.
    stalled = results == optx.RESULTS.nonlinear_max_steps_reached
    failed = ~(jnp.max(errs) < 1e-10) | jnp.any((results != optx.RESULTS.successful) & ~stalled)
    z = _assemble(n, unknown, zu, known, z_r[ik])
    zd = _assemble(n, unknown, zu_dot, known, zd_r[ik])
    # A balance found outside the chains' reach is no state: there the closed-form closure works
    # on clipped values, is locally flat, and the balance equations can hold spuriously (a strip
    # too thin to carry the loads collapses the chain).
    # (The margin is the last iterate's, a step below the tolerance from z: no further
    # evaluation of the kinematics.)
    failed = failed | ~(margins[0] > 0)
    return z, zd, failed


# Compiled once per (model, actuation type, shapes): run op by op, the Newton iteration's many
# small operations cost minutes.
_quasi_static_state_jit = eqx.filter_jit(_quasi_static_state)
