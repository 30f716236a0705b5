"""Tests of the PRB fit (ppr_jax._prb_fit) and its shipped table (ppr_jax._prb_table).

References: Howell & Midha's straight-beam values (gamma ~ 0.85, K_Theta ~ 2.65); the fit
recomputed from scratch vs the shipped table; the closed-form PRB geometry (rho, Theta_i);
scipy's not-a-knot CubicSpline for the interpolant; central finite differences for its derivative.
"""

import jax
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
import scipy.interpolate  # noqa: E402

from ppr_jax import (
    PPRError,  # noqa: E402
    _prb_fit as prb,  # noqa: E402
    _prb_table as tab,  # noqa: E402
)
from tests.helpers import raises_in_compiled_code  # noqa: E402


@pytest.fixture(scope="session")
def fit0():
    return prb.fit_prb(0.0)


def test_straight_beam_matches_howell(fit0):
    assert abs(fit0.gamma - 0.85) <= 0.02
    assert abs(fit0.K_theta - 2.65) <= 0.1
    assert fit0.rho == pytest.approx(fit0.gamma, abs=1e-14)  # straight beam: rho = gamma
    assert fit0.theta_i == 0.0
    assert fit0.tip_error_max < 0.02
    assert 0.6 < fit0.dtheta_max < 1.0  # the documented PRB deflection range


def test_per_direction_straight_beam_trend():
    """Howell's trend: tension (n < 0) moves the pivot towards the clamp (larger gamma)."""
    g = [prb.fit_prb(0.0, n_values=(n,), senses=(1.0,), n_loads=8).gamma for n in (-1.0, 0.0, 5.0)]
    assert g[0] > g[1] > g[2]
    assert abs(g[1] - 0.8517) < 0.015  # Howell, n = 0 (his criterion differs slightly from ours)


def test_table_loads_and_is_complete():
    t = tab.prb_table()
    assert "meta" in t and "load_range" in t["meta"]
    np.testing.assert_allclose(t["kappa0"], np.arange(21) * 0.1, atol=1e-12)
    for name in ("gamma", "rho", "K_theta", "tip_error_max", "load_error_max"):
        assert t[name].shape == (21,) and np.all(np.isfinite(t[name]))
    # rho and Theta_i are Howell's geometry for the tabulated gamma.
    rho, theta_i = tab.prb_geometry(t["kappa0"], t["gamma"])
    np.testing.assert_allclose(t["rho"], rho, atol=1e-12)
    np.testing.assert_allclose(t["theta_i"], theta_i, atol=1e-12)


def _assert_row_matches(fit, kappa0):
    t = tab.prb_table()
    i = int(round(kappa0 * 10))
    for name in ("gamma", "rho", "K_theta", "tip_error_max", "load_error_max"):
        assert getattr(fit, name) == pytest.approx(t[name][i], rel=1e-6, abs=1e-8), name


def test_table_row_kappa0_0_matches_fresh_fit(fit0):
    _assert_row_matches(fit0, 0.0)


@pytest.mark.parametrize("kappa0", [1.0, pytest.param(2.0, marks=pytest.mark.slow)])  # ~2 s each
def test_table_rows_match_fresh_fit(kappa0):
    _assert_row_matches(prb.fit_prb(kappa0), kappa0)


def test_prb_error_reproduces_fit(fit0):
    err = prb.prb_error(0.0, fit0.gamma, fit0.rho, fit0.K_theta)
    assert err.tip_error_max == pytest.approx(fit0.tip_error_max, rel=1e-12)
    assert err.load_error_max == pytest.approx(fit0.load_error_max, rel=1e-12)
    # gamma is the minimax optimum: moving it increases the max tip error.
    for dg in (-0.02, 0.02):
        assert prb.prb_error(0.0, fit0.gamma + dg).tip_error_max > fit0.tip_error_max
    # K_theta is the least-squares optimum: the default (None) equals it.
    assert prb.prb_error(0.0, fit0.gamma).load_error_rms == pytest.approx(fit0.load_error_rms,
                                                                          rel=1e-12)


