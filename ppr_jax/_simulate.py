"""Forward simulation with diffrax (MODEL.md sections 5 and 6).

`simulate` integrates a model under an actuation from (z0, z0') and returns a `Solution` at the
requested output times, with solver statistics and the diffrax result code. It is jit-compiled once
per (model, actuation type, solver, shapes) and vmappable over parameter batches; a failure (max
steps, step size collapse, a chain leaving its reach) is raised as `SimulationError`, naming the
failed batch members when the call is batched.
"""

from __future__ import annotations

from typing import Optional

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._actuation import AbstractActuation
from ._checks import PPRError, RESULTS, check_array, check_number, check_result, first_failure
from ._custom_types import Array, Float
from ._dynamics import eom_terms, generalized_force
from ._linalg import solve_spd
from ._models import AbstractModel
from ._params import params_invalid
from ._robot import RobotLike, as_robot

SOLVERS = {
    "tsit5": diffrax.Tsit5,
    "dopri5": diffrax.Dopri5,
    "dopri8": diffrax.Dopri8,
    "kvaerno5": diffrax.Kvaerno5,
    "kvaerno3": diffrax.Kvaerno3,
}


def get_solver(solver) -> diffrax.AbstractSolver:
    """A diffrax solver from a name (tsit5, dopri5, dopri8, kvaerno3, kvaerno5) or an instance."""
    if isinstance(solver, diffrax.AbstractSolver):
        return solver
    try:
        return SOLVERS[str(solver).lower()]()
    except KeyError:
        raise PPRError(f"unknown solver {solver!r}; allowed: {', '.join(SOLVERS)}") from None


class Solution(eqx.Module):
    """Result of `simulate`. ts (m,), z and zdot (m, n) the model's coordinates and velocities,
    tau (m, 3) actuator torques (applied, or the reaction torques when motion-driven) (N m),
    result a `ppr_jax.RESULTS` code (diffrax's, or invalid parameters), num_steps / num_accepted / num_rejected solver statistics."""

    ts: Array
    z: Array
    zdot: Array
    tau: Array
    result: RESULTS
    num_steps: Array
    num_accepted: Array
    num_rejected: Array


def _split(model: AbstractModel, actuation: AbstractActuation):
    """(free, prescribed) coordinate indices under `actuation` (static)."""
    if not isinstance(actuation, AbstractActuation):
        raise TypeError(
            f"actuation must be a ppr_jax actuation (TorqueDriven, MotionDriven, PDServo or a "
            f"subclass of AbstractActuation), got {type(actuation).__name__}"
        )
    n = model.n_dof
    if not actuation.prescribes_angles:
        return tuple(range(n)), ()
    if model.actuated_index is None:
        raise PPRError(
            f"model {model.name!r} has no free degree of freedom when motion-driven: its pose "
            f"follows from the actuated angles by forward kinematics (use "
            f"ppr_jax.forward_kinematics_path); no ODE is needed"
        )
    p = tuple(model.actuated_index)
    return tuple(i for i in range(n) if i not in p), p


def _full_state(model, actuation, t, zf, zfd):
    free, pres = _split(model, actuation)
    if not pres:
        return zf, zfd, None
    tha, thad, thadd = actuation.angles_at(t)
    n = model.n_dof
    z = jnp.zeros(n).at[jnp.array(free)].set(zf).at[jnp.array(pres)].set(tha)
    zd = jnp.zeros(n).at[jnp.array(free)].set(zfd).at[jnp.array(pres)].set(thad)
    return z, zd, thadd


def _accel(model, robot, actuation, wrench, t, zf, zfd):
    """(z, z', z'', tau) at time t from the free state."""
    free, pres = _split(model, actuation)
    z, zd, thadd = _full_state(model, actuation, t, zf, zfd)
    eom = eom_terms(model, robot, z, zd)
    if not pres:
        tau = actuation.torque_at(t, eom.kin.th_a, eom.Jth @ zd)
        zdd = solve_spd(eom.M, generalized_force(eom, tau, wrench) - eom.h)
        return z, zd, zdd, tau
    f, p = jnp.array(free), jnp.array(pres)
    rhs = generalized_force(eom, jnp.zeros(3), wrench) - eom.h
    Mff = eom.M[f][:, f]
    zdd_f = solve_spd(Mff, rhs[f] - eom.M[f][:, p] @ thadd)
    zdd = jnp.zeros(model.n_dof).at[f].set(zdd_f).at[p].set(thadd)
    # The actuated coordinates are th_a themselves, so their rows give the reaction torques.
    tau = (eom.M @ zdd - rhs)[p]
    return z, zd, zdd, tau


def _outputs(model, robot, actuation, wrench, t, zf, zfd):
    """(z, z', tau) at an output time: torque-driven, tau is the actuation's own (kinematics
    and its rate only: no mass matrix, which at every output time would cost as much as a
    fifth of the integration); motion-driven, the reaction torques need the dynamics."""
    free, pres = _split(model, actuation)
    if pres:
        z, zd, _, tau = _accel(model, robot, actuation, wrench, t, zf, zfd)
        return z, zd, tau
    k, kd = jax.jvp(lambda z: model.kinematics(robot, z), (zf,), (zfd,))
    return zf, zfd, actuation.torque_at(t, k.th_a, kd.th_a)


