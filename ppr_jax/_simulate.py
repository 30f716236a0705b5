"""Forward simulation with diffrax (MODEL.md sections 5 and 6).

`simulate` integrates a model under an actuation from (z0, z0') and returns a `Solution` at the
requested output times, with solver statistics and the diffrax result code. It is jit-compiled once
per (model, actuation type, solver, shapes) and vmappable over parameter batches; a failure (max
steps, step size collapse, a chain leaving its reach) is raised as `SimulationError`, naming the
failed batch members when the call is batched.
"""

from __future__ import annotations

from typing import NamedTuple, Optional

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from ._actuation import AbstractActuation
from ._custom_types import Array, Float, as_f64
from ._dynamics import eom_terms, generalized_force, torque_driven_accelerations
from ._errors import (
    RESULTS,
    PPRError,
    check_array,
    check_number,
    check_result,
    first_failure,
    is_traced,
)
from ._esdirk import KeptKvaerno5
from ._lean import Tape, lean_applies, lean_solve, lean_vjp, method_of
from ._linalg import solve_spd
from ._models import AbstractModel
from ._params import params_invalid
from ._robot import RobotLike, as_robot
from ._rosw import Ros34PW2

#: Most iterations of an implicit stage's nonlinear solve (diffrax's `root_find_max_steps`).
CHORD_MAX_STEPS = 10


class StageChord(diffrax.VeryChord):
    """diffrax's `VeryChord` (Newton on the stage equations with the Jacobian evaluated once per
    step), with the convergence test it was meant to have, measured where the step's error is.

    Two things made half of Kvaerno5's steps fail on L2 `servo-circle` (every rejected step was
    a failed stage solve, none was rejected by the error estimate):

    1. diffrax 0.7.2's `VeryChord.terminate` (optimistix 0.1.0's Newton/Chord share the code)
       reports `nonlinear_divergence` as soon as the second iterate has not met the tolerance,
       however fast the iteration contracts, and optimistix stops at the first non-successful
       result: every stage got two iterations whatever `root_find_max_steps` said (optimistix
       issue 221, fixed upstream in optimistix PR 230 and diffrax PR 754, after the versions
       this project pins). Here the iteration goes on while it is not diverging.
    2. diffrax measures the corrections of the stage's unknown, the stage derivative
       f_i = (z', z''), against atol + rtol |f_i|. L2's accelerations are small differences of
       large elastic forces (modes at 100-350 Hz), so an acceleration converged to rtol of
       itself asks for positions converged far below the step's own error tolerance: the first
       correction was 1e5-1e7 such tolerances long and two iterations never got below kappa.
       Here a correction is measured by what it changes in the stage's state
       y_i = y_partial + a_ii dt f_i, against atol + rtol |y_i|: the norm the step-size
       controller applies to the step's error (Hairer and Wanner, Solving ODEs II, IV.8).

    Termination: converged when the predicted remaining correction, rate / (1 - rate) times the
    last one, is below kappa, or the correction is at rounding level; diverged when the rate is
    not finite or above 2 (diffrax's threshold: the first two corrections can be dominated by
    different components, positions then velocities, so their ratio is a poor rate), or, from
    the third iterate, when even at the current rate the iterations left up to `max_steps`
    cannot get below kappa. A stage that diverges or reaches the limit makes diffrax return an
    infinite error estimate, so the step is rejected and retried shorter, never accepted."""

    max_steps: int = eqx.field(static=True, default=CHORD_MAX_STEPS)

    def step(self, fn, y, args, options, state, tags):
        new_y, new_state, aux = super().step(fn, y, args, options, state, tags)
        size = _stage_state_size(self, new_state.diff, new_y, args)
        if size is not None:
            new_state = eqx.tree_at(lambda s: s.diffsize, new_state, size)
        return new_y, new_state, aux

    def terminate(self, fn, y, args, options, state, tags):
        del fn, y, args, options, tags
        at_least_two = state.step >= 2
        rate = state.diffsize / state.diffsize_prev
        small = state.diffsize < 10.0 ** (2 - jnp.finfo(state.diffsize.dtype).precision)
        contracting = jnp.isfinite(rate) & (rate < 1)
        safe = jnp.where(contracting, rate, 0.5)
        converged = contracting & (state.diffsize * safe / (1 - safe) < self.kappa)
        # Hairer-Wanner's early exit, from the third iterate: even contracting at this rate,
        # the iterations left would not bring the correction below kappa.
        left = jnp.maximum(self.max_steps - state.step, 0)
        hopeless = (state.step >= 3) & contracting & (
            state.diffsize * safe**left / (1 - safe) > self.kappa
        )
        diverged = ~jnp.isfinite(rate) | (rate > 2) | hopeless
        done = at_least_two & (small | converged | diverged)
        failed = at_least_two & ~small & ~converged & diverged
        result = optx.RESULTS.where(
            failed, optx.RESULTS.nonlinear_divergence, optx.RESULTS.successful
        )
        linsolve_fail = state.result != optx.RESULTS.successful
        result = optx.RESULTS.where(linsolve_fail, state.result, result)
        return linsolve_fail | done, result


