"""Offline pseudo-rigid-body (PRB) fit of an initially curved cantilever to the elastica.

:func:`fit_prb` fits Howell's PRB parameters ``gamma, rho, K_theta`` of a cantilever of
nondimensional initial curvature ``kappa0 = l/R`` (beam length ``l = 1``, ``EI = 1``; spring
``K = rho K_theta EI/l``) to elastica solutions (:mod:`ppr_jax.elastica`) over a range of end
loads; :func:`prb_error` measures the errors of given parameters over the same load range.
``scripts/make_prb_table.py`` runs the fit to produce the shipped table, which
:mod:`ppr_jax._prb_table` loads and interpolates at runtime without this module.

The PRB model, the fitting procedure step by step (load directions, load range, gamma, rho,
K_theta, error measures; cited below as "steps 1-6") and the resulting table are described in
``docs/prb_fit.md``.
"""

from __future__ import annotations

import functools  # noqa: E402
from typing import NamedTuple  # noqa: E402

import jax
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import scipy.optimize  # noqa: E402

from ._errors import PPRError  # noqa: E402
from ._prb_table import prb_geometry  # noqa: E402
from .elastica import ElasticaConvergenceError, solve_cantilever  # noqa: E402

__all__ = [
    "DEFAULT_LOAD_RANGE",
    "PRBError",
    "PRBFit",
    "fit_prb",
    "prb_error",
]

#: Default load range of the fit (docs/prb_fit.md, steps 1-2).
DEFAULT_LOAD_RANGE = dict(
    n_values=(-1.0, -0.5, 0.0, 0.5, 1.0, 1.5, 2.0),
    senses=(1.0, -1.0),
    dtheta_tip_max=1.0,
    load_cap=10.0,
    n_loads=16,
)


class PRBError(NamedTuple):
    """Errors of a PRB model against the elastica over a load range (nondimensional)."""

    tip_error_max: float  #: max tip-position error / l
    tip_error_rms: float  #: RMS tip-position error / l
    load_error_max: float  #: max torque error / (max torque of the direction)
    load_error_rms: float  #: RMS of the same
    dtheta_max: float  #: largest PRB deflection |Theta - Theta_i| [rad] in the range
    theta_i: float  #: rest PRB angle [rad]


class PRBFit(NamedTuple):
    """Result of :func:`fit_prb` (nondimensional; ``K = rho K_theta EI/l``)."""

    kappa0: float
    gamma: float
    rho: float
    K_theta: float
    theta_i: float
    tip_error_max: float
    tip_error_rms: float
    load_error_max: float
    load_error_rms: float
    dtheta_max: float


# ------------------------------------------------------------------------------------------------
# Elastica samples
# ------------------------------------------------------------------------------------------------


def _solve_tip(kappa0, fx, fy):
    sol = solve_cantilever(1.0, 1.0, kappa0, (fx, fy), 0.0, n_continuation=16, throw=False)
    return sol.tip_x, sol.tip_y, sol.tip_angle, sol.converged


_solve_tip_batch = jax.jit(jax.vmap(_solve_tip, in_axes=(None, 0, 0)))


def _directions(kappa0, n_values, senses):
    """Unit force directions, shape (n_dir, 2), and their (n, sigma) labels."""
    c = 0.5 * kappa0
    e_c = np.array([np.cos(c), np.sin(c)])
    e_t = np.array([-np.sin(c), np.cos(c)])
    labels = [(n, s) for s in senses for n in n_values]
    d = np.array([(s * e_t - n * e_c) / np.hypot(1.0, n) for n, s in labels])
    return d, labels


def _tips(kappa0, forces, *, allow_failure=False):
    """Elastica tips (x, y, angle, converged) for forces (m, 2); raises on failure unless
    allowed."""
    out = _solve_tip_batch(float(kappa0), jnp.asarray(forces[:, 0]), jnp.asarray(forces[:, 1]))
    x, y, th, ok = (np.asarray(v) for v in out)
    if not allow_failure and not ok.all():
        bad = forces[~ok]
        raise ElasticaConvergenceError(
            f"fit_prb: elastica did not converge for kappa0={kappa0} and forces {bad[:4].tolist()}")
    return x, y, th, ok


