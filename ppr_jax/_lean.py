"""The default explicit solve in one loop: Tsit5 or Dopri8 under diffrax's I controller, saved in
blocks.

Every scene of L0-L2 integrates with Tsit5 (diffrax's), and the quasi-static L3 with Dopri8,
under diffrax's default adaptive controller (`PIDController` with only its integral term).
`diffeqsolve` runs that as a general loop: a Runge-Kutta step written for any tableau and any
state pytree (its stages in a loop with a buffer of increments), a controller that handles every
option, and saving that visits the output times one at a time in a loop of its own. At the sizes
of these models (6-12 states) that machinery is a third of a step's kernels, and the saving loop
alone several kernels per output time: an L1 `paper-circle` run (160 steps, 755 output times)
spent about a third of its time saving.

`lean_solve` is the same algorithm written for this one case on a flat state: diffrax's tableau,
its interpolant (`interpolation_cls`; Dopri8's evaluated without a dot, `Method.interpolate`)
and the controller's own `adapt_step_size`, the same first step and clipping of the last step to
the end (within 100 ulp); the stages written out on an (s, n) array of increments (s = 7 for
Tsit5, 14 for Dopri8: `Method`), and output times saved a block of `BLOCK` at a time, each block
one vectorised interpolation. Its solutions equal `diffeqsolve`'s to rounding (the sums are
taken in another order), with the same step counts; it is forward-differentiable (`jax.jvp`,
`jax.jacfwd`: the step sizes carry no derivative, as diffrax's controller stops them) and maps
under `vmap`.

Reverse mode (`lean_vjp`, through `_simulate._solve_recorded`) differentiates the steps this
loop accepted: recorded (`record=True`), the loop also keeps each accepted step's end (a
`max_steps + 1` grid) and the state at every `SEGMENT`-th accepted step (the `Tape`). The
backward pass takes the segments from the last: it replays one from its recorded state under
`jax.vjp` and transposes it. Each stage is rematerialised (`jax.checkpoint`), so a segment keeps
only its stages' increments, not every intermediate of every right-hand side: kept, their
stacking was most of the backward pass's kernels (L1 `paper-circle` gradient 24.5 ms, with the
stages rematerialised 12.3 ms). Before, reverse mode ran diffrax's `diffeqsolve` twice
(recording, then on the recorded grid under its checkpointed loop); its result is the same to
rounding (`tests/test_lean.py`), and a chosen number of checkpoints still runs it.

Dopri8 joined for the quasi-static L3, whose run was bound by kernel launches: its right-hand
side (the strips' solves, the generic equations of motion) is thousands of kernels a step, and
diffrax's loop of steps is not one that XLA compiles as one kernel (`_devices`). On the lean
loop, with no dot left in it, it is, for N up to 8 at the import's threshold
(`_devices.SMALL_LOOP_BYTES`): L3 `paper-circle` at N = 4 on the 2-core CPU 650 -> 180 ms.

The first step is 0.01 s, which is what diffrax 0.7 takes, not the Hairer estimate its
controller means to take: `PIDController.init` estimates a first step only for an `ODETerm`, and
`diffeqsolve` hands it the terms wrapped (`WrapTerm`), so it falls back to 0.01 for every solve
(found when this loop, with the estimate, took other steps than `diffeqsolve`).
`tests/test_lean.py` compares the two loops' steps and solutions, so a diffrax that changes this
shows there.

Steps clipped to given times (a `ClipStepSizeController` with `step_ts`: the knots of a
command log or a spline path, `_scenes._base.stepping_to`) are this case too: the loop clips as
diffrax's controller does (`_clip_to_steps`), with the same steps (`tests/test_lean.py`). Such
solves (an identification's runs, a `PathScene` on `Waypoints`, compensation's replays) ran on
`diffeqsolve` before.

`lean_applies` decides, in Python before tracing, whether a solve is this case; anything else
(another solver or controller, a controller with options, jumps, `throw`, a progress meter,
other saving) runs on `diffeqsolve` as before, and so does every member of a
vmapped batch (`AbstractModel.batch_member`, `_simulate._solve`): under `vmap` this loop
measured slower than diffrax's (L1 `paper-circle` x256: 530 against 652 trajectories/s; a block
of one output time 393, of four 509, of sixteen 484). On a CPU a batch of L0-L2 is not vmapped:
its members run this loop one after another (`_scenes/_batch.py`).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import diffrax
import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
import numpy as np

from ._custom_types import Array

#: the first step (s): what diffrax 0.7's controller takes (module docstring)
FIRST_STEP = 0.01
#: output times saved per block (one vectorised interpolation each; a step that passes more
#: output times takes several blocks)
BLOCK = 8
#: accepted steps a reverse-mode segment replays (`lean_vjp`): the forward pass keeps the state
#: at every SEGMENT-th step, and the backward pass holds one segment's residuals at a time
SEGMENT = 16

class Method(NamedTuple):
    """An explicit first-same-as-last Runge-Kutta method as the lean loop runs it, from
    diffrax's own solver class: `A` (s, s) stage weights (row i: the increments that stage i
    adds), `C` (s,) stage times, `B_SOL` and `B_ERR` (s,) the solution's and the error
    estimate's weights, `error_order` as `diffeqsolve` gives it to the controller, and the
    solver's interpolant (`interpolation_cls(t0=, t1=, y0=, y1=, k=)`)."""

    A: np.ndarray
    C: np.ndarray
    B_SOL: np.ndarray
    B_ERR: np.ndarray
    error_order: int
    interpolation_cls: type

    @property
    def stages(self) -> int:
        return self.C.shape[0]

    def interpolate(self, t0, t1, y0, y1, k, t):
        """The solver's dense output on the step (t0, t1) from y0 to y1 with increments k
        (s, n), at t: diffrax's interpolant. Dopri8's is evaluated here with the same
        coefficients as a sum of weighted rows (`_weighted`): diffrax's evaluates it as a
        product of (14,) coefficients with k, which under the saving block's `vmap` is a
        (BLOCK, 14) x (14, n) dot, and a dot of that size keeps XLA's CPU compiler from
        compiling the loop that holds it as one kernel (`_devices`)."""
        if self.interpolation_cls is not _DOPRI8_INTERPOLATION:
            return self.interpolation_cls(t0=t0, t1=t1, y0=y0, y1=y1, k=k).evaluate(t)
        # (t - t0) / (t1 - t0), 0 on a step of zero length (diffrax's `linear_rescale`)
        same = t0 == t1
        x = jnp.where(same, 0.0, t - t0) / jnp.where(same, 1.0, t1 - t0)
        coeffs = jnp.asarray(_DOPRI8_INTERPOLATION.eval_coeffs, dtype=x.dtype)
        w = jnp.polyval(coeffs.T, x) * x  # Horner's rule on every row at once: (14,)
        return y0 + _weighted([w[i] for i in range(w.shape[0])], k)