def _stage_state_size(rf, diff, new, args):
    """The size of a stage iteration's correction measured where the step's error is measured:
    as the change it makes to the stage's state y_i = y_partial + a_ii dt f_i (f-space) or
    y_partial + a_ii k_i (k-space), in units of atol + rtol |y_i| (diffrax's argument layouts of
    `_implicit_relation_f` / `_implicit_relation_k`; None for any other caller)."""
    if not (isinstance(args, tuple) and len(args) in (7, 8)):
        return None
    if len(args) == 8:
        _, diag, _, prod, _, y_partial, _, control = args
        dy = prod(diff, control)
        y_i = jax.tree_util.tree_map(lambda a, b: a + diag * b, y_partial, prod(new, control))
    else:
        _, diag, _, _, y_partial, _, control = args
        dy = diff
        y_i = jax.tree_util.tree_map(lambda a, b: a + diag * b, y_partial, new)
    if jax.tree_util.tree_structure(dy) != jax.tree_util.tree_structure(y_i):
        return None
    scaled = jax.tree_util.tree_map(
        lambda d, yy: diag * d / (rf.atol + rf.rtol * jnp.abs(yy)), dy, y_i
    )
    return rf.norm(scaled)


def stage_root_finder(**kwargs) -> StageChord:
    """The implicit solvers' root finder: `StageChord` at the step-size controller's
    tolerances (diffrax fills them in), `kwargs` (kappa, max_steps) passed on."""
    return diffrax.with_stepsize_controller_tols(StageChord)(**kwargs)


def _implicit(cls):
    def make():
        return cls(root_finder=stage_root_finder(), root_find_max_steps=CHORD_MAX_STEPS)

    return make


#: the solvers by name (the names, in this order, are `_names.SOLVER_NAMES`: the CLI's choices)
SOLVERS = {
    "tsit5": diffrax.Tsit5,
    "dopri5": diffrax.Dopri5,
    "dopri8": diffrax.Dopri8,
    "kvaerno5": _implicit(diffrax.Kvaerno5),
    "kvaerno3": _implicit(diffrax.Kvaerno3),
    "kvaerno5-kept": KeptKvaerno5,
    "ros34pw2": Ros34PW2,
}


#: PI coefficients of the step-size controller for the implicit solvers. With diffrax's default
#: (an I controller: pcoeff 0, icoeff 1) Kvaerno5 on L2 `servo-circle` grew its step until the
#: error estimate was just above tolerance and was then rejected, one step in four or five (every
#: rejected error ratio between 1.0 and 1.6; t = 2 mm, rtol 1e-6: 225 steps, 54 rejected). A PI
#: controller smooths the growth: measured on t = 2 and 4 mm at rtol 1e-4 and 1e-6, (0.3, 0.3)
#: rejected 0-5 % in 40-318 steps, (0.4, 0.3) 0-8 % in 40-324, (0.2, 0.4) 0-5 % in 33-278.
IMPLICIT_PI = {"pcoeff": 0.2, "icoeff": 0.4}


def default_controller(solver, rtol, atol) -> diffrax.PIDController:
    """The adaptive step-size controller at (rtol, atol) (arrays: changing them does not
    recompile): diffrax's I controller for explicit solvers, the PI controller `IMPLICIT_PI`
    for implicit ones (and the linearly implicit `Ros34PW2`)."""
    kw = IMPLICIT_PI if is_stiff_solver(solver) else {}
    return diffrax.PIDController(rtol=as_f64(rtol), atol=as_f64(atol), **kw)


