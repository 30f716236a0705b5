"""Linear modes against simulation (an independent reference) and across model levels."""

import jax.numpy as jnp
import numpy as np
import pytest

import ppr_jax as pj


@pytest.fixture(scope="module")
def L2_locked(params):
    return pj.modes(pj.Double1R(), params, actuators="locked")


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_symmetric_pairs_and_stability(params, L2_locked):
    f = np.asarray(L2_locked.freq_hz)
    assert f.shape == (3,) and np.all(f > 0)
    np.testing.assert_allclose(f[0], f[1], rtol=1e-9)  # 120-degree symmetry: a degenerate pair
    r1 = pj.modes(pj.Reduced(), params, actuators="free")
    f1 = np.asarray(r1.freq_hz)
    assert f1[0] < 0 and r1.growth_rate[0] > 0  # the home pose is unstable in rotation
    assert np.all(np.isfinite(f1))
    assert pj.modes(pj.Reduced(), params, actuators="locked").freq_hz.shape == (0,)


def test_L2_free_low_modes_match_L1_free(params):
    f1 = np.asarray(pj.modes(pj.Reduced(), params, actuators="free").freq_hz)
    f2 = np.asarray(pj.modes(pj.Double1R(), params, actuators="free").freq_hz)
    # the quasi-static assumption is exact at equilibrium with no actuator torque: low modes agree
    np.testing.assert_allclose(f2[:3], f1, rtol=2e-3)
    assert f2[3] > 10 * abs(f1).max()


def _simulated_frequency(params, locked):
    """Free vibration after a small push along the highest locked mode, actuators held by a
    motion-driven simulation: the dominant frequency (Hz) from zero crossings, and the mode's.

    The push is 1e-7 m, so the velocities are about 2 pi f 1e-7 (2e-4 m/s at 4 mm): rtol
    1e-12 alone would ask for them to 2e-16 m/s, below the rounding of accelerations computed
    from deflections 1e-7 of angles of order 1. The error control then chased rounding: with
    atol 1e-16, dopri8 took 191,000 steps at t = 4 mm (a quarter rejected; 7,900 at 0.3 mm),
    and 374 with atol 1e-13, at the same frequency."""
    m = pj.Double1R()
    z_eq = locked.z_eq
    shape = locked.shapes[:, 2]
    z0 = z_eq.at[:3].add(1e-7 * shape / jnp.abs(shape).max())
    f_mode = float(locked.freq_hz[2])
    ts = jnp.linspace(0.0, 5 / f_mode, 2001)
    sol = pj.simulate(m, params, pj.MotionDriven(pj.Hold(z_eq[3:])), z0, jnp.zeros(6), ts,
                      solver="dopri8", rtol=1e-12, atol=1e-13)
    y = np.asarray((sol.z[:, :3] - z_eq[None, :3]) @ (locked.M @ shape))
    crossings = np.flatnonzero(np.sign(y[:-1]) != np.sign(y[1:]))
    tc = np.asarray(ts)[crossings]
    return (len(tc) - 1) / (2 * (tc[-1] - tc[0])), f_mode


def test_L2_locked_frequency_against_simulation(params, L2_locked):
    """The dominant frequency of a simulated free vibration equals the eigenvalue's."""
    f_sim, f_mode = _simulated_frequency(params, L2_locked)
    np.testing.assert_allclose(f_sim, f_mode, rtol=5e-3)


def test_modes_of_thick_strips(params):
    """At t = 4 mm (joints 2,370 times stiffer) home is an equilibrium whose residual is at
    round-off (K eps); Newton's steps there are noise, which once read as divergence ("static
    equilibrium not found" at t >= 1 mm locked, 2 mm free). The modes are found, the highest
    locked one equals a simulated free vibration's frequency, and the free low modes are
    L1's, as at 0.3 mm."""
    thick = params.replace(t=4e-3)
    locked = pj.modes(pj.Double1R(), thick, actuators="locked")
    f_sim, f_mode = _simulated_frequency(thick, locked)
    np.testing.assert_allclose(f_sim, f_mode, rtol=5e-3)
    assert f_mode > 40 * float(pj.modes(pj.Double1R(), params, actuators="locked").freq_hz[2])
    f1 = np.asarray(pj.modes(pj.Reduced(), thick, actuators="free").freq_hz)
    f2 = np.asarray(pj.modes(pj.Double1R(), thick, actuators="free").freq_hz)
    np.testing.assert_allclose(f2[:3], f1, rtol=2e-3)


def test_unstable_growth_rate_against_simulation(params):
    """With actuators free the home pose diverges in rotation like cosh(lambda t)."""
    r = pj.modes(pj.Reduced(), params, actuators="free")
    lam = float(r.growth_rate[0])
    ts = jnp.linspace(0.0, 2.0, 21)
    X0 = r.z_eq + 1e-8 * r.shapes[:, 0] / jnp.abs(r.shapes[:, 0]).max()
    sol = pj.simulate(pj.Reduced(), params, pj.TorqueDriven(pj.Hold(jnp.zeros(3))), X0,
                      jnp.zeros(3), ts, rtol=1e-12, atol=1e-20)
    dphi = np.asarray(sol.z[:, 2] - r.z_eq[2])
    np.testing.assert_allclose(dphi, dphi[0] * np.cosh(lam * np.asarray(ts)), rtol=1e-3)


def test_modes_scene_defaults_to_table_1():
    """`modes_scene()` without parameters runs on Table 1, as `ppr-jax modes` does (it asked
    for the parameters of a registered scene named 'modes', which does not exist, and raised)."""
    r = pj.modes_scene(model="double1r")
    assert r["frequencies_hz"] == pj.modes_scene(pj.RobotParams(), model="double1r")[
        "frequencies_hz"]
    assert len(r["frequencies_hz"]) == 3 and min(r["frequencies_hz"]) > 0
