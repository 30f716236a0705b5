import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ppr_jax as pj
from ppr_jax import _geometry as K
from ppr_jax._paper_eom import paper_jacobian
from tests.helpers import fd_jvp, rotate_pose

POSES = [
    [0.45, 0.2598076, 0.0],
    [0.55, 0.2598076, 0.0],
    [0.40, 0.32, -0.05],
    [0.47, 0.20, 0.04],
]


@pytest.mark.parametrize("X", POSES)
def test_ik_closes_loops_and_keeps_quasi_static_constraint(params, robot, X):
    r = pj.inverse_kinematics(params, X)
    res = K.loop_residual(robot, r.th, jnp.asarray(X))
    assert float(jnp.abs(res).max()) < 1e-10
    np.testing.assert_allclose(r.th[:, 0] - 2 * r.th[:, 1] + r.th[:, 2], 0, atol=1e-13)
    r0 = pj.inverse_kinematics(params, X, pj.Rigid())
    assert float(jnp.abs(K.loop_residual_rigid(robot, r0.th, jnp.asarray(X))).max()) < 1e-10


def _ik_l3_eager(p, X, l3):
    """L1's inverse kinematics th (3, 3) at pose X of the robot `p` with l3 replaced (traced:
    the general, Newton path)."""
    from ppr_jax._geometry import ik_reduced

    return ik_reduced(pj.Robot(p.replace(l3=l3)), X)[0]


# Compiled, each one program for every robot (evaluated eagerly, op by op, the Newton solve and
# its derivatives are hundreds of compilations of single operations)
_ik_l3 = jax.jit(_ik_l3_eager)
_ik_l3_jacfwd = jax.jit(jax.jacfwd(_ik_l3_eager, argnums=2))
_ik_l3_grad_rev = jax.jit(jax.grad(lambda p, X, l3: jnp.sum(jnp.sin(_ik_l3_eager(p, X, l3))),
                                   argnums=2))


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
@pytest.mark.parametrize("l1,l3", [(0.3, 0.33), (0.2, 0.5)])
def test_newton_path_for_unequal_links(params, l1, l3):
    """Unequal links: Newton to convergence (three fixed steps left 0.8 mm for 0.2 / 0.5 m), with
    derivatives (forward and reverse) equal to central differences of the converged solve."""
    p = params.replace(l1=l1, l3=l3)
    robot = pj.Robot(p)
    assert not robot.equal_links
    X = jnp.array(POSES[2])
    r = pj.inverse_kinematics(p, X)
    assert float(jnp.abs(K.loop_residual(robot, r.th, X)).max()) < 1e-12
    np.testing.assert_allclose(r.th[:, 0] - 2 * r.th[:, 1] + r.th[:, 2], 0, atol=1e-13)

    th = functools.partial(_ik_l3, p, X)
    h = 1e-6
    fd = (th(l3 + h) - th(l3 - h)) / (2 * h)
    g = _ik_l3_jacfwd(p, X, l3)
    np.testing.assert_allclose(g, fd, rtol=0, atol=1e-8)
    # reverse mode against central differences of the scalar, not against the forward-mode
    # output of the same code (which would share any error in the custom derivative rules)
    g_rev = _ik_l3_grad_rev(p, X, l3)
    fd_rev = (jnp.sum(jnp.sin(th(l3 + h))) - jnp.sum(jnp.sin(th(l3 - h)))) / (2 * h)
    np.testing.assert_allclose(g_rev, fd_rev, rtol=0, atol=1e-8)
    assert abs(float(fd_rev)) > 0.1