@eqx.filter_jit
def _vector_field(model, robot, actuation, wrench, skip, t, y):
    """(z_f', z_f'') of the free state y = (z_f, z_f'). A jitted function of its own, although
    it is only ever called inside other traces: the solver's loop traces it several times (its
    stages, and reverse mode's forward, residual and backward passes), and one cached jaxpr
    means JAX linearises and transposes it once instead of once per trace (the L1 gradient of
    `paper-circle` traced in 16 s before, mostly re-linearising this function)."""
    free, _ = _split(model, actuation)
    _, _, zdd, _ = _accel(model, robot, actuation, wrench, t, *y)
    dy = (y[1], zdd[jnp.array(free)])
    if skip is not None:
        # A member already known to have failed (for example an open chain at t = 0) is
        # frozen, so it finishes in a few steps instead of running a batch to max_steps.
        dy = jax.tree_util.tree_map(lambda a: jnp.where(skip, 0.0, a), dy)
    return dy


@eqx.filter_jit
def _simulate_core(
    model, robot, actuation, z0, zdot0, ts, solver, stepsize_controller, dt0, max_steps, wrench,
    throw, progress_meter, adjoint=None, skip=None,
):
    robot = as_robot(robot)
    free, _ = _split(model, actuation)
    f = jnp.array(free)
    y0 = (z0[f], zdot0[f])

    def vf(t, y, args):
        return _vector_field(model, robot, actuation, wrench, skip, t, y)

    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(vf), solver, ts[0], ts[-1], dt0, y0,
        saveat=diffrax.SaveAt(ts=ts), stepsize_controller=stepsize_controller,
        max_steps=max_steps, throw=throw, progress_meter=progress_meter,
        adjoint=diffrax.RecursiveCheckpointAdjoint() if adjoint is None else adjoint,
    )
    z, zd, tau = jax.vmap(
        lambda t, a, b: _outputs(model, robot, actuation, wrench, t, a, b)
    )(sol.ts, *sol.ys)
    # A status code, not a host callback: invalid (traced) parameters name themselves.
    result = first_failure((params_invalid(robot.params), RESULTS.invalid_parameter),
                           sol.result)
    return Solution(
        ts=sol.ts, z=z, zdot=zd, tau=tau, result=result,
        num_steps=sol.stats["num_steps"], num_accepted=sol.stats["num_accepted_steps"],
        num_rejected=sol.stats["num_rejected_steps"],
    )


def _is_traced(tree) -> bool:
    return any(isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves(tree))


def simulate(
    model: AbstractModel,
    robot: RobotLike,
    actuation,
    z0: Float[Array, " n"],
    zdot0: Float[Array, " n"],
    ts: Float[Array, " m"],
    *,
    solver="tsit5",
    rtol: float = 1e-8,
    atol: float = 1e-10,
    dt0: Optional[float] = None,
    max_steps: int = 200_000,
    wrench: Optional[Float[Array, "3"]] = None,
    stepsize_controller: Optional[diffrax.AbstractStepSizeController] = None,
    progress: bool = False,
    adjoint: Optional[diffrax.AbstractAdjoint] = None,
) -> Solution:
    """Integrate `model` under `actuation` from (z0, z0') and save at times `ts` (increasing).

    `solver`: a name (tsit5, dopri5, dopri8, kvaerno3, kvaerno5) or a diffrax solver; adaptive
    steps with a PID controller at (rtol, atol) unless `stepsize_controller` is given (then `dt0`
    is the constant step). For a motion-driven model the prescribed coordinates of z0 are ignored
    (they follow the actuation). On failure raises `SimulationError`; called under a JAX
    transformation (grad, vmap of the caller) the failure is raised by diffrax inside the trace.
    `adjoint`: how to differentiate: diffrax's default (reverse mode, recursive checkpointing) or
    `diffrax.ForwardMode()` for `jax.jvp` / `jax.jacfwd`.
    """
    robot = as_robot(robot)
    ts = check_array("ts", ts)
    z0 = check_array("z0", z0)
    zdot0 = check_array("zdot0", zdot0)
    if z0.shape != (model.n_dof,) or zdot0.shape != (model.n_dof,):
        raise PPRError(
            f"z0 and zdot0 must have shape ({model.n_dof},) for model {model.name!r}; got "
            f"{z0.shape} and {zdot0.shape}"
        )
    if ts.ndim != 1 or ts.shape[0] < 2:
        raise PPRError("ts must be a 1-D array of at least two increasing output times")
    if not _is_traced(ts) and not bool(np.all(np.diff(np.asarray(ts)) > 0)):
        raise PPRError("ts must be strictly increasing")
    max_steps = check_number("max_steps", max_steps, 1, 10**9, integer=True)
    if stepsize_controller is None:
        # Finite, not negative, at most the scenes' 1e-2 (above it the result is not worth a
        # number); tiny values stay allowed here (a pure relative or absolute control).
        if not _is_traced(rtol):
            rtol = check_number("rtol", rtol, 0.0, 1e-2)
        if not _is_traced(atol):
            atol = check_number("atol", atol, 0.0, 1e-2)
        if not _is_traced((rtol, atol)) and rtol == 0 and atol == 0:
            raise PPRError("rtol and atol are both 0: the step-size control needs one of them > 0")
        # Array tolerances: changing them does not recompile.
        stepsize_controller = diffrax.PIDController(
            rtol=jnp.asarray(rtol, dtype=jnp.float64), atol=jnp.asarray(atol, dtype=jnp.float64)
        )
    w = jnp.zeros(3) if wrench is None else check_array("wrench", wrench, (3,))
    traced = _is_traced((robot, actuation, z0, zdot0, ts, w))
    meter = diffrax.TextProgressMeter() if progress else diffrax.NoProgressMeter()
    sol = _simulate_core(
        model, robot, actuation, z0, zdot0, ts, get_solver(solver), stepsize_controller, dt0,
        max_steps, w, traced, meter, adjoint,
    )
    if not traced:
        check_result(sol.result)
    return sol