_DOPRI8_INTERPOLATION = diffrax.Dopri8.interpolation_cls


@functools.cache
def method_of(solver_cls: type) -> Method:
    """The `Method` of one of diffrax's explicit FSAL solver classes (`LEAN_SOLVERS`)."""
    tab = solver_cls.tableau
    s = len(tab.b_sol)
    A = np.zeros((s, s))
    for i, row in enumerate(tab.a_lower):
        A[i + 1, : i + 1] = row
    C = np.concatenate([[0.0], np.asarray(tab.c)])
    # the error order `diffeqsolve` hands the controller: the solver's own for an ODE
    order = solver_cls().error_order(diffrax.ODETerm(lambda t, y, args: y))
    return Method(A, C, np.asarray(tab.b_sol), np.asarray(tab.b_error), int(order),
                  solver_cls.interpolation_cls)


#: the solvers the lean loop runs: Tsit5 (L0-L2's default) and Dopri8 (the quasi-static L3's),
#: both explicit and first same as last (the last stage is f(t1, y1))
LEAN_SOLVERS = (diffrax.Tsit5, diffrax.Dopri8)
#: Tsit5's method: the default of `lean_solve` and `lean_vjp`
TSIT5 = method_of(diffrax.Tsit5)


def clipped(controller):
    """(the adaptive controller, step_ts (k,) or None): `controller` itself, or the one a
    `diffrax.ClipStepSizeController` wraps and its `step_ts`."""
    if type(controller) is diffrax.ClipStepSizeController:
        return controller.controller, controller.step_ts
    return controller, None


