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


def test_batch_decides_once_for_all_members():
    """Under vmap the table-or-exact choice is one unbatched decision (a batched lax.cond would
    run both branches): the table when every member's is fine, the exact input for all when any
    member's table is too coarse; each member's value is still its own."""
    from ppr_jax._tabulated import TableOrExact

    def member(w, t):
        fn = lambda t: jnp.sin(w * t)[None]  # noqa: E731
        tox = TableOrExact(tabulate(fn, 0.0, 2.0, 161, order=1), fn)
        return tox.use_table, tox(t), tox.table(t), fn(t)

    t = 1.2345
    use, got, table, exact = jax.vmap(member, (0, None))(jnp.array([1.0, 2.0]), t)
    assert use.shape == (2,) and bool(use.all())  # the decision came back unbatched, broadcast
    np.testing.assert_allclose(got, table, rtol=1e-14)
    assert float(jnp.max(jnp.abs(table - exact))) > 0  # the table is not the exact input
    use, got, table, exact = jax.vmap(member, (0, None))(jnp.array([1.0, 300.0]), t)
    assert not bool(use.any())
    np.testing.assert_allclose(got, exact, rtol=1e-14)
    # a cond survives in the batched program (a batched predicate turns it into a select)
    assert "cond[" in str(jax.make_jaxpr(jax.vmap(member, (0, None)))(jnp.array([1.0, 2.0]), t))


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
