"""Kelvin-Voigt material loss of the full L3's strips (`Beam.strip_loss`): the damping vector in
closed form, the springs' force against the Jacobian form, the energy balance of an unforced
damped motion (energy lost = dissipated work), the checks of the argument, and the CLI option.

Compiled functions are shared through module fixtures; N = 4 throughout (15 coordinates)."""

import argparse

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ppr_jax as pj
from ppr_jax._dynamics import passive_force
from ppr_jax._errors import PPRError
from ppr_jax._models import get_model
from ppr_jax._models.beam import Beam
from tests.helpers import coords_from_pose, energies, outputs

N = 4
TAU = 1e-5  # s: damping ratio 0.075 for the first strip mode at N = 8, 0.12 for the top one here


def _closed_form_stiffness(p, n):
    EI = p.E * p.w * p.t**3 / 12
    ds = p.r * p.theta_c / n
    return np.tile(np.r_[2.0, np.ones(n - 1), 2.0] * float(EI / ds), 3)


def test_damping_vector_closed_form(params, robot):
    c = 2e-4
    p = params.replace(c_spring=c)
    r = pj.Robot(p)
    k = _closed_form_stiffness(p, N)
    np.testing.assert_allclose(Beam(N, strip_loss=TAU).damping(r), c + TAU * k, rtol=1e-14)
    np.testing.assert_allclose(Beam(N, TAU).damping(r), c + TAU * k, rtol=1e-14)  # positional
    # default 0: the scalar c_spring of every level
    assert Beam(N).strip_loss == 0.0 and float(Beam(N).damping(r)) == c
    # the shape of Kin.deflection
    z = Beam(N).coords_from_pose(robot, jnp.array([0.46, 0.25, 0.01]))
    assert Beam(N, TAU).damping(r).shape == Beam(N).kinematics(r, z).deflection.shape


# Compiled, one program per model (evaluated eagerly, op by op, every primitive of the strips'
# kinematics and their derivatives is a compilation of its own)
_passive_force = eqx.filter_jit(passive_force)


@eqx.filter_jit
def _deflections_and_jacobian(m, robot, z):
    """(d deflection/dz, deflection) of the strips at z."""
    return jax.jacfwd(lambda z: m.kinematics(robot, z).deflection)(z), m.kinematics(
        robot, z).deflection


@eqx.filter_jit
def _dissipated_power(m, robot, z, zd):
    """sum_i c_i (d deflection_i/dt)^2 (W) along states z, zd (n, n_dof)."""
    rates = jax.vmap(
        lambda z, zd: jax.jvp(lambda z: m.kinematics(robot, z).deflection, (z,), (zd,))[1]
    )(z, zd)
    return jnp.sum(m.damping(robot)[None, :] * rates**2, axis=1)


