"""Static equilibria and quasi-static (L1-consistent) initial states.

Every residual here is the generalized force balance of `_dynamics.py`, solved with optimistix
Newton (differentiable by the implicit function theorem, forward and reverse mode).
"""

from __future__ import annotations

from typing import Callable, Optional

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array

from ._actuation import (
    AbstractActuation,
    InverseKinematicsAngles,
    MotionDriven,
    TorqueDriven,
)
from ._dynamics import eom_terms, generalized_force, potential_of
from ._errors import PPRError, raise_if, result_code
from ._kinematics import fk_solve
from ._linalg import SmallLU, solve
from ._models import AbstractModel, Reduced
from ._robot import RobotLike, as_robot
from ._simulate import accelerations, split_coordinates
from ._trajectory import derivatives


def assemble(n, idx_u, zu, idx_k, zk):
    z = jnp.zeros(n, dtype=jnp.float64)
    if idx_u:
        z = z.at[jnp.array(idx_u)].set(zu)
    if idx_k:
        z = z.at[jnp.array(idx_k)].set(zk)
    return z


class _StepTested(optx.AbstractRootFinder):
    """A Newton iteration that stops once its last step (`state.relative_step`, in units of
    atol + rtol |y|, the step taken) is below 1, or at once, diverged, when that step is NaN
    (a singular Jacobian, a balance out of reach: not another `max_steps` of NaN iterations):
    `_Newton` and `_FDNewton` implement `init` and `step`."""

    def terminate(self, fn, y, args, options, state, tags):
        del fn, y, args, options, tags
        nan = jnp.isnan(state.relative_step)
        return (state.relative_step < 1) | nan, optx.RESULTS.where(
            nan, optx.RESULTS.nonlinear_divergence, optx.RESULTS.successful)

    def postprocess(self, fn, y, aux, args, options, state, tags, result):
        del fn, args, options, state, tags, result
        return y, aux, {}


class _NewtonState(eqx.Module):
    #: the last step's size in units of atol + rtol |y| (max norm)
    relative_step: Array


class _Newton(_StepTested):
    """Newton's iteration with the exact (forward-mode) Jacobian whose every step is its own
    convergence test: it stops once a step is below atol + rtol |y| (max norm), that step
    taken (`_newton` says why)."""

    rtol: float
    atol: float
    norm: Callable = optx.max_norm

    def init(self, fn, y, args, options, f_struct, aux_struct, tags):
        del fn, args, options, f_struct, aux_struct, tags
        return _NewtonState(jnp.array(jnp.inf, dtype=y.dtype))

    def step(self, fn, y, args, options, state, tags):
        del options, state, tags

        def f(y):
            r, aux = fn(y, args)
            return r, (r, aux)

        J, (r, aux) = jax.jacfwd(f, has_aux=True)(y)
        step = solve(J, r)
        size = self.norm(step / (self.atol + self.rtol * jnp.abs(y)))
        return y - step, _NewtonState(size), aux


def _newton(resid, y0, args, rtol=1e-12, atol=1e-12, max_steps=100):
    """Newton's root of `resid(y, args)` from y0: (y, optimistix result).

    Convergence is judged by the step itself, |J^-1 r| <= atol + rtol |y| componentwise (and
    taken: `_Newton`), not by optimistix's `Newton`, which reads the ratio of successive steps
    as the contraction rate. Near a root whose residual is at round-off (stiff joints: forces of
    K eps), the steps are noise of 1e-16 and that ratio is noise too: L2 at home with locked
    actuators at t >= 1 mm (free at t >= 2 mm) ended "diverged" after two steps or at max_steps
    with the root found to 1e-16 rad. (Checked by one more step after optimistix's own loop
    before, that step was a second copy of the balance's Jacobian in every program: L3's modes
    at N = 8 compiled in 11.8 s, 7.9 s without it.) Differentiated implicitly as a root of
    `resid` (optimistix's `ImplicitAdjoint`)."""
    sol = optx.root_find(
        resid, _Newton(rtol=rtol, atol=atol), y0, args=args, max_steps=max_steps, throw=False,
        adjoint=optx.ImplicitAdjoint(SmallLU()),
    )
    return sol.value, sol.result


def free_coordinates(model: AbstractModel, locked: bool) -> tuple:
    """The coordinates `static_equilibrium` solves for, decided in Python: every one with free
    actuators; with locked actuators all but the actuated angles (none for L0 and L1, whose
    pose follows from the angles)."""
    if not locked:
        return tuple(range(model.n_dof))
    if model.actuated_index is None:
        return ()
    return tuple(i for i in range(model.n_dof) if i not in tuple(model.actuated_index))


