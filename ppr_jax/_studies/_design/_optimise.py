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
from ._goals import band_g
from ._problem import Problem

#: a constraint counts as met where its violation (`Scaled.violations`), judged on the metric
#: against its bound or the band's edges, relative to the bound (1 where the bound is 0, or a
#: path margin's), is at most FEAS_TOL: metric <= bound + FEAS_TOL |bound| (upper), likewise
#: for a lower bound, and a band to avoid is met by a metric at or below lo + FEAS_TOL |lo| or
#: at or above hi - FEAS_TOL |hi|. Never on the band's smooth g: a band of width w makes g's
#: tolerance FEAS_TOL w in the metric's unit, and a band wide enough to cover every reachable
#: value (avoid (0, 1e12)) would have every design inside it "feasible"
FEAS_TOL = 1e-8


@dataclasses.dataclass
class Scaled:
    """The problem as the optimiser sees it: minimise sign * metric_0 / f_scale subject to the
    scaled constraints c(u) >= 0 (`FEAS_TOL`), u in [0, 1]^p. One scaled constraint per raw row
    of a constrained metric (`Problem.sizes`: a sampled metric's bound holds on every sample):
    `rows` (q,) its raw row, `sides` (q,) the index of the constraint side (metric and bound) it
    belongs to, `bounds` (q,) the bound, `upper` (q,) bool, `scale` (q,) |bound| (1 where the
    bound is 0). A band to avoid (`Constraint`) is a row with `avoid` (q,) True, `bounds` its
    lo, `band_hi` (q,) its hi and scale 1: c = (m - lo)(m - hi)/(hi - lo)^2. The objective's
    metric is raw row 0 (never sampled)."""

    problem: Problem
    sign: float
    f_scale: Optional[float]
    rows: np.ndarray
    bounds: np.ndarray
    upper: np.ndarray
    scale: np.ndarray
    sides: Optional[np.ndarray] = None
    avoid: Optional[np.ndarray] = None
    band_hi: Optional[np.ndarray] = None
    edge_scale: Optional[np.ndarray] = None

    def _band(self):
        """(avoid (q,) bool, hi (q,)): hi the band's upper edge, bound + 1 off the bands."""
        if self.avoid is None or not self.avoid.any():
            return None, None
        return self.avoid, np.where(self.avoid, self.band_hi, self.bounds + 1.0)

    def dc_dm(self, values) -> np.ndarray:
        """d c/d metric (..., q) of the scaled constraints at raw values (..., n)."""
        m = values[..., self.rows]
        d = np.where(self.upper, -1.0, 1.0) + 0.0 * m
        avoid, hi = self._band()
        if avoid is not None:
            d = np.where(avoid, band_g(m, self.bounds, hi)[1], d)
        return d / self.scale

    def dc_dbounds(self, values) -> tuple[np.ndarray, np.ndarray]:
        """(d c/d bound, d c/d hi) (..., q) at raw values (..., n): the scaled constraints'
        derivatives in their bound (a band's lo) and in a band's hi (0 off the bands)."""
        m = values[..., self.rows]
        d_lo = np.where(self.upper, 1.0, -1.0) + 0.0 * m
        d_hi = 0.0 * m
        avoid, hi = self._band()
        if avoid is not None:
            _, _, g_lo, g_hi = band_g(m, self.bounds, hi)
            d_lo, d_hi = np.where(avoid, g_lo, d_lo), np.where(avoid, g_hi, d_hi)
        return d_lo / self.scale, d_hi / self.scale

    def constraints_of(self, values) -> np.ndarray:
        """Scaled constraints c (..., q) of raw values (..., n): >= 0 where met."""
        m = values[..., self.rows]
        c = np.where(self.upper, self.bounds - m, m - self.bounds)
        avoid, hi = self._band()
        if avoid is not None:
            c = np.where(avoid, band_g(m, self.bounds, hi)[0], c)
        return c / self.scale

    def violations(self, values) -> np.ndarray:
        """How far each constraint row is violated (..., q) at raw values (..., n), >= 0, judged
        on the metric against its bound or its band's edges (`FEAS_TOL`): (metric - bound)/scale
        above an upper bound, (bound - metric)/scale below a lower one; inside a band (lo, hi)
        the lesser of (metric - lo)/scale_lo and (hi - metric)/scale_hi (`edge_scale`, each
        edge's |value|, 1 where it is 0 or a path margin's). NaN (a failed scene) is inf."""
        m = values[..., self.rows]
        v = np.where(self.upper, m - self.bounds, self.bounds - m) / self.scale
        avoid, hi = self._band()
        if avoid is not None:
            s_lo, s_hi = self.edge_scale[:, 0], self.edge_scale[:, 1]
            inside = np.minimum((m - self.bounds) / s_lo, (hi - m) / s_hi)
            v = np.where(avoid, inside, v)
        return np.where(np.isnan(v), np.inf, np.maximum(v, 0.0))

    def feasible(self, values) -> np.ndarray:
        """The one feasibility judgement of a design (..., ): every constraint row's violation
        at most `FEAS_TOL` and every raw value finite, at raw values (..., n)."""
        ok = np.all(np.isfinite(values), axis=-1)
        if self.rows.size:
            ok = ok & np.all(self.violations(values) <= FEAS_TOL, axis=-1)
        return ok

    def violation_of(self, u) -> float:
        """The largest violation (`violations`) at normalised variables u, 0 without
        constraints."""
        if not self.rows.size:
            return 0.0
        v, _ = self.problem.raw_value_and_jacobian(self.problem.x_of(u))
        return float(np.max(self.violations(v)))

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
        v, J = self.problem.raw_value_and_jacobian(self.problem.x_of(u))
        Ju = J[self.rows] * (self.problem.hi - self.problem.lo)[None, :]
        return self.dc_dm(v)[:, None] * Ju