def test_interpolant_reproduces_nodes():
    t = tab.prb_table()
    g, r, K = jax.jit(tab.prb_parameters)(jnp.asarray(t["kappa0"]))
    np.testing.assert_allclose(g, t["gamma"], atol=1e-12)
    np.testing.assert_allclose(r, t["rho"], atol=1e-12)
    np.testing.assert_allclose(K, t["K_theta"], atol=1e-12)


@pytest.mark.parametrize("name", ["gamma", "K_theta"])
def test_spline_matches_scipy_not_a_knot(name):
    """The numpy not-a-knot spline (no scipy at runtime) equals scipy's CubicSpline (default bc)."""
    t = tab.prb_table()
    ref = scipy.interpolate.CubicSpline(t["kappa0"], t[name])
    knots, coef = tab._splines()
    np.testing.assert_allclose(knots, ref.x, rtol=0, atol=0)
    np.testing.assert_allclose(coef[name], ref.c, rtol=0, atol=1e-12 * np.abs(ref.c).max())
    k = np.concatenate([np.linspace(0.0, 2.0, 2001),
                        np.random.default_rng(0).uniform(0.0, 2.0, 500)])
    g, _, K = tab.prb_parameters(k)
    value = {"gamma": g, "K_theta": K}[name]
    np.testing.assert_allclose(value, ref(k), rtol=0, atol=1e-12)
    # Its derivative (autodiff through the JAX evaluation) is the spline's derivative.
    i = {"gamma": 0, "K_theta": 2}[name]
    dk = jax.vmap(jax.grad(lambda x: tab.prb_parameters(x)[i]))(jnp.asarray(k))
    np.testing.assert_allclose(dk, ref(k, 1), rtol=0, atol=1e-11)


@pytest.mark.parametrize("n", [4, 5, 9, 40])
def test_not_a_knot_spline_on_uneven_nodes(n):
    """The spline solver itself, on uneven nodes and rough data, against scipy."""
    rng = np.random.default_rng(n)
    x = np.cumsum(rng.uniform(0.05, 1.0, n))
    y = rng.normal(size=n)
    ref = scipy.interpolate.CubicSpline(x, y)
    c = tab._not_a_knot_coefficients(x, y)
    np.testing.assert_allclose(c, ref.c, rtol=0, atol=1e-12 * np.abs(ref.c).max())
    xs = np.linspace(x[0], x[-1], 1000)
    ys = tab._spline_eval(x, c, jnp.asarray(xs))
    np.testing.assert_allclose(ys, ref(xs), rtol=0, atol=1e-12 * np.abs(y).max())


@pytest.mark.parametrize("kappa0", [0.05, 0.37, 0.94, 1.55, 1.98])
def test_interpolant_gradient_matches_finite_differences(kappa0):
    def f(k):
        return jnp.stack(tab.prb_parameters(k))

    d_rev = jax.jit(jax.jacrev(f))(kappa0)
    d_fwd = jax.jit(jax.jacfwd(f))(kappa0)
    eps = 1e-6
    d_fd = (f(kappa0 + eps) - f(kappa0 - eps)) / (2 * eps)
    np.testing.assert_allclose(d_rev, d_fd, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(d_fwd, d_fd, rtol=1e-6, atol=1e-8)


def test_interpolant_is_smooth_between_nodes():
    """C1 across a node: left and right derivatives agree."""
    f = jax.grad(lambda k: tab.prb_parameters(k)[0])
    for node in (0.5, 1.0, 1.5):
        assert float(f(node - 1e-9)) == pytest.approx(float(f(node + 1e-9)), abs=1e-6)


def test_interpolant_out_of_range():
    with pytest.raises(PPRError, match=r"kappa0 must lie in \[0.0, 2.0\]"):
        tab.prb_parameters(2.5)
    with pytest.raises(PPRError, match=r"kappa0 must lie in"):
        tab.prb_parameters(-0.1)
    with raises_in_compiled_code(r"kappa0 must lie in"):
        jax.block_until_ready(jax.jit(tab.prb_parameters)(2.5))
