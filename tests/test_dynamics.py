import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ppr_jax as pj
from tests.helpers import raises_in_compiled_code, rotate_pose, rotate_vel

TS = jnp.linspace(0.0, 1.5, 151)


def _energy(model, params, sol):
    robot = pj.Robot(params)
    T, U = jax.vmap(lambda z, zd: pj.energy(model, robot, z, zd))(sol.z, sol.zdot)
    return np.asarray(T), np.asarray(U)


@pytest.mark.parametrize("model", [pj.Reduced(), pj.Double1R()])
def test_energy_conservation_undamped_unforced(params, model):
    robot = pj.Robot(params)
    z0 = model.coords_from_pose(robot, jnp.array([0.46, 0.25, 0.01]))
    zd0 = jnp.concatenate([jnp.array([0.05, -0.04, 0.2]), jnp.zeros(model.n_dof - 3)])
    if model.n_dof == 6:
        zd0 = zd0.at[3:].set(jnp.array([0.1, -0.05, 0.02]))
    sol = pj.simulate(
        model, params, pj.TorqueDriven(pj.Hold(jnp.zeros(3))), z0, zd0, TS,
        solver="dopri8", rtol=1e-13, atol=1e-14,
    )
    T, U = _energy(model, params, sol)
    E = T + U
    drift = np.abs(E - E[0]).max() / T.max()
    assert drift <= 1e-8, drift
    assert T.max() > 1e-4  # it really moved


def test_damping_dissipates(params):
    p = params.replace(c_spring=2e-3, c_act=1e-3)
    model = pj.Double1R()
    robot = pj.Robot(p)
    z0 = model.coords_from_pose(robot, jnp.array([0.46, 0.25, 0.01]))
    zd0 = jnp.array([0.05, -0.04, 0.2, 0.1, -0.05, 0.02])
    sol = pj.simulate(model, p, pj.TorqueDriven(pj.Hold(jnp.zeros(3))), z0, zd0, TS,
                      solver="dopri8", rtol=1e-13, atol=1e-14)
    T, U = _energy(model, p, sol)
    E = T + U
    assert np.all(np.diff(E) <= 1e-14)
    assert E[-1] < E[0] - 1e-6


def test_inverse_then_forward_dynamics_reproduces_circle(paper_circle_L1):
    r = paper_circle_L1
    dev = np.linalg.norm(r.X - r.X_nominal, axis=-1).max()
    assert dev <= 1e-6, dev
    assert abs(r.metrics["phi_error_max_rad"]) <= 1e-6
    assert r.metrics["constraint_residual_max_m"] <= 1e-10


@pytest.mark.parametrize("model", [pj.Rigid(), pj.Reduced()])
def test_inverse_dynamics_rotational_symmetry(robot, model):
    c = jnp.array([0.45, 0.45 / jnp.sqrt(3.0)])
    X, Xd, Xdd = jnp.array([0.5, 0.27, 0.03]), jnp.array([0.1, -0.2, 0.3]), jnp.array([1., .5, -2.])
    tau, e1 = pj.inverse_dynamics(model, robot, X, Xd, Xdd)
    Xr, Xdr, Xddr = rotate_pose(X, c), rotate_vel(Xd), rotate_vel(Xdd)
    tau_r, e2 = pj.inverse_dynamics(model, robot, Xr, Xdr, Xddr)
    np.testing.assert_allclose(tau_r, jnp.roll(tau, 1), rtol=1e-9, atol=1e-13)
    E1 = pj.energy(model, robot, X, Xd)
    E2 = pj.energy(model, robot, Xr, Xdr)
    np.testing.assert_allclose(E1, E2, rtol=1e-11)


