"""Tests of ppr_jax.elastica against independent references.

References: the closed-form circular arc under a pure end moment; Mattiasson (1981), Table 1
(straight cantilever, tip force perpendicular to the undeformed beam, here ``force = (0, -F)``
so the tip deflects towards -y: ``v = -y_tip``); global moment balance; central finite
differences; a Python loop for vmap.
"""

import equinox as eqx  # noqa: E402
import jax
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from ppr_jax import PPRError, elastica  # noqa: E402
from tests.helpers import eqx_raise_mode, raises_in_compiled_code  # noqa: E402

L, EI = 1.7, 2.3  # deliberately not 1: checks the nondimensionalization


def _arc(L, curvature, s):
    """Closed-form circular arc from the clamp with the given (dimensional) curvature."""
    c = curvature
    if abs(c) < 1e-14:
        return s, 0 * s, 0 * s
    return np.sin(c * s) / c, (1 - np.cos(c * s)) / c, c * s


@pytest.mark.parametrize("kappa0", [0.0, 0.94, 2.0, -0.5])
@pytest.mark.parametrize("m_nd", [0.0, 0.3, -1.7, np.pi, 2 * np.pi])
def test_pure_moment_is_circular_arc(kappa0, m_nd):
    m = m_nd * EI / L
    sol = elastica.solve_cantilever(L, EI, kappa0, (0.0, 0.0), m)
    x, y, th = _arc(L, kappa0 / L + m / EI, np.asarray(sol.s))
    np.testing.assert_allclose(sol.x, x, rtol=0, atol=1e-10 * L)
    np.testing.assert_allclose(sol.y, y, rtol=0, atol=1e-10 * L)
    np.testing.assert_allclose(sol.theta, th, rtol=0, atol=1e-10)
    np.testing.assert_allclose(sol.moment, m, rtol=0, atol=1e-10 * EI / L)
    assert bool(sol.converged)


def test_zero_load_gives_initial_arc():
    for kappa0 in (0.0, 0.3, 1.5):
        sol = elastica.solve_cantilever(L, EI, kappa0)
        R = L / kappa0 if kappa0 else np.inf
        if kappa0:
            np.testing.assert_allclose(
                sol.tip, [R * np.sin(kappa0), R * (1 - np.cos(kappa0)), kappa0], atol=1e-12)
        else:
            np.testing.assert_allclose(sol.tip, [L, 0.0, 0.0], atol=1e-12)
        assert abs(float(sol.clamp_moment)) < 1e-12


# Mattiasson (1981) Table 1: load index alpha^2 = F L^2/EI -> (v/L, (L - x_tip)/L).
MATTIASSON = {1.0: (0.30172, 0.05643), 2.0: (0.49346, 0.16064), 5.0: (0.71379, 0.38763),
              10.0: (0.81061, 0.55500)}


@pytest.mark.parametrize("alpha2", sorted(MATTIASSON))
def test_mattiasson_table(alpha2):
    F = alpha2 * EI / L**2
    sol = elastica.solve_cantilever(L, EI, 0.0, (0.0, -F), 0.0)
    v, u = MATTIASSON[alpha2]
    # "to the 5 digits given": within half a unit of the 5th decimal.
    assert abs(-float(sol.tip_y) / L - v) <= 5e-6
    assert abs((L - float(sol.tip_x)) / L - u) <= 5e-6


def test_global_moment_balance():
    """M(0) = m - fx y(L) + fy x(L) for any load (independent of the shooting residual)."""
    fx, fy, m = 0.8, -1.9, 0.35
    sol = elastica.solve_cantilever(L, EI, 0.7, (fx, fy), m)
    np.testing.assert_allclose(sol.clamp_moment, m - fx * sol.tip_y + fy * sol.tip_x, atol=1e-12)
    assert abs(float(sol.residual)) < 1e-11


def _tip(p):
    length, ei, k0, fx, fy, m = p
    return elastica.solve_cantilever(length, ei, k0, (fx, fy), m).tip


@pytest.fixture(scope="module")
def p0():
    return jnp.array([1.3, 2.0, 0.7, 0.8, -2.5, 0.4])


@pytest.fixture(scope="module")
def jac_fd(p0):
    f = jax.jit(_tip)
    eps = 1e-5
    cols = [(f(p0.at[i].add(eps)) - f(p0.at[i].add(-eps))) / (2 * eps) for i in range(p0.size)]
    return np.stack(cols, axis=1)


