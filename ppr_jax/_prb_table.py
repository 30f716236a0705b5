"""The shipped PRB table of initially curved cantilevers and its JAX interpolant.

Runtime half of the PRB parameters: :func:`prb_table` loads ``ppr_jax/data/prb_table.json`` and
:func:`prb_parameters` interpolates it (traceable, differentiable). Needs only numpy and JAX; the
offline fit that produced the table (:mod:`ppr_jax._prb_fit`, elastica + scipy) is not imported.
The PRB model, the fitting procedure and the table are described in ``docs/prb_fit.md``.

Nondimensional: beam length ``l = 1``, ``kappa0 = l/R`` the initial curvature. PRB geometry
(Howell): pivot at ``((1 - gamma) l, 0)`` in the clamp tangent frame, unloaded tip
``(a_i, b_i) = (R sin kappa0, R (1 - cos kappa0))``, ``rho = |(a_i - (1-gamma) l, b_i)|/l`` and rest
PRB angle ``Theta_i = atan2(b_i, a_i - (1-gamma) l)``.
"""

from __future__ import annotations

import functools  # noqa: E402
import importlib.resources  # noqa: E402
import json  # noqa: E402

import equinox as eqx  # noqa: E402
import jax
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from ._errors import PPRError

__all__ = ["KAPPA0_RANGE", "prb_parameters", "prb_table"]

#: Table domain of kappa0.
KAPPA0_RANGE = (0.0, 2.0)


# ------------------------------------------------------------------------------------------------
# PRB geometry
# ------------------------------------------------------------------------------------------------


def _arc_tip(kappa0):
    """Unloaded tip (a_i, b_i)/l of the arc; stable (and smooth) at kappa0 = 0. Works on jnp/np."""
    xp = jnp if isinstance(kappa0, jax.Array) else np
    a = xp.sinc(kappa0 / np.pi)  # sin(k)/k
    b = 0.5 * kappa0 * xp.sinc(kappa0 / (2 * np.pi)) ** 2  # (1 - cos k)/k
    return a, b


def prb_geometry(kappa0, gamma):
    """(rho_default, Theta_i) for given kappa0, gamma (numpy or jax)."""
    xp = jnp if isinstance(kappa0, jax.Array) or isinstance(gamma, jax.Array) else np
    a, b = _arc_tip(kappa0)
    dx = a - (1.0 - gamma)
    return xp.sqrt(dx**2 + b**2), xp.arctan2(b, dx)


# ------------------------------------------------------------------------------------------------
# Shipped table and its interpolant
# ------------------------------------------------------------------------------------------------


@functools.lru_cache(maxsize=1)
def prb_table() -> dict:
    """The shipped PRB table (``ppr_jax/data/prb_table.json``), cached.

    Returns a dict with ``meta`` (procedure, load range, error measures) and one numpy array per
    column: ``kappa0, gamma, rho, K_theta, theta_i, tip_error_max, tip_error_rms,
    load_error_max, load_error_rms, dtheta_max``. Treat it as read-only.
    """
    text = (importlib.resources.files("ppr_jax") / "data" / "prb_table.json").read_text()
    raw = json.loads(text)
    out = {"meta": raw["meta"]}
    for k in raw["columns"]:
        out[k] = np.asarray(raw[k], dtype=np.float64)
    return out


