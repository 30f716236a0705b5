"""Hard cases within the documented ranges, through one compiled L2 paper-circle program (the
trajectory and the output times are arrays, so every case reuses it).

Each case finishes with every chain closed to 1e-10 m and the energy balance of the undamped robot
holding (the change of T + U equals the actuators' work, integrated independently from the output
samples), or fails with a message naming the cause.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ppr_jax as pj

N_OUT = 401


def _energy_balance_error(r, model):
    """max |E(t) - E(0) - W(t)| / max |W| with W the actuators' work by the trapezoidal rule."""
    ia = np.asarray(model.actuated_index)
    P = np.sum(r.tau * r.zdot[:, ia], axis=1)
    W = np.concatenate([[0.0], np.cumsum(0.5 * (P[1:] + P[:-1]) * np.diff(r.ts))])
    E = r.kinetic + r.potential
    return float(np.max(np.abs(E - E[0] - W)) / max(np.max(np.abs(W)), 1e-12))


CASES = {
    "paper": (dict(), pj.Circle(), 0.5),
    "thin strip 0.05 mm": (dict(t=5e-5), pj.Circle(), 0.5),
    "thick strip 2 mm": (dict(t=2e-3), pj.Circle(), 0.5),
    "fast circle (10x)": (dict(), pj.Circle(omega=jnp.asarray(50 / 6)), 0.5),
    "near the workspace edge (R = 0.3 m)": (dict(), pj.Circle(radius=jnp.asarray(0.3)), 0.5),
    "long horizon (20 s)": (dict(), pj.Circle(), 20.0),
}


@pytest.mark.parametrize("name", list(CASES))
def test_hard_case_closes_loops_and_balances_energy(name):
    over, traj, t_end = CASES[name]
    p = pj.scene_params("paper-circle", **over)
    r = pj.paper_circle(p, model="double1r", trajectory=traj, t_end=t_end, n_out=N_OUT,
                        max_steps=500_000)
    r = jax.tree_util.tree_map(np.asarray, r)
    assert float(np.max(r.residual)) <= 1e-10
    assert np.all(np.isfinite(r.X))
    # trapezoidal work on 401 samples: error ~ (dt omega_max)^2 / 12, below 1e-3 here
    assert _energy_balance_error(r, pj.Double1R()) < 2e-3, name


def test_too_thin_a_strip_names_the_cause():
    """At 0.03 mm the strip cannot hold the scene's initial inertial loads near the nominal pose:
    the quasi-static start fails, and says so (the L2 scenes need t >= 0.05 mm at this speed)."""
    p = pj.scene_params("paper-circle", t=3e-5)
    with pytest.raises(pj.SimulationError, match="quasi-static initial state was not found"):
        pj.paper_circle(p, model="double1r", t_end=0.5, n_out=N_OUT)