def is_stiff_solver(solver) -> bool:
    """Whether `solver` is one for stiff problems: diffrax's implicit Runge-Kutta methods,
    `KeptKvaerno5` or the Rosenbrock-W `Ros34PW2`."""
    return isinstance(solver, (diffrax.AbstractImplicitSolver, Ros34PW2))


def get_solver(solver) -> diffrax.AbstractSolver:
    """A diffrax solver from a name (tsit5, dopri5, dopri8, kvaerno3, kvaerno5, kvaerno5-kept,
    ros34pw2) or an instance.
    The implicit ones by name solve their stages with `StageChord`; an instance whose root
    finder is diffrax's own `VeryChord` gets `StageChord` with the same kappa and linear solver
    (see `StageChord` for why); any other instance is used as given."""
    if isinstance(solver, diffrax.AbstractSolver):
        rf = getattr(solver, "root_finder", None)
        if type(rf) is diffrax.VeryChord:
            new = stage_root_finder(kappa=rf.kappa, linear_solver=rf.linear_solver,
                                    max_steps=int(solver.root_find_max_steps))
            new = eqx.tree_at(lambda f: (f.rtol, f.atol, f.norm), new,
                              (rf.rtol, rf.atol, rf.norm))
            solver = eqx.tree_at(lambda s: s.root_finder, solver, new)
        return solver
    try:
        return SOLVERS[str(solver).lower()]()
    except KeyError:
        raise PPRError(f"unknown solver {solver!r}; allowed: {', '.join(SOLVERS)}") from None


class Solution(eqx.Module):
    """Result of `simulate`. ts (m,), z and zdot (m, n) the model's coordinates and velocities,
    tau (m, 3) actuator torques (applied, or the reaction torques when motion-driven) (N m),
    result a `ppr_jax.RESULTS` code (diffrax's, or invalid parameters), num_steps / num_accepted /
    num_rejected solver statistics."""

    ts: Array
    z: Array
    zdot: Array
    tau: Array
    result: RESULTS
    num_steps: Array
    num_accepted: Array
    num_rejected: Array


def split_coordinates(model: AbstractModel, actuation: AbstractActuation):
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


def _runs(idx):
    """[(start, stop)] of the runs of consecutive integers in `idx` (static)."""
    out = []
    for i in idx:
        if out and out[-1][1] == i:
            out[-1][1] = i + 1
        else:
            out.append([i, i + 1])
    return [tuple(r) for r in out]


def _take(x, idx, axis: int = 0):
    """`x` at the static indices `idx` along `axis`, as slices of its runs of consecutive
    indices. Indexing with an index array is a gather, which XLA's CPU compiler runs as a
    kernel of its own wherever it is not the identity (and its transpose, in reverse mode, as a
    scatter): L2 `servo-circle` over 1 s (motion-driven, 428 steps) launched 140,751 kernels
    with the gathers and scatters of its free and prescribed coordinates, 125,320 with
    slices."""
    idx = tuple(int(i) for i in idx)
    if idx == tuple(range(x.shape[axis])) or not idx:
        return jax.lax.slice_in_dim(x, 0, len(idx), axis=axis)
    parts = [jax.lax.slice_in_dim(x, a, b, axis=axis) for a, b in _runs(idx)]
    return parts[0] if len(parts) == 1 else jnp.concatenate(parts, axis=axis)


def _interleave(parts):
    """The vector whose entries at the static indices `idx` are `v`, for each (idx, v) of
    `parts` (the indices together a permutation of range(n)): `.at[idx].set(v)` as slices
    and one concatenation instead of scatters."""
    where = {}
    for k, (idx, _) in enumerate(parts):
        for j, i in enumerate(idx):
            where[int(i)] = (k, j)
    pieces, i, n = [], 0, len(where)
    while i < n:
        k, j = where[i]
        m = 1
        while i + m < n and where[i + m] == (k, j + m):
            m += 1
        pieces.append(parts[k][1][j : j + m])
        i += m
    return pieces[0] if len(pieces) == 1 else jnp.concatenate(pieces)


