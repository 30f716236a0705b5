"""Kvaerno's ESDIRK 5(4) for diffrax with its Jacobian and iteration matrix kept across steps.

diffrax's `Kvaerno5` evaluates the Jacobian of the vector field afresh at every step. On the full
L3 (`Beam`, N = 16: 102 state components) a Jacobian is 102 forward-mode directions through the
equations of motion and costs as much as 22 right-hand sides, so over the whole paper-circle
most of Kvaerno5's run went to Jacobians. `KeptKvaerno5` solves the same stage equations with
the same tableau, but as Hairer and Wanner's implicit codes do (Solving ODEs II, IV.8, RADAU5):
the Jacobian is kept while the simplified Newton iteration converges fast with it, and only
the iteration matrix W = I - h gamma J is refactorised when the step changes (an LU of 102 x 102
costs a fraction of a right-hand side). The solution does not depend on how old J is, only the
number of Newton iterations does: each stage is converged to the step-size controller's
tolerance whatever matrix drives the iteration.
"""

from __future__ import annotations

from typing import ClassVar

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from ._rosw import check_jacobian_every, flat_field

_TAB = diffrax.Kvaerno5.tableau
_S = _TAB.num_stages  # 7: an explicit first stage, six implicit ones of diagonal gamma
_GAMMA = float(_TAB.a_diagonal[1])


def _rows(rows) -> np.ndarray:
    out = np.zeros((_S, _S))
    for i, row in enumerate(rows, start=1):
        out[i, : len(row)] = row
    return out


_A = _rows(_TAB.a_lower)  # (7, 7) strictly lower: stage i's explicit part
_P = _rows(_TAB.a_predictor)  # (7, 7): stage i's predictor of its own derivative
_C = np.concatenate([[0.0], _TAB.c])
_B_ERR = np.asarray(_TAB.b_error)
assert np.allclose(_TAB.b_sol, _A[-1, :-1].tolist() + [_GAMMA])  # stiffly accurate