def lean_applies(solver, controller, dt0, throw, progress_meter, saveat) -> bool:
    """Whether a solve is the one `lean_solve` computes (module docstring): diffrax's `Tsit5`
    or `Dopri8` (`LEAN_SOLVERS`)
    under a `PIDController` with only its integral term (pcoeff 0, dcoeff 0: its state then
    does not enter the step size) and no dtmin or dtmax, itself or wrapped in a
    `ClipStepSizeController` with `step_ts` only (no `jump_ts`, no stored rejections); the
    first step chosen by the controller (dt0 None); no `throw`, no progress meter; output at
    given times only."""
    if type(controller) is diffrax.ClipStepSizeController and (
            controller.jump_ts is not None or controller.store_rejected_steps is not None
            or controller.callback_on_reject is not None):
        return False
    controller, _ = clipped(controller)
    if type(solver) not in LEAN_SOLVERS or type(controller) is not diffrax.PIDController:
        return False
    c = controller
    if not all(isinstance(x, (int, float)) and x == 0 for x in (c.pcoeff, c.dcoeff)):
        return False
    return (c.dtmin is None and c.dtmax is None and dt0 is None and not throw
            and isinstance(progress_meter, diffrax.NoProgressMeter) and saveat is None)


def _weighted(weights, k):
    """sum_i weights[i] k[i] over the nonzero weights (Python numbers or arrays broadcasting
    against k's rows); k (s, n)."""
    out = None
    for i, w in enumerate(weights):
        if isinstance(w, (int, float, np.floating)) and w == 0:
            continue
        term = w * k[i]
        out = term if out is None else out + term
    return out


def ulps_below(x: Array, n: int) -> Array:
    """x lowered by `n` ulp: `diffeqsolve`'s `n` steps of `eqxi.prevbefore` (its clipping
    threshold below t1) as one subtraction on the bits, not `n` unrolled steps of about 17
    operations each (1,705 of an L1 scene program's 8,435 compiled operations, one fused
    kernel that LLVM compiled on every first call). Equal to the steps for |x| >= 1e-290
    (`tests/test_lean.py`); below, where the steps pass through zero and the subnormals (which
    XLA's CPU code flushes), x - n times the smallest normal number."""
    idt = jnp.int64 if x.dtype == jnp.float64 else jnp.int32
    bits = jax.lax.bitcast_convert_type(x, idt)
    # sign and magnitude: a lower positive number has smaller bits, a lower negative one larger
    below = jax.lax.bitcast_convert_type(jnp.where(x > 0, bits - n, bits + n), x.dtype)
    return jnp.where(jnp.abs(x) >= 1e-290, below, x - n * jnp.finfo(x.dtype).tiny)


def _first_above(t, step_ts, i):
    """The index of the first of `step_ts` (k,) (sorted) above t, searched from i: diffrax's
    `_find_idx_with_hint` (k where none is)."""
    k = step_ts.shape[0]
    i = jax.lax.while_loop(lambda j: (j < k) & (step_ts[jnp.minimum(j, k - 1)] <= t),
                           lambda j: j + 1, i)
    return jax.lax.while_loop(lambda j: (j > 0) & (step_ts[jnp.maximum(j - 1, 0)] > t),
                              lambda j: j - 1, i)


def _at(step_ts, i):
    """step_ts[i], inf for i = k (diffrax's `_get_t`)."""
    k = step_ts.shape[0]
    return jnp.where(i >= k, jnp.inf, step_ts[jnp.minimum(i, k - 1)])


def _clip_to_steps(nt0, nt1, step_ts, i):
    """(next t1, index): `ClipStepSizeController`'s clipping of the step (nt0, nt1) to the
    first of `step_ts` after nt0 (after nt0 bumped past a step time it sits on or one ulp
    before: its `_bump_next_t0`), searched from the index i of the previous step. diffrax
    bumps by testing nt0 against every step time; here against the two about the first one
    above nt0, the only ones that can equal nt0 or the float after it."""
    up = eqxi.nextafter(nt0)
    above = _first_above(nt0, step_ts, i)
    on = (above > 0) & (_at(step_ts, above - 1) == nt0)
    bumped = jnp.where(on, up, jnp.where(_at(step_ts, above) == up, eqxi.nextafter(up), nt0))
    i = _first_above(bumped, step_ts, above)
    return jnp.minimum(_at(step_ts, i), nt1), i