@pytest.mark.parametrize("mode", ["fwd", "rev"])
def test_gradients_match_finite_differences(mode, p0, jac_fd):
    jac = (jax.jacfwd if mode == "fwd" else jax.jacrev)(_tip)
    J = jax.jit(jac)(p0)
    assert np.all(np.isfinite(J))
    np.testing.assert_allclose(J, jac_fd, rtol=1e-7, atol=1e-8)


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_vmap_equals_loop():
    F = jnp.linspace(-3.0, 4.0, 6)
    k0 = jnp.linspace(0.0, 1.5, 6)

    def one(f, k):
        return elastica.solve_cantilever(L, EI, k, (0.3 * f, f), 0.1 * f)

    batched = jax.vmap(one)(F, k0)
    assert batched.x.shape == (6, 101) and batched.tip.shape == (6, 3)
    for i in range(6):
        s = one(F[i], k0[i])
        np.testing.assert_allclose(batched.x[i], s.x, atol=1e-13)
        np.testing.assert_allclose(batched.theta[i], s.theta, atol=1e-13)
        np.testing.assert_allclose(batched.clamp_moment[i], s.clamp_moment, atol=1e-13)
    assert bool(jnp.all(batched.converged))


@pytest.mark.parametrize(
    "name,kwargs",
    [("length", dict(length=0.0)), ("length", dict(length=-1.0)), ("EI", dict(EI=-2.0))],
)
def test_bad_inputs_raise_eagerly(name, kwargs):
    args = dict(length=L, EI=EI, kappa0=0.5) | kwargs
    with pytest.raises(PPRError, match=rf"{name} must be > 0 \(allowed range \(0, inf\)\)"):
        elastica.solve_cantilever(**args)


def test_bad_inputs_raise_when_traced():
    f = jax.jit(lambda length, ei: elastica.solve_cantilever(length, ei, 0.5, (1.0, 0.0), 0.0).tip)
    with raises_in_compiled_code("length must be > 0"):
        jax.block_until_ready(f(-1.0, EI))
    with raises_in_compiled_code("EI must be > 0"):
        jax.block_until_ready(f(L, 0.0))


def test_non_convergence_is_reported():
    F = 1e3 * EI / L**2  # load index 1000: beyond the default continuation
    with pytest.raises(elastica.ElasticaConvergenceError, match=r"force=\(0.0, -") as info:
        elastica.solve_cantilever(L, EI, 0.0, (0.0, -F), 0.0)
    assert isinstance(info.value, PPRError) and isinstance(info.value, RuntimeError)
    sol = elastica.solve_cantilever(L, EI, 0.0, (0.0, -F), 0.0, throw=False)
    assert not bool(sol.converged)
    f = eqx.filter_jit(lambda F: elastica.solve_cantilever(L, EI, 0.0, (0.0, -F), 0.0).tip)
    # eqx.filter_jit re-raises eqx.error_if's failure as equinox's own runtime error
    with eqx_raise_mode(), pytest.raises(eqx.EquinoxRuntimeError,
                                         match="did not converge for this load"):
        jax.block_until_ready(f(F))


def test_curved_beam_oblique_load_vs_scipy():
    """Curved beam, oblique force + moment vs an independent shooting with scipy's DOP853."""
    from scipy.integrate import solve_ivp
    from scipy.optimize import brentq

    k0, fx, fy, m = 1.2, -1.5, 2.5, -0.4  # nondimensional (L = EI = 1 here)

    def shoot(mu0):
        def rhs(s, u):
            return [np.cos(u[2]), np.sin(u[2]), k0 + u[3], fx * np.sin(u[2]) - fy * np.cos(u[2])]

        return solve_ivp(rhs, (0, 1), [0, 0, 0, mu0], method="DOP853", rtol=1e-13,
                         atol=1e-13).y[:, -1]

    sol = elastica.solve_cantilever(L, EI, k0, (fx * EI / L**2, fy * EI / L**2), m * EI / L)
    mu0 = float(sol.clamp_moment) * L / EI
    mu0_ref = brentq(lambda mu: shoot(mu)[3] - m, mu0 - 0.2, mu0 + 0.2, xtol=1e-14)
    ref = shoot(mu0_ref)
    assert abs(mu0 - mu0_ref) < 1e-9
    np.testing.assert_allclose(np.asarray(sol.tip) / [L, L, 1.0], ref[:3], atol=1e-9)
