"""The fits: Levenberg-Marquardt with bounds by reparametrisation, or optimistix's solvers."""

from __future__ import annotations

import math
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..._errors import IdentificationError, result_message
from ._problem import (
    INIT_SCALE,
    MAX_STEP_Z,
    POOR_FIT_SCALE,
    _anonymous,
    _residual_and_jacobian,
    _residual_vector,
    _succeeded,
    _to_p,
)


def _initial_state_guess(prob, z0, mask):
    """Start the initial-state unknowns where the data put them: the pose offset as the first
    measured sample minus the simulated one, the velocity offset as the same difference of the
    first two samples' finite difference. A released robot oscillates at 10 to 100 Hz, so the
    cost is far from convex in the initial state; from zero offsets the fit can end in a local
    minimum."""
    _, _, ok, X = _residual_and_jacobian(prob, jnp.asarray(z0))
    _check_ok(ok, z0, prob, start=True)
    X, Xm, ts = np.asarray(X), np.asarray(prob.X), np.asarray(prob.ts)
    P, k = len(prob.names), prob.n_init
    d = np.zeros((X.shape[0], 6))
    for j in range(X.shape[0]):
        i = np.flatnonzero(mask[j])
        d[j, :3] = Xm[j, i[0]] - X[j, i[0]]
        dt = ts[j, i[1]] - ts[j, i[0]]
        d[j, 3:] = ((Xm[j, i[1]] - Xm[j, i[0]]) - (X[j, i[1]] - X[j, i[0]])) / dt
    z0 = np.array(z0, dtype=np.float64)
    z0[P:P + X.shape[0] * k] = (d[:, :k] / np.asarray(INIT_SCALE[:k])).reshape(-1)
    return z0


def _value_text(name, v):
    """`strip thickness t = 0.55 mm`: a parameter's meaning, name, value and unit (mm for m)."""
    from ..._names import PARAM_RANGES

    _, _, unit, meaning = PARAM_RANGES.get(name, (0, 0, "", ""))
    if unit == "m":
        v, unit = v * 1e3, "mm"
    text = f"{name} = {v:.6g}" + (f" {unit}" if unit and unit != "-" else "")
    return f"{meaning} {text}" if meaning else text


def _check_ok(codes, z, prob, start=False, names=None):
    """Raise `IdentificationError` unless every experiment's simulation succeeded (`codes`, the
    result codes (E,) of `_residual_and_jacobian`): naming the experiment, the parameters (their
    meaning and unit) and the cause that the simulation reported. `start`: z is where a fit
    begins (nothing fitted yet), so the data, not the fit, took the model there: the message
    then puts the data's units and robot before the tolerances. `names`: the experiments'
    names."""
    codes = np.atleast_1d(np.asarray(codes))
    if np.all(codes == 0):
        return
    p = np.asarray(_to_p(prob, jnp.asarray(z)))
    at = ", ".join(_value_text(n, float(v)) for n, v in zip(prob.names, p))
    k = int(np.flatnonzero(codes != 0)[0])
    names = prob.experiment_names if names is None else names
    which = f"experiment {names[k]!r}" if names else f"experiment {k + 1}"
    what = f"the {prob.model.name} simulation of {which} ({prob.scene})"
    cause = result_message(int(codes[k]))
    opts = prob.options
    tols = (f"rtol {float(opts.rtol):g}, atol {float(opts.atol):g}, max_steps "
            f"{opts.max_steps}")
    if not start:
        raise IdentificationError(f"{what} failed at {at}: {cause} ({tols})")
    given = []
    if prob.tau is not None:
        given.append("driven by the measured torques tau_1..tau_3")
    if prob.th is not None:
        given.append("driven by the measured angles th_1..th_3")
    if prob.n_init:
        given.append("started from the data's first samples")
    how = f" ({'; '.join(given)})" if given else ""
    raise IdentificationError(
        f"{what}{how} failed at the start of the fit, before anything was fitted ({at}): "
        f"{cause}; the data are far from any state the model reaches from this start. Check "
        f"the data's units (declare them: '# units: length=mm, angle=deg, torque=N mm') and "
        f"that they come from this robot and scene (params=, --params-file, --scene); only if "
        f"they do, loosen the tolerances or raise max_steps ({tols})")