def _adapt(tprev, tn, y, y1, err, controller, t1, floor, error_order, steps=None):
    """(keep, next t0, next t1, step index): the controller's own decision on the step
    (tprev, tn) from y to y1 with error estimate err (NaN read as inf, as `diffeqsolve` does)
    of the method's `error_order`, clipped to the step times where there are (`steps` =
    (step_ts, index of the first one above tprev); None: none; `_clip_to_steps`), then
    `diffeqsolve`'s clipping of a step that ends within 100 ulp (`floor`) of t1."""
    err = jnp.where(jnp.isnan(err), jnp.inf, err)
    # an I controller's state (its previous error ratios) does not enter its step size, so the
    # state `PIDController.init` returns serves every step
    state = (jnp.ones((), y.dtype), jnp.ones((), y.dtype), False)
    keep, nt0, nt1, _, _, _ = controller.adapt_step_size(tprev, tn, y, y1, None, err,
                                                          error_order, state)
    index = None
    if steps is not None:
        nt1, index = _clip_to_steps(nt0, nt1, *steps)
    nt0 = jnp.minimum(nt0, t1)
    nt1 = jnp.where(nt1 > floor, jnp.where(keep, t1, nt0 + 0.5 * (t1 - nt0)), nt1)
    return keep, nt0, nt1, index


def _stage_f(vf, tprev, h, y, k, i, method: Method):
    """Stage i's derivative vf(tprev + c_i h, y + sum_j a_ij k_j); i traced, k (s, n)."""
    yi = y + jnp.sum(jnp.asarray(method.A)[i][:, None] * k, axis=0)
    return vf(tprev + jnp.asarray(method.C)[i] * h, yi)


def _stages(vf, tprev, h, y, fy, method: Method, remat=False):
    """`method`'s step from (tprev, y) over h: (k (s, n) the stages' increments, y1 (n,), the
    last stage's derivative (n,)); fy is vf(tprev, y) (first same as last). A step of size 0
    evaluates vf(tprev, y) at every stage: its last derivative is fy's own value."""
    def stage(k, i):
        f = _stage_f(vf, tprev, h, y, k, i, method)
        return k.at[i].set(f * h), f

    if remat:
        stage = jax.checkpoint(stage, policy=jax.checkpoint_policies.nothing_saveable,
                               prevent_cse=False)
    s = method.stages
    k = jnp.zeros((s, y.shape[0]), y.dtype).at[0].set(fy * h)
    # the stages in a loop, as diffrax runs them: unrolled, XLA fuses the right-hand sides
    # of neighbouring stages into each other and compiles for longer
    k, fs = jax.lax.scan(stage, k, jnp.arange(1, s))
    return k, y + _weighted(method.B_SOL, k), fs[-1]


def _stages_from(vf, tprev, h, y, fy, first, method: Method):
    """`_stages`, where on the `first` step (a traced bool) the loop also computes fy =
    vf(tprev, y), its stage 0 (A's row 0 and c_0 are zero), instead of taking it: the solve
    then compiles its right-hand side once, in the loop, not a second time for the start
    (L1 `paper-circle`: 1,226 of the program's 8,435 compiled operations). Returns (k, y1,
    fy)."""
    def stage(i, c):
        k, f0 = c
        f = _stage_f(vf, tprev, h, y, k, i, method)
        return k.at[i].set(f * h), jnp.where(i == 0, f, f0)

    # on the first step fy is a placeholder of zeros: k[0] = 0 until stage 0 sets it, and
    # stage 0 reads y + 0
    s = method.stages
    k = jnp.zeros((s, y.shape[0]), y.dtype).at[0].set(fy * h)
    lo = jnp.where(first, 0, 1)
    k, f0 = jax.lax.fori_loop(lo, s, stage, (k, fy))
    return k, y + _weighted(method.B_SOL, k), jnp.where(first, f0, fy)


class Tape(NamedTuple):
    """What a recorded `lean_solve` leaves for `lean_vjp`: `grid` (max_steps + 1,) the
    accepted steps' ends after t0 (inf past the last), `tape` (max_steps // SEGMENT + 1, 2n)
    the state and its derivative (y, vf(t, y)) at the start of every SEGMENT-th accepted
    step, `accepted` their number."""

    grid: Array
    tape: Array
    accepted: Array