def _full_state(model, actuation, t, zf, zfd):
    free, pres = split_coordinates(model, actuation)
    if not pres:
        return zf, zfd, None
    tha, thad, thadd = actuation.angles_at(t)
    z = _interleave([(free, zf), (pres, tha)])
    zd = _interleave([(free, zfd), (pres, thad)])
    return z, zd, thadd


def accelerations(model, robot, actuation, wrench, t, zf, zfd):
    """(z, z', z'', tau) at time t from the free state."""
    free, pres = split_coordinates(model, actuation)
    z, zd, thadd = _full_state(model, actuation, t, zf, zfd)
    if not pres:
        zdd, tau = torque_driven_accelerations(model, robot, actuation, wrench, t, z, zd)
        return z, zd, zdd, tau
    eom = eom_terms(model, robot, z, zd)
    rhs = generalized_force(eom, jnp.zeros(3), wrench) - eom.h
    Mf = _take(eom.M, free)
    zdd_f = solve_spd(_take(Mf, free, axis=1), _take(rhs, free) - _take(Mf, pres, axis=1) @ thadd)
    zdd = _interleave([(free, zdd_f), (pres, thadd)])
    # The actuated coordinates are th_a themselves, so their rows give the reaction torques.
    tau = _take(eom.M @ zdd - rhs, pres)
    return z, zd, zdd, tau


def _outputs(model, robot, actuation, wrench, t, zf, zfd):
    """(z, z', tau) at an output time: torque-driven, tau is the actuation's own (kinematics
    and its rate only: no mass matrix, which at every output time would cost as much as a
    fifth of the integration); motion-driven, the reaction torques need the dynamics."""
    free, pres = split_coordinates(model, actuation)
    if pres:
        z, zd, _, tau = accelerations(model, robot, actuation, wrench, t, zf, zfd)
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
    free, _ = split_coordinates(model, actuation)
    _, _, zdd, _ = accelerations(model, robot, actuation, wrench, t, *y)
    dy = (y[1], _take(zdd, free))
    if skip is not None:
        # A member already known to have failed (for example an open chain at t = 0) is
        # frozen, so it finishes in a few steps instead of running a batch to max_steps.
        dy = jax.tree_util.tree_map(lambda a: jnp.where(skip, 0.0, a), dy)
    return dy


class RecordedGrid(diffrax.AbstractStepSizeController):
    """Steps to the times an adaptive solve accepted (`ts`: t0, then each accepted step's end;
    entries past the last step repeat t1 and are never reached). Every step is accepted.

    Reverse mode differentiates the adaptive solve on this grid, which gives diffrax's own
    adaptive gradient (its controllers stop the gradient of the step sizes) without deciding
    the steps again: see `simulate_core`."""

    ts: Float[Array, " k"]

    def wrap(self, direction):
        return self

    def init(self, terms, t0, t1, y0, dt0, args, func, error_order):
        del terms, t0, t1, y0, dt0, args, func, error_order
        return self.ts[1], jnp.asarray(2)

    def adapt_step_size(self, t0, t1, y0, y1_candidate, args, y_error, error_order,
                        controller_state):
        del t0, y0, y1_candidate, args, y_error, error_order
        return (True, t1, self.ts[controller_state], False, controller_state + 1,
                diffrax.RESULTS.successful)


def _flat_field(model, skip):
    """(d = (robot, actuation, wrench), t, y) -> y' on the flat free state y = (z_f, z_f')."""
    def field(d, t, y):
        robot, actuation, wrench = d
        nf = len(split_coordinates(model, actuation)[0])
        dz, dzd = _vector_field(model, robot, actuation, wrench, skip, t, (y[:nf], y[nf:]))
        return jnp.concatenate([dz, dzd])
    return field


def _lean_reverse(model, solver, controller, dt0, throw, progress_meter, adjoint) -> bool:
    """Whether reverse mode runs on the lean loop (`_lean.lean_vjp`): a solve the lean loop
    computes, outside a mapped batch, under diffrax's default checkpointing (a chosen number
    of checkpoints is diffrax's `RecursiveCheckpointAdjoint`'s)."""
    del throw  # the lean loop raises after its loop (`_solve`)
    return (not model.batch_member and adjoint.checkpoints is None
            and lean_applies(solver, controller, dt0, False, progress_meter, None))


