"""The default explicit solve in one loop: Tsit5 under diffrax's I controller, saved in blocks.

Every scene of L0-L2 integrates with Tsit5 (diffrax's) under diffrax's default adaptive
controller (`PIDController` with only its integral term). `diffeqsolve` runs that as a general
loop: a Runge-Kutta step written for any tableau and any state pytree (its stages in a loop with
a buffer of increments), a controller that handles every option, and saving that visits the
output times one at a time in a loop of its own. At the sizes of these models (6-12 states)
that machinery is a third of a step's kernels, and the saving loop alone several kernels per
output time: an L1 `paper-circle` run (160 steps, 755 output times) spent about a third of its
time saving.

`lean_solve` is the same algorithm written for this one case on a flat state: diffrax's
tableau, its interpolant (`Tsit5.interpolation_cls`) and the controller's own
`adapt_step_size`, the same first step and clipping of the last step to the end (within 100
ulp); the stages written out on a (7, n) array of increments, and output times saved a block
of `BLOCK` at a time, each block one vectorised interpolation.
Its solutions equal `diffeqsolve`'s to rounding (the sums are taken in another order), with
the same step counts; it is forward-differentiable (`jax.jvp`, `jax.jacfwd`: the step sizes
carry no derivative, as diffrax's controller stops them) and maps under `vmap`. Reverse mode
keeps diffrax's solve (`_simulate._solve_recorded`), whose forward pass records the steps, so
a gradient follows the steps of diffrax's own solution.

The first step is 0.01 s, which is what diffrax 0.7 takes, not the Hairer estimate its
controller means to take: `PIDController.init` estimates a first step only for an `ODETerm`,
and `diffeqsolve` hands it the terms wrapped (`WrapTerm`), so it falls back to 0.01 for every
solve (found when this loop, with the estimate, took other steps than `diffeqsolve`).
`tests/test_lean.py` compares the two loops' steps and solutions, so a diffrax that changes
this shows there.

`lean_applies` decides, in Python before tracing, whether a solve is this case; anything else
(another solver or controller, a controller with options, steps clipped to given times, `throw`,
a progress meter, other saving) runs on `diffeqsolve` as before, and so does every member of a
mapped batch (`AbstractModel.batch_member`, `_simulate._solve`): under `vmap` this loop
measured slower than diffrax's (L1 `paper-circle` x256: 530 against 652 trajectories/s; a
block of one output time 393, of four 509, of sixteen 484).
"""

from __future__ import annotations

import diffrax
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
import numpy as np
from diffrax._solver.tsit5 import _tsit5_tableau as _TABLEAU

from ._custom_types import Array

#: the first step (s): what diffrax 0.7's controller takes (module docstring)
FIRST_STEP = 0.01
#: the order of Tsit5's error estimate, as `diffeqsolve` gives it to the controller
ERROR_ORDER = 5
#: output times saved per block (one vectorised interpolation each; a step that passes more
#: output times takes several blocks)
BLOCK = 8

# The tableau as (7, 7) stage weights (row i: the increments that stage i adds), the stage
# times and the 5th-order weights and the error weights, from diffrax's own Tsit5.
_A = np.zeros((7, 7))
for _i, _row in enumerate(_TABLEAU.a_lower):
    _A[_i + 1, : _i + 1] = _row
_C = np.concatenate([[0.0], np.asarray(_TABLEAU.c)])
_B_SOL = np.asarray(_TABLEAU.b_sol)
_B_ERR = np.asarray(_TABLEAU.b_error)


def lean_applies(solver, controller, dt0, throw, progress_meter, saveat) -> bool:
    """Whether a solve is the one `lean_solve` computes (module docstring): diffrax's `Tsit5`
    under a `PIDController` with only its integral term (pcoeff 0, dcoeff 0: its state then
    does not enter the step size) and no dtmin or dtmax; the first step chosen by the
    controller (dt0 None); no `throw`, no progress meter; output at given times only."""
    if type(solver) is not diffrax.Tsit5 or type(controller) is not diffrax.PIDController:
        return False
    c = controller
    if not all(isinstance(x, (int, float)) and x == 0 for x in (c.pcoeff, c.dcoeff)):
        return False
    return (c.dtmin is None and c.dtmax is None and dt0 is None and not throw
            and isinstance(progress_meter, diffrax.NoProgressMeter) and saveat is None)


def _weighted(weights, k):
    """sum_i weights[i] k[i] over the nonzero weights (Python numbers or arrays broadcasting
    against k's rows); k (7, n)."""
    out = None
    for i, w in enumerate(weights):
        if isinstance(w, (int, float, np.floating)) and w == 0:
            continue
        term = w * k[i]
        out = term if out is None else out + term
    return out