def _levenberg_marquardt(prob, z0, max_iter, xtol, ftol, stat_tol, free=None, first=None):
    """Levenberg-Marquardt (Marquardt's diagonal scaling, Nielsen's damping update) on the host,
    around the one compiled residual-and-Jacobian function. Each trial point costs one call.
    `free` (bool, like z) the unknowns that move (default all; a profile holds one fixed and
    reuses the same compiled function). `first`: (r, J, ok, X, seconds) already evaluated at z0
    (the preflight's), reused for the first iteration."""
    t0 = time.perf_counter()
    if first is None:
        r, J, ok, X = _residual_and_jacobian(prob, jnp.asarray(z0))
        r, J = np.asarray(r), np.asarray(J)
        compile_s = time.perf_counter() - t0
    else:
        r, J, ok, X, compile_s = first
        r, J = np.asarray(r), np.asarray(J)
    _check_ok(ok, z0, prob, start=free is None)
    t1 = time.perf_counter()
    z = np.array(z0, dtype=np.float64)
    sel = np.arange(z.size) if free is None else np.flatnonzero(free)
    cost = float(r @ r)
    n_w = int(np.count_nonzero(np.asarray(prob.w)))  # residuals of weight > 0
    A = J.T @ J
    lam = 1e-3  # dimensionless: the damping term is lam * diag(J^T J) (Marquardt's scaling)
    nu = 2.0
    costs = [cost]
    n_eval, it, reason = 1, 0, "max_iter" if max_iter > 0 else "no step (max_iter = 0)"
    for it in range(1, max_iter + 1):
        Jf = J[:, sel]
        g = Jf.T @ r
        A = Jf.T @ Jf
        if not np.max(np.diag(A)) > 0:
            # e.g. t with a kinematic model (L0/L1 motion-driven): nothing to fit
            reason = "the residuals do not depend on the unknowns"
            break
        D = np.maximum(np.diag(A), 1e-12 * max(float(np.max(np.diag(A))), 1e-300))
        try:
            dz = -np.linalg.solve(A + lam * np.diag(D), g)
        except np.linalg.LinAlgError:
            lam *= nu
            nu *= 2
            continue
        # A trust region in z (unit steps: a factor of about 10 in a log-bounded parameter):
        # along a direction the data barely see (t against K_theta) the Gauss-Newton step is
        # huge and would run the estimate into its bounds.
        big = float(np.max(np.abs(dz)))
        if big > MAX_STEP_Z:
            dz = dz * (MAX_STEP_Z / big)
        z_new = z.copy()
        z_new[sel] += dz
        r_new, J_new, ok_new, X_new = _residual_and_jacobian(prob, jnp.asarray(z_new))
        n_eval += 1
        r_new = np.asarray(r_new)
        cost_new = float(r_new @ r_new) if _succeeded(ok_new) else np.inf
        pred = float(dz @ (lam * D * dz - g))  # predicted reduction of the cost (>= 0)
        if np.isfinite(cost_new) and cost_new < cost:
            rho_gain = (cost - cost_new) / max(pred, 1e-300)
            rel = (cost - cost_new) / max(cost, 1e-300)
            z, r, J, X, cost = z_new, r_new, np.asarray(J_new), X_new, cost_new
            costs.append(cost)
            lam *= max(1 / 3, 1 - (2 * rho_gain - 1) ** 3)
            nu = 2.0
            # Statistical stop: a step below `stat_tol` standard errors of every unknown moves
            # the estimate by nothing the data can tell (noise-dominated residuals make
            # Gauss-Newton converge only linearly, so the plain tests would take many steps).
            # The step's length in standard errors is measured with the information matrix
            # (sqrt(dz' J'J dz / s^2)): steps along directions the data do not determine (t
            # against K_theta) are free and must not count, steps along determined ones must.
            # The noise scale is the smaller of the stated one (1 in weighted units) and the
            # residuals' estimate: far from the optimum the misfit inflates the latter, which
            # would make every step look negligible.
            Jf = J[:, sel]
            A = Jf.T @ Jf
            s2 = min(cost / max(n_w - sel.size, 1), 1.0)
            step_se = math.sqrt(max(float(dz @ A @ dz), 0.0) / max(s2, 1e-300))
            if (np.max(np.abs(dz)) < xtol * (1 + np.max(np.abs(z))) or rel < ftol
                    or step_se < stat_tol):
                reason = "converged"
                break
        else:
            lam *= nu
            nu *= 2
            if np.max(np.abs(dz)) < xtol * (1 + np.max(np.abs(z))):
                reason = "converged"  # no smaller cost within a negligible step
                break
    hist = {"solver": "lm (host loop, compiled residual+Jacobian)", "iterations": it,
            "evaluations": n_eval, "cost": costs, "stop": reason, "compile_s": compile_s,
            "run_s": time.perf_counter() - t1}
    return (z, r, J, np.asarray(X)), hist


