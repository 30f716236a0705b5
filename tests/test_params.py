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


@pytest.mark.parametrize("gamma", [0.75, 0.81, 0.85, 0.9])
def test_pseudo_link_and_rest_turn_from_the_arc(params, gamma):
    """Build the double-1R joint from the ideal arc directly (pivots s along the arc's end
    tangents from its ends) and compare with eqs 4-8 and psi0: the pivot distance is r2 (with
    Howell's rho) and each pivot turns by psi0 = theta_c/2 whatever gamma is."""
    p = params.replace(gamma=gamma)
    dv = pj.derived(p)
    r_i, th_c = float(p.r + p.b_r / 2), float(p.theta_c)
    s = (1 - gamma) * r_i * th_c / 2
    # arc of radius r_i from the origin heading +x, turning clockwise by theta_c
    start, t_start = np.array([0.0, 0.0]), np.array([1.0, 0.0])
    end = np.array([r_i * np.sin(th_c), -r_i * (1 - np.cos(th_c))])
    t_end = np.array([np.cos(th_c), -np.sin(th_c)])
    P1, P2 = start + s * t_start, end - s * t_end
    link = P2 - P1
    np.testing.assert_allclose(np.linalg.norm(link), float(dv.r2), rtol=1e-12)
    turn1 = -np.arctan2(link[1], link[0])  # from the first tangent to the pseudo-link
    turn2 = np.arctan2(link[1], link[0]) - np.arctan2(t_end[1], t_end[0])
    np.testing.assert_allclose([turn1, turn2], float(dv.psi0), rtol=1e-12)
    np.testing.assert_allclose(float(dv.s), s, rtol=1e-12)
    # and gamma moves r2 but not psi0 (derivatives by autodiff, not constants)
    g_r2 = jax.grad(lambda g: pj.derived(params.replace(gamma=g)).r2)(gamma)
    assert abs(float(g_r2)) > 1e-4


def test_explicit_rho_overrides(params):
    assert float(pj.derived(params.replace(rho=0.9)).rho) == 0.9


@pytest.mark.parametrize(
    "name,value",
    [("t", -0.3e-3), ("E", 0.0), ("theta_c", 4.0), ("gamma", 1.5), ("a", float("nan"))],
)
def test_out_of_range_parameter_names_parameter_and_range(name, value):
    with pytest.raises(pj.PPRError, match=rf"'{name}'.*range \[") as info:
        pj.RobotParams(**{name: value})
    # the range said once (it was "out of its physical range [...] (allowed range [...])")
    assert str(info.value).count("range [") == 1, info.value


def test_unknown_parameter_and_bad_sigma(params):
    with pytest.raises(pj.PPRError, match="unknown parameter"):
        params.replace(thickness=1.0)
    with pytest.raises(pj.PPRError, match="sigma"):
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


def test_unstack_params_inverts_stack_params(params):
    """Each member of `unstack_params` equals the robot it was stacked from, leaf by leaf and in
    kind (JAX arrays, explicit PRB parameters kept)."""
    members = [params.replace(t=0.3e-3, gamma=0.85), params.replace(t=0.45e-3, gamma=0.8),
               params.replace(a=0.95, gamma=0.9)]
    back = pj.unstack_params(pj.stack_params(members))
    assert len(back) == 3
    for p, q in zip(members, back):
        lp, tp = jax.tree_util.tree_flatten(p)
        lq, tq = jax.tree_util.tree_flatten(q)
        assert tp == tq
        for x, y in zip(lp, lq):
            assert isinstance(y, jax.Array) and y.shape == np.shape(x)
            np.testing.assert_array_equal(np.asarray(y), np.asarray(x))


def test_a_batch_on_a_scene_with_nothing_to_check_is_not_cut(params, monkeypatch):
    """A built-in scene checks no commands, so a batch run does not cut its robots into members
    on the host (one dispatched operation per member and field: as long as the run itself for
    1,024 robots); a path scene with an angle log still judges every member."""
    from ppr_jax._scenes import _base

    def refuse(_):
        raise AssertionError("the batch was cut into members")

    monkeypatch.setattr("ppr_jax._params.unstack_params", refuse)
    from ppr_jax._scenes import get_scene

    batch = pj.stack_params([params, params.replace(t=0.4e-3)])
    scene = get_scene("paper-circle")
    _base.check_scene_commands(scene, batch, scene.trajectory(), 1.0)
    with pytest.raises(AssertionError, match="cut into members"):  # the patch is reached
        log = pj.PathScene(path=scene.trajectory(), drive="motion",
                           command_log=lambda t: jnp.zeros(3))
        _base.check_scene_commands(log, batch, scene.trajectory(), 1.0)


def test_a_scenes_defaults_are_built_once_and_read_only():
    """A scene's default parameters and robot are one shared object per thickness
    (`table1_with_thickness`, `table1_robot`): equal to Table 1 built afresh, their leaves
    read-only (an in-place change would reach every later call), and overrides build anew."""
    import numpy as np

    from ppr_jax._scenes import get_scene

    scene = get_scene("paper-circle")
    p = scene.default_params()
    assert p is scene.default_params()
    fresh = pj.RobotParams().replace(t=scene.thickness)
    for a, b in zip(jax.tree_util.tree_leaves(p), jax.tree_util.tree_leaves(fresh)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    with pytest.raises(ValueError, match="read-only"):
        p.t[()] = 1e-3
    robot = scene.default_robot()
    assert robot is scene.default_robot() and robot.params is p
    ref = pj.Robot(fresh)
    for a, b in zip(jax.tree_util.tree_leaves(robot), jax.tree_util.tree_leaves(ref)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    other = scene.default_params(E=2.0e11)
    assert other is not p and float(other.E) == 2.0e11 and float(p.E) != 2.0e11
