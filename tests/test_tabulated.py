"""The scenes' tabulated inputs (`ppr_jax._tabulated`): Hermite interpolation exact on the
polynomials it must reproduce, within its error bound on a smooth function, and the paper-circle
torques and servo-circle angles within 1e-9 of the exact inputs at random times, values and
derivatives, and differentiable in the parameters that made them."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ppr_jax as pj
from ppr_jax._tabulated import MIN_NODES, scene_nodes, tabulate

RNG = np.random.default_rng(0)
T = jnp.asarray(RNG.uniform(0.0, 2.0, 200))


@pytest.mark.parametrize("order, degree", [(1, 3), (2, 5)])
def test_reproduces_polynomials_exactly(order, degree):
    c = jnp.asarray(RNG.normal(size=degree + 1))

    def f(t):
        return jnp.polyval(c, t)[None]

    tab = tabulate(f, 0.0, 2.0, 7, order=order)
    np.testing.assert_allclose(jax.vmap(tab)(T), jax.vmap(f)(T), rtol=1e-12, atol=1e-12)
    # and the derivatives the integrator takes through it
    d_tab = jax.vmap(lambda t: pj.derivatives(tab, t)[2])(T)
    d_f = jax.vmap(lambda t: pj.derivatives(f, t)[2])(T)
    np.testing.assert_allclose(d_tab, d_f, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("order, bound", [(1, lambda h, w: h**4 / 384 * w**4),
                                          (2, lambda h, w: h**6 / 46080 * w**6)])
def test_error_within_bound(order, bound):
    w, n = 7.0, 41
    tab = tabulate(lambda t: jnp.sin(w * t)[None], 0.0, 2.0, n, order=order)
    err = float(jnp.max(jnp.abs(jax.vmap(tab)(T)[:, 0] - jnp.sin(w * T))))
    h = 2.0 / (n - 1)
    assert err <= bound(h, w)
    assert err >= 1e-3 * bound(h, w)  # the bound is tight, not vacuous: the grid matters


def test_scene_nodes():
    assert scene_nodes(100) == MIN_NODES
    assert scene_nodes(755) == 755
    assert scene_nodes(10_001) == 10_001


@pytest.fixture(scope="module")
def robot_and_inputs():
    robot = pj.Robot(pj.scene_params("paper-circle"))
    L1 = pj.Reduced()
    return (robot, pj.InverseDynamicsTorque(L1, robot, pj.Circle()),
            pj.InverseKinematicsAngles(L1, robot, pj.Circle()))


def test_paper_circle_torques(robot_and_inputs):
    _, tau, _ = robot_and_inputs
    ts = T * 3.77
    tab, exact = jax.jit(
        lambda ts: (jax.vmap(tabulate(tau, 0.0, 7.54, scene_nodes(755)))(ts), jax.vmap(tau)(ts))
    )(ts)
    assert float(jnp.max(jnp.abs(tab - exact))) <= 1e-9 * float(jnp.max(jnp.abs(exact)))


def test_servo_circle_angles_and_derivatives(robot_and_inputs):
    _, _, ang = robot_and_inputs
    ts = T * 3.77

    @jax.jit
    def both(ts):
        tab = tabulate(ang, 0.0, 7.54, scene_nodes(755), order=2)
        return (jax.vmap(lambda t: jnp.stack(pj.derivatives(tab, t)))(ts),
                jax.vmap(lambda t: jnp.stack(pj.derivatives(ang, t)))(ts))

    a, b = both(ts)
    # angle, rate, acceleration (two derivatives of the quintic lose a little to rounding)
    for k, rel in enumerate((1e-12, 1e-10, 1e-8)):
        assert float(jnp.max(jnp.abs(a[:, k] - b[:, k]))) <= rel * float(jnp.max(jnp.abs(b[:, k])))


def test_gradient_through_the_table():
    """d/dw of the tabulated sin(w t) is the exact t cos(w t) to interpolation accuracy, forward
    and reverse."""

    def f(w, t):
        return tabulate(lambda s: jnp.sin(w * s)[None], 0.0, 2.0, 201)(t)[0]

    w, t = 3.0, 1.2345
    exact = t * np.cos(w * t)
    assert abs(float(jax.grad(f)(w, t)) - exact) < 1e-8
    assert abs(float(jax.jvp(lambda w: f(w, t), (w,), (1.0,))[1]) - exact) < 1e-8


@pytest.mark.parametrize("order", [1, 2])
def test_error_estimate_is_the_error(order):
    """The table's own estimate (no extra evaluations) is within a factor 3 of its true error."""
    w = 7.0
    for n in (41, 161):
        tab = tabulate(lambda t: jnp.sin(w * t)[None], 0.0, 2.0, n, order=order)
        err = float(jnp.max(jnp.abs(jax.vmap(tab)(T)[:, 0] - jnp.sin(w * T))))
        est = float(tab.error_estimate())
        assert err / 3 <= est <= 3 * err, (n, err, est)


def test_coarse_table_falls_back_to_the_exact_input(robot_and_inputs):
    """400 s of L2 paper-circle with 401 output times would interpolate the torques on a 0.4 s
    grid (relative error ~1e-4): the scene's input is then the exact torque, not the table; on
    the scene's usual horizon it is the table."""
    from ppr_jax._tabulated import scene_input

    _, tau, _ = robot_and_inputs
    ts_ok, ts_coarse = jnp.linspace(0.0, 7.54, 755), jnp.linspace(0.0, 400.0, 401)

    @jax.jit
    def inputs(t):
        ok = scene_input(pj.Double1R(), tau, ts_ok, 1)
        coarse = scene_input(pj.Double1R(), tau, ts_coarse, 1)
        return ok.use_table, coarse.use_table, coarse(t), coarse.table(t), tau(t)

    use_ok, use_coarse, got, table, exact = inputs(123.456)
    assert bool(use_ok) and not bool(use_coarse)
    np.testing.assert_array_equal(got, exact)
    assert float(jnp.max(jnp.abs(table - exact))) > 1e-6 * float(jnp.max(jnp.abs(exact)))
    # L0/L1 are never tabulated
    assert scene_input(pj.Reduced(), tau, ts_ok, 1) is tau
