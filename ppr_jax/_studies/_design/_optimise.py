"""The constrained optimiser: scipy's SLSQP or trust-constr fed the problem's JAX Jacobian, in
normalised variables u in [0, 1]^p, objective and constraints scaled to order one; and the
screening of several starts in one batched call.

SLSQP is the default by measurement (benchmarks/design.py, tier 1): it lands on the active
bounds exactly and reaches the closed form to 2e-12. trust-constr's interior point stays inside
them: with scipy's default initial barrier parameter (0.1) it ends 1.4e-6 below the closed
form, with 1e-4 (used here) 1.7e-7, its active bounds about 1e-6 of the box away, which the
KKT check (`_verify.ACTIVE_TOL`) does not count as active."""

from __future__ import annotations

import dataclasses
import time
from typing import Optional

import numpy as np
import scipy.optimize as so
from scipy.stats import qmc

from ..._errors import DesignError
from ._problem import Problem

#: a constraint counts as met where its scaled value c = (bound - metric)/|bound| (upper) or
#: (metric - bound)/|bound| (lower) is at least -FEAS_TOL
FEAS_TOL = 1e-8


@dataclasses.dataclass
class Scaled:
    """The problem as the optimiser sees it: minimise sign * metric_0 / f_scale subject to the
    scaled constraints c(u) >= 0 (`FEAS_TOL`), u in [0, 1]^p. One scaled constraint per raw row
    of a constrained metric (`Problem.sizes`: a sampled metric's bound holds on every sample):
    `rows` (q,) its raw row, `sides` (q,) the index of the constraint side (metric and bound) it
    belongs to, `bounds` (q,) the bound, `upper` (q,) bool, `scale` (q,) |bound| (1 where the
    bound is 0). The objective's metric is raw row 0 (never sampled)."""

    problem: Problem
    sign: float
    f_scale: Optional[float]
    rows: np.ndarray
    bounds: np.ndarray
    upper: np.ndarray
    scale: np.ndarray
    sides: Optional[np.ndarray] = None

    def constraints_of(self, values) -> np.ndarray:
        """Scaled constraints c (..., q) of raw values (..., n): >= 0 where met."""
        m = values[..., self.rows]
        c = np.where(self.upper, self.bounds - m, m - self.bounds)
        return c / self.scale

    def merit(self, values) -> np.ndarray:
        """Scaled objective plus 1e3 times the summed violation (..., ): how starts are ranked;
        inf where a value is not finite (a failed scene); `values` raw (..., n)."""
        obj = self.sign * values[..., 0] / self.f_scale
        viol = np.sum(np.maximum(-self.constraints_of(values), 0.0), axis=-1)
        out = obj + 1e3 * viol
        return np.where(np.all(np.isfinite(values), axis=-1), out, np.inf)

    def fun(self, u):
        v, J = self.problem.raw_value_and_jacobian(self.problem.x_of(u))
        return self.sign * v[0] / self.f_scale

    def grad(self, u):
        v, J = self.problem.raw_value_and_jacobian(self.problem.x_of(u))
        return self.sign * J[0] * (self.problem.hi - self.problem.lo) / self.f_scale

    def cons(self, u):
        v, _ = self.problem.raw_value_and_jacobian(self.problem.x_of(u))
        return self.constraints_of(v)

    def cons_jac(self, u):
        _, J = self.problem.raw_value_and_jacobian(self.problem.x_of(u))
        Ju = J[self.rows] * (self.problem.hi - self.problem.lo)[None, :]
        return np.where(self.upper[:, None], -Ju, Ju) / self.scale[:, None]