def _adapt(tprev, tn, y, y1, err, controller, t1, floor):
    """(keep, next t0, next t1): the controller's own decision on the step (tprev, tn) from y to
    y1 with error estimate err (NaN read as inf, as `diffeqsolve` does), then `diffeqsolve`'s
    clipping of a step that ends within 100 ulp (`floor`) of t1."""
    err = jnp.where(jnp.isnan(err), jnp.inf, err)
    # an I controller's state (its previous error ratios) does not enter its step size, so the
    # state `PIDController.init` returns serves every step
    state = (jnp.ones((), y.dtype), jnp.ones((), y.dtype), False)
    keep, nt0, nt1, _, _, _ = controller.adapt_step_size(tprev, tn, y, y1, None, err,
                                                          ERROR_ORDER, state)
    nt0 = jnp.minimum(nt0, t1)
    nt1 = jnp.where(nt1 > floor, jnp.where(keep, t1, nt0 + 0.5 * (t1 - nt0)), nt1)
    return keep, nt0, nt1


def lean_solve(vf, y0: Array, ts: Array, controller: diffrax.PIDController, max_steps: int):
    """Solve y' = vf(t, y) from (ts[0], y0) to ts[-1], saving at `ts` (module docstring).

    **Arguments:**

    - `vf`: (t, y (n,)) -> y' (n,).
    - `y0`: (n,) the initial state.
    - `ts`: (m,) output times, increasing, ts[0] the start.
    - `controller`: the `PIDController` that decides the steps (`lean_applies`).
    - `max_steps`: the step budget (static).

    **Returns:** (ys (m, n), saved times (m,), result, stats) as `diffeqsolve`'s `Solution`
    gives them: rows not reached are inf, result `RESULTS.max_steps_reached` if the budget ran
    out, stats the counts of steps, accepted and rejected steps.
    """
    n, m = y0.shape[0], ts.shape[0]
    t0, t1 = ts[0], ts[-1]
    floor = t1
    for _ in range(100):  # diffrax clips a step that ends within 100 ulp of t1
        floor = eqxi.prevbefore(floor)
    f0 = vf(t0, y0)
    tnext = jnp.minimum(t0 + FIRST_STEP, t1)
    padded = jnp.concatenate([ts, jnp.full((BLOCK,), jnp.inf, ts.dtype)])
    rows = jnp.arange(BLOCK)
    A, C = jnp.asarray(_A), jnp.asarray(_C)

    def step(state):
        tprev, tn, y, fy, steps, accepted, ys, saved = state
        h = tn - tprev

        def stage(k, i):
            yi = y + jnp.sum(A[i][:, None] * k, axis=0)
            return k.at[i].set(vf(tprev + C[i] * h, yi) * h), None

        k = jnp.zeros((7, n), y.dtype).at[0].set(fy * h)
        # the stages in a loop, as diffrax runs them: unrolled, XLA fuses the right-hand sides
        # of neighbouring stages into each other and compiles for longer
        k, _ = jax.lax.scan(stage, k, jnp.arange(1, 7))
        y1 = y + _weighted(_B_SOL, k)
        keep, nt0, nt1 = _adapt(tprev, tn, y, y1, _weighted(_B_ERR, k), controller, t1, floor)

        # diffrax's own Tsit5 interpolant on this step
        dense = diffrax.Tsit5.interpolation_cls(t0=tprev, t1=tn, y0=y, y1=y1, k=k)

        def more(c):
            j, _ = c
            return keep & (padded[j] <= tn) & (j < m)

        def save(c):
            j, ys = c
            tt = jax.lax.dynamic_slice(padded, (j,), (BLOCK,))
            due = (tt <= tn) & (rows + j < m)
            vals = jax.vmap(dense.evaluate)(jnp.where(due, tt, tprev))
            old = jax.lax.dynamic_slice(ys, (j, 0), (BLOCK, n))
            ys = jax.lax.dynamic_update_slice(ys, jnp.where(due[:, None], vals, old), (j, 0))
            return j + jnp.sum(due, dtype=j.dtype), ys

        saved, ys = jax.lax.while_loop(more, save, (saved, ys))
        return (nt0, nt1, jnp.where(keep, y1, y), jnp.where(keep, k[6] / h, fy), steps + 1,
                accepted + keep.astype(accepted.dtype), ys, saved)

    def going(state):
        return (state[0] < t1) & (state[4] < max_steps)

    zero = jnp.asarray(0)
    ys0 = jnp.full((m + BLOCK, n), jnp.inf, y0.dtype)
    out = jax.lax.while_loop(going, step, (t0, tnext, y0, f0, zero, zero, ys0, zero))
    tprev, _, _, _, steps, accepted, ys, saved = out
    result = diffrax.RESULTS.where(tprev < t1, diffrax.RESULTS.max_steps_reached,
                                   diffrax.RESULTS.successful)
    times = jnp.where(jnp.arange(m) < saved, ts, jnp.inf)
    stats = {"num_steps": steps, "num_accepted_steps": accepted,
             "num_rejected_steps": steps - accepted, "max_steps": max_steps}
    return ys[:m], times, result, stats