@functools.lru_cache(maxsize=64)
def _samples(kappa0, n_values, senses, dtheta_tip_max, load_cap, n_loads):
    """Elastica samples of the load range (docs/prb_fit.md, steps 1-2).

    Returns a dict of numpy arrays: ``forces (n_dir, n_loads, 2)``, ``tip (n_dir, n_loads, 2)``,
    ``P_max (n_dir,)`` and the direction ``labels`` ``(n, sigma)``.
    """
    d, labels = _directions(kappa0, n_values, senses)
    n_dir = len(labels)

    def excess(P, i):
        # Tip rotation beyond the target; a load the elastica solver cannot follow counts as beyond
        # the range (so the root search stops at the last solvable load).
        _, _, th, ok = _tips(kappa0, (P * d[i])[None], allow_failure=True)
        return float(np.abs(th[0] - kappa0) - dtheta_tip_max) if ok[0] else 1.0

    # Bracket P* on a geometric grid, all directions at once, then refine with Brent. The grid
    # has n_loads points so that this batch has the same shape as the final one (one compile).
    grid = load_cap * np.geomspace(1e-3, 1.0, n_loads)
    f = (d[:, None, :] * grid[None, :, None]).reshape(-1, 2)
    _, _, th, ok = _tips(kappa0, f, allow_failure=True)
    beyond = (np.abs(th.reshape(n_dir, -1) - kappa0) > dtheta_tip_max) | ~ok.reshape(n_dir, -1)
    p_max = np.empty(n_dir)
    for i in range(n_dir):
        above = np.nonzero(beyond[i])[0]
        if above.size == 0:
            p_max[i] = load_cap
            continue
        j = above[0]
        lo = grid[j - 1] if j > 0 else 0.0
        p_max[i] = scipy.optimize.brentq(excess, lo, grid[j], args=(i,), xtol=1e-10, rtol=1e-12)
        if excess(p_max[i], i) > 0.5:  # Brent ended on the solver-failure side of the bracket
            p_max[i] = scipy.optimize.brentq(excess, lo, p_max[i], args=(i,), xtol=1e-10,
                                             rtol=1e-12) * (1 - 1e-9)
    P = p_max[:, None] * (np.arange(1, n_loads + 1) / n_loads)[None, :]
    forces = d[:, None, :] * P[..., None]
    x, y, _, _ = _tips(kappa0, forces.reshape(-1, 2))
    tip = np.stack([x, y], -1).reshape(n_dir, n_loads, 2)
    return dict(forces=forces, tip=tip, P_max=p_max, labels=labels)


def _load_range(load_range):
    unknown = set(load_range) - set(DEFAULT_LOAD_RANGE)
    if unknown:
        raise TypeError(f"unknown load-range options {sorted(unknown)}; "
                        f"allowed: {sorted(DEFAULT_LOAD_RANGE)}")
    lr = {**DEFAULT_LOAD_RANGE, **load_range}
    return (
        tuple(float(v) for v in lr["n_values"]),
        tuple(float(v) for v in lr["senses"]),
        float(lr["dtheta_tip_max"]),
        float(lr["load_cap"]),
        int(lr["n_loads"]),
    )


# ------------------------------------------------------------------------------------------------
# Error measures
# ------------------------------------------------------------------------------------------------


def _prb_angles(kappa0, gamma, tip):
    pivot_x = 1.0 - gamma
    dx, dy = tip[..., 0] - pivot_x, tip[..., 1]
    return np.hypot(dx, dy), np.arctan2(dy, dx)


def _tip_error(kappa0, gamma, rho, tip):
    r, _ = _prb_angles(kappa0, gamma, tip)
    return np.abs(r - rho)


def _torque_data(kappa0, gamma, samples):
    """(Theta - Theta_i, F_t) per sample, shape (n_dir, n_loads)."""
    _, theta_i = prb_geometry(kappa0, gamma)
    _, theta = _prb_angles(kappa0, gamma, samples["tip"])
    F = samples["forces"]
    f_t = -F[..., 0] * np.sin(theta) + F[..., 1] * np.cos(theta)
    return theta - theta_i, f_t, theta_i