def _solve(diff, model, solver, stepsize_controller, dt0, max_steps, throw, progress_meter,
           adjoint, skip, saveat=None, record=False):
    """diffrax's solve of the free state y = (z_f, z_f') from `diff` = (robot, actuation,
    wrench, y0, ts): what reverse mode differentiates; the lean loop's where it applies (with
    `record`, its `Tape` after the solution)."""
    robot, actuation, wrench, y0, ts = diff
    field = _flat_field(model, skip)

    def vf(t, y, args):
        return field((robot, actuation, wrench), t, y)

    # `throw` (what `simulate` asks under a transformation, `jax.grad` among them): the lean
    # loop runs all the same, and its result raises after it, as diffrax's `throw` does after
    # its own loop. diffrax's loop and its checkpointed reverse pass took 107 s to trace and
    # compile for getting_started's gradient (1 s of L1), the lean loop's 30 s; warm 9 -> 4 ms.
    if not model.batch_member and lean_applies(solver, stepsize_controller, dt0, False,
                                               progress_meter, saveat):
        out = lean_solve(lambda t, y: vf(t, y, None), y0, ts, stepsize_controller, max_steps,
                         record=record, method=method_of(type(solver)))
        if throw:
            # on the states and on the tape, which reverse mode's backward pass reads (jax.grad
            # keeps no primal output, so a check on the states alone would be dropped)
            result = out[2]
            checked = result.error_if((out[0],) + out[4:], result != diffrax.RESULTS.successful)
            out = (checked[0], *out[1:4], *checked[1:])
        return (_LeanSolution(*out[:4]), out[4]) if record else _LeanSolution(*out)
    return diffrax.diffeqsolve(
        diffrax.ODETerm(vf), solver, ts[0], ts[-1], dt0, y0,
        saveat=diffrax.SaveAt(ts=ts) if saveat is None else saveat,
        stepsize_controller=stepsize_controller, max_steps=max_steps, throw=throw,
        progress_meter=progress_meter, adjoint=adjoint,
    )


class _LeanSolution(NamedTuple):
    # what `_solve_out` reads of diffrax's `Solution`
    ys: Array
    ts: Array
    result: RESULTS
    stats: dict


def _solve_out(sol):
    return sol.ys, sol.ts, sol.result, sol.stats


def _nothing(t, y, args):
    return jnp.zeros((0,), y.dtype)


@eqx.filter_custom_vjp
def _solve_recorded(diff, *rest):
    return _solve_out(_solve(diff, *rest))


@_solve_recorded.def_fwd
def _solve_recorded_fwd(perturbed, diff, *rest):
    del perturbed
    ts = diff[4]
    model, solver, controller, dt0, _, throw, meter, adjoint, _ = rest
    if _lean_reverse(model, solver, controller, dt0, throw, meter, adjoint):
        sol, tape = _solve(diff, *rest, record=True)
        return _solve_out(sol), tape
    # the grid as one more output of the same adaptive solve: the accepted steps' ends, which
    # diffrax keeps as that output's times; its values are empty (a copy of the times there
    # would be a second max_steps-long buffer written every step)
    saveat = diffrax.SaveAt(subs=[diffrax.SubSaveAt(ts=ts),
                                  diffrax.SubSaveAt(steps=True, fn=_nothing)])
    sol = _solve(diff, *rest, saveat=saveat)
    ends = sol.ts[1]
    grid = jnp.concatenate([ts[:1], jnp.where(jnp.isfinite(ends), ends, ts[-1])])
    out = (sol.ys[0], sol.ts[0], sol.result, sol.stats)
    return out, grid


