"""A run does not depend on its horizon: the first T seconds of a long run and a run of T
seconds are the same trajectory, for T from 5 ms up, torque- and motion-driven.

The quasi-static start differentiates its balance over +-10 ms about t0 and reads the scene's
input there; the input is a table over the horizon, and a table that ended at t0 + T (or began
at t0) extrapolated its end polynomial, so that L2 started 49 um and 0.67 mrad off at T = 50 ms
and failed below. The table now reaches the start's stencil on both sides
(`_tabulated.START_MARGIN`). A prescribed motion's start reads the exact commands, not the
table, whose polynomials' derivatives differ with the horizon (`SceneInput.start`)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ppr_jax as pj
from ppr_jax._actuation import InverseDynamicsTorque
from ppr_jax._statics import QS_DT, STENCIL
from ppr_jax._tabulated import START_MARGIN, scene_input
from ppr_jax._trajectory import Circle

LONG = pj.SceneOptions(t_end=1.0, n_out=201)  # output every 5 ms


def test_the_table_reaches_the_start_stencil():
    # The torque drive's start reads the input table at t0 + STENCIL * QS_DT, on both sides of
    # t0: there the table of a 5 ms run must hold the input's own values (a table that ended at
    # t0 + T or began at t0 extrapolated its end polynomial: 49 um off at the start).
    fn = InverseDynamicsTorque(pj.get_model("reduced"), pj.RobotParams(), Circle())
    ts = jnp.array([0.0, 0.005])
    st = jnp.asarray(STENCIL * QS_DT)

    @jax.jit
    def both():
        table = scene_input(fn, ts)
        return jax.vmap(table)(st), jax.vmap(fn)(st)

    tab, exact = both()
    assert np.all(np.abs(STENCIL) * QS_DT <= START_MARGIN)
    np.testing.assert_allclose(tab, exact, rtol=0, atol=1e-9 * float(jnp.max(jnp.abs(exact))))


@pytest.fixture(scope="module", params=[
    # second tier: the start on L2, L1 and L0 and under the other drive (the default tier checks
    # the start's commands at t0 above, and the start against an independent one in
    # tests/test_sensitivity_reference.py)
    pytest.param(("paper-circle", "double1r"), marks=pytest.mark.slow),
    pytest.param(("paper-circle", "reduced"), marks=pytest.mark.slow),
    pytest.param(("servo-circle", "double1r"), marks=pytest.mark.slow),
    pytest.param(("servo-circle", "rigid"), marks=pytest.mark.slow),
    pytest.param(("paper-circle", "rigid"), marks=pytest.mark.slow)],
                ids=lambda p: f"{p[0]}-{p[1]}")
def long_run(request):
    scene, model = request.param
    return scene, model, pj.solve_scene(scene, model=model, options=LONG)


@pytest.mark.parametrize("T", [0.005, 0.05])
def test_a_short_run_is_the_start_of_a_long_one(long_run, T):
    scene, model, long = long_run
    short = pj.solve_scene(scene, model=model, options=pj.SceneOptions(t_end=T, n_out=2))
    k = int(round(T / (LONG.t_end / (LONG.n_out - 1))))
    assert abs(float(long.ts[k]) - T) < 1e-12
    # the same start: it reads the exact commands at t0, not a table whose polynomials differ
    # with the horizon (a prescribed motion's start took its angles' accelerations from them
    # and was 5e-9 rad apart, passing or failing with the CPU and XLA's optimisation level) ...
    # The two programs differ (their output counts), so they round differently: the balances
    # agree to their Newton tolerance (1e-13 relative) and the rates, differences of balances
    # QS_DT apart (sum |D1| = 1.5), to 1.5e-13 |z| / QS_DT, about 1e-10 (3e-11 seen).
    np.testing.assert_allclose(short.z[0], long.z[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(short.zdot[0], long.zdot[0], rtol=0, atol=1e-9)
    # ... and the same state at T, to the solver's tolerance (rtol 1e-8 on coordinates of 0.1-3)
    np.testing.assert_allclose(short.X[-1], long.X[k], rtol=0, atol=2e-9)
