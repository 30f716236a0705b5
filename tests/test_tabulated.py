"""The scenes' tabulated inputs (`ppr_jax._tabulated`): piecewise Chebyshev interpolation exact
on the polynomials it must reproduce, converging geometrically on a smooth function with an
error estimate that bounds the error without being vacuous, the paper-circle torques and
servo-circle angles within 1e-11 of the exact inputs at random times, values and derivatives,
the reach check taken from the table's nodes, and differentiable in the parameters that made
them."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ppr_jax as pj
from ppr_jax._tabulated import MIN_PANELS, PANEL_NODES, scene_panels, tabulate

RNG = np.random.default_rng(0)
T = jnp.asarray(RNG.uniform(0.0, 2.0, 200))


@pytest.mark.parametrize("panels", [1, 3])
def test_reproduces_polynomials_exactly(panels):
    """A polynomial of degree PANEL_NODES - 1 is reproduced with its first two derivatives (the
    ones the integrator takes through a table of prescribed angles)."""
    c = jnp.asarray(RNG.normal(size=PANEL_NODES)) / 2.0**np.arange(PANEL_NODES)

    def f(t):
        return jnp.stack([jnp.polyval(c, t), -2.0 * jnp.polyval(c, t)])

    tab = tabulate(f, 0.0, 2.0, panels)
    # to rounding, relative to the largest value (a degree-15 polynomial spans many magnitudes)
    for k, rel in ((0, 1e-12), (1, 1e-10), (2, 1e-8)):
        d_tab = jax.vmap(lambda t: pj.derivatives(tab, t)[k])(T)
        d_f = jax.vmap(lambda t: pj.derivatives(f, t)[k])(T)
        np.testing.assert_allclose(d_tab, d_f, rtol=0, atol=rel * float(jnp.max(jnp.abs(d_f))))


def _sin_error(w, panels):
    tab = tabulate(lambda t: jnp.sin(w * t)[None], 0.0, 2.0, panels)
    err = float(jnp.max(jnp.abs(jax.vmap(tab)(T)[:, 0] - jnp.sin(w * T))))
    return err, float(tab.error_estimate())


def test_geometric_convergence_and_the_estimate_bounds_the_error():
    """sin(w t): the error falls by orders of magnitude as the panels shrink (degree 15 on each:
    for an analytic function much faster than any fixed power of the panel length), and the
    table's own estimate (its highest coefficients, no extra evaluations) lies above the error
    but within a factor 1,000 of it."""
    w = 20.0
    errs = []
    for panels in (2, 4, 8):
        err, est = _sin_error(w, panels)
        errs.append(err)
        assert err <= est <= 1e3 * max(err, 1e-15), (panels, err, est)
    assert errs[0] > 1e-4 and errs[1] < 1e-3 * errs[0] and errs[2] < 1e-11


def test_scene_panels():
    assert scene_panels(100) == MIN_PANELS
    assert scene_panels(755) == -(-755 // PANEL_NODES)  # about one node per output time
    # one panel per radian where the motion's extent is known, in powers of two times the minimum
    assert scene_panels(100, 6.0) == MIN_PANELS
    assert scene_panels(100, 10.0) == 2 * MIN_PANELS
    assert scene_panels(3000, 10.0) == 2 * MIN_PANELS  # the horizon decides, not the outputs


@pytest.fixture(scope="module")
def robot_and_inputs():
    robot = pj.Robot(pj.scene_params("paper-circle"))
    L1 = pj.Reduced()
    return (robot, pj.InverseDynamicsTorque(L1, robot, pj.Circle()),
            pj.InverseKinematicsAngles(L1, robot, pj.Circle()))


def test_paper_circle_torques(robot_and_inputs):
    from ppr_jax._scenes import input_panels

    _, tau, _ = robot_and_inputs
    ts = T * 3.77
    tab, exact = jax.jit(
        lambda ts: (jax.vmap(tabulate(tau, 0.0, 7.54, input_panels(pj.Circle(), 7.54, 755)))(ts),
                    jax.vmap(tau)(ts))
    )(ts)
    assert float(jnp.max(jnp.abs(tab - exact))) <= 1e-11 * float(jnp.max(jnp.abs(exact)))


def test_servo_circle_angles_and_derivatives(robot_and_inputs):
    from ppr_jax._scenes import input_panels

    _, _, ang = robot_and_inputs
    ts = T * 3.77

    @jax.jit
    def both(ts):
        tab = tabulate(ang, 0.0, 7.54, input_panels(pj.Circle(), 7.54, 755))
        return (jax.vmap(lambda t: jnp.stack(pj.derivatives(tab, t)))(ts),
                jax.vmap(lambda t: jnp.stack(pj.derivatives(ang, t)))(ts))

    a, b = both(ts)
    # angle, rate, acceleration (each derivative of the polynomial loses a little to rounding)
    for k, rel in enumerate((1e-13, 1e-11, 1e-8)):
        assert float(jnp.max(jnp.abs(a[:, k] - b[:, k]))) <= rel * float(jnp.max(jnp.abs(b[:, k])))


def test_reach_check_from_the_table_nodes(robot_and_inputs):
    """The residual the table returns at its nodes is the inverse kinematics' own: zero on the
    paper's circle, metres for a base too wide for the chains (a = 3 m)."""
    from ppr_jax._tabulated import scene_input

    robot, _, _ = robot_and_inputs
    wide = pj.Robot(pj.scene_params("paper-circle", a=3.0))
    ts = jnp.linspace(0.0, 7.54, 755)
    for r, lo, hi in ((robot, 0.0, 1e-12), (wide, 0.5, 10.0)):
        for fn in (pj.InverseDynamicsTorque(pj.Reduced(), r, pj.Circle()),
                   pj.InverseKinematicsAngles(pj.Reduced(), r, pj.Circle())):
            _, resid = scene_input(fn.with_residual, ts, aux=True)
            assert resid.shape == ((scene_panels(755) + 1) * PANEL_NODES,)  # + the pre-start panel
            assert lo <= float(jnp.max(resid)) <= hi