def test_double1r_accelerations_rotational_symmetry(robot):
    m = pj.Double1R()
    c = jnp.array([0.45, 0.45 / jnp.sqrt(3.0)])
    X, Xd = jnp.array([0.5, 0.27, 0.03]), jnp.array([0.1, -0.2, 0.3])
    z = m.coords_from_pose(robot, X) + jnp.array([0, 0, 0, 0.01, -0.02, 0.005])
    zd = jnp.concatenate([Xd, jnp.array([0.2, -0.1, 0.3])])
    tau = jnp.array([0.1, -0.2, 0.05])
    from ppr_jax._dynamics import accelerations

    a = accelerations(pj.eom_terms(m, robot, z, zd), tau, jnp.zeros(3))
    zr = jnp.concatenate([rotate_pose(z[:3], c), jnp.roll(z[3:], 1) + 2 * jnp.pi / 3])
    zdr = jnp.concatenate([rotate_vel(zd[:3]), jnp.roll(zd[3:], 1)])
    ar = accelerations(pj.eom_terms(m, robot, zr, zdr), jnp.roll(tau, 1), jnp.zeros(3))
    np.testing.assert_allclose(ar[:3], rotate_vel(a[:3]), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(ar[3:], jnp.roll(a[3:], 1), rtol=1e-9, atol=1e-12)


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_motion_driven_reaction_torques_drive_torque_driven_model(params):
    """L2 motion-driven along L1's angles; its reaction torques, fed back torque-driven
    (interpolated), reproduce the same motion: a consistency check of the partitioned EOM."""
    model = pj.Double1R()
    traj = pj.Circle()
    ts = jnp.linspace(0.0, 0.6, 601)
    angles = pj.InverseKinematicsAngles(pj.Reduced(), params, traj)
    z0, zd0 = pj.quasi_static_state(model, params, traj, 0.0, motion_driven=True)
    s1 = pj.simulate(model, params, pj.MotionDriven(angles), z0, zd0, ts, rtol=1e-11, atol=1e-12)
    s2 = pj.simulate(model, params, pj.TorqueDriven(pj.Interpolated(ts, s1.tau)), s1.z[0],
                     s1.zdot[0], ts[:201], rtol=1e-11, atol=1e-12)
    np.testing.assert_allclose(s2.z[:, 3:], s1.z[:201, 3:], atol=2e-7)
    np.testing.assert_allclose(s2.z[:, :3], s1.z[:201, :3], atol=2e-7)


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_pd_servo_converges_to_motion_driven(params):
    model = pj.Double1R()
    traj = pj.Circle()
    ts = jnp.linspace(0.0, 0.5, 51)
    angles = pj.InverseKinematicsAngles(pj.Reduced(), params, traj)
    z0, zd0 = pj.quasi_static_state(model, params, traj, 0.0, motion_driven=True)
    ref = pj.simulate(model, params, pj.MotionDriven(angles), z0, zd0, ts)
    ff = pj.InverseDynamicsTorque(pj.Reduced(), params, traj)
    errs = []
    for kp in (2e2, 2e3):
        servo = pj.PDServo(angles, Kp=jnp.asarray(kp), Kd=jnp.asarray(2 * np.sqrt(kp) * 0.15),
                           feedforward=ff)
        sol = pj.simulate(model, params, servo, z0, zd0, ts, rtol=1e-8, atol=1e-10)
        errs.append(float(jnp.abs(sol.z[:, :3] - ref.z[:, :3]).max()))
    assert errs[1] < errs[0] / 3, errs
    assert errs[1] < 2e-4, errs


def test_max_steps_is_a_clear_error(params):
    model = pj.Reduced()
    X0 = pj.home_pose(params)
    with pytest.raises(pj.SimulationError, match="maximum number of solver steps"):
        pj.simulate(model, params, pj.TorqueDriven(pj.Hold(jnp.zeros(3))), X0,
                    jnp.array([0.1, 0.0, 0.3]), TS, max_steps=3)


def test_max_steps_raises_under_jit_and_grad_from_the_lean_loop(params):
    """Traced (a caller's jit, `jax.grad`), `simulate` cannot return a `SimulationError`: its
    failed solve raises inside the program, after the lean loop that computes it (not
    diffrax's loop, whose reverse pass compiled four times longer), and a good solve's
    gradient is the lean loop's."""
    from ppr_jax._simulate import _LeanSolution, _solve, default_controller, get_solver

    model = pj.Reduced()
    X0 = pj.home_pose(params)
    act = pj.TorqueDriven(pj.Hold(jnp.zeros(3)))

    def final_x(t, max_steps):
        p = params.replace(t=t)
        s = pj.simulate(model, pj.Robot(p), act, X0, jnp.array([0.1, 0.0, 0.3]), TS,
                        max_steps=max_steps)
        return s.z[-1, 0]

    with raises_in_compiled_code("maximum number of solver steps"):
        jax.jit(final_x, static_argnums=1)(params.t, 3)
    with raises_in_compiled_code("maximum number of solver steps"):
        jax.jit(jax.grad(final_x), static_argnums=1)(params.t, 3)
    solver = get_solver("tsit5")
    y0 = jnp.concatenate([X0, jnp.array([0.1, 0.0, 0.3])])
    sol = _solve((pj.Robot(params), act, jnp.zeros(3), y0, TS), model, solver,
                 default_controller(solver, 1e-8, 1e-10), None, 1000, True,
                 diffrax.NoProgressMeter(), diffrax.RecursiveCheckpointAdjoint(), None)
    assert isinstance(sol, _LeanSolution)


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_implicit_solver_agrees_with_explicit_on_l0(params):
    """The default suite's implicit run: Kvaerno5 (diffrax's Newton on the Jacobian of the L0
    right-hand side) against Tsit5 on a free vibration, 0.3 s."""
    model = pj.Rigid()
    X0 = pj.home_pose(params) + jnp.array([0.01, 0.0, 0.0])
    act = pj.TorqueDriven(pj.Hold(jnp.zeros(3)))
    ts = jnp.linspace(0.0, 0.3, 31)
    a = pj.simulate(model, params, act, X0, jnp.zeros(3), ts, solver="tsit5", rtol=1e-10,
                    atol=1e-12)
    b = pj.simulate(model, params, act, X0, jnp.zeros(3), ts, solver="kvaerno5", rtol=1e-10,
                    atol=1e-12)
    assert float(jnp.abs(a.z[-1] - a.z[0]).max()) > 1e-4  # it really moves (0.8 mm)
    np.testing.assert_allclose(a.z, b.z, atol=1e-8)
    assert int(b.num_steps) > 0


@pytest.mark.slow
def test_explicit_and_implicit_solvers_agree(params):
    """L1 free vibration from an offset of 1 cm, 1.5 s: Tsit5 and Kvaerno5 agree, both report
    success, and both follow an independent reference: the paper's closed-form equations of
    motion (eq 54, `_paper_eom`) integrated by scipy's DOP853 (before, the test only compared
    the two diffrax solvers on one right-hand side and checked the type of a result code)."""
    from scipy.integrate import solve_ivp

    from ppr_jax._paper_eom import paper_workspace_eom

    model = pj.Reduced()
    X0 = pj.home_pose(params) + jnp.array([0.01, 0.0, 0.0])
    act = pj.TorqueDriven(pj.Hold(jnp.zeros(3)))
    a = pj.simulate(model, params, act, X0, jnp.zeros(3), TS, solver="tsit5", rtol=1e-10,
                    atol=1e-12)
    b = pj.simulate(model, params, act, X0, jnp.zeros(3), TS, solver="kvaerno5", rtol=1e-10,
                    atol=1e-12)
    assert int(a.result._value) == int(b.result._value) == int(pj.RESULTS.successful._value)
    np.testing.assert_allclose(a.z, b.z, rtol=0, atol=2e-9)  # measured 1.8e-10 m

    @jax.jit
    def rhs(y):
        Me, CeXd, spring = paper_workspace_eom(params, y[:3], y[3:])
        return jnp.concatenate([y[3:], jnp.linalg.solve(Me, -CeXd - spring)])

    ref = solve_ivp(lambda t, y: np.asarray(rhs(jnp.asarray(y))), (0.0, float(TS[-1])),
                    np.concatenate([np.asarray(X0), np.zeros(3)]), method="DOP853",
                    t_eval=np.asarray(TS), rtol=1e-12, atol=1e-14)
    assert ref.success
    assert np.abs(ref.y[:3].T - np.asarray(X0)).max() > 5e-3  # it really moves
    # measured: Tsit5 6.8e-13 m and 2.3e-12 m/s off the reference, Kvaerno5 1.8e-10 m (the
    # motion: 2 cm); a robot of t = 0.301 mm in the reference (0.3 % stiffer) is 9e-5 m off
    np.testing.assert_allclose(a.z, ref.y[:3].T, rtol=0, atol=1e-10)
    np.testing.assert_allclose(a.zdot, ref.y[3:].T, rtol=0, atol=1e-9)
    np.testing.assert_allclose(b.z, ref.y[:3].T, rtol=0, atol=2e-9)


@pytest.mark.parametrize("motion_driven", [False, pytest.param(True, marks=pytest.mark.slow)])
def test_quasi_static_state_balances_and_its_velocity_is_its_time_derivative(params,
                                                                             motion_driven):
    model, traj = pj.Double1R(), pj.Circle()
    tau = None if motion_driven else pj.InverseDynamicsTorque(pj.Reduced(), params, traj)

    @jax.jit
    def qs(t):
        return pj.quasi_static_state(model, params, traj, t, motion_driven=motion_driven,
                                     torque=tau)

    z, zd = qs(1.0)
    h = 1e-5
    fd = (qs(1.0 + h)[0] - qs(1.0 - h)[0]) / (2 * h)
    np.testing.assert_allclose(zd, fd, rtol=1e-6, atol=1e-9)
    # The balanced rows, with the applied (or no) torque, at the state's velocities and the
    # quasi-static path's own accelerations (its 5-point second difference: error ~3e-9 rad/s^2;
    # the second pass leaves (omega/omega_mode)^2 of the first's error, 1e-8 N m, where
    # balancing at the L1 reference's accelerations, a single pass, leaves 1.5e-5 N m).
    robot = pj.Robot(params)
    ref = lambda t: model.coords_from_pose(robot, traj(t))  # noqa: E731
    H = 2e-2
    zs = [qs(1.0 + k * H)[0] for k in (-2, -1, 1, 2)]
    zdd = (-zs[0] + 16 * zs[1] - 30 * z + 16 * zs[2] - zs[3]) / (12 * H**2)
    eom = pj.eom_terms(model, robot, z, zd)
    t_a = jnp.zeros(3) if motion_driven else tau(1.0)
    r = eom.M @ zdd + eom.h - (eom.Q_passive + eom.Jth.T @ t_a)
    rows = jnp.array([0, 1, 2]) if motion_driven else jnp.array([3, 4, 5])
    assert float(jnp.abs(r[rows]).max()) < 3e-7, r
    # it differs from the L1 state: the L2 model is not bound by eq 29
    assert float(jnp.abs(z - ref(1.0)).max()) > 1e-6


def _closure_cases():
    # The default tier covers each model, both joint geometries, and L1's closed form (equal
    # links) and Newton path (unequal); the other eight combinations run in the second tier.
    kept = {("rigid", False, "strip"), ("reduced", False, "centerline"),
            ("reduced", True, "strip"), ("double1r", True, "centerline")}
    for i, model in enumerate([pj.Rigid(), pj.Reduced(), pj.Double1R()]):
        for unequal in (False, True):
            for geometry in ("centerline", "strip"):
                slow = (model.name, unequal, geometry) not in kept
                yield pytest.param(model, geometry, unequal, id=f"model{i}-{unequal}-{geometry}",
                                   marks=[pytest.mark.slow] if slow else [])


@pytest.mark.parametrize(("model", "geometry", "unequal"), list(_closure_cases()))
def test_implicit_closure_derivatives_equal_autodiff_of_closed_form(params, model, geometry,
                                                                     unequal):
    """A second formulation: the equations of motion from implicit differentiation of the loop
    closures (the library's) against forward-mode derivatives of the closed-form closure, at a
    state off home with every velocity nonzero, for equal and unequal links (L1's Newton path)."""
    from ppr_jax._dynamics import _eom_terms

    p = params.replace(joint_geometry=geometry)
    if unequal:
        p = p.replace(l3=1.1 * p.l3)
    robot = pj.Robot(p)
    X = pj.home_pose(robot) + jnp.array([0.01, -0.02, 0.05])
    rng = np.random.default_rng(1)
    z = model.coords_from_pose(robot, X)
    z = z + 1e-2 * rng.standard_normal(z.shape) * (np.arange(z.shape[0]) >= 3)
    zd = jnp.asarray(rng.standard_normal(z.shape))
    # compiled, one program per formulation, not op by op (the default tier's four: 24 -> 17 s)
    terms = eqx.filter_jit(_eom_terms)
    a = terms(model, robot, z, zd, implicit=True)
    b = terms(model, robot, z, zd, implicit=False)
    for name in ("M", "h", "Q_passive", "Jth", "JX"):
        x, y = getattr(a, name), getattr(b, name)
        np.testing.assert_allclose(x, y, rtol=0, atol=1e-13 * float(jnp.max(jnp.abs(y))),
                                   err_msg=name)


def test_eom_terms_takes_params_or_robot(params):
    """The public `eom_terms` takes `RobotParams` as every public function does: the same terms
    as from the `Robot` built from them."""
    model = pj.Double1R()
    robot = pj.Robot(params)
    z = model.coords_from_pose(robot, jnp.array([0.45, 0.26, 0.01]))
    zd = jnp.array([0.01, -0.02, 0.05, 0.1, -0.2, 0.3])
    a, b = pj.eom_terms(model, robot, z, zd), pj.eom_terms(model, params, z, zd)
    for x, y in ((a.M, b.M), (a.h, b.h), (a.Q_passive, b.Q_passive)):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=0, atol=0)
    with pytest.raises(TypeError, match="expected Robot or RobotParams"):
        pj.eom_terms(model, {"t": 3e-4}, z, zd)
