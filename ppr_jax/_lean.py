"""The default explicit solve in one loop: Tsit5 under diffrax's I controller, saved in blocks.

Every scene of L0-L2 integrates with Tsit5 (diffrax's) under diffrax's default adaptive
controller (`PIDController` with only its integral term). `diffeqsolve` runs that as a general
loop: a Runge-Kutta step written for any tableau and any state pytree (its stages in a loop with
a buffer of increments), a controller that handles every option, and saving that visits the
output times one at a time in a loop of its own. At the sizes of these models (6-12 states)
that machinery is a third of a step's kernels, and the saving loop alone several kernels per
output time: an L1 `paper-circle` run (160 steps, 755 output times) spent about a third of its
time saving.

`lean_solve` is the same algorithm written for this one case on a flat state: the same tableau
and its interpolant, the same error norm (`optimistix.rms_norm`), step-size rule (safety, factor
bounds, a rejected step's factor at most `safety`), first step, the same clipping of the last
step to the end (within 100 ulp), and
output times saved a block of `BLOCK` at a time, each block one vectorised interpolation.
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
import optimistix as optx
from diffrax._solver.tsit5 import _tsit5_tableau as _TABLEAU

from ._custom_types import Array

#: the first step (s): what diffrax 0.7's controller takes (module docstring)
FIRST_STEP = 0.01
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
    under a `PIDController` with only its integral term (pcoeff 0, icoeff 1, dcoeff 0), no
    dtmin or dtmax, the RMS norm and diffrax's error order; the first step chosen by the
    controller (dt0 None); no `throw`, no progress meter; output at given times only."""
    if type(solver) is not diffrax.Tsit5 or type(controller) is not diffrax.PIDController:
        return False
    c = controller
    coeffs = (c.pcoeff, c.icoeff, c.dcoeff)
    if not all(isinstance(x, (int, float)) for x in coeffs) or coeffs != (0, 1, 0):
        return False
    return (c.dtmin is None and c.dtmax is None and c.norm is optx.rms_norm
            and c.error_order is None
            and all(isinstance(x, (int, float)) for x in (c.factormin, c.factormax, c.safety))
            and dt0 is None and not throw
            and isinstance(progress_meter, diffrax.NoProgressMeter) and saveat is None)


def _rescale(t0, t, t1):
    """(t - t0) / (t1 - t0), 0 where t1 == t0 (diffrax's `linear_rescale`)."""
    same = t0 == t1
    return jnp.where(same, 0.0, (t - t0) / jnp.where(same, 1.0, t1 - t0))


def _interpolant(s):
    """Tsit5's dense-output weights (7, ...) at s in [0, 1] (diffrax's `_Tsit5Interpolation`)."""
    b1 = (-1.0530884977290216 * s * (s - 1.3299890189751412)
          * (s**2 - 1.4364028541716351 * s + 0.7139816917074209))
    b2 = 0.1017 * s**2 * (s**2 - 2.1966568338249754 * s + 1.2949852507374631)
    b3 = 2.490627285651252793 * s**2 * (s**2 - 2.38535645472061657 * s + 1.57803468208092486)
    b4 = -16.54810288924490272 * (s - 1.21712927295533244) * (s - 0.61620406037800089) * s**2
    b5 = 47.37952196281928122 * (s - 1.203071208372362603) * (s - 0.658047292653547382) * s**2
    b6 = -34.87065786149660974 * (s - 1.2) * (s - 0.666666666666666667) * s**2
    b7 = 2.5 * (s - 1) * (s - 0.6) * s**2
    return (b1, b2, b3, b4, b5, b6, b7)


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
    """(keep, next t0, next t1): diffrax's I controller on the step (tprev, tn) from y to y1
    with error estimate err, and `diffeqsolve`'s clipping of a step that ends within 100 ulp
    (`floor`) of t1."""
    c = controller
    err = jnp.where(jnp.isnan(err), jnp.inf, err)
    y1 = jnp.where(jnp.any(jnp.isnan(y1)), y, y1)
    scaled = optx.rms_norm(err / (c.atol + jnp.maximum(jnp.abs(y), jnp.abs(y1)) * c.rtol))
    keep = scaled < 1
    # the step size carries no derivative (diffrax's controller stops it the same way)
    factor = jnp.clip(c.safety * jax.lax.stop_gradient(1 / scaled) ** (1 / 5),
                      jnp.where(keep, 1.0, c.factormin), jnp.where(keep, c.factormax, c.safety))
    nt0 = jnp.where(keep, tn, tprev)
    nt1 = nt0 + (tn - tprev) * jax.lax.stop_gradient(factor)
    nt0 = jnp.minimum(nt0, t1)
    nt1 = jnp.where(nt1 > floor, jnp.where(keep, t1, nt0 + 0.5 * (t1 - nt0)), nt1)
    return keep, nt0, nt1


def lean_solve(vf, y0: Array, ts: Array, controller: diffrax.PIDController, max_steps: int):
    """Solve y' = vf(t, y) from (ts[0], y0) to ts[-1], saving at `ts` (module docstring).

    **Arguments:**

    - `vf`: (t, y (n,)) -> y' (n,).
    - `y0`: (n,) the initial state.
    - `ts`: (m,) output times, increasing, ts[0] the start.
    - `controller`: the `PIDController` whose rtol, atol, safety and factor bounds are used
      (`lean_applies`).
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

        def more(c):
            j, _ = c
            return keep & (padded[j] <= tn) & (j < m)

        def save(c):
            j, ys = c
            tt = jax.lax.dynamic_slice(padded, (j,), (BLOCK,))
            due = (tt <= tn) & (rows + j < m)
            w = _interpolant(_rescale(tprev, jnp.where(due, tt, tprev), tn))
            vals = y[None, :] + _weighted([wi[:, None] for wi in w], k[:, None, :])
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