def _errors(kappa0, gamma, rho, K_theta, samples) -> PRBError:
    e_tip = _tip_error(kappa0, gamma, rho, samples["tip"])
    dth, f_t, theta_i = _torque_data(kappa0, gamma, samples)
    # rho cancels in the relative torque error.
    e_load = np.abs(K_theta * dth - f_t) / np.max(np.abs(f_t), axis=1, keepdims=True)
    return PRBError(
        tip_error_max=float(e_tip.max()),
        tip_error_rms=float(np.sqrt(np.mean(e_tip**2))),
        load_error_max=float(e_load.max()),
        load_error_rms=float(np.sqrt(np.mean(e_load**2))),
        dtheta_max=float(np.abs(dth).max()),
        theta_i=float(theta_i),
    )


def _best_K_theta(kappa0, gamma, samples):
    dth, f_t, _ = _torque_data(kappa0, gamma, samples)
    return float(np.sum(f_t * dth) / np.sum(dth**2))


def _check_kappa0(kappa0):
    k = float(kappa0)
    if not np.isfinite(k):
        raise PPRError(f"kappa0 must be finite (got {k}).")
    return k


def fit_prb(kappa0: float, **load_range) -> PRBFit:
    """Fit gamma, rho, K_theta of an initially curved cantilever to the elastica.

    Args:
        kappa0: nondimensional initial curvature ``l/R`` (any finite value; the shipped table
            covers ``[0, 2]``). Concrete Python/numpy scalar (offline fit, not traceable).
        **load_range: overrides of :data:`DEFAULT_LOAD_RANGE`: ``n_values`` (Howell's force
            parameters), ``senses`` (+1 closing, -1 opening), ``dtheta_tip_max`` [rad],
            ``load_cap`` (max ``F l^2/EI``), ``n_loads`` (samples per direction).

    Returns:
        :class:`PRBFit` with ``gamma, rho, K_theta`` (``K = rho K_theta EI/l``), ``theta_i`` [rad]
        and the errors of the fitted model over the load range (docs/prb_fit.md, step 6).

    Takes about two seconds per ``kappa0`` after compilation (14 x 16 elastica solves, vmapped,
    plus the root searches of step 2).
    """
    kappa0 = _check_kappa0(kappa0)
    samples = _samples(kappa0, *_load_range(load_range))
    tip = samples["tip"]

    def objective(gamma):
        rho, _ = prb_geometry(kappa0, gamma)
        return _tip_error(kappa0, gamma, rho, tip).max()

    grid = np.arange(0.5, 1.0 + 1e-12, 0.002)
    vals = np.array([objective(g) for g in grid])
    i = int(np.argmin(vals))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    res = scipy.optimize.minimize_scalar(objective, bounds=(lo, hi), method="bounded",
                                         options=dict(xatol=1e-9))
    gamma = float(res.x) if res.fun <= vals[i] else float(grid[i])
    rho, _ = prb_geometry(kappa0, gamma)
    K_theta = _best_K_theta(kappa0, gamma, samples)
    err = _errors(kappa0, gamma, rho, K_theta, samples)
    return PRBFit(kappa0=kappa0, gamma=gamma, rho=float(rho), K_theta=K_theta, **err._asdict())


def prb_error(
    kappa0: float, gamma: float, rho: float | None = None, K_theta: float | None = None,
    **load_range,
) -> PRBError:
    """Errors of given PRB parameters against the elastica over the fit's load range.

    Args:
        kappa0: nondimensional initial curvature (concrete scalar).
        gamma: characteristic radius factor (pivot at ``(1 - gamma) l`` along the clamp tangent).
        rho: PRB link length / l; ``None``: Howell's geometric default for this ``gamma``.
        K_theta: stiffness coefficient (``K = rho K_theta EI/l``); ``None``: the least-squares
            optimum for this ``gamma`` (fit step 5).
        **load_range: as in :func:`fit_prb`.

    Returns:
        :class:`PRBError` (tip errors in units of ``l``; load errors relative, docs/prb_fit.md
            step 6).
    """
    kappa0 = _check_kappa0(kappa0)
    samples = _samples(kappa0, *_load_range(load_range))
    gamma = float(gamma)
    rho = float(prb_geometry(kappa0, gamma)[0]) if rho is None else float(rho)
    K_theta = _best_K_theta(kappa0, gamma, samples) if K_theta is None else float(K_theta)
    return _errors(kappa0, gamma, rho, K_theta, samples)