def _not_a_knot_coefficients(x, y):
    """Coefficients ``c (4, n-1)`` of the not-a-knot cubic spline through ``(x, y)`` (numpy).

    On interval ``i`` the spline is ``sum_m c[m, i] (t - x_i)^(3-m)`` (the layout of
    ``scipy.interpolate.CubicSpline(x, y).c``, which it reproduces to rounding). Unknowns are the
    node slopes ``s``: C2 continuity at the interior nodes, and continuity of the third derivative
    at ``x_1`` and ``x_{n-2}`` (not-a-knot) as the two end conditions. Needs ``n >= 4`` nodes.
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    n = x.shape[0]
    if n < 4 or y.shape != x.shape:
        raise PPRError("not-a-knot spline needs at least 4 nodes and y of the same shape as x")
    h = np.diff(x)
    if not np.all(h > 0):
        raise PPRError("spline nodes must be strictly increasing")
    d = np.diff(y) / h  # secant slopes
    A = np.zeros((n, n))
    r = np.zeros(n)
    i = np.arange(1, n - 1)
    A[i, i - 1] = h[i]
    A[i, i] = 2 * (h[i - 1] + h[i])
    A[i, i + 1] = h[i - 1]
    r[i] = 3 * (h[i] * d[i - 1] + h[i - 1] * d[i])
    w = h[0] + h[1]
    A[0, 0], A[0, 1] = h[1], w
    r[0] = ((h[0] + 2 * w) * h[1] * d[0] + h[0] ** 2 * d[1]) / w
    w = h[-1] + h[-2]
    A[-1, -2], A[-1, -1] = w, h[-2]
    r[-1] = (h[-1] ** 2 * d[-2] + (2 * w + h[-1]) * h[-2] * d[-1]) / w
    s = np.linalg.solve(A, r)
    t = (s[:-1] + s[1:] - 2 * d) / h
    return np.stack([t / h, (d - s[:-1]) / h - t, s[:-1], y[:-1]])


@functools.lru_cache(maxsize=1)
def _splines():
    t = prb_table()
    k = t["kappa0"]
    # Not-a-knot cubic splines (C2); coefficients c[m, i] of (kappa0 - k_i)^(3-m) on interval i.
    # numpy (not jnp) so that the cache never holds arrays created under a trace.
    coef = {name: _not_a_knot_coefficients(k, t[name]) for name in ("gamma", "K_theta")}
    return np.asarray(k), coef


def _spline_eval(knots, c, x, xp=jnp):
    knots, c = xp.asarray(knots), xp.asarray(c)
    i = xp.clip(xp.searchsorted(knots, x, side="right") - 1, 0, knots.shape[0] - 2)
    t = x - knots[i]
    return ((c[0, i] * t + c[1, i]) * t + c[2, i]) * t + c[3, i]


def prb_parameters(kappa0):
    """PRB parameters ``(gamma, rho, K_theta)`` at ``kappa0``, interpolated from the shipped table.

    ``gamma`` and ``K_theta`` are not-a-knot cubic splines (C2) through the table nodes; ``rho`` is
    Howell's geometric value for the interpolated ``gamma`` (so it equals the table's ``rho`` at
    the nodes and stays consistent with ``Theta_i``). JAX-traceable and differentiable in
    ``kappa0`` (scalar or any shape; outputs have its shape).

    Raises:
        ValueError: ``kappa0`` concrete and outside ``[0, 2]`` (the table's range).
        equinox runtime error (``eqx.error_if``): the same when traced.
    """
    lo, hi = KAPPA0_RANGE
    tol = 1e-12
    try:
        k_np = np.asarray(kappa0, dtype=np.float64)
    except (jax.errors.JAXTypeError, TypeError):
        k_np = None
    if k_np is not None:
        _check_range(k_np)
    k = jnp.asarray(kappa0, jnp.float64)
    k = eqx.error_if(
        k,
        ~((k >= lo - tol) & (k <= hi + tol)),
        f"prb_parameters: kappa0 must lie in [{lo}, {hi}] (the PRB table's range).",
    )
    knots, coef = _splines()
    gamma = _spline_eval(knots, coef["gamma"], k)
    K_theta = _spline_eval(knots, coef["K_theta"], k)
    rho, _ = prb_geometry(k, gamma)
    return gamma, rho, K_theta


def prb_parameters_numpy(kappa0):
    """`prb_parameters` for concrete values, in numpy (numpy arrays, no compiled program)."""
    k = _check_range(np.asarray(kappa0, dtype=np.float64))
    knots, coef = _splines()
    gamma = _spline_eval(knots, coef["gamma"], k, np)
    K_theta = _spline_eval(knots, coef["K_theta"], k, np)
    rho, _ = prb_geometry(k, gamma)
    return gamma, rho, K_theta


def _check_range(k):
    lo, hi = KAPPA0_RANGE
    if not np.all((k >= lo - 1e-12) & (k <= hi + 1e-12)):
        raise PPRError(f"prb_parameters: kappa0 must lie in [{lo}, {hi}] (the PRB table's range); "
                       f"got {k}.")
    return k
