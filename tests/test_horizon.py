"""A run does not depend on its horizon: the first T seconds of a long run and a run of T
seconds are the same trajectory, for T from 5 ms up, torque- and motion-driven.

The quasi-static start differentiates its balance over +-10 ms about t0 and reads the scene's
input there; the input is a table over the horizon, and a table that ended at t0 + T (or began
at t0) extrapolated its end polynomial, so that L2 started 49 um and 0.67 mrad off at T = 50 ms
and failed below. The table now reaches the start's stencil on both sides
(`_tabulated.START_MARGIN`)."""

import numpy as np
import pytest

import ppr_jax as pj
from ppr_jax._statics import QS_DT, STENCIL
from ppr_jax._tabulated import START_MARGIN

LONG = pj.SceneOptions(t_end=1.0, n_out=201)  # output every 5 ms


def test_the_table_reaches_the_start_stencil():
    assert START_MARGIN >= np.max(np.abs(STENCIL)) * QS_DT


@pytest.fixture(scope="module", params=[("paper-circle", "double1r"),
                                        # its 5 ms start: 3.8e-9 from the long run's under
                                        # XLA's defaults, 5.8e-9 at LLVM -O0 (the limit 5e-9)
                                        pytest.param(("servo-circle", "double1r"),
                                                     marks=pytest.mark.xla_defaults),
                                        ("paper-circle", "reduced"),
                                        ("servo-circle", "rigid"),
                                        ("paper-circle", "rigid")],
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
    # the same start (to 1e-12 under torques; a prescribed motion's start takes the angles'
    # accelerations from each table's own polynomials: its pose 2e-9 apart, and its rates,
    # differences of balances 5 ms apart, 2e-7) ...
    np.testing.assert_allclose(short.z[0], long.z[0], rtol=0, atol=5e-9)
    np.testing.assert_allclose(short.zdot[0], long.zdot[0], rtol=0, atol=1e-6)
    # ... and the same state at T, to the solver's tolerance (rtol 1e-8 on coordinates of 0.1-3)
    np.testing.assert_allclose(short.X[-1], long.X[k], rtol=0, atol=2e-9)
