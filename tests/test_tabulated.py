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


@pytest.mark.parametrize("D", ["exact", "differences"])
@pytest.mark.parametrize("order, degree", [(1, 3), (2, 5)])
def test_reproduces_polynomials_exactly(order, degree, D):
    """Both ways of taking the nodes' derivatives: forward mode, and central differences (exact
    up to degree 6)."""
    c = jnp.asarray(RNG.normal(size=degree + 1))

    def f(t):
        return jnp.polyval(c, t)[None]

    tab = tabulate(f, 0.0, 2.0, 7, order=order, derivatives=D)
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
    # 60 per radian where the motion's extent is known, in powers of two times the minimum
    assert scene_nodes(100, 6.0) == MIN_NODES
    assert scene_nodes(100, 10.0) == 2 * MIN_NODES
    assert scene_nodes(3000, 10.0) == 2 * MIN_NODES  # the horizon decides, not the outputs


@pytest.fixture(scope="module")
def robot_and_inputs():
    robot = pj.Robot(pj.scene_params("paper-circle"))
    L1 = pj.Reduced()
    return (robot, pj.InverseDynamicsTorque(L1, robot, pj.Circle()),
            pj.InverseKinematicsAngles(L1, robot, pj.Circle()))


@pytest.mark.parametrize("D", ["exact", "differences"])
def test_paper_circle_torques(robot_and_inputs, D):
    _, tau, _ = robot_and_inputs
    ts = T * 3.77
    tab, exact = jax.jit(
        lambda ts: (jax.vmap(tabulate(tau, 0.0, 7.54, scene_nodes(755), derivatives=D))(ts),
                    jax.vmap(tau)(ts))
    )(ts)
    assert float(jnp.max(jnp.abs(tab - exact))) <= 1e-9 * float(jnp.max(jnp.abs(exact)))


@pytest.mark.parametrize("D", ["exact", "differences"])
def test_servo_circle_angles_and_derivatives(robot_and_inputs, D):
    _, _, ang = robot_and_inputs
    ts = T * 3.77

    @jax.jit
    def both(ts):
        tab = tabulate(ang, 0.0, 7.54, scene_nodes(755), order=2, derivatives=D)
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


def test_long_horizon_gets_more_nodes_and_a_coarse_table_is_flagged(robot_and_inputs):
    """400 s of L2 paper-circle with 401 output times: on the minimum grid (512 nodes, 0.78 s
    apart) the torques interpolate to about 1e-4 and the table is flagged as too coarse (the
    scene then fails with `RESULTS.input_table_too_coarse`); with the horizon known the scene
    takes enough nodes (60 per radian of the circle, rounded up to 512 times a power of two) and
    the table is fine and accurate. On the scene's usual horizon the minimum suffices."""
    from ppr_jax._scenes import input_nodes
    from ppr_jax._tabulated import NODES_PER_RADIAN, input_too_coarse, scene_input

    _, tau, _ = robot_and_inputs
    circle = pj.Circle()
    n_long = input_nodes(circle, 400.0, 401)
    assert n_long >= NODES_PER_RADIAN * 400.0 * 5 / 6 and n_long / MIN_NODES == 64
    assert input_nodes(circle, 7.54, 755) == MIN_NODES and input_nodes(circle, 7.54, 11) == MIN_NODES
    ts_ok, ts_long = jnp.linspace(0.0, 7.54, 755), jnp.linspace(0.0, 400.0, 401)
    t = jnp.linspace(100.0, 101.0, 7)

    @jax.jit
    def inputs():
        ok = scene_input(tau, ts_ok, 1)
        coarse = scene_input(tau, ts_long, 1)
        fine = scene_input(tau, ts_long, 1, n_long)
        return (input_too_coarse(ok), input_too_coarse(coarse), input_too_coarse(fine),
                jax.vmap(coarse)(t), jax.vmap(fine)(t), jax.vmap(tau)(t))

    c_ok, c_coarse, c_fine, coarse, fine, exact = inputs()
    assert not bool(c_ok) and bool(c_coarse) and not bool(c_fine)
    scale = float(jnp.max(jnp.abs(exact)))
    assert float(jnp.max(jnp.abs(coarse - exact))) > 1e-6 * scale
    assert float(jnp.max(jnp.abs(fine - exact))) < 1e-9 * scale
    assert input_too_coarse(tau) is None  # an exact input: nothing to check


# ---------------------------------------------------------------------------------------------
# The spline through measured samples (identification with measured actuated angles)
# ---------------------------------------------------------------------------------------------


def test_spline_pieces_cubic_exact_smooth_fourth_order_and_padding():
    """`spline_pieces` + `PiecewiseCubic`: a cubic is reproduced with its derivatives
    (not-a-knot); sin(3 t) sampled at h is within 5 h^4 |f''''| / 384 (the clamped-spline bound,
    loosened 5 times for not-a-knot's ends) and the error falls about 16 times when h halves;
    before the samples the first piece continues, after them a C1 linear continuation."""
    from ppr_jax._trajectory import PiecewiseCubic, spline_pieces

    c = RNG.normal(size=4)
    ts = np.linspace(0.2, 2.0, 13)
    grid = np.concatenate([[0.0], ts, 2.0 + 0.15 * np.arange(1, 4)])
    ys = np.polyval(c, ts)[:, None] * np.array([1.0, -2.0])
    f = PiecewiseCubic(jnp.asarray(grid), jnp.asarray(spline_pieces(grid, ts, ys)))
    t = jnp.asarray(RNG.uniform(0.0, 2.0, 50))
    exact = np.polyval(c, np.asarray(t))[:, None] * np.array([1.0, -2.0])
    np.testing.assert_allclose(jax.vmap(f)(t), exact, rtol=1e-11, atol=1e-11)
    dd = jax.vmap(lambda t: pj.derivatives(f, t)[2])(t)
    np.testing.assert_allclose(dd, np.polyval(np.polyder(c, 2), np.asarray(t))[:, None]
                               * np.array([1.0, -2.0]), rtol=1e-9, atol=1e-9)
    # padding: value and slope continue from the end, no curvature
    y2, v2 = np.polyval(c, 2.0), np.polyval(np.polyder(c), 2.0)
    x, xd, xdd = pj.derivatives(f, 2.3)
    np.testing.assert_allclose(x[0], y2 + 0.3 * v2, rtol=1e-11)
    np.testing.assert_allclose(xd[0], v2, rtol=1e-11)
    assert float(xdd[0]) == 0.0

    errs = []
    for n in (41, 81):
        ts = np.linspace(0.0, 2.0, n)
        g = PiecewiseCubic(jnp.asarray(ts), jnp.asarray(spline_pieces(ts, ts, np.sin(3 * ts)[:, None])))
        tt = np.linspace(0.0, 2.0, 2001)
        errs.append(float(np.max(np.abs(np.asarray(jax.vmap(g)(jnp.asarray(tt)))[:, 0]
                                        - np.sin(3 * tt)))))
        h = 2.0 / (n - 1)
        assert errs[-1] < 5 * h ** 4 * 81 / 384, (n, errs[-1])
    assert 10 < errs[0] / errs[1] < 24, errs
