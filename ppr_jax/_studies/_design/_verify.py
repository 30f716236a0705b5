"""The verification of an optimum: the Karush-Kuhn-Tucker conditions with the multipliers of the
active constraints and bounds, a finite-difference check of the JAX gradient there, and a dense
grid (a Sobol sample beyond a few variables) over the same box, every point in one batched
call."""

from __future__ import annotations

import time

import numpy as np
from scipy.optimize import nnls
from scipy.stats import qmc

from ._optimise import Scaled

#: a constraint (scaled) or a normalised variable within this of its bound counts as active
ACTIVE_TOL = 1e-7
#: the finite-difference step, relative to each variable's box
FD_STEP = 1e-5
#: a metric whose change across the box (normalised Jacobian) is below this fraction of its
#: value counts as constant in the gradient check: its finite differences are rounding noise
CONSTANT_RTOL = 1e-6
#: below this many points per axis, the grid becomes a Sobol sample of the same size
MIN_PER_AXIS = 5
#: the KKT residual (relative) below which the optimum counts as a stationary point
KKT_TOL = 1e-5


def kkt(scaled: Scaled, u) -> dict:
    """The multipliers of the active constraints and bounds at u, by non-negative least squares
    on the stationarity condition grad(phi) = sum_k mu_k grad(c_k) (phi the scaled objective,
    c_k >= 0 the active constraints and bounds, all in normalised variables).

    **Returns:** {constraints: [(index, mu)], bounds: [(variable index, 'lower'|'upper', mu)],
    residual: |grad phi - A mu| / |grad phi| (0 for a stationary point: the optimum is a KKT
    point where this is small)}. The multipliers mu are those of the scaled problem; the caller
    converts them into d(optimum)/d(bound).
    """
    g = scaled.grad(u)
    cols, tags = [], []
    if scaled.rows.size:
        c = scaled.cons(u)
        Jc = scaled.cons_jac(u)
        for k in np.flatnonzero(np.abs(c) <= ACTIVE_TOL):
            cols.append(Jc[k])
            tags.append(("constraint", int(k)))
    p = u.size
    for i in range(p):
        if u[i] <= ACTIVE_TOL:
            cols.append(np.eye(p)[i])
            tags.append(("lower", i))
        elif u[i] >= 1 - ACTIVE_TOL:
            cols.append(-np.eye(p)[i])
            tags.append(("upper", i))
    gn = float(np.linalg.norm(g))
    if not cols:
        return {"constraints": [], "bounds": [], "residual": gn / max(gn, 1e-300) if gn else 0.0}
    A = np.stack(cols, axis=1)
    norms = np.maximum(np.linalg.norm(A, axis=0), 1e-300)
    mu_s, _ = nnls(A / norms, g)
    mu = mu_s / norms
    res = float(np.linalg.norm(g - A @ mu) / max(gn, 1e-300))
    out_c = [(k, float(m)) for (kind, k), m in zip(tags, mu) if kind == "constraint"]
    out_b = [(i, kind, float(m)) for (kind, i), m in zip(tags, mu) if kind != "constraint"]
    return {"constraints": out_c, "bounds": out_b, "residual": res}


