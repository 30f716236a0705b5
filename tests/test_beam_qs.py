"""L3 with quasi-static strips (`QuasiStaticBeam`): the same statics as the full L3 (`Beam`, an
independent formulation: interior angles as coordinates, Newton on the whole robot), the strip
solve's implicit derivatives against finite differences (forward and reverse mode), the envelope
form of the strip forces against the Jacobian of the deflections, energy balance, and modes
against the full L3's low modes."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ppr_jax as pj
from ppr_jax._models import strip
from ppr_jax._models.strip import kkt_residual, solve_kkt, strip_equilibrium
from tests.helpers import coords_from_pose, energies, fd_jvp, outputs

WRENCH = jnp.array([0.4, -0.3, 0.004])  # N, N, N m


@pytest.fixture(scope="module")
def static_locked():
    return eqx.filter_jit(
        lambda m, p, z, w: pj.static_equilibrium(m, p, z, locked=True, wrench=w)[0]
    )


def test_registry_and_layout():
    m = pj.get_model("beam", 6)
    assert isinstance(m, pj.QuasiStaticBeam) and (m.n_dof, m.n_elements, m.level) == (9, 6, 3)
    assert isinstance(pj.get_model("beam", 6, strip_dynamics="full"), pj.Beam)
    with pytest.raises(pj.PPRError, match="strip_dynamics"):
        pj.get_model("beam", 6, strip_dynamics="implicit")


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
@pytest.mark.parametrize("sigma", [-1, 1])
def test_statics_equal_full_l3(static_locked, sigma):
    """Locked equilibrium under a platform wrench away from home: the quasi-static strips and the
    full L3 find the same pose and the same strip shapes (one potential, two formulations)."""
    params = pj.RobotParams(sigma=sigma)
    robot = pj.Robot(params)
    X = pj.home_pose(params) + jnp.array([0.01, -0.005, 0.05])
    qs, full = pj.QuasiStaticBeam(4), pj.Beam(4)
    z_qs = static_locked(qs, params, qs.coords_from_pose(robot, X), WRENCH)
    z_full0 = full.coords_from_pose(robot, X).at[3:6].set(z_qs[3:6])
    z_full = static_locked(full, params, z_full0, WRENCH)
    np.testing.assert_allclose(z_qs[:3], z_full[:3], rtol=0, atol=1e-12)
    k_qs, k_full = qs.kinematics(robot, z_qs), full.kinematics(robot, z_full)
    np.testing.assert_allclose(k_qs.th, k_full.th, rtol=0, atol=1e-11)
    assert np.abs(z_qs[:3] - X).max() > 1e-4  # the wrench really moved it
    assert np.abs(np.asarray(qs.loop_residual(robot, k_qs))).max() < 1e-14


def _strip(q):
    """(u, lam) of a 6-element strip as one vector, from q = (d_x, d_y, beta, h) (m, m, rad, m)."""
    u, lam, _ = strip_equilibrium(6, q[3], -0.1, q[:2], q[2])
    return jnp.concatenate([u, lam])


Q0 = jnp.array([0.0275, 0.0069, -0.55, 0.0049])


def test_strip_solution_is_the_constrained_equilibrium():
    u, lam, err = strip_equilibrium(6, Q0[3], -0.1, Q0[:2], Q0[2])
    assert float(err) < 1e-12
    # the end lands on d and the energy is stationary along the constraint (the KKT rows,
    # assembled here from the energy by autodiff, independently of the solver's residual)
    np.testing.assert_allclose(Q0[3] * jnp.sum(pj._geometry.e(u), axis=0), Q0[:2], atol=1e-15)

    def energy(u):
        d = jnp.concatenate([u[:1] + 0.05, jnp.diff(u) + 0.1, Q0[2:3] - u[-1:] + 0.05])
        k = jnp.array([2.0, 1, 1, 1, 1, 1, 2.0])
        return 0.5 * jnp.sum(k * d**2)

    g = jax.grad(energy)(u)
    # dU/du = mu . dc/du with mu = lam h (units of k_in) and dc/du = (-sin u, cos u)
    np.testing.assert_allclose(g, jnp.stack([-jnp.sin(u), jnp.cos(u)]).T @ (lam * Q0[3]),
                               atol=1e-12)
    assert np.abs(np.asarray(lam)).max() > 1.0  # loaded: the check is not trivial
    y = jnp.concatenate([u, lam * Q0[3]])
    p = jnp.stack([Q0[0] / Q0[3], Q0[1] / Q0[3], Q0[2], -0.1])
    assert np.abs(np.asarray(kkt_residual(y, p))).max() < 1e-12


@pytest.mark.parametrize("N", [3, 8, strip.UNROLL_MAX + 4])
def test_kkt_solve_against_dense_elimination(N):
    """`solve_kkt` (Thomas's sweeps on the tridiagonal block and a 2 x 2 Schur complement;
    unrolled, and a scan above UNROLL_MAX) and its transpose against NumPy's LAPACK solve of the
    KKT matrix from forward-mode differentiation of the residual."""
    rng = np.random.default_rng(N)
    y = jnp.asarray(np.concatenate([0.1 * rng.standard_normal(N), 0.3 * rng.standard_normal(2)]))
    p = jnp.asarray([0.9 * N, 0.2, 0.3, 0.05])
    R, W = (jnp.asarray(rng.standard_normal((N + 2, 3))) for _ in range(2))
    J, X, JtW = _kkt_solves(y, p, R, W)
    J = np.asarray(J)
    np.testing.assert_allclose(X, np.linalg.solve(J, R), rtol=1e-10, atol=1e-11)
    np.testing.assert_allclose(JtW, np.linalg.solve(J.T, W), rtol=1e-10, atol=1e-11)


@jax.jit
def _kkt_solves(y, p, R, W):
    """(the KKT matrix by forward-mode differentiation of the residual, solve_kkt(y, R), its
    transpose applied to W), one compiled program per size (eagerly, each primitive of the
    sweeps is a compilation of its own)."""
    (JtW,) = jax.linear_transpose(lambda R: solve_kkt(y, R), R)(W)
    return jax.jacfwd(kkt_residual)(y, p), solve_kkt(y, R), JtW


@pytest.mark.parametrize("j", range(4))
def test_strip_derivatives_vs_finite_differences(j):
    """Forward mode (jvp) and reverse mode (vjp) of the implicit strip solve against central
    differences, in each of the clamp-gap, end-angle and segment-length directions."""
    v = jnp.zeros(4).at[j].set(1.0) * jnp.array([1e-3, 1e-3, 1e-1, 1e-4])
    w = jnp.cos(jnp.arange(8.0))
    fd, jv, vjp_w, hv, fd_grad = _strip_derivatives(Q0, v, w)
    np.testing.assert_allclose(jv, fd, rtol=1e-6, atol=1e-8 * np.abs(fd).max())
    np.testing.assert_allclose(vjp_w @ v, w @ jv, rtol=1e-10)
    # second order: the Hessian of a scalar of the solution, forward over reverse vs FD of grad
    np.testing.assert_allclose(hv, fd_grad, rtol=1e-5, atol=1e-7 * np.abs(hv).max())


@jax.jit
def _strip_derivatives(q, v, w):
    """Along v at q: the strip solution's central difference (h = 1e-4) and JVP, its VJP with
    w, and the Hessian-vector product of sum(sin(solution)) (forward over reverse) with the
    central difference (h = 1e-5) of its gradient; one compiled program for every direction
    (eagerly, each primitive of the implicit solve and its derivatives compiles alone)."""
    def f(q):
        return jnp.sum(jnp.sin(_strip(q)))

    _, vjp = jax.vjp(_strip, q)
    return (fd_jvp(_strip, q, v, h=1e-4), jax.jvp(_strip, (q,), (v,))[1], vjp(w)[0],
            jax.jvp(jax.grad(f), (q,), (v,))[1], fd_jvp(jax.grad(f), q, v, h=1e-5))


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_envelope_forces_match_the_deflection_jacobian(params):
    """`spring_force` (envelope theorem, no Jacobian of the shape) against -J_d^T (k d) - c J_d^T
    J_d z' from the Jacobian of the deflections through the implicit solve; its derivatives in z
    (elastic and damping parts) against central differences."""
    m = pj.QuasiStaticBeam(5)
    p = params.replace(c_spring=2e-3)
    robot = pj.Robot(p)
    z = m.coords_from_pose(robot, pj.home_pose(p)) + 1e-3 * jnp.sin(jnp.arange(9.0))
    zd = 0.3 * jnp.cos(jnp.arange(9.0))

    @jax.jit  # one compilation instead of op-by-op dispatch through the inner iterations
    def both(z, zd):
        k = m.kinematics(robot, z)
        Jd = jax.jacfwd(lambda z: m.kinematics(robot, z).deflection)(z)
        ref = -(Jd.T @ (m.stiffness(robot) * k.deflection)) - p.c_spring * (Jd.T @ (Jd @ zd))
        return m.spring_force(robot, z, zd, k), ref

    Q, ref = both(z, zd)
    np.testing.assert_allclose(Q, ref, rtol=1e-10, atol=1e-12 * np.abs(ref).max())

    # and its derivative (the stiffness matrix) through the implicit shape
    def force(z):
        return m.spring_force(robot, z, 0 * zd, m.kinematics(robot, z))

    v = jnp.sin(jnp.arange(9.0) + 1)
    Kv = jax.jit(lambda z: jax.jvp(force, (z,), (v,))[1])(z)
    fd = fd_jvp(jax.jit(force), z, v, h=1e-7)
    np.testing.assert_allclose(Kv, fd, rtol=1e-5, atol=1e-6 * np.abs(fd).max())

    # and the strips' damping force alone (the moving state's force less the resting one's), whose
    # Jacobian of the deflections comes from the implicit function theorem at the solved shapes:
    # its derivative in z, forward mode against central differences, reverse against forward
    def damping(z):
        k = m.kinematics(robot, z)
        return m.spring_force(robot, z, zd, k) - m.spring_force(robot, z, 0 * zd, k)

    Dv = jax.jit(lambda z: jax.jvp(damping, (z,), (v,))[1])(z)
    fd = fd_jvp(jax.jit(damping), z, v, h=1e-6)
    assert np.abs(np.asarray(fd)).max() > 1e-6
    np.testing.assert_allclose(Dv, fd, rtol=1e-5, atol=1e-5 * np.abs(fd).max())
    w = jnp.cos(jnp.arange(9.0))
    wD = jax.jit(lambda z: jax.vjp(damping, z)[1](w)[0])(z)
    np.testing.assert_allclose(wD @ v, w @ Dv, rtol=1e-10)


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_unreachable_strip_is_reported(params):
    """A platform pulled beyond the strips' length: margin <= 0 (the scenes then fail with
    loop_not_closed / kinematics_failed), never a silent shape."""
    m = pj.QuasiStaticBeam(4)
    robot = pj.Robot(params)
    z = m.coords_from_pose(robot, pj.home_pose(params)).at[1].add(0.02)
    k = m.kinematics(robot, z)
    assert float(jnp.min(k.margin)) <= 0


def test_energy_balance_undamped_unforced(params):
    """N = 4, free vibration from a displaced state, Dopri8 at rtol 1e-10: the total energy
    (links' kinetic + strips' potential from the solved shapes) stays constant."""
    m = pj.QuasiStaticBeam(4)
    robot = pj.Robot(params)
    z0 = coords_from_pose(m, robot, jnp.array([0.46, 0.25, 0.01]))
    zd0 = jnp.zeros(9).at[:6].set(jnp.array([0.05, -0.04, 0.2, 0.1, -0.05, 0.02]))
    ts = jnp.linspace(0.0, 0.1, 11)
    sol = pj.simulate(m, params, pj.TorqueDriven(pj.Hold(jnp.zeros(3))), z0, zd0, ts,
                      solver="dopri8", rtol=1e-11, atol=1e-13)
    T, U = energies(m, robot, sol.z, sol.zdot)
    E = np.asarray(T + U)
    assert float(np.max(T)) > 1e-4 and float(np.max(U)) > 1e-4
    assert np.abs(E - E[0]).max() / float(np.max(T)) < 1e-8
    out = outputs(m, robot, sol.z, sol.zdot)
    assert float(np.max(out.residual)) < 1e-12


@pytest.mark.slow  # the CLI test compares the same modes at N = 3 in the default suite
def test_modes_match_full_l3(params):
    """Locked modes: the quasi-static strips keep the full L3's six robot modes (the strip modes
    above 2 kHz are gone); the lumped strip inertia shifts them by < 0.2 %."""
    f_qs = np.asarray(pj.modes(pj.QuasiStaticBeam(4), params, actuators="locked").freq_hz)
    f_full = np.asarray(pj.modes(pj.Beam(4), params, actuators="locked").freq_hz)
    assert len(f_qs) == 6 and f_full[6] > 1000
    np.testing.assert_allclose(f_qs, f_full[:6], rtol=2e-3)


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_damping_derivative_in_c_spring_at_zero(params):
    """The strips' damping is skipped at c_spring = 0 for speed, but its derivative there is
    still -J_d^T J_d z' (forward and reverse mode), not 0."""
    m = pj.QuasiStaticBeam(3)
    z = m.coords_from_pose(pj.Robot(params), pj.home_pose(params)) + 1e-3 * jnp.sin(
        jnp.arange(9.0))
    zd = 0.3 * jnp.cos(jnp.arange(9.0))

    def Q(c):
        robot = pj.Robot(params.replace(c_spring=c))
        return m.spring_force(robot, z, zd, m.kinematics(robot, z))

    @jax.jit
    def reference():
        robot = pj.Robot(params)
        Jd = jax.jacfwd(lambda z: m.kinematics(robot, z).deflection)(z)
        return -(Jd.T @ (Jd @ zd))

    ref = reference()
    assert np.abs(np.asarray(ref)).max() > 1e-3
    np.testing.assert_allclose(jax.jit(jax.jacfwd(Q))(0.0), ref, rtol=1e-9, atol=1e-12)
    w = jnp.sin(jnp.arange(9.0))
    np.testing.assert_allclose(jax.jit(jax.grad(lambda c: w @ Q(c)))(0.0), w @ ref, rtol=1e-9)
    Qj = jax.jit(Q)
    np.testing.assert_allclose((Qj(1e-3) - Qj(0.0)) / 1e-3, ref, rtol=1e-9, atol=1e-12)