def screen(scaled: Scaled, u_base, n_candidates: int, n_starts: int, seed: int):
    """The `n_starts` best of `n_candidates` points (the base robot's point, clipped into the
    box, and a scrambled Sobol sequence), ranked by `Scaled.merit` from one batched call. Sets
    `scaled.f_scale` where it is None: |objective| at the base robot's point.

    **Returns:** (starts (n_starts, p), candidates (n, p), their merits (n,), seconds)."""
    p = len(scaled.problem.names)
    t0 = time.perf_counter()
    m = max(int(n_candidates) - 1, 1)
    sob = qmc.Sobol(p, scramble=True, seed=seed).random(1 << int(np.ceil(np.log2(m))))[:m]
    U = np.concatenate([np.clip(u_base, 0.0, 1.0)[None], sob], axis=0)
    V = scaled.problem.batch_raw(scaled.problem.x_of(U))
    if scaled.f_scale is None:  # the objective's scale: its size at the best-known point
        finite = np.isfinite(V[:, 0]) & (V[:, 0] != 0)
        f = V[0, 0] if finite[0] else (np.median(np.abs(V[finite, 0])) if finite.any() else 1.0)
        scaled.f_scale = float(abs(f))
    merit = scaled.merit(V)
    order = np.argsort(merit, kind="stable")
    ok = order[np.isfinite(merit[order])]
    if ok.size == 0:
        raise DesignError(f"every one of the {U.shape[0]} screened starts failed (a metric is "
                          f"not finite there: the scene failed); narrow the bounds")
    return U[ok[:n_starts]], U, merit, time.perf_counter() - t0


def optimise(scaled: Scaled, u0, method: str, max_iter: int) -> dict:
    """One run of scipy.optimize.minimize from u0 (p,).

    **Arguments:**

    - `scaled`: the `Scaled` problem.
    - `u0`: the start, normalised.
    - `method`: 'slsqp' or 'trust-constr'.
    - `max_iter`: the optimiser's iteration limit.

    **Returns:** {u, fun, max_violation, success, message, nit, nfev, jacobians (the points
    whose values and Jacobian were computed: each evaluation of the problem), history, seconds,
    multipliers} (history: one entry per iteration, {iteration, u, objective (scaled),
    max_violation (scaled)}; multipliers: scipy's own, where it gives them).
    """
    q = scaled.rows.size
    history = []

    def record(u):
        c = scaled.cons(u) if q else np.zeros(0)
        history.append({"iteration": len(history), "u": np.asarray(u, dtype=float).copy(),
                        "objective": float(scaled.fun(u)),
                        "max_violation": float(max(0.0, -c.min())) if q else 0.0})

    def callback(intermediate_result):
        record(intermediate_result.x)

    u0 = np.asarray(u0, dtype=np.float64)
    jac0 = scaled.problem.jacobians
    record(u0)
    t0 = time.perf_counter()
    p = u0.size
    if method == "slsqp":
        cons = [{"type": "ineq", "fun": scaled.cons, "jac": scaled.cons_jac}] if q else []
        res = so.minimize(scaled.fun, u0, jac=scaled.grad, method="SLSQP",
                          bounds=[(0.0, 1.0)] * p, constraints=cons, callback=callback,
                          options={"maxiter": max_iter, "ftol": 1e-12})
    elif method == "trust-constr":
        cons = ([so.NonlinearConstraint(scaled.cons, 0.0, np.inf, jac=scaled.cons_jac,
                                        hess=so.BFGS())] if q else [])
        res = so.minimize(scaled.fun, u0, jac=scaled.grad, hess=so.BFGS(),
                          method="trust-constr", bounds=so.Bounds(np.zeros(p), np.ones(p)),
                          constraints=cons, callback=callback,
                          options={"maxiter": max_iter, "gtol": 1e-12, "xtol": 1e-14,
                                   "barrier_tol": 1e-12, "initial_barrier_parameter": 1e-4})
    else:
        raise DesignError(f"optimizer must be 'slsqp' or 'trust-constr', got {method!r}")
    seconds = time.perf_counter() - t0
    u = np.clip(np.asarray(res.x, dtype=np.float64), 0.0, 1.0)
    c = scaled.cons(u) if q else np.zeros(0)
    mult = getattr(res, "multipliers", None)
    return {"u": u, "fun": float(scaled.fun(u)),
            "max_violation": float(max(0.0, -c.min())) if q else 0.0,
            "success": bool(res.success), "message": str(res.message), "nit": int(res.nit),
            "nfev": int(res.nfev), "history": history,
            "jacobians": scaled.problem.jacobians - jac0, "seconds": seconds,
            "multipliers": None if mult is None else np.asarray(mult, dtype=float)}