def test_gradient_through_the_table():
    """d/dw of the tabulated sin(w t) is the exact t cos(w t) to interpolation accuracy, forward
    and reverse."""

    def f(w, t):
        return tabulate(lambda s: jnp.sin(w * s)[None], 0.0, 2.0, 4)(t)[0]

    w, t = 3.0, 1.2345
    exact = t * np.cos(w * t)
    assert abs(float(jax.grad(f)(w, t)) - exact) < 1e-10
    assert abs(float(jax.jvp(lambda w: f(w, t), (w,), (1.0,))[1]) - exact) < 1e-10


def test_long_horizon_gets_more_panels_and_a_coarse_table_is_flagged(robot_and_inputs):
    """400 s of L2 paper-circle with 401 output times: on the minimum grid (8 panels of 50 s,
    42 rad of the circle each) the torques do not interpolate and the table is flagged as too
    coarse (the scene then fails with `RESULTS.input_table_too_coarse`); with the horizon known
    the scene takes enough panels (one per radian of the circle, rounded up to 8 times a power of
    two) and the table is fine and accurate. On the scene's usual horizon the minimum
    suffices."""
    from ppr_jax._scenes import input_panels
    from ppr_jax._tabulated import PANEL_RADIANS, input_too_coarse, scene_input

    _, tau, _ = robot_and_inputs
    circle = pj.Circle()
    p_long = input_panels(circle, 400.0, 401)
    assert p_long >= 400.0 * 5 / 6 / PANEL_RADIANS and p_long / MIN_PANELS == 64
    assert input_panels(circle, 7.54, 755) == MIN_PANELS
    assert input_panels(circle, 7.54, 11) == MIN_PANELS
    ts_ok, ts_long = jnp.linspace(0.0, 7.54, 755), jnp.linspace(0.0, 400.0, 401)
    t = jnp.linspace(100.0, 101.0, 7)

    @jax.jit
    def inputs():
        ok = scene_input(tau, ts_ok)
        coarse = scene_input(tau, ts_long)
        fine = scene_input(tau, ts_long, p_long)
        return (input_too_coarse(ok), input_too_coarse(coarse), input_too_coarse(fine),
                jax.vmap(coarse)(t), jax.vmap(fine)(t), jax.vmap(tau)(t))

    c_ok, c_coarse, c_fine, coarse, fine, exact = inputs()
    assert not bool(c_ok) and bool(c_coarse) and not bool(c_fine)
    scale = float(jnp.max(jnp.abs(exact)))
    assert float(jnp.max(jnp.abs(coarse - exact))) > 1e-6 * scale
    assert float(jnp.max(jnp.abs(fine - exact))) < 1e-11 * scale
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
        g = PiecewiseCubic(jnp.asarray(ts),
                           jnp.asarray(spline_pieces(ts, ts, np.sin(3 * ts)[:, None])))
        tt = np.linspace(0.0, 2.0, 2001)
        errs.append(float(np.max(np.abs(np.asarray(jax.vmap(g)(jnp.asarray(tt)))[:, 0]
                                        - np.sin(3 * tt)))))
        h = 2.0 / (n - 1)
        assert errs[-1] < 5 * h ** 4 * 81 / 384, (n, errs[-1])
    assert 10 < errs[0] / errs[1] < 24, errs


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_scene_input_reaches_before_the_start_with_a_panel_boundary_at_t0():
    """The start reads the input 10 ms on both sides of t0: the table holds it there, exact to
    interpolation accuracy, and a motion that starts from rest at t0 (max(t, 0)^3: a jump of
    the third derivative) is not smeared across t0 (t0 is a panel boundary), so the table is
    not judged too coarse."""
    from ppr_jax._tabulated import START_MARGIN, input_too_coarse, scene_input

    def f(t):
        return jnp.stack([jnp.maximum(t, 0.0) ** 3, jnp.cos(3.0 * t)])

    ts = jnp.linspace(0.0, 0.005, 2)  # shorter than the margin: the table reaches t0 + 10 ms
    tab = scene_input(f, ts)
    t = jnp.linspace(-START_MARGIN, START_MARGIN, 41)
    np.testing.assert_allclose(jax.vmap(tab)(t), jax.vmap(f)(t), rtol=0, atol=1e-14)
    assert not bool(input_too_coarse(tab))
    # second derivatives where the start takes them, on both sides of t0
    d2 = jax.vmap(lambda s: jax.grad(jax.grad(lambda u: tab(u)[0]))(s))(t)
    np.testing.assert_allclose(d2, 6 * np.maximum(np.asarray(t), 0.0), rtol=0, atol=1e-9)