def lean_solve(vf, y0: Array, ts: Array, controller: diffrax.PIDController, max_steps: int,
               record: bool = False, method: Method = TSIT5):
    """Solve y' = vf(t, y) from (ts[0], y0) to ts[-1], saving at `ts` (module docstring).

    **Arguments:**

    - `vf`: (t, y (n,)) -> y' (n,).
    - `y0`: (n,) the initial state.
    - `ts`: (m,) output times, increasing, ts[0] the start.
    - `controller`: the `PIDController` that decides the steps, or a
      `ClipStepSizeController` that wraps one and clips its steps to its `step_ts`
      (`lean_applies`).
    - `max_steps`: the step budget (static).
    - `record`: also return the `Tape` that `lean_vjp` differentiates on (static).

    **Returns:** (ys (m, n), saved times (m,), result, stats) as `diffeqsolve`'s `Solution`
    gives them: rows not reached are inf, result `RESULTS.max_steps_reached` if the budget ran
    out, stats the counts of steps, accepted and rejected steps; with `record`, the `Tape`
    after them.
    """
    n, m = y0.shape[0], ts.shape[0]
    t0, t1 = ts[0], ts[-1]
    controller, step_ts = clipped(controller)
    floor = ulps_below(t1, 100)  # diffrax clips a step that ends within 100 ulp of t1
    tnext = t0 + FIRST_STEP
    clip = ()  # with step times, the index of the first one after the step's start
    if step_ts is not None:
        step_ts = jnp.asarray(step_ts, ts.dtype)
        index = jnp.searchsorted(step_ts, t0, side="right")
        tnext = jnp.minimum(_at(step_ts, index), tnext)
        clip = (index,)
    tnext = jnp.minimum(tnext, t1)
    padded = jnp.concatenate([ts, jnp.full((BLOCK,), jnp.inf, ts.dtype)])
    rows = jnp.arange(BLOCK)

    def step(state):
        tprev, tn, y, fy, steps, accepted, ys, saved = state[:8]
        h = tn - tprev
        first = steps == 0
        k, y1, fy = _stages_from(vf, tprev, h, y, fy, first, method)
        c = len(clip)
        keep, nt0, nt1, index = _adapt(
            tprev, tn, y, y1, _weighted(method.B_ERR, k), controller, t1, floor,
            method.error_order, (step_ts, state[8]) if c else None)


        def more(c):
            j, _ = c
            return keep & (padded[j] <= tn) & (j < m)

        def save(c):
            j, ys = c
            tt = jax.lax.dynamic_slice(padded, (j,), (BLOCK,))
            due = (tt <= tn) & (rows + j < m)
            # the solver's own interpolant on this step
            vals = jax.vmap(lambda t: method.interpolate(tprev, tn, y, y1, k, t))(
                jnp.where(due, tt, tprev))
            old = jax.lax.dynamic_slice(ys, (j, 0), (BLOCK, n))
            ys = jax.lax.dynamic_update_slice(ys, jnp.where(due[:, None], vals, old), (j, 0))
            return j + jnp.sum(due, dtype=j.dtype), ys

        saved, ys = jax.lax.while_loop(more, save, (saved, ys))
        y_next, f_next = jnp.where(keep, y1, y), jnp.where(keep, k[-1] / h, fy)
        new = accepted + keep.astype(accepted.dtype)
        out = (nt0, nt1, y_next, f_next, steps + 1, new, ys, saved) + ((index,) if c else ())
        if record:
            grid, tape = state[8 + c:]
            # an accepted step's end; every SEGMENT-th accepted step's state, and on the first
            # step the start's (its derivative comes from that step's loop), in one write
            grid = grid.at[new].set(jnp.where(keep, tn, grid[new]))
            row = jnp.where(first, jnp.concatenate([y, fy]), jnp.concatenate([y_next, f_next]))
            at = jnp.where(first, 0, new // SEGMENT)
            write = first | (keep & (new % SEGMENT == 0))
            tape = tape.at[at].set(jnp.where(write, row, tape[at]))
            out = out + (grid, tape)
        return out

    def going(state):
        return (state[0] < t1) & (state[4] < max_steps)

    zero = jnp.asarray(0)
    ys0 = jnp.full((m + BLOCK, n), jnp.inf, y0.dtype)
    # vf(t0, y0) comes from the first step's loop (`_stages_from`)
    init = (t0, tnext, y0, jnp.zeros_like(y0), zero, zero, ys0, zero) + clip
    if record:
        grid = jnp.full((max_steps + 1,), jnp.inf, ts.dtype).at[0].set(t0)
        tape = jnp.zeros((max_steps // SEGMENT + 1, 2 * n), y0.dtype)
        init = init + (grid, tape)
    out = jax.lax.while_loop(going, step, init)
    tprev, _, _, _, steps, accepted, ys, saved = out[:8]
    result = diffrax.RESULTS.where(tprev < t1, diffrax.RESULTS.max_steps_reached,
                                   diffrax.RESULTS.successful)
    times = jnp.where(jnp.arange(m) < saved, ts, jnp.inf)
    stats = {"num_steps": steps, "num_accepted_steps": accepted,
             "num_rejected_steps": steps - accepted, "max_steps": max_steps}
    if record:
        return ys[:m], times, result, stats, Tape(*out[8 + len(clip):], accepted)
    return ys[:m], times, result, stats


def lean_vjp(vf, d, y0: Array, ts: Array, tape: Tape, g_ys: Array, times: bool = True,
             method: Method = TSIT5):
    """Reverse mode of `lean_solve` on its own accepted steps: the cotangents of (d, y0, ts)
    given the cotangent `g_ys` (m, n) of its saved states (module docstring).

    The solve is differentiated as the sequence of steps the forward pass accepted (`tape`),
    each a function of the state and d; the step sizes are constants, as diffrax's
    controllers stop their gradient. Segments of SEGMENT steps are taken from the last to the
    first: each is replayed from its recorded start under `jax.vjp` (one `scan`, whose
    residuals are that segment's), and the saved states' cotangents enter through the
    interpolant of the step that saved them. The output times carry their derivative through
    the interpolant, and the first and last through the steps that start and end the solve
    there, as diffrax's solve on the recorded steps (`_simulate.RecordedGrid`) gives it.

    **Arguments:**

    - `vf`: (d, t, y (n,)) -> y' (n,); d a pytree whose floating arrays are differentiated.
    - `d`, `y0` (n,), `ts` (m,): what the forward pass solved with.
    - `tape`: the forward pass's `Tape` (`lean_solve(..., record=True)`).
    - `g_ys`: (m, n) the cotangent of the saved states (rows not reached are ignored).
    - `times`: whether to differentiate the output times (static; False: g_ts is None, and
      the right-hand sides' time derivatives are not transposed).

    **Returns:** (g_d, g_y0 (n,), g_ts (m,)); g_d as `eqx.filter_vjp` gives it (None where d
    has no floating array).
    """
    n, m = y0.shape[0], ts.shape[0]
    grid, accepted = tape.grid, tape.accepted
    # output j is saved by the first accepted step that ends at or after it
    owner = jnp.searchsorted(grid[1:], ts, side="left").astype(accepted.dtype)
    reached = owner < accepted
    g_ys = jnp.where(reached[:, None], g_ys, 0.0)
    pad_ts = jnp.concatenate([ts, jnp.full((BLOCK,), ts[0])])
    pad_g = jnp.concatenate([g_ys, jnp.zeros((BLOCK, n), g_ys.dtype)])
    pad_owner = jnp.concatenate([jnp.where(reached, owner, -1),
                                 jnp.full((BLOCK,), -1, owner.dtype)])
    # the step that ends the solve at ts[-1] (none if the budget ran out)
    last = jnp.where(grid[accepted] == ts[-1], accepted - 1, -1)
    lanes = jnp.arange(SEGMENT)
    rows = jnp.arange(BLOCK)
    ends = (ts[0], ts[-1])

    def segment(dd, y, fy, t0, t1, start, count, first):
        """The segment's `count` steps from accepted step `start`: its end (y, fy) and each
        step's start state and increments (SEGMENT, n), (SEGMENT, s, n). `first` (with count
        0, from the start): the step before the first, of size 0, whose end is (y0, vf(t0,
        y0)), the first step's derivative (`back`)."""
        def one(c, i):
            y, fy = c
            # a step past the segment's end is a step of zero size from a finite time: the
            # backward pass multiplies its (zero) cotangents by finite partials
            active = i < count
            zeroth = first & (i == 0)
            tprev = jnp.where(active | zeroth,
                              jnp.where(start + i == 0, t0, grid[start + i]), grid[start])
            tn = jnp.where(start + i == last, t1, grid[start + i + 1])
            h = jnp.where(active, tn - tprev, 0.0)
            k, y1, f = _stages(lambda t, yy: vf(dd, t, yy), tprev, h, y, fy, method,
                               remat=True)
            nxt = (jnp.where(active, y1, y),
                   jnp.where(active, k[-1] / jnp.where(active, h, 1.0),
                             jnp.where(zeroth, f, fy)))
            return nxt, (y, k)

        (y, fy), (ys, ks) = jax.lax.scan(one, (y, fy), lanes)
        return y, fy, ys, ks

    def outputs_cotangent(start, count, ys, ks, g_ts):
        """The saved rows of the segment's steps, through their interpolants: cotangents of
        (ys, ks) and of the output times."""
        lo = jnp.searchsorted(owner, start, side="left").astype(start.dtype)
        hi = jnp.searchsorted(owner, start + count, side="left").astype(start.dtype)

        def interp(y, k, tprev, tn, t):
            return method.interpolate(tprev, tn, y, y, k, t)

        def more(c):
            return c[0] < hi

        def block(c):
            j, g_y, g_k, g_ts = c
            due = rows + j < hi
            local = jnp.where(due, jax.lax.dynamic_slice(pad_owner, (j,), (BLOCK,)) - start, 0)
            tprev = jnp.where(start + local == 0, ts[0], grid[start + local])
            tn = jnp.where(start + local == last, ts[-1], grid[start + local + 1])
            t = jnp.where(due, jax.lax.dynamic_slice(pad_ts, (j,), (BLOCK,)), tprev)
            g = jnp.where(due[:, None], jax.lax.dynamic_slice(pad_g, (j, 0), (BLOCK, n)), 0.0)
            _, pull = jax.vjp(jax.vmap(interp), ys[local], ks[local], tprev, tn, t)
            gy, gk, g0, g1, gt = pull(g)
            g_y = g_y.at[local].add(jnp.where(due[:, None], gy, 0.0))
            g_k = g_k.at[local].add(jnp.where(due[:, None, None], gk, 0.0))
            old = jax.lax.dynamic_slice(g_ts, (j,), (BLOCK,))
            g_ts = jax.lax.dynamic_update_slice(g_ts, old + jnp.where(due, gt, 0.0), (j,))
            # the first step starts at ts[0], the last ends at ts[-1]: their interpolants move
            g_ts = g_ts.at[0].add(jnp.sum(jnp.where(due & (start + local == 0), g0, 0.0)))
            g_ts = g_ts.at[m - 1].add(jnp.sum(jnp.where(due & (start + local == last), g1,
                                                        0.0)))
            return j + BLOCK, g_y, g_k, g_ts

        _, g_y, g_k, g_ts = jax.lax.while_loop(
            more, block, (lo, jnp.zeros_like(ys), jnp.zeros_like(ks), g_ts))
        return g_y, g_k, g_ts

    def back(c):
        # segments from the last to the first, then (s = 0) the step of size 0 before the
        # first, whose end is the first step's derivative vf(t0, y0): that derivative is
        # transposed by the loop's own copy of the right-hand side, not by one more copy
        # after the loop (getting_started's gradient: 4 s of its 21 s of XLA compilation)
        s, g_y, g_fy, g_d, g_ts = c
        s = s - 1
        seg = jnp.maximum(s - 1, 0)
        first = s == 0
        start = seg * SEGMENT
        count = jnp.where(first, 0, jnp.minimum(SEGMENT, accepted - start))
        y, fy = tape.tape[seg, :n], tape.tape[seg, n:]
        # the ends of the solve are differentiated only with the times (else constants)
        (_, _, ys, ks), pull = eqx.filter_vjp(
            lambda dd, yy, ff, *t: segment(dd, yy, ff, *(t or ends), start, count, first),
            d, y, fy, *(ends if times else ()))
        gys, gks, g_ts = outputs_cotangent(start, count, ys, ks, g_ts)
        dd, gy, gf, *gt = pull((g_y, g_fy, gys, gks))
        if times:
            g_ts = g_ts.at[0].add(gt[0]).at[m - 1].add(gt[1])
        return s, gy, gf, _add(g_d, dd), g_ts

    zero_d = jax.tree_util.tree_map(jnp.zeros_like, eqx.filter(d, eqx.is_inexact_array))
    n_seg = (accepted + SEGMENT - 1) // SEGMENT
    g_ts = jnp.zeros((m + BLOCK,), ts.dtype)
    init = (n_seg + 1, jnp.zeros_like(y0), jnp.zeros_like(y0), zero_d, g_ts)
    _, g_y, _, g_d, g_ts = jax.lax.while_loop(lambda c: c[0] > 0, back, init)
    return g_d, g_y, (g_ts[:m] if times else None)


def _add(a, b):
    return jax.tree_util.tree_map(lambda x, y: x + y, a, b)