def _latin_hypercube(dim: int, n: int, seed: int) -> np.ndarray:
    """n points (n, dim) of a Latin hypercube in (0.05, 0.95)^dim: away from the bounds, where
    the reparametrisation is flat."""
    from scipy.stats import qmc

    return 0.05 + 0.9 * qmc.LatinHypercube(d=dim, seed=seed).random(n)


@eqx.filter_jit
def _costs(prob, Z):
    """Costs sum r^2 (K,) at K points Z (K, n) in one vmapped call of the residual (no
    Jacobian); a point whose simulation fails costs inf."""
    def one(z):
        r, (codes, _) = _residual_vector(prob, z)
        return jnp.where(jnp.all(codes == 0), r @ r, jnp.inf)

    return jax.vmap(one)(Z)


def at_bound(prob, z) -> list:
    """Names of the unknowns of `z` (the fit's unbounded scale) at a bound of theirs: where the
    reparametrisation is flat (the sigmoid's slope below 1e-9), so the chain rule loses the
    physical Jacobian there and the fit cannot move the unknown back."""
    sz = 1 / (1 + np.exp(-np.asarray(z)[:len(prob.names)]))
    return [n for n, v in zip(prob.names, sz * (1 - sz)) if v < 1e-9]


def _escalation_reason(prob, zrj, dof):
    """Why the fit `zrj` = (z, r, J, X) of the given start calls for more starts
    (`starts="auto"`), or None: it does not explain the data (residual scale s above
    `POOR_FIT_SCALE`, the threshold `quality` uses) or an unknown ended at a bound."""
    r = np.asarray(zrj[1])
    s = math.sqrt(float(r @ r) / max(dof, 1))
    bound = at_bound(prob, zrj[0])
    why = []
    if not s <= POOR_FIT_SCALE:
        why.append(f"the given start does not explain the data (residual scale s = {s:.3g} > "
                   f"{POOR_FIT_SCALE:g})")
    if bound:
        why.append(f"the given start ended with {', '.join(bound)} at a bound")
    return "; ".join(why) or None