def test_spring_force_matches_jacobian_form(params):
    """Q = -J_d^T (K d + (c_spring + tau K) J_d z') at a deflected, moving state, against the
    Jacobian of the deflections; and the loss adds exactly -tau J_d^T K J_d z' to the undamped
    strips' force of the generic path."""
    c = 3e-4
    p = params.replace(c_spring=c)
    r = pj.Robot(p)
    m0, m = Beam(N), Beam(N, strip_loss=TAU)
    z = coords_from_pose(m, r, jnp.array([0.46, 0.25, 0.01])) + 0.01 * jnp.sin(jnp.arange(15.0))
    zd = 0.3 * jnp.cos(jnp.arange(15.0) * 1.7)
    Jd, d = _deflections_and_jacobian(m, r, z)
    k = jnp.asarray(_closed_form_stiffness(p, N))
    Q_ref = -Jd.T @ (k * d + (c + TAU * k) * (Jd @ zd))
    zero = jnp.zeros(3)
    Q = _passive_force(m, r, z, zd, zero, zero)
    Q0 = _passive_force(m0, r, z, zd, zero, zero)
    scale = float(jnp.abs(Q_ref).max())
    np.testing.assert_allclose(Q, Q_ref, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(Q - Q0, -TAU * Jd.T @ (k * (Jd @ zd)), rtol=0, atol=1e-12 * scale)
    assert float(jnp.abs(Q - Q0).max()) > 1e-4 * scale  # the loss is not negligible here


@pytest.fixture(scope="module")
def damped_run(params, robot):
    """Unforced, no other damping (c_spring = c_act = 0), strips out of equilibrium (the L1-manifold
    guess) and the platform and drives moving: 5 ms of Dopri8 at rtol 1e-11, 4001 outputs."""
    assert float(params.c_spring) == 0 and float(params.c_act) == 0
    m = Beam(N, strip_loss=TAU)
    z0 = coords_from_pose(m, robot, jnp.array([0.46, 0.25, 0.01]))
    zd0 = jnp.zeros(m.n_dof).at[:6].set(jnp.array([0.05, -0.04, 0.2, 0.1, -0.05, 0.02]))
    ts = jnp.linspace(0.0, 0.005, 4001)
    sol = pj.simulate(m, params, pj.TorqueDriven(pj.Hold(jnp.zeros(3))), z0, zd0, ts,
                      solver="dopri8", rtol=1e-11, atol=1e-13)
    return m, ts, sol


def test_energy_drop_equals_dissipated_work(robot, damped_run):
    """E(0) - E(t) = int_0^t sum_i c_i (d deflection_i/dt)^2 dt (Simpson on 4001 outputs, about
    70 per period of the fastest mode), c_i = tau k_i, to 1e-6 of the energy lost at the end;
    and the loss is substantial (several % of the strain energy), so an unapplied or doubled
    damping fails."""
    m, ts, sol = damped_run
    T, U = energies(m, robot, sol.z, sol.zdot)
    E = np.asarray(T + U)
    P = np.asarray(_dissipated_power(m, robot, sol.z, sol.zdot))  # dissipated power (W)
    dt = float(ts[1] - ts[0])
    # cumulative Simpson at every second output
    W = np.concatenate([[0.0], np.cumsum(dt / 3 * (P[:-2:2] + 4 * P[1:-1:2] + P[2::2]))])
    lost = E[0] - E[::2]
    assert lost[-1] > 0.03 * float(U[0] - U.min()) and lost[-1] > 1e-7, (lost[-1], U[0])
    assert np.all(np.diff(E[::2]) <= 1e-12 * E[0])  # energy never grows
    err = np.abs(lost - W).max() / lost[-1]
    assert err < 1e-6, err
    out = outputs(m, robot, sol.z, sol.zdot)
    assert float(np.max(out.residual)) < 1e-13


@pytest.mark.parametrize("bad", [-1e-6, float("nan"), float("inf"), True, "1e-5"])
def test_negative_or_bad_strip_loss_is_a_clear_error(bad):
    with pytest.raises(PPRError, match=r"strip_loss.*\[0, inf\)"):
        Beam(N, strip_loss=bad)


def test_get_model_and_cli_pass_strip_loss(capsys):
    from ppr_jax._cli import main, model_from_args

    m = get_model("beam", 4, "full", strip_loss=TAU)
    assert isinstance(m, Beam) and m.strip_loss == TAU and m.n_elements == 4
    assert get_model("beam", 4, "full").strip_loss == 0.0
    with pytest.raises(PPRError, match="strip_loss"):
        get_model("beam", 4, "quasi-static", strip_loss=TAU)
    # an array for the number is named, not a TypeError of the model cache's key
    with pytest.raises(PPRError, match=r"strip_loss.*\[0, inf\)"):
        get_model("beam", 4, "full", strip_loss=np.array([TAU]))
    args = argparse.Namespace(elements=3, strip_dynamics="full", strip_loss=2e-5)
    assert model_from_args(args, "beam") == Beam(3, strip_loss=2e-5)
    assert model_from_args(args, "reduced") == pj.Reduced()  # L0-L2 beside the beam: no strips
    # the option itself: quasi-static strips refuse it, a negative value is refused
    assert main(["modes", "--model", "beam", "--elements", "3", "--strip-loss", "1e-5"]) == 2
    assert "--strip-dynamics full" in capsys.readouterr().err
    assert main(["modes", "--model", "beam", "--elements", "3", "--strip-dynamics", "full",
                 "--strip-loss=-1e-5"]) == 2
    assert "strip_loss" in capsys.readouterr().err