def screen(scaled: Scaled, u_base, n_candidates: int, n_starts: int, seed: int):
    """The `n_starts` best of `n_candidates` points (the base robot's point, clipped into the
    box, and a scrambled Sobol sequence), ranked by `Scaled.merit` from one batched call. Sets
    `scaled.f_scale` where it is None: |objective| at the base robot's point. Where a band is
    avoided, the best candidate of each side of it (each combination of sides of several
    bands, a candidate in a band counted on the side of its nearer edge) comes first, as far
    as `n_starts` allows (`pick_starts`): the feasible set has a part on each side, and an
    optimiser stays in the part its start leads to.

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
    return U[pick_starts(scaled, V, ok, n_starts)], U, merit, time.perf_counter() - t0


def pick_starts(scaled: Scaled, V, ok, n_starts: int) -> np.ndarray:
    """The indices of the `n_starts` starts among the candidates `ok` (ranked best first) of
    raw values V (n, n_raw): the best candidate of each combination of the bands' sides found
    (above or below each band's middle), then the best of the rest; in rank order."""
    ok = np.asarray(ok)
    avoid, hi = scaled._band()
    if avoid is None:
        return ok[:n_starts]
    mid = (scaled.bounds[avoid] + hi[avoid]) / 2
    above = V[ok][:, scaled.rows[avoid]] > mid
    first: dict = {}
    for i, key in zip(ok, map(tuple, above)):
        first.setdefault(key, i)
    lead = list(first.values())[:n_starts]
    taken = set(lead)
    picked = set(lead + [i for i in ok if i not in taken][:n_starts - len(lead)])
    return np.array([i for i in ok if i in picked], dtype=int)


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
    max_violation (`Scaled.violations`: on the metrics, relative to each bound)}; multipliers:
    scipy's own, where it gives them).
    """
    q = scaled.rows.size
    history = []

    def record(u):
        history.append({"iteration": len(history), "u": np.asarray(u, dtype=float).copy(),
                        "objective": float(scaled.fun(u)),
                        "max_violation": scaled.violation_of(u)})

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
    mult = getattr(res, "multipliers", None)
    return {"u": u, "fun": float(scaled.fun(u)), "max_violation": scaled.violation_of(u),
            "success": bool(res.success), "message": str(res.message), "nit": int(res.nit),
            "nfev": int(res.nfev), "history": history,
            "jacobians": scaled.problem.jacobians - jac0, "seconds": seconds,
            "multipliers": None if mult is None else np.asarray(mult, dtype=float)}


def multistart(scaled: Scaled, u_base, n_candidates: int, n_starts: int, seed: int,
               method: str, max_iter: int) -> tuple:
    """The starts screened (`screen`), one `optimise` run from each, and the best: the least
    objective among the feasible optima (`Scaled.feasible` on the raw metrics), else the least
    violation.

    **Returns:** (runs, best run, feasible runs, {screen_s, optimise_s}); each run `optimise`'s
    dict with its start `u0` and `feasible` added."""
    U0, _, _, screen_s = screen(scaled, u_base, n_candidates, n_starts, seed)
    t0 = time.perf_counter()
    runs = [optimise(scaled, u0, method, max_iter) for u0 in U0]
    optimise_s = time.perf_counter() - t0
    prob = scaled.problem
    for r, u0 in zip(runs, U0):
        r["u0"] = u0
        r["feasible"] = bool(scaled.feasible(prob.raw_value_and_jacobian(prob.x_of(r["u"]))[0]))
    feasible = [r for r in runs if r["feasible"]]
    best = (min(feasible, key=lambda r: r["fun"]) if feasible
            else min(runs, key=lambda r: (r["max_violation"], r["fun"])))
    return runs, best, feasible, {"screen_s": screen_s, "optimise_s": optimise_s}