# ---------------------------------------------------------------------------------------------
# Paths with knots: the table's panels end at the path's breakpoints
# ---------------------------------------------------------------------------------------------


def _lissajous_waypoints(hz, T=2.0):
    """A non-circular path (a Lissajous figure about the workspace centre, 30 mm by 20 mm and
    0.04 rad) sampled at `hz` over [0, T] and splined (`Waypoints`, clamped: from rest)."""
    ts = np.arange(0.0, T + 1e-12, 1.0 / hz)
    w = 2 * np.pi / T
    X = np.array([0.45, 0.26, 0.0]) + np.column_stack(
        [0.03 * np.sin(w * ts), 0.02 * np.sin(2 * w * ts), 0.04 * np.sin(w * ts) ** 2])
    return pj.Waypoints(ts, X)


@pytest.mark.parametrize("hz", [20, pytest.param(100, marks=pytest.mark.slow)])
def test_spline_path_torques_with_panels_at_the_knots(hz):
    """L1 inverse-dynamics torques along a C2 spline path (its third derivative jumps at every
    knot, so the torques have a kink there): with the knots among the panel boundaries the
    table is accurate to 1e-8 of the largest torque at random times between the nodes (against
    the exact inverse dynamics) and not judged coarse; equal panels alone (the circle's table)
    are judged too coarse even with 2001 output times. A horizon shorter than the samples
    (knots beyond it: empty panels) and a traced horizon give the same accurate table."""
    from ppr_jax._tabulated import breakpoints, input_too_coarse, scene_input

    robot = pj.Robot(pj.scene_params("paper-circle"))
    path = _lissajous_waypoints(hz)
    tau = pj.InverseDynamicsTorque(pj.Reduced(), robot, path)
    assert breakpoints(pj.Circle()) is None
    np.testing.assert_array_equal(breakpoints(path), path.ts)
    t = jnp.asarray(RNG.uniform(-0.01, 2.0, 400))
    t_short = jnp.asarray(RNG.uniform(-0.01, 0.7, 100))

    @jax.jit
    def inputs(t_end):
        knots = scene_input(tau, jnp.linspace(0.0, 2.0, 201), breaks=breakpoints(path))
        equal = scene_input(tau, jnp.linspace(0.0, 2.0, 2001))
        short = scene_input(tau, jnp.linspace(0.0, t_end, 71), breaks=breakpoints(path))
        return (input_too_coarse(knots), input_too_coarse(equal), input_too_coarse(short),
                jax.vmap(knots)(t), jax.vmap(tau)(t), jax.vmap(short)(t_short),
                jax.vmap(tau)(t_short), short.bounds)

    c_knots, c_equal, c_short, tab, exact, tab_s, exact_s, bounds = inputs(0.7)
    assert not bool(c_knots) and bool(c_equal) and not bool(c_short)
    scale = float(jnp.max(jnp.abs(exact)))
    err = float(jnp.max(jnp.abs(tab - exact)))
    assert err <= 1e-8 * scale, err / scale
    assert float(jnp.max(jnp.abs(tab_s - exact_s))) <= 1e-8 * scale
    # every knot in the short table's span is a boundary; the others are clipped to its ends
    inside = np.asarray(path.ts)[np.asarray(path.ts) < 0.7]
    assert np.isin(inside, np.asarray(bounds)).all()
    assert np.asarray(bounds).min() == -0.01 and np.asarray(bounds).max() == 0.7


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_a_table_on_knots_is_differentiable_in_time_and_in_the_samples():
    """Derivatives through a table with knots: d/dt of the tabulated prescribed angles
    (the servo's rate) matches the exact inverse kinematics' rate between the knots, and the
    gradient of a tabulated torque with respect to the path's samples matches central
    differences."""
    from ppr_jax._tabulated import breakpoints, scene_input

    robot = pj.Robot(pj.scene_params("paper-circle"))
    ts = np.arange(0.0, 1.0 + 1e-12, 0.05)
    X0 = np.asarray(jax.vmap(_lissajous_waypoints(20, 1.0))(jnp.asarray(ts)))
    grid = jnp.linspace(0.0, 1.0, 21)

    def table_of(X, fn_cls):
        path = pj.Waypoints(ts, X)
        return scene_input(fn_cls(pj.Reduced(), robot, path), grid, breaks=breakpoints(path))

    t = jnp.asarray([0.123, 0.4567, 0.89])

    # compiled once each (op by op, the table's construction and its derivatives took 40 s)
    @jax.jit
    def rates(X):
        tab = table_of(X, pj.InverseKinematicsAngles)
        ang = pj.InverseKinematicsAngles(pj.Reduced(), robot, pj.Waypoints(ts, X))
        return (jax.vmap(lambda s: pj.derivatives(tab, s)[1])(t),
                jax.vmap(lambda s: pj.derivatives(ang, s)[1])(t))

    rate_tab, rate = rates(jnp.asarray(X0))
    np.testing.assert_allclose(rate_tab, rate, rtol=0, atol=1e-9 * float(jnp.max(jnp.abs(rate))))

    @jax.jit
    def f(X):
        return table_of(X, pj.InverseDynamicsTorque)(0.4567)[1]

    # one direction (a sample between the knots of the evaluated panel), forward mode
    h, dX = 1e-6, np.zeros_like(X0)
    dX[8, 1] = 1.0
    _, g = jax.jit(lambda X, dX: jax.jvp(f, (X,), (dX,)))(jnp.asarray(X0), jnp.asarray(dX))
    fd = (float(f(jnp.asarray(X0 + h * dX))) - float(f(jnp.asarray(X0 - h * dX)))) / (2 * h)
    assert abs(float(g) - fd) <= 1e-6 * abs(fd) and abs(fd) > 0, (float(g), fd)


