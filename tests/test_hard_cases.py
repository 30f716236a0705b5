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


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_a_start_whose_stencil_collapses_is_refused_not_run(tmp_path):
    """L2 motion-driven along a figure eight read from a file, strips 0.333 mm x 10 mm: the
    balance holds at t = 0, but the start's neighbours 10 ms either side (its rates are their
    differences) collapse out of the chains' reach. The start must fail, as it does for a
    thinner strip, and the run must stop at once: it was reported found with z' ~ 1e287 and
    stalled at t = 0 for all 200,000 steps (11 s, and as long for every member of a batch
    holding it). A slightly thicker strip starts and runs."""
    ts = np.arange(0.0, 1.2 + 1e-9, 0.02)
    w = 2 * np.pi * ts / 1.2
    X = np.column_stack([0.45 + 0.04 * np.sin(w), 0.26 + 0.03 * np.sin(2 * w),
                         0.01 * np.sin(w)])
    path = tmp_path / "fig8.csv"
    np.savetxt(path, np.column_stack([ts, X]), delimiter=",", header="time,x,y,phi",
               comments="", fmt="%.17g")
    scene = pj.PathScene(pj.load_path(str(path)), drive="motion", name="fig8")
    opts = pj.SceneOptions(t_end=1.2, n_out=25)
    base = scene.default_params().replace(w=0.01)
    bad = pj.solve_scene(scene, base.replace(t=0.333e-3), model="double1r", options=opts,
                         throw=False)
    assert bad.result == pj.RESULTS.initial_state_failed, bad.result
    assert int(bad.num_steps) < 1000
    good = pj.solve_scene(scene, base.replace(t=0.4e-3), model="double1r", options=opts,
                          throw=False)
    assert good.result == pj.RESULTS.successful, good.result
    assert np.all(np.isfinite(np.asarray(good.X)))