@_solve_recorded.def_bwd
def _solve_recorded_bwd(grid, g_out, perturbed, diff, model, solver, stepsize_controller, dt0,
                        max_steps, throw, progress_meter, adjoint, skip):
    # the saved times' cotangent is dropped: they are the requested ts (or inf where the
    # solve stopped short), and simulate_core takes their derivative from ts itself
    g_ys = g_out[0]
    if g_ys is None:
        g_ys = jnp.zeros((diff[4].shape[0], diff[3].shape[0]), diff[3].dtype)
    # the forward rule's choice, carried by its residual: the lean loop's `Tape` or a grid
    if isinstance(grid, Tape):
        y0, ts = diff[3], diff[4]
        # only what is differentiated: a robot's arrays that no parameter moves, and the
        # output times (their derivative transposes every right-hand side's in t), are left out
        dyn, const = eqx.partition(diff[:3], perturbed[:3])
        field = _flat_field(model, skip)
        g_d, g_y0, g_ts = lean_vjp(lambda d, t, y: field(eqx.combine(d, const), t, y), dyn, y0,
                                   ts, grid, g_ys, times=bool(perturbed[4]),
                                   method=method_of(type(solver)))
        return (*g_d, g_y0, g_ts)
    del perturbed, stepsize_controller, dt0, throw, progress_meter

    def ys(d):
        return _solve(d, model, solver, RecordedGrid(grid), None, max_steps, False,
                      diffrax.NoProgressMeter(), adjoint, skip).ys

    _, vjp = eqx.filter_vjp(ys, diff)
    (g_diff,) = vjp(g_ys)
    return g_diff


def _on_recorded_grid(adjoint, controller) -> bool:
    """Whether reverse mode differentiates on the recorded steps: diffrax's
    `RecursiveCheckpointAdjoint` with an adaptive controller that makes no jumps (after a
    `jump_ts` time a first-same-as-last solver evaluates the vector field again, which a grid
    of step ends does not say)."""
    return (isinstance(adjoint, diffrax.RecursiveCheckpointAdjoint)
            and isinstance(controller, diffrax.AbstractAdaptiveStepSizeController)
            and getattr(controller, "jump_ts", None) is None)