@pytest.mark.parametrize("X", POSES[1:])
def test_jacobian_against_finite_differences_and_eq47(params, X):
    X = jnp.asarray(X)
    r = pj.inverse_kinematics(params, X)
    v = jnp.array([0.3, -0.2, 0.5])
    fd = fd_jvp(lambda X: pj.inverse_kinematics(params, X).th.reshape(-1), X, v, 1e-6)
    np.testing.assert_allclose(r.J[:9] @ v, fd, rtol=1e-7, atol=1e-8)
    Jp, _ = paper_jacobian(params, X)
    np.testing.assert_allclose(r.J, Jp, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(r.S, r.J[jnp.array([0, 3, 6])], rtol=0, atol=0)


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_newton_path_higher_derivatives_equal_the_closed_form(params):
    """The equations of motion differentiate the inverse kinematics twice in X (convective terms)
    and once more for parameter gradients: with l1 == l3 the general (Newton) path must match the
    closed form, which is exact to every order, in second and third derivatives."""
    from ppr_jax._geometry import ik_reduced

    X = jnp.array([0.46, 0.25, 0.02])
    v = jnp.array([0.3, -0.2, 0.5])

    def th(X, equal, l1=params.l1):
        p = params.replace(l1=l1, l3=l1)
        return ik_reduced(pj.Robot(p, equal_links=equal), X)[0]

    h2 = {e: jax.jvp(lambda X: jax.jvp(lambda Y: th(Y, e), (X,), (v,))[1], (X,), (v,))[1]
          for e in (True, False)}
    np.testing.assert_allclose(h2[False], h2[True], rtol=0, atol=1e-10)
    w = jnp.arange(1.0, 10.0).reshape(3, 3)

    def d2(l, e):
        return jnp.sum(w * jax.jvp(lambda Y: jax.jvp(lambda Z: th(Z, e, l), (Y,), (v,))[1],
                                   (X,), (v,))[1])

    d3 = {e: jax.grad(lambda l: d2(l, e))(params.l1) for e in (True, False)}
    assert abs(float(d3[True])) > 1e-3
    np.testing.assert_allclose(d3[False], d3[True], rtol=1e-8)
    assert float(jnp.abs(h2[True]).max()) > 1e-2


def test_forward_kinematics_round_trip(params):
    for model in (pj.Reduced(), pj.Rigid()):
        X = jnp.array(POSES[3])
        th_a = pj.inverse_kinematics(params, X, model).th_a
        Xr = pj.forward_kinematics(params, th_a, model=model)
        np.testing.assert_allclose(Xr, X, atol=1e-12)
    path = jnp.stack([pj.inverse_kinematics(params, jnp.array(x)).th_a for x in POSES])
    Xs = pj.forward_kinematics_path(params, path)
    np.testing.assert_allclose(Xs, jnp.array(POSES), atol=1e-12)


def test_a_paths_error_is_its_first_failing_samples():
    """`raise_first`: the message of the check the earliest failing sample fails, though a
    check of higher precedence fails later samples (after one failure the warm start of the
    samples after it may be anywhere, and they fail any check by chance)."""
    from ppr_jax._errors import raise_first

    x = np.zeros(6)
    early = np.array([False, False, True, True, False, False])
    late = np.array([False, False, False, False, True, True])
    with pytest.raises(pj.PPRError, match=r"^second \(2 samples: \[2, 3\]\)"):
        raise_first(x, [(late, "first"), (early, "second")])
    # where one sample fails two checks, the one of precedence names it
    with pytest.raises(pj.PPRError, match=r"^first \(3 samples: \[2, 4, 5\]\)"):
        raise_first(x, [(late | (np.arange(6) == 2), "first"), (early, "second")])
    assert raise_first(x, [(np.zeros(6, bool), "never")]) is x


def test_forward_kinematics_path_names_the_failing_samples(params):
    """Turning one actuator by up to 3 rad from home drives the platform out of reach; the
    error names the samples (from the first failing one), not just 'some member'."""
    th0 = pj.inverse_kinematics(params, pj.home_pose(params)).th_a
    path = th0[None, :] + jnp.linspace(0.0, 3.0, 31)[:, None] * jnp.array([[1.0, 0.0, 0.0]])
    with pytest.raises(pj.PPRError, match=r"samples: \[") as info:
        pj.forward_kinematics_path(params, path)
    first = int(str(info.value).split("samples: [")[1].split(",")[0].rstrip("]"))
    assert first > 0  # the start is fine
    ok = pj.forward_kinematics_path(params, path[:first])  # the samples before it pass
    np.testing.assert_allclose(pj.inverse_kinematics(params, ok).th_a, path[:first], atol=1e-10)


def test_rotational_symmetry_of_kinematics(params, robot):
    c = jnp.array([0.45, 0.45 / jnp.sqrt(3.0)])
    X = jnp.array(POSES[2])
    th = pj.inverse_kinematics(params, X).th
    th_r = pj.inverse_kinematics(params, rotate_pose(X, c)).th
    # chain i of the rotated robot is chain i-1 of the original, turned by 120 degrees
    d = (th_r - jnp.roll(th, 1, axis=0) - 2 * jnp.pi / 3 + jnp.pi) % (2 * jnp.pi) - jnp.pi
    np.testing.assert_allclose(d, 0, atol=1e-12)


def test_predeflection_at_home(params):
    pd = pj.predeflection(params)
    np.testing.assert_allclose(pd["reduced"], -0.0152, atol=2e-4)
    # closed form: d = ((th3 - th1) - sigma theta_c)/2 with cos v = (|E-A| - r2)/(2 r1)
    robot = pj.Robot(params)
    dist = float(jnp.linalg.norm(K.platform_points(robot, pj.home_pose(params))[0]))
    v = np.arccos((dist - float(robot.r2)) / (2 * float(robot.r1)))
    np.testing.assert_allclose(pd["reduced"][0, 0], (-2 * v + 1.88) / 2, rtol=1e-12)


def test_unreachable_pose_is_a_clear_error(params):
    with pytest.raises(pj.PPRError, match="unreachable pose"):
        pj.inverse_kinematics(params, [1.5, 0.2, 0.0])


def test_singular_configuration_is_a_clear_error(params):
    # det(S) changes sign along phi at the centre: bisect onto the (type II) singularity.
    c = jnp.array([0.45, 0.45 / np.sqrt(3.0)])
    from ppr_jax._kinematics import _ik_jit

    def det(phi):
        return float(jnp.linalg.det(_ik_jit(pj.Reduced(), params, jnp.array([c[0], c[1], phi])).S))

    grid = np.linspace(-1.2, 1.2, 241)
    vals = np.array([det(p) for p in grid])
    k = np.flatnonzero(np.sign(vals[:-1]) != np.sign(vals[1:]))
    assert k.size > 0, "no singularity found on the grid"
    lo, hi = grid[k[0]], grid[k[0] + 1]
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if np.sign(det(mid)) == np.sign(det(lo)):
            lo = mid
        else:
            hi = mid
    with pytest.raises(pj.PPRError, match="singular configuration"):
        pj.inverse_kinematics(params, [c[0], c[1], lo])


def test_equal_links_fast_path_keeps_exact_derivatives_in_l1_alone(params):
    """With equal links the L1 inverse kinematics is closed form plus an implicit correction
    (a static choice, no lax.cond); its derivative in l1 alone (which breaks the symmetry the
    closed form assumes) equals the general Newton path's and central differences."""
    from ppr_jax._geometry import ik_reduced

    X = jnp.array([0.46, 0.25, 0.02])

    @functools.partial(jax.jit, static_argnums=1)  # one program each, not op by op
    def th(l1, equal):
        return ik_reduced(pj.Robot(params.replace(l1=l1), equal_links=equal), X)[0]

    l1 = float(params.l1)
    assert pj.Robot(params).equal_links and not pj.Robot(params.replace(l1=0.3)).equal_links
    g_fast = jax.jacfwd(lambda l: th(l, True))(l1)
    g_newton = jax.jacfwd(lambda l: th(l, False))(l1)
    h = 1e-6
    fd = (th(l1 + h, False) - th(l1 - h, False)) / (2 * h)
    np.testing.assert_allclose(g_fast, g_newton, rtol=0, atol=1e-12)
    np.testing.assert_allclose(g_fast, fd, rtol=0, atol=1e-8)
    assert float(jnp.abs(g_fast).max()) > 0.1
    g_rev = jax.grad(lambda l: jnp.sum(jnp.sin(th(l, True))))(l1)
    # (central differences of the Newton path: the fast path needs l1 == l3 exactly)
    fd_rev = (jnp.sum(jnp.sin(th(l1 + h, False))) - jnp.sum(jnp.sin(th(l1 - h, False)))) / (2 * h)
    np.testing.assert_allclose(g_rev, fd_rev, rtol=0, atol=1e-8)
    assert abs(float(fd_rev)) > 0.1
    with pytest.raises(pj.PPRError, match="equal_links=True needs l1 == l3"):
        pj.Robot(params.replace(l1=0.3), equal_links=True)


def _base_centre_path(params, phi_end, n=41):
    """Poses at the base centre with phi from -0.70 to `phi_end`; the default robot's type-II
    singularity there is near phi = -0.814."""
    phis = np.linspace(-0.70, phi_end, n)
    X = np.column_stack([np.full(n, 0.45), np.full(n, 0.15 * np.sqrt(3.0)), phis])
    return X, pj.inverse_kinematics(params, X).th_a


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
@pytest.mark.xla_defaults  # which sample meets the fold is a matter of rounding
def test_forward_kinematics_path_through_a_type2_singularity_is_refused(params):
    """The issue's reproducer: forward kinematics of the L1 angles of 41 poses through the
    singularity. Before, the returned phi rose to -0.812 and turned back to -0.728 while the
    poses went on to -0.90 (0.17 rad off), every check passed. Now the fold is named at the
    samples around it; the path before it, and a path that stops short of it, pass exactly.
    Sample 22 (phi = -0.810, S's inverse condition number 7e-4) solves to 1.0e-13, Newton's
    tolerance: whether it converges there, or the fold shows at [23, 24] or at [23] alone, is
    rounding (a custom derivative of the sines moved it, and the 3 x 3 elimination written
    entry by entry), and every such refusal names the singularity at sample 23."""
    X, th = _base_centre_path(params, -0.90)
    with pytest.raises(pj.PPRError,
                       match=r"type-II singularity.*samples: \[(22, 23|23, 24|23)\]"):
        pj.forward_kinematics_path(params, th, X[0])
    ok = pj.forward_kinematics_path(params, th[:22], X[0])
    np.testing.assert_allclose(ok, X[:22], atol=1e-12)
    X2, th2 = _base_centre_path(params, -0.80)
    np.testing.assert_allclose(pj.forward_kinematics_path(params, th2, X2[0]), X2, atol=1e-12)


def test_fold_flags_on_synthetic_determinants():
    from ppr_jax._kinematics import fold_flags

    s = np.linspace(-1.0, 1.0, 21) + 0.025  # the singularity between samples 9 and 10
    assert not np.any(fold_flags(jnp.asarray(s)))  # crossing: det changes sign (another check)
    assert not np.any(fold_flags(jnp.asarray(-1.0 - s ** 2)))  # a regular path
    # the fold: |det| turns up, sign unchanged; flagged from the first sample past it (the next
    # one's extrapolation, from samples on both sides of the fold, trips too)
    v = fold_flags(jnp.asarray(-np.abs(s)))
    assert np.flatnonzero(np.asarray(v)).tolist() == [10, 11]
    ts = np.concatenate([np.linspace(0, 1, 10), 1 + np.linspace(0.5, 5.5, 11)])
    v = fold_flags(jnp.asarray(-np.abs(ts - 1.2)), ts)  # uneven times: extrapolated in time
    assert np.flatnonzero(np.asarray(v)).tolist()[0] == 10
    assert not np.any(fold_flags(jnp.asarray(-1.0 - (ts - 1.2) ** 2), ts))


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_servo_circle_through_a_type2_singularity_is_a_status_code():
    """L1 motion-driven (warm-started forward kinematics, no ODE) on a circle whose phi passes
    the singularity: before, phi folded back and the scene reported ok; now `singular_path`.
    A circle that stays short of it is followed exactly."""
    p = pj.scene_params("servo-circle")
    kw = dict(model="reduced", t_end=2.0, n_out=201)
    r = pj.servo_circle(p, trajectory=pj.Circle(radius=jnp.asarray(0.02),
                                                phi_amp=jnp.asarray(0.85)), throw=False, **kw)
    assert int(r.result._value) == int(pj.RESULTS.singular_path._value)
    with pytest.raises(pj.SimulationError, match="type-II singularity"):
        pj.servo_circle(p, trajectory=pj.Circle(radius=jnp.asarray(0.02),
                                                phi_amp=jnp.asarray(0.85)), **kw)
    ok = pj.servo_circle(p, trajectory=pj.Circle(radius=jnp.asarray(0.02),
                                                 phi_amp=jnp.asarray(0.78)), **kw)
    np.testing.assert_allclose(ok.X, ok.X_nominal, atol=1e-9)


def test_paper_circle_through_a_type2_singularity_names_the_singular_path():
    """paper_circle's torques are L1's inverse dynamics along the nominal path, unbounded where
    that path meets L1's type-II singularity. Before, the circle through it failed as "input
    table too coarse" (the wrong cause); now `singular_path`, judged before the table, with the
    time of the crossing: phi = -0.85 sin(5t/6) passes the base centre's singular phi (about
    -0.814) near 5t/6 = asin(0.814/0.85), t = 1.54 s. A circle short of it runs, on the circle."""
    p = pj.scene_params("paper-circle")
    kw = dict(model="reduced", t_end=2.0, n_out=201)
    through = pj.Circle(radius=jnp.asarray(0.02), phi_amp=jnp.asarray(0.85))
    r = pj.paper_circle(p, trajectory=through, throw=False, **kw)
    assert int(r.result._value) == int(pj.RESULTS.singular_path._value)
    assert "between t = 1.53 and 1.54 s" in r.failures(p)[None]
    with pytest.raises(pj.SimulationError,
                       match=r"type-II singularity.*L1's \(reduced\) type-II singularity between"):
        pj.paper_circle(p, trajectory=through, **kw)
    ok = pj.paper_circle(p, trajectory=pj.Circle(radius=jnp.asarray(0.02),
                                                 phi_amp=jnp.asarray(0.78)), **kw)
    np.testing.assert_allclose(ok.X, ok.X_nominal, atol=1e-8)


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_servo_circle_L0_near_the_singularity_is_its_own_regular_motion():
    """The issue also saw L0 on the circle through L1's singularity end "ok with phi 0.13 rad
    off". That is L0's motion, not a fold: L0's pins sit elsewhere, so L1's angles there are a
    regular motion of L0. Its poses reproduce the commanded angles, det S of L0 keeps one sign
    and stays far from 0 (no singularity of L0 is approached, so the continuous solution is
    unique), and four times finer output gives the same poses."""
    from ppr_jax._kinematics import det3

    p = pj.scene_params("servo-circle")
    through = pj.Circle(radius=jnp.asarray(0.02), phi_amp=jnp.asarray(0.85))
    r = pj.servo_circle(p, model="rigid", trajectory=through, t_end=2.0, n_out=201)
    assert float(np.max(np.abs(r.X[:, 2] - r.X_nominal[:, 2]))) > 0.1  # the deviation is real
    ik0 = pj.inverse_kinematics(p, r.X, model=pj.Rigid())
    np.testing.assert_allclose(ik0.th_a, pj.inverse_kinematics(p, r.X_nominal).th_a,
                               rtol=0, atol=1e-10)
    det = np.asarray(det3(ik0.S))
    assert np.all(det < -0.2) and float(np.min(ik0.singularity)) > 0.02
    fine = pj.servo_circle(p, model="rigid", trajectory=through, t_end=2.0, n_out=801)
    np.testing.assert_allclose(fine.X[::4], r.X, rtol=0, atol=1e-10)


@pytest.mark.parametrize("name", [pytest.param("rigid", marks=pytest.mark.slow), "reduced"])
def test_the_input_tables_determinant_is_the_path_checks(name):
    """A torque-driven scene checks its path for type-II singularities from its input table's
    own evaluations (`with_checks`: det S of the matrix the torques are solved with). That S
    against the path check's, a forward-mode Jacobian of the inverse kinematics
    (`path_margins`), on an off-centre circle that crosses L1's singularity and stays clear of
    L0's: equal to rounding, and the crossing (L1) or none (L0) found from the nodes as from
    the path check."""
    from ppr_jax._actuation import InverseDynamicsTorque
    from ppr_jax._kinematics import path_margins
    from ppr_jax._scenes._base import singular_at_nodes

    p = pj.scene_params("paper-circle")
    model = pj.get_model(name)
    through = pj.Circle(center=jnp.asarray([0.43, 0.27]), radius=jnp.asarray(0.02),
                        phi_amp=jnp.asarray(0.85))
    ts = jnp.linspace(0.0, 2.0, 41)
    # each side compiled as one program, not op by op
    torque = InverseDynamicsTorque(model, p, through)
    _, (_, det, t) = eqx.filter_jit(lambda s: jax.vmap(torque.with_checks)(s))(ts[::-1])
    margins = eqx.filter_jit(path_margins)(model, p, jax.vmap(through)(ts))
    np.testing.assert_allclose(det[::-1], margins.det, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(t[::-1], ts)
    crossed = bool(jnp.any(margins.singular()))
    assert crossed == (name == "reduced")
    assert bool(singular_at_nodes(det, t)) == crossed


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_a_spline_path_through_the_singularity_is_refused_at_the_table_nodes():
    """A torque-driven `PathScene` on a spline through 21 waypoints (its knots are panel
    boundaries of the input table), once through L1's type-II singularity and once short of
    it: the scene's verdict from its table's nodes equals an independent check of the spline at
    4,001 samples (`path_margins`), and the path short of it is followed."""
    from ppr_jax._kinematics import path_margins

    p = pj.scene_params("paper-circle")
    ts = np.linspace(0.0, 2.0, 21)
    fine = jnp.linspace(0.0, 2.0, 4001)
    for amp, crosses in ((0.85, True), (0.3, False)):
        c = pj.Circle(center=jnp.asarray([0.43, 0.27]), radius=jnp.asarray(0.02),
                      phi_amp=jnp.asarray(amp))
        wp = pj.Waypoints(ts, np.asarray(jax.vmap(c)(jnp.asarray(ts))))
        ref = bool(jnp.any(path_margins(pj.Reduced(), p, jax.vmap(wp)(fine)).singular()))
        assert ref == crosses
        r = pj.solve_scene(pj.PathScene(wp, drive="torque"), p, model="reduced",
                           options=pj.SceneOptions(t_end=2.0, n_out=41), throw=False)
        singular = int(r.result._value) == int(pj.RESULTS.singular_path._value)
        assert singular == crosses, pj.RESULTS[r.result]
        if not crosses:
            assert bool(r.ok)
            np.testing.assert_allclose(r.X, r.X_nominal, rtol=0, atol=1e-8)


@functools.partial(jax.jit, static_argnums=(2, 3))
def _ik_trig_both(X, l1, equal, order, l3_rel=1.0):
    """(the closed form's cosines and sines, those of its angles) of L1's inverse kinematics at
    X, and their derivatives in (X, l1) of the given order (forward mode), one program each.
    l3 = 0.3 m on Newton's path, l1 * `l3_rel` on the closed form's."""
    from ppr_jax._geometry import ik_reduced_trig

    def both(X, l1):
        p = pj.RobotParams().replace(l1=l1, l3=0.3 if not equal else l1 * l3_rel)
        th, _, trig = ik_reduced_trig(pj.Robot(p, equal_links=equal), X)
        given = jnp.concatenate(list(trig.cos) + list(trig.sin))
        own = jnp.concatenate([jnp.cos(th[:, k]) for k in range(3)]
                              + [jnp.sin(th[:, k]) for k in range(3)])
        return jnp.stack([given, own])

    f = both
    for _ in range(order):
        f = jax.jacfwd(f, argnums=(0, 1))
        f = (lambda g: lambda X, l1: jnp.concatenate(
            [a.reshape(2, -1) for a in jax.tree_util.tree_leaves(g(X, l1))], axis=1))(f)
    return f(X, l1)


@pytest.mark.parametrize("equal", [True, False])
def test_the_closed_forms_sines_are_its_angles_sines(equal):
    """L1's inverse kinematics hands its chain angles' cosines and sines to the equations of
    motion and the outputs without evaluating them (`ik_reduced_trig`: products of the chain
    vector's direction and the closed form's cosine, turned by the Newton correction's Taylor
    polynomial). At random poses off the paper's circle, on the closed form's path (equal links)
    and Newton's (l3 = 0.3 m), they equal jnp.cos / jnp.sin of the returned angles in value and
    in first and second derivatives in the pose and in l1 alone (which breaks the symmetry the
    closed form assumes), and in reverse mode."""
    rng = np.random.default_rng(7)
    l1 = 0.24 if equal else 0.26
    for _ in range(3):
        r, a = 0.07 * np.sqrt(rng.uniform()), rng.uniform(0, 2 * np.pi)
        X = jnp.array([0.45 + r * np.cos(a), 0.26 + r * np.sin(a), rng.uniform(-0.15, 0.15)])
        for order, tol in [(0, 2e-15), (1, 1e-12), (2, 1e-9)]:
            given, own = _ik_trig_both(X, l1, equal, order)
            scale = max(1.0, float(jnp.abs(own).max()))
            np.testing.assert_allclose(given, own, rtol=0, atol=tol * scale,
                                       err_msg=f"order {order} at {X}")
        rev = jax.jacrev(lambda X, l: _ik_trig_both(X, l, equal, 0), argnums=(0, 1))(X, l1)
        for g in rev:
            np.testing.assert_allclose(g[0], g[1], rtol=0, atol=1e-12)
        if equal:
            # traced link lengths a finite difference's step from the equal ones that chose
            # the closed form (a sensitivity's central differences): the correction turns them
            given, own = _ik_trig_both(X, l1, True, 0, 1 + 1e-5)
            np.testing.assert_allclose(given, own, rtol=0, atol=2e-15)