def gradient_check(scaled: Scaled, u, rtol: float) -> dict:
    """Central finite differences (second-order one-sided ones at a bound of the box) of every
    raw value (each sample of a sampled metric: `Problem.sizes`) in every variable at u, all
    points in one batched call, against the JAX Jacobian.

    **Returns:** {step_relative, max_relative_error (per metric, |J - J_fd|_inf / |J|_inf over
    its rows, in normalised variables; |J|_inf at least `CONSTANT_RTOL` of the metric's
    largest value), worst, ok (worst <= rtol), rtol, jacobian, finite_difference (k, p) in SI
    units: the metrics' own (a sampled metric's: its extreme sample's row)}."""
    prob = scaled.problem
    x = prob.x_of(u)
    v, J = prob.raw_value_and_jacobian(x)
    p = u.size
    h = FD_STEP
    pts, plan = [], []
    for i in range(p):
        e = np.eye(p)[i] * h
        if u[i] - h >= 0 and u[i] + h <= 1:
            plan.append(("c", len(pts)))
            pts += [u + e, u - e]
        elif u[i] + 2 * h <= 1:
            plan.append(("f", len(pts)))
            pts += [u, u + e, u + 2 * e]
        else:
            plan.append(("b", len(pts)))
            pts += [u, u - e, u - 2 * e]
    V = prob.batch_raw(prob.x_of(np.stack(pts)))
    dx = h * (prob.hi - prob.lo)
    fd = np.zeros_like(J)
    for i, (kind, j) in enumerate(plan):
        if kind == "c":
            fd[:, i] = (V[j] - V[j + 1]) / (2 * dx[i])
        elif kind == "f":
            fd[:, i] = (-3 * V[j] + 4 * V[j + 1] - V[j + 2]) / (2 * dx[i])
        else:
            fd[:, i] = (3 * V[j] - 4 * V[j + 1] + V[j + 2]) / (2 * dx[i])
    # compared in normalised variables (columns times the box), so every variable counts alike
    # against the Jacobian's largest entry, or CONSTANT_RTOL of the metric's value where the
    # metric hardly depends on the variables (the path margins under a strip's thickness: the
    # differences are rounding noise, eps |v|/h)
    Ju, Fu = J * (prob.hi - prob.lo), fd * (prob.hi - prob.lo)
    err = []
    for idx in prob.blocks:
        ref = max(float(np.max(np.abs(Ju[idx]))), CONSTANT_RTOL * float(np.max(np.abs(v[idx]))))
        err.append(float(np.max(np.abs(Ju[idx] - Fu[idx]))) / max(ref, 1e-300))
    worst = float(np.max(err))
    _, Jk = prob.reduce(v, J)
    _, Fk = prob.reduce(v, fd)
    return {"step_relative": h, "max_relative_error": dict(zip(prob.metrics, err)),
            "worst": worst, "ok": bool(worst <= rtol), "rtol": rtol,
            "jacobian": Jk.tolist(), "finite_difference": Fk.tolist()}


def grid_check(scaled: Scaled, u_opt, n_points: int, rtol: float, seed: int = 0) -> dict:
    """The best feasible objective on a dense grid over the box (`n_points` in all, the same
    number per axis; a scrambled Sobol sample of `n_points` where that leaves fewer than
    `MIN_PER_AXIS` per axis), every point in one batched call, against the optimum's.

    **Returns:** {kind ('grid' or 'sobol'), points, per_axis, feasible, best_objective, best_x
    (SI), optimum_objective, gap ((best - optimum)/|best| for a maximisation, the other way
    round for a minimisation: > 0 where the grid found better), ok (gap <= rtol), rtol, seconds}.
    """
    prob = scaled.problem
    p = len(prob.names)
    per_axis = int(np.floor(n_points ** (1.0 / p) + 1e-9))
    t0 = time.perf_counter()
    if per_axis >= MIN_PER_AXIS:
        axes = [np.linspace(0.0, 1.0, per_axis)] * p
        U = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, p)
        kind = "grid"
    else:
        U = qmc.Sobol(p, scramble=True, seed=seed).random(int(n_points))
        kind, per_axis = "sobol", None
    V = prob.batch_raw(prob.x_of(U))
    seconds = time.perf_counter() - t0
    ok_pts = scaled.feasible(V)
    v_opt = prob.values(prob.x_of(u_opt))[0]
    out = {"kind": kind, "points": int(U.shape[0]), "per_axis": per_axis,
           "feasible": int(ok_pts.sum()), "optimum_objective": float(v_opt), "rtol": rtol,
           "seconds": seconds}
    if not ok_pts.any():
        out.update(best_objective=None, best_x=None, gap=None, ok=True)
        return out
    obj = scaled.sign * V[:, 0]
    best = int(np.flatnonzero(ok_pts)[np.argmin(obj[ok_pts])])
    f_best = float(V[best, 0])
    gap = scaled.sign * (v_opt - f_best) / max(abs(f_best), 1e-300)
    out.update(best_objective=f_best,
               best_x=dict(zip(prob.names, map(float, prob.x_of(U[best])))),
               gap=float(gap), ok=bool(gap <= rtol))
    return out


def verify(scaled: Scaled, u, fd_rtol: float, n_grid: int, grid_rtol: float, seed: int) -> tuple:
    """The verification of the optimum u: its KKT residual (`kkt`, within `KKT_TOL`), the
    gradient against finite differences (`gradient_check`, within `fd_rtol`) and the grid
    (`grid_check`: `n_grid` points, within `grid_rtol`).

    **Returns:** (the `kkt` dict, {kkt_residual, kkt_tol, gradient_check, grid, ok})."""
    kk = kkt(scaled, u)
    gc = gradient_check(scaled, u, fd_rtol)
    gr = grid_check(scaled, u, n_grid, grid_rtol, seed)
    return kk, {"kkt_residual": kk["residual"], "kkt_tol": KKT_TOL, "gradient_check": gc,
                "grid": gr, "ok": bool(kk["residual"] <= KKT_TOL and gc["ok"] and gr["ok"])}