@eqx.filter_jit
def simulate_core(
    model, robot, actuation, z0, zdot0, ts, solver, stepsize_controller, dt0, max_steps, wrench,
    throw, progress_meter, adjoint=None, skip=None,
):
    """The compiled solve behind `simulate` and the scenes.

    Reverse mode (diffrax's `RecursiveCheckpointAdjoint`, the default) with an adaptive
    controller: the forward pass records the accepted steps' times, and the backward pass
    differentiates the solve on that grid (`RecordedGrid`). diffrax's own backward pass
    instead recomputes steps from its checkpoints and decides each again; a recomputed error
    estimate that rounds differently from the forward pass's (at tight tolerances it is a
    difference of nearly equal numbers, close to rounding) can reject a step the forward pass
    kept, and the gradient then follows another step sequence than the solution: an L2
    gradient at rtol 1e-12 came out 1.06 % off central differences under one set of XLA
    flags and right under others. On the recorded grid nothing is decided again, and the
    gradient is diffrax's adaptive one (its controllers stop the step sizes' gradient). The
    cost is one more forward pass in reverse mode and a `max_steps`-long grid per solve;
    forward mode and undifferentiated runs are unchanged. Where the lean loop runs the solve
    and no number of checkpoints is chosen (`_lean_reverse`), both passes are its own: it
    records its steps and a state every `SEGMENT` steps, and `_lean.lean_vjp` replays and
    transposes them a segment at a time."""
    robot = as_robot(robot)
    free, _ = split_coordinates(model, actuation)
    # The state as one flat array (z_f, z_f'): a Runge-Kutta stage's combination of
    # increments, the error norm and the saved rows are then one array operation each, not
    # one per leaf of a pytree.
    y0 = jnp.concatenate([_take(z0, free), _take(zdot0, free)])
    if skip is not None:
        # A member known to have failed is frozen (`_vector_field`), but a start that is not
        # finite (what a failed quasi-static start may hold) makes every step's error estimate
        # NaN: the step is rejected until max_steps (seen on L2 under XLA's -O0 code).
        y0 = jnp.where(skip & ~jnp.isfinite(y0), 0.0, y0)
    adjoint = diffrax.RecursiveCheckpointAdjoint() if adjoint is None else adjoint
    diff = (robot, actuation, wrench, y0, ts)
    rest = (model, solver, stepsize_controller, dt0, max_steps, throw, progress_meter, adjoint,
            skip)
    if _on_recorded_grid(adjoint, stepsize_controller):
        ys, saved, result, stats = _solve_recorded(diff, *rest)
        # diffrax's saved times: ts, inf where the solve stopped short
        saved = jnp.where(jnp.isfinite(saved), ts, saved)
    else:
        ys, saved, result, stats = _solve_out(_solve(diff, *rest))
    nf = len(free)
    z, zd, tau = jax.vmap(
        lambda t, a, b: _outputs(model, robot, actuation, wrench, t, a, b)
    )(saved, ys[:, :nf], ys[:, nf:])
    # A status code, not a host callback: invalid (traced) parameters name themselves.
    result = first_failure((params_invalid(robot.params), RESULTS.invalid_parameter), result)
    return Solution(
        ts=saved, z=z, zdot=zd, tau=tau, result=result,
        num_steps=stats["num_steps"], num_accepted=stats["num_accepted_steps"],
        num_rejected=stats["num_rejected_steps"],
    )


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
    """Integrate `model` under `actuation` from (z0, z0') and save at times `ts`.

    **Arguments:**

    - `model`: a model (L0-L3); `robot`: a `Robot` or `RobotParams`.
    - `actuation`: an `AbstractActuation` (`TorqueDriven`, `MotionDriven`, `PDServo`). For a
      motion-driven model the prescribed coordinates of z0 are ignored (they follow it).
    - `z0`, `zdot0`: (n,) the initial coordinates and rates.
    - `ts`: (m,) strictly increasing output times (s), m >= 2; ts[0] the start.
    - `solver`: a name (tsit5, dopri5, dopri8, kvaerno3, kvaerno5, kvaerno5-kept, ros34pw2) or a
      diffrax solver.
    - `rtol`, `atol`: the adaptive steps' tolerances (a PID controller, `default_controller`:
      PI for the implicit solvers), each in [0, 1e-2], not both 0.
    - `dt0`: the first step (s), or the constant step with a constant `stepsize_controller`;
      None: chosen by diffrax.
    - `max_steps`: the step budget, in [1, 1e9].
    - `wrench`: (3,) a constant platform wrench (N, N, N m); None: none.
    - `stepsize_controller`: a diffrax controller instead of the default one.
    - `progress`: print diffrax's text progress meter.
    - `adjoint`: how to differentiate: diffrax's default (reverse mode, recursive
      checkpointing; with an adaptive controller on the forward pass's recorded steps, see
      `simulate_core`) or `diffrax.ForwardMode()` for `jax.jvp` / `jax.jacfwd`.

    **Returns:** a `Solution` (ts, z, zdot, tau (m, 3) applied or reaction torques, result,
    step counts).

    **Raises:** `PPRError` for bad arguments; `SimulationError` on a failed solve (under a JAX
    transformation, grad or a caller's vmap, diffrax raises inside the trace).
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
    if not is_traced(ts) and not bool(np.all(np.diff(np.asarray(ts)) > 0)):
        raise PPRError("ts must be strictly increasing")
    max_steps = check_number("max_steps", max_steps, 1, 10**9, integer=True)
    solver = get_solver(solver)
    if stepsize_controller is None:
        # Finite, not negative, at most the scenes' 1e-2 (above it the result is not worth a
        # number); tiny values stay allowed here (a pure relative or absolute control).
        if not is_traced(rtol):
            rtol = check_number("rtol", rtol, 0.0, 1e-2)
        if not is_traced(atol):
            atol = check_number("atol", atol, 0.0, 1e-2)
        if not is_traced((rtol, atol)) and rtol == 0 and atol == 0:
            raise PPRError("rtol and atol are both 0: the step-size control needs one of them > 0")
        stepsize_controller = default_controller(solver, rtol, atol)
    w = jnp.zeros(3) if wrench is None else check_array("wrench", wrench, (3,))
    traced = is_traced((robot, actuation, z0, zdot0, ts, w))
    meter = diffrax.TextProgressMeter() if progress else diffrax.NoProgressMeter()
    sol = simulate_core(
        model, robot, actuation, z0, zdot0, ts, solver, stepsize_controller, dt0,
        max_steps, w, traced, meter, adjoint,
    )
    if not traced:
        check_result(sol.result, stiff=is_stiff_solver(solver))
    return sol