def springs_from_potential(model: AbstractModel) -> bool:
    """Whether the static balances of `model` are taken as gradients of its springs'
    potential energy (`potential_of`; decided from its class before tracing): where the
    springs' force is the deflections' own (`AbstractModel.spring_force` not overridden), at
    rest it is -dU/dz exactly, and the potential's derivatives hold no mass matrix or velocity
    terms, which a derivative of the balance differentiates once more. A model whose springs
    are implicit in z (the quasi-static L3) keeps its own spring force, whose derivatives never
    differentiate its inner solve (the potential's Hessian would: its modes' first call 6.3 ->
    7.2 s)."""
    return type(model).spring_force is AbstractModel.spring_force


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
    """Static equilibrium z* of `model` near `z_guess` (Newton on the free rows of
    M z'' + h = Q at zero velocity and acceleration, that is Q = 0 at rest: minus the gradient
    of the total potential energy under the constant loads, `springs_from_potential`).

    **Arguments:**

    - `model`: a model (L0-L3); `robot`: a `Robot` or `RobotParams`.
    - `z_guess`: (n,) starting coordinates of Newton; with `locked`, also the source of the
      held actuated angles.
    - `locked`: True: the actuated angles stay at their values in `z_guess` and only the other
      coordinates move (L2: the pose; L0/L1 have none left and `z_guess` is returned).
      False: every coordinate is free and the actuators apply constant torques `tau`.
    - `tau`: (3,) constant actuator torques (N m) when not `locked`; None (default): 0, "free
      actuators".
    - `wrench`: (3,) constant platform load (N, N, N m); None (default): no load.
    - `check`: raise `PPRError` if Newton does not converge (default True). `check=False`
      leaves the check to the caller (with `return_failed`): no host callback inside a compiled
      program.
    - `return_failed`: also return the traceable bool `failed` (default False).

    **Returns:**

    (z*, free_index): z* (n,) the equilibrium coordinates and free_index the tuple of the
    coordinates that were free; with `return_failed`, (z*, free_index, failed).

    **Raises:**

    `PPRError` (with `check`) if Newton does not converge: the load may exceed what the joints
    hold, or the guess is far from an equilibrium.
    """
    robot = as_robot(robot)
    n = model.n_dof
    tau = jnp.zeros(3) if tau is None else jnp.asarray(tau, dtype=jnp.float64)
    w = jnp.zeros(3) if wrench is None else jnp.asarray(wrench, dtype=jnp.float64)
    z_guess = jnp.asarray(z_guess, dtype=jnp.float64)
    free = free_coordinates(model, locked)
    if not free:
        return (z_guess, (), jnp.asarray(False)) if return_failed else (z_guess, ())
    known = tuple(i for i in range(n) if i not in free)
    zk = z_guess[jnp.array(known)] if known else None

    def potential(zf):
        # at rest Q = -dU/dz + Jth^T tau + JX^T w (no damping or friction without velocity):
        # minus the gradient of the total potential energy under the constant loads
        z = assemble(n, free, zf, known, zk)
        k = model.kinematics(robot, z)
        return potential_of(model, robot, k) - jnp.sum(k.th_a * tau) - jnp.sum(k.X * w)

    def resid(zf, _):
        if springs_from_potential(model):
            # the balance as the potential's gradient, equal to the equations of motion's Q at
            # rest (equilibria the same to 1e-16, modes to 1e-13 relative)
            return -jax.grad(potential)(zf)
        z = assemble(n, free, zf, known, zk)
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
    z = assemble(n, free, zf, known, zk)
    return (z, free, failed) if return_failed else (z, free)


#: time step (s) of the 5-point stencil that gives the quasi-static path's velocity and
#: acceleration. Truncation ~ dt^4 z^(5)/30 in the velocity (1e-11 relative for the scenes'
#: motions, periods of seconds), dt^3 z^(5) in the one-sided accelerations at the stencil's ends
#: (1e-8); rounding ~ 30 eps / dt^2 in those accelerations, which the second pass's solutions
#: carry into the velocity: at 1 ms that noise reached 5e-6 of phi', at 5 ms it is 1e-7.
QS_DT = 5e-3
#: the step (s) of a one-sided start stencil (`start_stencil`), at a kink of the path
QS_DT_ONE_SIDED = 1e-3
#: how far (s) from a kink of the path the central stencil of `QS_DT` would reach across it:
#: within this, a start takes a one-sided stencil (`start_stencil`) and an inversion that did not
#: settle is put down to the kink (`_studies/_compensate.py`)
STENCIL_REACH = 2.0 * QS_DT * (1.0 + 1e-9)


#: the quasi-static solves' times, in steps of QS_DT about t
STENCIL = np.arange(-2.0, 3.0)
#: the stencils a start may take, in steps of QS_DT from t: central (`STENCIL`), forward (a
#: path that kinks just before t: the stencil must not reach back across it) and backward (a
#: kink at t, the end of a hold, or just after t: the motion up to t); `start_stencil` chooses
STENCILS = np.stack([STENCIL, STENCIL + 2.0, STENCIL - 2.0])

#: passes of the quasi-static start (`quasi_static_core`): the first balances the unknowns at
#: the reference's rates and accelerations, each further one at the previous pass's own. Two is
#: the start of MODEL.md section 6; one is kept as a module setting for the comparison in
#: benchmarks/start_sensitivity.py (read when a program is traced: set it before compiling).
QS_PASSES = 2


def _differentiation_matrices(s):
    """(D1, D2): the first and second derivatives at the nodes `s` of the polynomial that
    interpolates values there (unit spacing; divide by the step and its square)."""
    k = np.arange(s.shape[0])
    V = s[:, None] ** k
    V1 = np.where(k > 0, k * s[:, None] ** np.maximum(k - 1, 0), 0.0)
    V2 = np.where(k > 1, k * (k - 1) * s[:, None] ** np.maximum(k - 2, 0), 0.0)
    Vi = np.linalg.inv(V)
    # NumPy, not JAX: a JAX array made at import would start JAX's backend before the user's
    # `configure_cpu` could set XLA's flags
    return V1 @ Vi, V2 @ Vi