def _multi_start(prob, z0, starts, seed, fit_one, guess=None, screen=None, given=None):
    """Fit from z0 and from `starts` - 1 points of a Latin hypercube of the unknowns within
    their bounds (uniform in the bounded scale: log for a log-bounded unknown; the nuisance
    unknowns as `guess(z)` puts them, else as in z0), by `fit_one(z) -> (zrj, hist)`; the
    best (lowest cost) wins. A start whose simulation fails is recorded and skipped.
    `screen` (an int k, or None): first evaluate the cost at every Latin-hypercube point in one
    vmapped call (`_costs`) and run the fit only from the k cheapest (plus z0); None fits from
    every point. `given`: the fit from z0, when already made. `hist["starts"]` lists every
    fitted start: its parameters, where it ended, its cost and stop; `hist["screening"]` the
    screened points' costs."""
    P = len(prob.names)
    points = [np.array(z0, dtype=np.float64)]
    for u in _latin_hypercube(P, starts - 1, seed):
        z = points[0].copy()
        z[:P] = np.log(u) - np.log1p(-u)
        points.append(z)
    order = list(range(len(points)))
    screening = None
    if screen is not None and len(points) - 1 > screen:
        t0 = time.perf_counter()
        c = np.asarray(_costs(_anonymous(prob), jnp.asarray(np.stack(points[1:]))))
        kept = [1 + int(k) for k in np.argsort(np.where(np.isfinite(c), c, np.inf))[:screen]]
        order = [0] + kept
        screening = {"points": len(points) - 1, "kept": kept,
                     "initial": [[float(v) for v in np.asarray(_to_p(prob, jnp.asarray(z[:P])))]
                                 for z in points[1:]],
                     "cost": [float(v) if np.isfinite(v) else None for v in c],
                     "run_s": time.perf_counter() - t0}
    best, runs = None, []
    for k in order:
        z = points[k]
        row = {"start": k, "initial": [float(v) for v in np.asarray(_to_p(prob, z[:P]))]}
        try:
            if k == 0 and given is not None:
                zrj, hist = given
            else:
                if guess is not None and k:
                    z = guess(z)
                zrj, hist = fit_one(z)
        except IdentificationError as err:
            runs.append({**row, "cost": None, "stop": f"failed: {err}"})
            continue
        cost = float(np.asarray(zrj[1]) @ np.asarray(zrj[1]))
        runs.append({**row, "estimate": [float(v) for v in
                                         np.asarray(_to_p(prob, jnp.asarray(zrj[0])[:P]))],
                     "cost": cost, "stop": hist["stop"]})
        if best is None or cost < best[2]:
            best = (zrj, hist, cost, k)
    if best is None:
        raise IdentificationError(f"every one of the {len(order)} starts failed: "
                                  + "; ".join(r["stop"] for r in runs))
    zrj, hist, _, k = best
    hist = dict(hist)
    hist["starts"] = runs
    hist["best_start"] = k
    if screening is not None:
        hist["screening"] = screening
    return zrj, hist


def _optimistix(prob, z0, solver, max_iter, xtol, ftol):
    import optimistix as optx

    fn = lambda z, _: _residual_vector(prob, z)[0]  # noqa: E731
    s = (optx.LevenbergMarquardt(rtol=xtol, atol=xtol) if solver == "optimistix-lm"
         else optx.GaussNewton(rtol=xtol, atol=xtol))
    run = eqx.filter_jit(lambda z0: optx.least_squares(fn, s, z0, max_steps=max_iter,
                                                       throw=False,
                                                       options={"jac": "fwd"}))
    t0 = time.perf_counter()
    sol = run(jnp.asarray(z0))
    z = np.asarray(sol.value)
    first = time.perf_counter() - t0
    t1 = time.perf_counter()
    r, J, ok, X = _residual_and_jacobian(prob, jnp.asarray(z))
    _check_ok(ok, z, prob)
    hist = {"solver": f"{solver} (optimistix)", "iterations": int(sol.stats["num_steps"]),
            "stop": "converged" if sol.result == optx.RESULTS.successful else str(sol.result),
            "compile_and_run_s": first, "covariance_compile_s": time.perf_counter() - t1,
            "cost": [float(np.asarray(r) @ np.asarray(r))]}
    return (z, np.asarray(r), np.asarray(J), np.asarray(X)), hist

