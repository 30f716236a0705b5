import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ppr_jax as pj


def test_defaults_match_table1(params):
    assert float(params.a) == 0.9 and float(params.h) == 0.08 and float(params.t) == 0.3e-3
    assert float(params.theta_c) == 1.88 and params.sigma == -1
    assert params.a.dtype == jnp.float64


def test_derived_by_hand(params):
    dv = pj.derived(params.replace(gamma=0.81, K_theta=2.5))
    # Independent hand computation of MODEL.md section 3 with numpy.
    r_i = 0.02 + 0.023 / 2
    l_h = r_i * 1.88 / 2
    k0 = 0.94
    a_i, b_i = r_i * np.sin(k0), r_i * (1 - np.cos(k0))
    s = 0.19 * l_h
    Th_i = np.arctan2(b_i, a_i - s)
    rho = np.hypot(a_i - s, b_i) / l_h
    Th_0 = 2 * Th_i + np.pi - 1.88
    I = 0.026 * 0.3e-3**3 / 12
    L = 0.02 * 1.88
    np.testing.assert_allclose(float(dv.r_i), r_i, rtol=1e-15)
    np.testing.assert_allclose(float(dv.kappa0), k0, rtol=1e-15)
    np.testing.assert_allclose(float(dv.rho), rho, rtol=1e-14)
    np.testing.assert_allclose(float(dv.Theta_0), Th_0, rtol=1e-14)
    np.testing.assert_allclose(float(dv.K), 2 * 71e9 * I * rho * 2.5 / L, rtol=1e-14)
    np.testing.assert_allclose(float(dv.K0), 71e9 * I / L, rtol=1e-14)
    np.testing.assert_allclose(float(dv.r2), 2 * r_i * np.sin(k0) - 2 * s * np.cos(k0), rtol=1e-13)
    np.testing.assert_allclose(float(dv.r1), 0.366 + s, rtol=1e-15)
    np.testing.assert_allclose(float(dv.R1), 0.366 + r_i * np.tan(0.94), rtol=1e-15)
    np.testing.assert_allclose(float(dv.m4), 2780 * np.sqrt(3) / 4 * 0.08**2 * 0.025, rtol=1e-14)


def test_default_prb_parameters_come_from_the_elastica_table(params, dv):
    from ppr_jax._prb_table import prb_parameters

    g, rho, K = prb_parameters(0.94)
    assert float(dv.gamma) == float(g) and float(dv.K_theta) == float(K)
    np.testing.assert_allclose(float(dv.rho), float(rho), rtol=1e-13)
    assert 0.80 < float(g) < 0.86 and 2.4 < float(K) < 2.9


def test_psi0_independent_of_prb_parameters(params):
    g = jax.grad(lambda g_: pj.derived(params.replace(gamma=g_)).psi0)(0.81)
    gk = jax.grad(lambda th: pj.derived(params.replace(theta_c=th)).s)(1.88)
    assert np.isfinite(float(gk)) and float(gk) != 0.0  # table-derived gamma is differentiable
    assert float(g) == 0.0
    assert float(pj.derived(params.replace(gamma=0.9, rho=0.7)).psi0) == pytest.approx(0.94)


def test_explicit_rho_overrides(params):
    assert float(pj.derived(params.replace(rho=0.9)).rho) == 0.9


@pytest.mark.parametrize(
    "name,value", [("t", -0.3e-3), ("E", 0.0), ("theta_c", 4.0), ("gamma", 1.5), ("a", float("nan"))]
)
def test_out_of_range_parameter_names_parameter_and_range(name, value):
    with pytest.raises(ValueError, match=rf"'{name}'.*range \["):
        pj.RobotParams(**{name: value})


def test_unknown_parameter_and_bad_sigma(params):
    with pytest.raises(ValueError, match="unknown parameter"):
        params.replace(thickness=1.0)
    with pytest.raises(ValueError, match="sigma"):
        pj.RobotParams(sigma=0)


def test_stack_and_traced_validation(params):
    """Under jit and vmap a parameter out of range is a status (no host callback), per member."""
    import equinox as eqx

    from ppr_jax._params import params_invalid

    batch = pj.stack_params([params, params.replace(t=0.5e-3)])
    assert batch.t.shape == (2,)
    bad = eqx.tree_at(lambda p: p.t, params, jnp.asarray(-1.0))
    nan = eqx.tree_at(lambda p: p.E, params, jnp.asarray(jnp.nan))
    f = jax.jit(jax.vmap(params_invalid))
    mixed = jax.tree_util.tree_map(lambda *x: jnp.stack(x), params, bad, nan, params)
    np.testing.assert_array_equal(np.asarray(f(mixed)), [False, True, True, False])