D1, D2 = _differentiation_matrices(STENCIL)
#: `STENCILS`' differentiation matrices (3, 5, 5) each (unit step)
D1S, D2S = (np.stack(m) for m in zip(*(_differentiation_matrices(s) for s in STENCILS)))


def path_kinks(*fns):
    """The times (k,) (s) where the functions move from a hold to a motion or back (their
    second or third derivatives jump), from their optional `kinks` attribute (a clamped
    `Waypoints` or `CommandLog`: its first and last sample; `Line`: 0 and its duration), or
    None where none of them declares any."""
    found = [getattr(f, "kinks", None) for f in fns]
    found = [jnp.asarray(k, dtype=jnp.float64).reshape(-1) for k in found if k is not None]
    return jnp.concatenate(found) if found else None


def start_stencil(trajectory: Callable, t, actuation: Optional[AbstractActuation] = None):
    """(offsets (5,), D1 (5, 5), D2 (5, 5), centre, dt, t_at): the quasi-static start's
    stencil about t in steps of dt (s), its differentiation matrices (unit step: divide by dt
    and dt^2), the index of t in it, and the time (s) the stencil is laid from (t, or t's left
    limit: below).

    Central (`STENCIL` in steps of `QS_DT`) unless the path declares kinks (an optional
    `kinks` attribute (k,) (s): the times where its acceleration or jerk jumps between a hold
    and a motion; a path is otherwise C2, as a scene requires): a clamped `Waypoints` is at
    rest before its first sample and accelerates after it, so its input (inverse-dynamics
    torques, prescribed angles) jumps there, and a quartic through values on both sides
    differentiates the jump (rates of the balance ~ jump / QS_DT, a second pass that diverges:
    no start was found; across `Line`'s jump of jerk at t = 0, the mean of the rates on either
    side: 2.5 mm off in the run).

    - A kink at t (the scene starts where a hold ends): backward, the hold's balance at rest. A
      robot that starts a move at t0 has been at rest before it, and it is that robot's state
      the start stands for: against the same `Line` move (0.5 s, motion-driven L2) started 0.1
      s earlier in the hold, so that the robot lives through the move's start, the backward
      start's run is 1.8e-11 m off, a forward one (the motion's quasi-static state after t)
      4.3e-4 m, the central one 2.5e-3 m. The stencil then ends at t's left limit `t_at`, a
      hair before t (max(1e-12 s, 64 roundings of t)): there the input table's panel before
      the kink holds the hold's values (at t itself the path, and the torques computed from
      it, read the motion's one-sided acceleration).
    - A kink in (t - 2 QS_DT, t): forward, the motion since that kink, which the stencil must
      not reach back across.
    - A kink in (t, t + 2 QS_DT): backward, the motion up to t.

    A one-sided stencil steps by `QS_DT_ONE_SIDED`: its error is O(dt^2) in the rates (a random
    clamped spline through 1 cm samples 0.1 s apart, 6.6 m/s^2 from rest: 2e-3 of the actuated
    angles' rates at 5 ms, 2e-5 at 1 ms, against a Richardson difference of the balances). The
    kinks are the path's and those of the function `actuation` holds (a clamped `CommandLog`'s
    ends)."""
    kinks = path_kinks(trajectory, getattr(actuation, "torque", None),
                       getattr(actuation, "angles", None))
    if kinks is None:
        return (jnp.asarray(STENCIL), jnp.asarray(D1), jnp.asarray(D2), STENCIL.shape[0] // 2,
                QS_DT, t)
    roundings = 8.0 * jnp.spacing(jnp.abs(t))
    at = jnp.any(jnp.abs(kinks - t) <= roundings)
    before = jnp.any((kinks < t - roundings) & (kinks > t - STENCIL_REACH))
    after = jnp.any((kinks > t + roundings) & (kinks < t + STENCIL_REACH))
    k = jnp.where(at, 2, jnp.where(before, 1, jnp.where(after, 2, 0)))
    centre = jnp.asarray([STENCIL.shape[0] // 2, 0, STENCIL.shape[0] - 1])[k]
    dt = jnp.asarray([QS_DT, QS_DT_ONE_SIDED, QS_DT_ONE_SIDED])[k]
    left = t - jnp.maximum(1e-12, 8.0 * roundings)
    t_at = jnp.where(at, left, t)
    return (jnp.asarray(STENCILS)[k], jnp.asarray(D1S)[k], jnp.asarray(D2S)[k], centre, dt,
            t_at)


#: relative step of the central differences that give the quasi-static Newton iteration's
#: Jacobian (error about 1e-10 relative: rounding over the step; truncation is 1e-12)
FD_STEP = 1e-6


class _FDNewtonState(eqx.Module):
    #: the step's size in units of atol + rtol |y| (max norm)
    relative_step: Array
    #: max |resid| at the last iterate, relative to max |J| max |y| (`_fd_newton_solve`)
    relative_residual: Array


class _FDNewton(_StepTested):
    """Newton's iteration for resid(y) = 0 with the Jacobian J by central differences (steps
    FD_STEP (1 + |y_j|)), the residual and its 2n neighbours in one vmapped evaluation; stops
    when a step is below atol + rtol |y| (max norm). `_fd_newton_solve` says why."""

    rtol: float
    atol: float
    norm: Callable = optx.max_norm

    def init(self, fn, y, args, options, f_struct, aux_struct, tags):
        del fn, args, options, f_struct, aux_struct, tags
        inf = jnp.array(jnp.inf, dtype=y.dtype)
        return _FDNewtonState(inf, inf)

    def step(self, fn, y, args, options, state, tags):
        del options, state, tags
        n = y.shape[0]
        d = FD_STEP * (1 + jnp.abs(y))
        pts = jnp.concatenate([y[None], y[None] + jnp.diag(d), y[None] - jnp.diag(d)])
        F, aux = jax.vmap(lambda p: fn(p, args))(pts)
        J = jax.lax.stop_gradient(((F[1:n + 1] - F[n + 1:]) / (2 * d)[:, None]).T)
        scale = jnp.maximum(jnp.max(jnp.abs(J)) * jnp.max(jnp.abs(y)), 1e-300)
        r = F[0]
        new_y = y - solve(J, r)
        size = self.norm((y - new_y) / (self.atol + self.rtol * jnp.abs(new_y)))
        state = _FDNewtonState(size, jnp.max(jnp.abs(r)) / scale)
        return new_y, state, jax.tree.map(lambda a: a[0], aux)


def _fd_newton_solve(resid, y0, rtol: float = 1e-13, atol: float = 1e-13, max_steps: int = 100):
    """Solve resid(y) = 0 near y0 by Newton's iteration with the Jacobian by central
    differences (`_FDNewton`: steps FD_STEP (1 + |y_j|), 1e-10 relative error, so the
    convergence is quadratic down to rounding), the residual and its 2n neighbours in one
    vmapped evaluation: the equations of motion appear once in the program. (A chord iteration
    with the springs' Jacobian from a separate evaluation of the passive forces, the previous
    form, put a second copy of the springs into the program: for L3's strips, 0.25 M of its
    0.92 M characters and a third of its compilation.) `resid` returns (residual, aux).

    Differentiated implicitly as a root of resid (optimistix's `ImplicitAdjoint`): dy =
    -(d resid/dy)^-1 (d resid/dparameters) at the root, with resid's own exact Jacobian at that
    one point, whatever the iteration's J. (Differentiated as a fixed point of the Newton map
    instead, the derivative held the Jacobian of the whole iteration, the 2n + 1 vmapped
    evaluations of the equations of motion: on L2's identification program that was 1.4 s of
    tracing and 2 s of XLA compilation of 13 s; the derivatives are the same to rounding.)
    Returns (y, relative residual at the last iterate, optimistix result, aux of that iterate)."""
    sol = optx.root_find(
        lambda y, args: resid(y), _FDNewton(rtol=rtol, atol=atol), y0, has_aux=True,
        max_steps=max_steps, throw=False, adjoint=optx.ImplicitAdjoint(SmallLU()),
    )
    return sol.value, sol.state.relative_residual, sol.result, sol.aux


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
    """Initial state (z, z') of `model` at time t, in balance under `actuation`.

    The known coordinates come from the scene: torque-driven (and PD servo), the platform pose
    and its rates are the trajectory's; motion-driven, the actuated angles, their rates and
    accelerations are the actuation's own at t (MODEL.md section 6), never the robot's inverse
    kinematics of `trajectory`: commands computed by another model, or measured angles, differ
    from it, and a start there is off balance and rings through the run. Every other
    coordinate (L2: the actuated angles, or the pose; L3: also the connecting links) sits at
    the quasi-static state: its rows of M z'' + h = Q balance, with the reference velocities
    and accelerations of the L1 manifold along `trajectory` (so `trajectory` is the guess of
    the pose under prescribed angles). Their velocity is the time derivative of that
    quasi-static solution (a 5-point central difference of step `QS_DT`, error ~1e-7), so no
    fast internal vibration is excited at t = 0 beyond what the model mismatch implies. The full
    L3's strip angles then move onto the strips' slow path (`onto_slow_manifold`): their
    accelerations under the full dynamics are the quasi-static path's, so the kHz strip modes
    start at rest.
    L0 and L1 have no internal coordinates: torque-driven they start on the trajectory;
    motion-driven at the forward kinematics of the prescribed angles (`kinematic_state`).

    **Arguments:**

    - `model`: a model (L0-L3); `robot`: a `Robot` or `RobotParams`.
    - `trajectory`: the platform's reference pose, t -> (3,) (m, m, rad).
    - `t`: time (s).
    - `actuation`: an `AbstractActuation`. The older flags say the same: `motion_driven=True`
      is `MotionDriven` with the robot's own L1 inverse-kinematics angles of `trajectory`,
      `motion_driven=False` with `torque` (a time function) is `TorqueDriven`; one or the other.
    - `wrench`: (3,) constant platform load (N, N, N m).

    **Returns:** (z, z'), (n,) each. Raises `PPRError` if no balance is found.
    """
    z, zd, failed = _quasi_static_state_jit(model, as_robot(robot), trajectory, t, actuation,
                                            motion_driven, torque, wrench)
    z = raise_if(
        z, failed,
        "quasi-static initial state not found (the Newton iteration did not converge): the "
        "scene's initial loads are beyond what the joints hold near the nominal pose",
    )
    return z, zd


def _zero_torque(t):
    return jnp.zeros(3)


def _actuation(robot, trajectory, actuation, motion_driven, torque) -> AbstractActuation:
    """`quasi_static_state`'s actuation: `actuation`, or the one the older flags say."""
    if actuation is None:
        if motion_driven is None:
            raise PPRError("quasi_static_state needs an actuation (or motion_driven=True/False)")
        # motion_driven=True: the angles of the robot's own L1 inverse kinematics of the
        # trajectory (what the flag always meant); other angles need an explicit MotionDriven.
        return (
            MotionDriven(InverseKinematicsAngles(Reduced(), robot, trajectory)) if motion_driven
            else TorqueDriven(_zero_torque if torque is None else torque)
        )
    if motion_driven is not None or torque is not None:
        raise PPRError("give either an actuation or motion_driven/torque, not both")
    return actuation


def quasi_static_core(model: AbstractModel, robot: RobotLike, trajectory: Callable, t,
                      actuation: AbstractActuation, wrench=None):
    """`quasi_static_state` under `actuation`, without raising: (z, z', failed), failed a
    traceable bool."""
    robot = as_robot(robot)
    prescribed = actuation.prescribes_angles
    n = model.n_dof
    w = jnp.zeros(3) if wrench is None else jnp.asarray(wrench, dtype=jnp.float64)

    def ref(t):
        return model.coords_from_pose(robot, trajectory(t))

    t = jnp.asarray(t, dtype=jnp.float64)
    if model.actuated_index is None:
        if prescribed:
            # L0/L1 under prescribed angles: the pose is their forward kinematics (started at
            # the trajectory's pose), not the trajectory's own pose.
            X, Xd, _, code, _ = kinematic_state(model, robot, actuation.angles_at(t),
                                             trajectory(t))
            return X, Xd, code != 0
        z, zd, _ = derivatives(ref, t)
        return z, zd, jnp.asarray(False)
    act = tuple(model.actuated_index)
    # torque-driven: the pose is nominal and every internal coordinate balances;
    # motion-driven: the actuated angles are prescribed and everything else balances.
    unknown = tuple(i for i in range(n) if i not in act) if prescribed else tuple(range(3, n))
    known = tuple(i for i in range(n) if i not in unknown)
    iu, ik = jnp.array(unknown), jnp.array(known)

    def reference(t):
        """(z_r, z_r', z_r'', tau) at time t: the reference's coordinates and rates, with the
        actuation's own angles where it prescribes them, and the actuator torques."""
        z_r, zd_r, zdd_r = derivatives(ref, t)
        ia = jnp.array(act)
        if prescribed:
            # The actuated angles, rates and accelerations are the actuation's own (MODEL.md
            # section 6): commands computed by another model, or measured angles, differ from
            # this robot's inverse kinematics of the trajectory, and a start on the latter is off
            # balance and rings through the whole run.
            tha, thad, thadd = actuation.angles_at(t)
            z_r, zd_r, zdd_r = z_r.at[ia].set(tha), zd_r.at[ia].set(thad), zdd_r.at[ia].set(thadd)
            return z_r, zd_r, zdd_r, jnp.zeros(3)
        # The torque at the reference motion (a servo's feedforward; a PD term is zero there);
        # the actuated angles are coordinates of the models that reach this line.
        return z_r, zd_r, zdd_r, actuation.torque_at(t, z_r[ia], zd_r[ia])

    def solve_at(zu_guess, zud, zudd, z_r, zd_r, zdd_r, tau):
        """The balance at the reference (z_r, z_r', z_r'', tau), the unknowns from zu_guess at
        the velocities and accelerations (zud, zudd)."""
        zd_b, zdd_b = zd_r.at[iu].set(zud), zdd_r.at[iu].set(zudd)

        def full(zu):
            # the balance, and the chains' reach (which the balance needs: below)
            z = assemble(n, unknown, zu, known, z_r[ik])
            eom = eom_terms(model, robot, z, zd_b)
            r = (eom.M @ zdd_b + eom.h - generalized_force(eom, tau, w))[iu]
            return r, jnp.min(eom.kin.margin)

        return _fd_newton_solve(full, zu_guess)

    # The solutions at t - 2 dt ... t + 2 dt, one after another; their rates and accelerations
    # by differentiating the interpolating quartic (exact derivatives would need third
    # derivatives of the kinematics, whose compilation cost more than the whole simulation).
    # Two passes of one traced body (a scan): the first balances at the reference's velocities
    # and accelerations, the second at the first pass's own. The reference's differ from the
    # quasi-static path's wherever the robot is not the reference (another model's commands:
    # phi'' 4e-3 rad/s^2 off, 12 % of its scale); one pass more leaves (omega/omega_mode)^2,
    # about 1e-4, of that.
    offsets, d1, d2, c, dt, t_at = start_stencil(trajectory, t, actuation)
    ts = t_at + offsets * dt
    refs = jax.vmap(reference)(ts)
    z_rs, zd_rs, zdd_rs, _ = refs

    def one_pass(carry, _):
        # the stencil's solves one after another (a map), not vectorised: traced once without
        # the batching interpreter, and its Newton loop unbatched (first calls L2 4.2 -> 3.8 s,
        # quasi-static L3 at N = 8 9.9 -> 9.0 s, the full L3 at N = 4 24 -> 22 s; the start
        # moves by rounding, 4e-16 rad)
        out = jax.lax.map(lambda a: solve_at(*a), (*carry, *refs))
        zus = out[0]
        return (zus, d1 @ zus / dt, d2 @ zus / dt**2), out

    # The first pass starts from the reference (its coordinates are Newton's guess, its rates
    # and accelerations those the balance takes): a carry that depends on the parameters from
    # the start, so that a derivative's scan finds which of its carries move in one pass (from
    # zeros, forward mode differentiated the whole start twice)
    init = (z_rs[:, iu], zd_rs[:, iu], zdd_rs[:, iu])
    (zus, zud, zudd), outs = jax.lax.scan(one_pass, init, length=QS_PASSES)
    _, errs, results, margins = jax.tree.map(lambda a: a[-1], outs)
    zu, zu_dot = zus[c], zud[c]
    z_r, zd_r = z_rs[c], zd_rs[c]
    # Running out of Newton steps is no failure when the residual is down to rounding: a residual
    # computed through an inner solve (L3's quasi-static strips at large N) has a noise floor
    # that the step criterion (1e-13 relative) may not reach. The residual decides.
    stalled = results == optx.RESULTS.nonlinear_max_steps_reached
    failed = ~(jnp.max(errs) < 1e-10) | jnp.any((results != optx.RESULTS.successful) & ~stalled)
    z = assemble(n, unknown, zu, known, z_r[ik])
    zd = assemble(n, unknown, zu_dot, known, zd_r[ik])
    fast = fast_coordinates(model)
    if fast:
        pos = jnp.array([unknown.index(i) for i in fast])
        # at the stencil's time: a start at a hold's end takes the hold's accelerations
        z = onto_slow_manifold(model, robot, actuation, w, t_at, z, zd, fast, zudd[c][pos])
    # A balance found outside the chains' reach is no state: there the closed-form closure works
    # on clipped values, is locally flat, and the balance equations can hold spuriously (a strip
    # too thin to carry the loads collapses the chain).
    # (The margin is the last iterate's, a step below the tolerance from z: no further
    # evaluation of the kinematics.) Every solution of the stencil, not only the centre's: the
    # rates and accelerations are differences of them, and one collapsed neighbour (a Newton
    # run off to 1e286 with a residual that underflows, which the stalled-solve rule above
    # accepts) gave a start with z' ~ 1e287 reported as found, whose run stalled at t = 0
    # for max_steps (L2, t = 0.333 mm, w = 10 mm on a figure eight).
    failed = failed | ~jnp.all(margins > 0)
    return z, zd, failed


#: Newton iterations of the slow-manifold projection (`onto_slow_manifold`): on the full L3
#: (N = 16, paper-circle) they bring the strip accelerations from up to 280 rad/s^2 off the
#: quasi-static path's to its acceleration from the balance's own 5 ms stencil; what is left
#: against the path's exact acceleration (up to a fifth of it, 0.006 rad/s^2, at N = 8) rings
#: at mismatch / omega^2, about 1e-11 rad.
SLOW_NEWTON = 3


def fast_coordinates(model: AbstractModel) -> tuple:
    """The coordinates of `model` whose own dynamics is far faster than the robot's (static,
    `AbstractModel.fast_index`): the full L3's interior strip angles (kHz strip modes), none
    for the other models."""
    return tuple(model.fast_index)


def onto_slow_manifold(model, robot, actuation, wrench, t, z, zd, fast, target):
    """`z` with its `fast` coordinates moved so that their accelerations under the full
    dynamics equal `target`, the quasi-static path's: the zero-derivative principle (Gear,
    Kaper, Kevrekidis and Zagaris, SIAM J. Appl. Dyn. Syst. 4 (2005) 711) for a second-order
    system.

    The quasi-static balance puts the strips in equilibrium under the inertial loads of the
    reference motion, but the robot's own acceleration at t0 differs from the reference's (an
    open-loop torque, another model's commands). The light strip segments then start 100-300
    rad/s^2 off their slow path (full L3, N = 16, paper-circle), and the strip modes, up to 5e5
    rad/s and undamped by default, ring through the whole run, which an integrator must then
    resolve (0.5 us steps at rtol 1e-6). Moving the strip angles by the static deflection of
    that mismatch (mismatch / omega^2) starts the strips on the robot's slow motion. Newton on
    the fast coordinates' accelerations, `SLOW_NEWTON` iterations with a forward-mode
    Jacobian; the velocities are the quasi-static path's already.

    **Arguments:**

    - `z`, `zd`: (n,) the quasi-static state (SI units, radians).
    - `fast`: the fast coordinates (static tuple); `target`: their accelerations (rad/s^2).

    **Returns:** z (n,) with the fast coordinates moved.
    """
    free, _ = split_coordinates(model, actuation)
    fr, fs = jnp.array(free), jnp.array(fast)

    def resid(s):
        zz = z.at[fs].set(s)
        return accelerations(model, robot, actuation, wrench, t, zz[fr], zd[fr])[2][fs] - target

    # a loop, not unrolled: each unrolled step was a copy of the full L3's accelerations and
    # their Jacobian in the program (N = 4 and 16: a first call 27-29 -> 20 s)
    s = jax.lax.fori_loop(0, SLOW_NEWTON,
                          lambda _, s: s - solve(jax.jacfwd(resid)(s), resid(s)), z[fs])
    return z.at[fs].set(s)


# Compiled once per (model, actuation type, shapes): run op by op, the Newton iteration's many
# small operations cost minutes.
def _quasi_static_state(model, robot, trajectory, t, actuation, motion_driven, torque, wrench):
    # the older flags' actuation built inside the trace, from the traced robot itself
    act = _actuation(robot, trajectory, actuation, motion_driven, torque)
    return quasi_static_core(model, robot, trajectory, t, act, wrench)


_quasi_static_state_jit = eqx.filter_jit(_quasi_static_state)


def kinematic_state(model: AbstractModel, robot, angles, X_guess, rtol=1e-13, atol=1e-13,
                    max_steps=50):
    """The pose of a model without internal coordinates (L0, L1) under prescribed actuated
    angles: X by forward kinematics (Newton from `X_guess`), X' and X'' from th_a(X) = th_a(t)
    differentiated once and twice.

    **Arguments:**

    - `angles`: (th_a, th_a', th_a'') (3,) each (rad, rad/s, rad/s^2).
    - `X_guess`: (3,) the pose Newton starts from (m, m, rad).

    **Returns:** (X, X', X'', code, S): (3,) each, the forward kinematics' optimistix result
    code (0 when it converged), and S = d th_a / dX (3, 3) at X."""
    th, thd, thdd = angles

    def tha_of_X(X):
        return model.kinematics(robot, model.coords_from_pose(robot, X)).th_a

    X, res = fk_solve(model, robot, th, X_guess, rtol, atol, max_steps)
    S = jax.jacfwd(tha_of_X)(X)
    Xd = solve(S, thd)
    conv = jax.jvp(lambda X: jax.jvp(tha_of_X, (X,), (Xd,))[1], (X,), (Xd,))[1]
    Xdd = solve(S, thdd - conv)
    return X, Xd, Xdd, result_code(res), S


#: passes of `inverse_path`: each balances the unknowns at the previous pass's own rates and
#: accelerations, and shrinks what is left by (omega_path / omega_zero)^2, omega_zero the
#: frequency of the inverse's internal (zero) dynamics (about 230 rad/s for Table 1's L2 at
#: 0.5 mm): on a figure eight at 2 rad/s the changes of passes 1-4 were 6e-4, 1e-7, 1e-9 and
#: 2e-11 rad. The last change is returned, so a path too fast for the iteration is told.
INVERSE_PASSES = 4


def _lagrange_weights(ts: np.ndarray, g0: float, h: float, size: int):
    """(first index (n,), weights (n, 5)) of the quartic through the 5 grid points nearest each
    time of ts on the grid g0 + k h (k < size): exact (one-hot) at a grid point."""
    j0 = np.clip(np.rint((ts - g0) / h).astype(int) - 2, 0, size - 5)
    s = (ts - g0) / h - j0
    k = np.arange(5.0)
    w = np.ones((ts.shape[0], 5))
    for m in range(5):
        for j in range(5):
            if j != m:
                w[:, m] *= (s - k[j]) / (k[m] - k[j])
    return j0, w


def inverse_path(model: AbstractModel, robot: RobotLike, path: Callable, ts, wrench=None):
    """The model's inverse along a prescribed platform path at the times ts: the coordinates
    that make the platform follow `path`, and the actuator torques that do it.

    The pose X(t) and its rates are the path's. Every other coordinate (L2: the actuated angles;
    quasi-static L3: also the connecting links; the full L3: also the strips) follows from the
    rows of M z'' + h = Q in which no actuator torque appears: with the pose prescribed they
    are (n - 3) equations in the (n - 3) unknowns. Their rates and accelerations enter those
    rows: the internal (zero) dynamics of the inverse, oscillatory or unstable (for Table 1's
    L2, a pair growing at about 76 1/s: the inverse is non-minimum-phase), so they are not
    integrated. The bounded solution, the slow manifold, is found as the quasi-static start
    finds its own (`quasi_static_core`): balances on a uniform grid of step `QS_DT` over the
    times (two steps beyond either end; within them for a path with `kinks`, a clamped
    spline), up to `INVERSE_PASSES` passes, each at the previous pass's own rates and
    accelerations (5-point differences; the first pass at the L1 manifold's); the pass that
    changed least is returned (they diverge where the path's content reaches the zero
    dynamics' frequency: a cubic spline's knots).
    The torques are the actuated rows. Values at the times ts are the quartic through the five
    nearest grid points (exact where ts lies on the grid: a rate of 200 Hz / k from ts[0]).
    L0 and L1 (z = X) need none of this: their angles are their kinematics' and their torques
    `inverse_dynamics`.

    **Arguments:**

    - `model`: a model (L0-L3); `robot`: a `Robot` or `RobotParams`.
    - `path`: the pose path t -> X (3,) (m, m, rad), C2 (differentiated twice).
    - `ts`: the times (n,) (s), increasing host values (the grid is static).
    - `wrench`: (3,) a constant platform wrench (N, N, N m); None: none.

    **Returns:** (z (n, nd), zdot (n, nd), th_a (n, 3) (rad), tau (n, 3) (N m), change,
    change_t, failed (n,)): the states on the path, the actuated angles and torques (all of
    the pass that changed least), that pass's largest change of the unknowns from the pass
    before (rad; the iteration's own error estimate), the grid time where it was largest (s),
    and where the inverse failed (no balance, or the chains out of reach).
    """
    robot = as_robot(robot)
    w = jnp.zeros(3) if wrench is None else jnp.asarray(wrench, dtype=jnp.float64)
    ts = np.asarray(ts, dtype=np.float64).reshape(-1)
    n = model.n_dof

    def ref(s):
        return model.coords_from_pose(robot, path(s))

    if model.actuated_index is None:
        from ._dynamics import inverse_dynamics

        def one(t):
            X, Xd, Xdd = derivatives(path, t)
            tau, eom = inverse_dynamics(model, robot, X, Xd, Xdd, w)
            bad = ~(jnp.min(eom.kin.margin) > 0) | ~jnp.all(jnp.isfinite(tau))
            return X, Xd, eom.kin.th_a, tau, bad

        z, zd, th_a, tau, failed = jax.vmap(one)(jnp.asarray(ts))
        return z, zd, th_a, tau, jnp.zeros(()), jnp.asarray(ts[0]), failed
    act = tuple(model.actuated_index)
    rows = jnp.array(tuple(i for i in range(n) if i not in act))
    ia = jnp.array(act)
    # The grid reaches two steps beyond either end, unless the path's acceleration jumps (a
    # clamped spline at rest before its first and after its last sample, `Waypoints.kinks`):
    # differences across the jump made the balances there diverge ("no inverse at t = 0") or
    # 2 % off, so the grid then starts at ts[0] and ends within ts[-1] (the last times a
    # fraction of a step beyond its last point take the end quartic; a span under four steps,
    # a single time, gets the four steps after ts[0]), its end rows one-sided.
    span = (ts[-1] - ts[0]) / QS_DT
    pad = 2 if path_kinks(path) is None else 0
    size = (int(np.ceil(span - 1e-9)) + 5 if pad else max(int(np.floor(span + 1e-9)) + 1, 5))
    grid = jnp.asarray(ts[0] + QS_DT * (np.arange(size) - float(pad)))
    # 5-point differences on the grid: central inside, one-sided at the two ends of either side
    rows1 = np.zeros((size, size))
    rows2 = np.zeros((size, size))
    for i in range(size):
        j = min(max(i - 2, 0), size - 5)
        rows1[i, j:j + 5], rows2[i, j:j + 5] = D1[i - j], D2[i - j]
    G1, G2 = jnp.asarray(rows1 / QS_DT), jnp.asarray(rows2 / QS_DT**2)

    def solve_at(s, zu_guess, zud, zudd, own):
        z_r, zd_r, zdd_r = derivatives(ref, s)
        zd_b = jnp.where(own, zd_r.at[3:].set(zud), zd_r)
        zdd_b = jnp.where(own, zdd_r.at[3:].set(zudd), zdd_r)

        def full(zu):
            z = jnp.concatenate([z_r[:3], zu])
            eom = eom_terms(model, robot, z, zd_b)
            r = eom.M @ zdd_b + eom.h - generalized_force(eom, jnp.zeros(3), w)
            return r[rows], (r[ia], jnp.min(eom.kin.margin), eom.kin.th_a)

        guess = jnp.where(own, zu_guess, z_r[3:])
        zu, err, result, aux = _fd_newton_solve(full, guess)
        stalled = result == optx.RESULTS.nonlinear_max_steps_reached
        bad = ~(err < 1e-10) | ((result != optx.RESULTS.successful) & ~stalled)
        return zu, bad, aux, z_r, zd_r

    def one_pass(carry, own):
        zus_prev, zud, zudd = carry
        out = jax.vmap(solve_at, in_axes=(0, 0, 0, 0, None))(grid, zus_prev, zud, zudd, own)
        zus = out[0]
        change = jnp.max(jnp.abs(zus - zus_prev), axis=1)
        return (zus, G1 @ zus, G2 @ zus), (out, change)

    zero = jnp.zeros((size, n - 3))
    _, (outs, changes) = jax.lax.scan(
        one_pass, (zero, zero, zero), jnp.array([False] + [True] * (INVERSE_PASSES - 1)))
    # The pass that changed least, not the last: where the path's frequency content reaches
    # the zero dynamics' (a cubic spline's knots, whose jerk jumps), the passes diverge. On a
    # random 9-sample spline (Table 1's L2 at 0.5 mm) the changes were 1e-2 rad at the second
    # pass and NaN at the third, whose NaN the differences spread over the whole grid: the
    # inverse was refused at t = 0 ("no inverse") for a divergence at the knots. The first
    # pass (its change is from zero) is taken only where every later one is not finite.
    size_of = jnp.max(changes, axis=1)
    score = jnp.where(jnp.isfinite(size_of), size_of, jnp.inf).at[0].set(
        jnp.where(INVERSE_PASSES > 1, jnp.finfo(jnp.float64).max, 0.0))
    best = jnp.argmin(score)
    zus, bad, (tau, margin, th_a), z_r, zd_r = jax.tree.map(lambda a: a[best], outs)
    zud = G1 @ zus
    changes = changes[best]
    j0, wts = _lagrange_weights(ts, float(ts[0]) - pad * QS_DT, QS_DT, size)
    idx = jnp.asarray(j0[:, None] + np.arange(5))
    wts = jnp.asarray(wts)

    def at_ts(a):
        return jnp.einsum("nk,nk...->n...", wts, a[idx])

    z = jnp.concatenate([at_ts(z_r[:, :3]), at_ts(zus)], axis=1)
    zd = jnp.concatenate([at_ts(zd_r[:, :3]), at_ts(zud)], axis=1)
    # The torques of the last pass balance the accelerations of the pass before: they differ
    # by the last change's effect, below the returned error estimate's.
    bad_grid = bad | ~(margin > 0)
    failed = jnp.any(bad_grid[idx], axis=1)
    # where that pass changed most: at a spline's knots, where the path's jerk jumps and the
    # balances' accelerations (read by differencing them) see its fourth derivative
    return (z, zd, at_ts(th_a), at_ts(tau), jnp.max(changes), grid[jnp.argmax(changes)],
            failed)