@pytest.mark.parametrize("where", ["interior", "end"])
def test_a_break_a_rounding_from_a_panel_bound_leaves_no_sliver_panel(where):
    """A path's sample a rounding away from an equal panel bound (a knot at
    0.6000000000000001 s against the bound 0.6, or the horizon's end t1 against the last
    equal bound) left a live panel of 1e-16 s, whose polynomial's second derivative, a
    prescribed motion's acceleration, is rounding / 1e-32: a motion-driven L2 on a spline
    stalled there for max_steps. Now no live panel is shorter than `SNAP` of the equal ones,
    and the table's second derivative about that time is the function's."""
    from ppr_jax._tabulated import SNAP, scene_input

    def f(t):
        return jnp.stack([jnp.sin(3.0 * t), jnp.cos(2.0 * t)])

    ts = jnp.linspace(0.0, 1.5, 151)
    P = scene_panels(ts.shape[0])
    t0, t1 = 0.0, 1.5
    j = P // 2 if where == "interior" else P
    bound = t0 + (t1 - t0) * np.arange(P + 1, dtype=float)[j] / P  # the table's own arithmetic
    knot = np.nextafter(bound, np.inf) if where == "interior" else np.nextafter(t1, -np.inf)
    breaks = jnp.asarray(np.array([0.0, 0.25, knot, 1.7]))
    tab = scene_input(f, ts, breaks=breaks)
    length = np.diff(np.asarray(tab.bounds))
    live = length[length > 0]
    assert live.min() >= SNAP * (t1 - t0) / P * (1 - 1e-9), live.min()
    t = jnp.asarray(knot) + jnp.array([-1e-3, -1e-15, 0.0, 1e-15, 1e-3])
    t = jnp.minimum(t, t1)
    d2 = jax.vmap(jax.jacfwd(jax.jacfwd(tab)))(t)
    # observed 2e-7 (the table's accuracy in a second derivative); a sliver: rounding / 1e-32
    np.testing.assert_allclose(d2, jax.vmap(jax.jacfwd(jax.jacfwd(f)))(t), rtol=0, atol=2e-6)