class KeptKvaerno5(diffrax.AbstractImplicitSolver, diffrax.AbstractAdaptiveSolver):
    """Kvaerno's 5(4) ESDIRK method (the tableau of `diffrax.Kvaerno5`: A-L stable, stiffly
    accurate, 7 stages, order 5 with an embedded order 4) whose Jacobian is kept across steps.

    Each implicit stage solves y_i = s_i + h gamma f(t_i, y_i) by the simplified Newton
    iteration with W = I - h gamma J, factorised (LU) once per step. J is the forward-mode
    Jacobian of the vector field at the second stage's predicted state (where diffrax's
    Kvaerno5 takes it), recomputed only when the iteration asks for it: when J is
    `jacobian_every` steps old, when a stage contracted slower than `refresh_rate`, or, within
    the same step, when a stage failed with a kept J (the step is then retried once with a
    fresh one). A stage that fails with a fresh J rejects the step (an infinite error
    estimate: diffrax retries it shorter; never accepted).
    Convergence is measured as `StageChord` measures it (Hairer and Wanner IV.8): the predicted
    remaining correction of the stage's state, in units of atol + rtol |y_i| of the step-size
    controller's tolerances, below `kappa`; at most `root_find_max_steps` iterations a stage,
    and a stage whose rate shows it cannot get there in time stops early.

    The stage derivative is taken from the converged stage, f_i = (y_i - s_i) / (h gamma),
    not from another evaluation of f (Hairer and Wanner IV.8: it keeps the stiff components'
    error at the iteration's tolerance). The last stage is the step's end
    (stiffly accurate), so its derivative is the next step's first stage and, with the
    start's, gives the cubic Hermite dense output.

    Under `jax.vmap` the refresh decision is a per-member `where`, so every step computes a
    Jacobian (as diffrax's Kvaerno5 does): the savings are for unbatched runs.

    Derivatives: forward mode only (`jax.jvp` / `jax.jacfwd` with `diffrax.ForwardMode()`, as
    the library's sensitivities and identification use): the Newton loops are while loops of
    data-dependent length, which JAX differentiates forward but cannot transpose, and J is
    held constant (`stop_gradient`), so the derivative is that of the converged iteration.
    For reverse mode use `diffrax.Kvaerno5` (solver `"kvaerno5"`), whose stage solves are
    differentiated implicitly, or `Ros34PW2`.

    **Arguments:**

    - `root_finder`: carries the Newton tolerances `rtol`, `atol`, `norm` (filled in from
      the step-size controller, diffrax's `with_stepsize_controller_tols`) and `kappa`.
    - `root_find_max_steps`: most Newton iterations of a stage (static; default 10).
    - `jacobian_every`: most steps a Jacobian is kept (static, >= 1; default 50).
    - `refresh_rate`: contraction rate above which the Jacobian is recomputed at the next
      step (in (0, 1); default 0.9). Over the whole paper-circle (full L3, N = 16, rtol 1e-4)
      0.2 recomputed it at 70 % of the steps (the ratio of a stage's first two corrections is
      often above 0.2 where the iteration still converges in two or three) and ran 97 s in
      2,678 steps; 0.9 ran 72 s in 2,764.
    """

    root_finder: diffrax.VeryChord = diffrax.with_stepsize_controller_tols(diffrax.VeryChord)()
    root_find_max_steps: int = eqx.field(static=True, default=10)
    jacobian_every: int = eqx.field(static=True, default=50)
    refresh_rate: float = eqx.field(static=True, default=0.9)

    term_structure: ClassVar = diffrax.AbstractTerm
    interpolation_cls: ClassVar = diffrax.ThirdOrderHermitePolynomialInterpolation

    def __check_init__(self):
        check_jacobian_every(self.jacobian_every)
        if not (isinstance(self.root_find_max_steps, int) and self.root_find_max_steps >= 2):
            raise ValueError(f"root_find_max_steps must be an integer >= 2, got "
                             f"{self.root_find_max_steps!r}")
        if not 0.0 < float(self.refresh_rate) < 1.0:
            raise ValueError(f"refresh_rate must be in (0, 1), got {self.refresh_rate!r}")

    def order(self, terms):
        return 5

    def error_order(self, terms):
        return 5

    def init(self, terms, t0, t1, y0, args):
        y, _, f = flat_field(terms, y0, args)
        # age = jacobian_every: the first step computes its own Jacobian
        return f(t0, y), jnp.zeros((y.size, y.size), y.dtype), jnp.asarray(self.jacobian_every)

    def step(self, terms, t0, t1, y0, args, solver_state, made_jump):
        y, unravel, f = flat_field(terms, y0, args)
        f0, J, age = solver_state
        if made_jump is not False:
            f0 = jax.lax.cond(made_jump, lambda: f(t0, y), lambda: f0)
        h = t1 - t0
        hg = h * _GAMMA
        n = y.shape[0]
        rf = self.root_finder
        kmax = self.root_find_max_steps
        A, P, C = (jnp.asarray(m, y.dtype) for m in (_A, _P, _C))

        def start(i, F):
            s = y + h * (A[i] @ F)
            return s, s + hg * (P[i] @ F)

        def stages(lu):
            def cond(c):
                i, *_, failed = c
                return (i < _S) & ~failed

            def body(c):
                i, k, s, yi, F, prev, worst, failed = c
                g = yi - s - hg * f(t0 + C[i] * h, yi)
                dy = -jax.scipy.linalg.lu_solve(lu, g)
                yi = yi + dy
                size = rf.norm(dy / (rf.atol + rf.rtol * jnp.abs(yi)))
                rate = size / prev
                small = size < 10.0 ** (2 - jnp.finfo(y.dtype).precision)
                contracting = jnp.isfinite(rate) & (rate < 1)
                # At least two iterates, as in `StageChord`: the first has no rate of its own,
                # and a rate carried over from the last stage (Hairer-Wanner's eta_0) is a
                # poor guess when the kept Jacobian has aged.
                eta = jnp.where(contracting, rate / (1 - rate), 1.0)
                converged = small | ((k >= 1) & contracting & (eta * size < rf.kappa))
                # Diverging only above rate 2, as in `StageChord`: the first corrections can be
                # dominated by different components (positions, then velocities), so their
                # ratio is a poor rate; from the third iterate, a rate too slow to reach kappa
                # in the iterations left stops the stage early.
                left = kmax - 1 - k
                diverged = (k >= 1) & (~jnp.isfinite(rate) | (rate > 2))
                hopeless = (k >= 2) & contracting & (size * rate**left / (1 - rate) > rf.kappa)
                failed = ~converged & (diverged | hopeless | (left <= 0)
                                       | ~jnp.isfinite(size))
                worst = jnp.where(k >= 1, jnp.maximum(worst, rate), worst)
                F = jnp.where(converged, F.at[i].set((yi - s) / hg), F)
                s_n, y_n = start(jnp.minimum(i + 1, _S - 1), F)
                return (jnp.where(converged, i + 1, i), jnp.where(converged, 0, k + 1),
                        jnp.where(converged, s_n, s), jnp.where(converged, y_n, yi), F,
                        jnp.where(converged, jnp.inf, size), worst, failed)

            F = jnp.zeros((_S, n), y.dtype).at[0].set(f0)
            s1, y1g = start(1, F)
            init = (jnp.asarray(1), jnp.asarray(0), s1, y1g, F, jnp.asarray(jnp.inf, y.dtype),
                    jnp.asarray(0.0, y.dtype), jnp.asarray(False))
            out = jax.lax.while_loop(cond, body, init)
            _, _, _, _, F, _, worst, failed = out
            return F, worst, failed

        def jacobian():
            # At the second stage's predicted state (t0 + c_2 h, y0 + c_2 h f0), as diffrax's
            # Kvaerno5 does, not at (t0, y0): the stages lie at c = 0.44 to 1.23 of the step,
            # and at N = 16 a Jacobian taken at the step's start left the Newton iteration
            # contracting at 0.6-0.95 on stage 2 (c = 1.23) of 5 ms steps, where this one
            # converges.
            tj = t0 + C[1] * h
            return jax.jacfwd(lambda x: f(tj, x))(y + (C[1] * h) * f0)

        # Attempt 0 uses the kept J (or a fresh one when it is due); a stage that fails with a
        # kept J is retried once, in the same step, with a fresh one. (A rejected step's solver
        # state is discarded by diffrax, so the retry cannot wait for the next step.)
        def attempt(c):
            a, J, fresh, *_ = c
            need = jnp.where(a == 0, age >= self.jacobian_every, True)
            J = jax.lax.cond(need, jacobian, lambda: J)
            J = jax.lax.stop_gradient(J)
            lu = jax.scipy.linalg.lu_factor(jnp.eye(n, dtype=y.dtype) - hg * J)
            return (a + 1, J, fresh | need) + stages(lu)

        def again(c):
            a, _, fresh, _, _, failed = c
            return (a == 0) | (failed & ~fresh)

        F0 = jnp.zeros((_S, n), y.dtype)
        init = (jnp.asarray(0), J, jnp.asarray(False), F0, jnp.asarray(0.0, y.dtype),
                jnp.asarray(False))
        _, J, fresh, F, worst, failed = jax.lax.while_loop(again, attempt, init)
        y1 = y + h * (jnp.asarray(_A[-1], y.dtype) @ F) + hg * F[-1]
        err = h * (jnp.asarray(_B_ERR, y.dtype) @ F)
        # A failed stage rejects the step (an infinite error: diffrax retries it shorter);
        # a slowly contracting one asks for a fresh J at the next step.
        err = jnp.where(failed, jnp.inf, err)
        age = jnp.where(failed | (worst > self.refresh_rate), self.jacobian_every,
                        jnp.where(fresh, 1, age + 1))
        y1 = jnp.where(failed, y, y1)
        f1 = jnp.where(failed, f0, F[-1])
        dense_info = dict(y0=y0, y1=unravel(y1), k0=unravel(h * f0), k1=unravel(h * f1))
        # With an adaptive controller the infinite error rejects the step and this code is
        # dropped; with constant steps it stops the solve instead of keeping y0.
        result = diffrax.RESULTS.where(
            failed, diffrax.RESULTS.promote(optx.RESULTS.nonlinear_divergence),
            diffrax.RESULTS.successful)
        return unravel(y1), unravel(err), dense_info, (f1, J, age), result

    def func(self, terms, t0, y0, args):
        return terms.vf(t0, y0, args)
