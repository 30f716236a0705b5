"""L2 (`double1r`) on paper-circle against an independent second formulation: the NumPy/scipy
contender of the benchmark suite (benchmarks/contenders/scipy_l2.py), which integrates 12
absolute coordinates with the 6 loop closures as Lagrange multipliers (index-1 form, Baumgarte
stabilised) where the library integrates 6 independent coordinates with closed-form closure and
Kane's projection. Same physics, different equations: the platform paths must agree to the
integration error, which checks the library's L2 as much as the contender. Also the contender's
own energy balance (kinetic + spring energy change = actuator work), which checks that its
velocity terms and spring forces are consistent with its kinetic and potential energy.

Both share only the inputs: parameters, the scene's torques and the initial state. The torques
(L1 inverse dynamics along eq 55, a function of time alone) are the library scene's own, applied
at its 1 ms output grid and splined by the contender (spline error ~1e-14 N m), which spares the
contender's separate tabulation its JAX compilation; the initial state is the library's first
state. A short window (0.4 s) keeps the test cheap: the library's L2 scene compiles in 20-30 s."""


import numpy as np
import pytest

import ppr_jax as pj
from benchmarks.contenders import scipy_l2

T_END = 0.4  # s
N_OUT = 401  # every 1 ms: the torque table's grid


@pytest.fixture(scope="module")
def scene():
    """(params, library paper-circle L2 report, torque spline) over [0, T_END]."""
    params = pj.scene_params("paper-circle")
    rep = pj.run_scene(
        "paper-circle",
        params,
        model="double1r",
        options=pj.SceneOptions(t_end=T_END, n_out=N_OUT, rtol=1e-10, atol=1e-12),
    )
    torque = scipy_l2.TorqueSpline(rep.result.ts, rep.result.tau)
    return params, rep, torque


def test_platform_path_matches_library(scene):
    params, rep, torque = scene
    res = rep.result
    out = scipy_l2.run(params, method="DOP853", rtol=1e-11, atol=1e-13, t_end=T_END,
                       n_out=N_OUT, repeats=1, z0=res.z[0], zdot0=res.zdot[0], torque=torque)
    assert out["status"] == 0
    np.testing.assert_allclose(out["t"], res.ts, rtol=0, atol=1e-15)
    # Observed ~1e-14 m; the brief's bound is 1e-7 m, 1e-9 m still leaves four orders of
    # magnitude to the integration error and catches any physical difference (the platform
    # moves by ~1e-5 m over this window if the pseudo-links' inertia is dropped).
    pos = np.linalg.norm(out["X"][:, :2] - res.X[:, :2], axis=1)
    assert pos.max() < 1e-9, pos.max()
    assert np.abs(out["X"][:, 2] - res.X[:, 2]).max() < 1e-8
    assert out["residual"] < 1e-12  # m, loop closure held by the stabilised index-1 form
    # and the platform really moved off its start, so the agreement is not trivial
    assert np.linalg.norm(res.X[-1, :2] - res.X[0, :2]) > 1e-2


def test_actuated_angles_and_energies_match_library(scene):
    params, rep, torque = scene
    res = rep.result
    model = scipy_l2.L2Model(params, torque)
    y0 = model.state_from_library(res.z[0], res.zdot[0])
    sol = scipy_l2.simulate(model, y0, np.asarray(res.ts), "DOP853", 1e-11, 1e-13)
    th_a = sol.y[0:9:3].T  # th_i1 (= th_a on the centre lines)
    np.testing.assert_allclose(th_a, res.z[:, 3:], rtol=0, atol=1e-9)
    np.testing.assert_allclose(sol.y[12:21:3].T, res.zdot[:, 3:], rtol=0, atol=1e-8)
    # the two formulations' energies (each from its own bodies) along the two solutions
    T, U = model.energy(sol.y)
    np.testing.assert_allclose(T, res.kinetic, rtol=1e-8, atol=1e-15)
    np.testing.assert_allclose(U, res.potential, rtol=1e-8, atol=1e-15)


def test_energy_balance_of_the_numpy_model(scene):
    """T + U - (T + U)(0) = W, the actuators' work (integrated as a 25th state), to 1e-9 of the
    energy exchanged (observed 1e-13 of it): a velocity term 1% off breaks it by 4e-5 of it."""
    params, rep, torque = scene
    res = rep.result
    model = scipy_l2.L2Model(params, torque, with_work=True)
    y0 = model.state_from_library(res.z[0], res.zdot[0])
    sol = scipy_l2.simulate(model, y0, np.linspace(0.0, T_END, N_OUT), "DOP853", 1e-12, 1e-14)
    assert sol.status == 0
    T, U = model.energy(sol.y)
    E = T + U
    W = sol.y[24]
    scale = np.max(np.abs(E - E[0]))
    assert scale > 1e-6  # J: energy really is exchanged
    np.testing.assert_allclose(E - E[0], W, rtol=0, atol=1e-9 * scale)


def test_damping_friction_and_rotor_inertia_match_library(scene):
    """The optional terms of MODEL.md section 1 (spring damping, actuator friction, rotor
    inertia): parameters are leaves, so the library's compiled scene is reused."""
    params = scene[0].replace(c_spring=1e-4, c_act=1e-3, J_rotor=1e-3)
    res = pj.run_scene("paper-circle", params, model="double1r",
                       options=pj.SceneOptions(t_end=T_END, n_out=N_OUT, rtol=1e-10,
                                               atol=1e-12)).result
    out = scipy_l2.run(params, method="DOP853", rtol=1e-11, atol=1e-13, t_end=T_END,
                       n_out=N_OUT, repeats=1, z0=res.z[0], zdot0=res.zdot[0],
                       torque=scipy_l2.TorqueSpline(res.ts, res.tau))  # rotor inertia: new torques
    pos = np.linalg.norm(out["X"][:, :2] - scene[1].result.X[:, :2], axis=1)
    assert pos.max() > 1e-7  # the terms matter here
    pos = np.linalg.norm(out["X"][:, :2] - res.X[:, :2], axis=1)
    assert pos.max() < 1e-9, pos.max()
