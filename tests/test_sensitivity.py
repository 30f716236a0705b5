"""Sensitivities by automatic differentiation against central finite differences, forward
against reverse mode, and the CLI table.

One forward-mode sensitivity (scene metrics and the base frequency together, one compiled
program) is shared by the module. Its metric values are checked against independent runs (the
scene's own single run with the numpy metrics of `scene_metrics`; the eigenvalues of the `modes`
scene); its derivatives against central differences of the compiled metric function
(`Sensitivity.evaluate`). Reverse mode (a further ~90 s compilation) is in the slow tests;
reverse-through-the-solver gradients in the default suite are in tests/test_gradients.py.
"""

import json

import numpy as np
import pytest

import ppr_jax as pj
from ppr_jax._cli import main
from ppr_jax._studies import metric_function

SCENE = dict(model="reduced", torque_model="rigid", t_end=0.3, n_out=7, rtol=1e-11, atol=1e-13)
PARAMS = ["t", "l3", "gamma", "w", "E"]
METRICS = ("radial_error_min_m", "torque_peak_Nm", "base_frequency_hz")


def _fd(fun, x0, rel=1e-5):
    """Central differences of fun(x) -> (k,) in each coordinate of x."""
    cols = []
    for j in range(len(x0)):
        h = rel * abs(x0[j])
        e = np.zeros_like(x0)
        e[j] = h
        cols.append((np.asarray(fun(x0 + e)) - np.asarray(fun(x0 - e))) / (2 * h))
    return np.stack(cols, axis=1)


@pytest.fixture(scope="module")
def base():
    return pj.scene_params("paper-circle")


@pytest.fixture(scope="module")
def fwd(base):
    return pj.sensitivity("paper-circle", base, mode="fwd", parameters=PARAMS, metrics=METRICS,
                          **SCENE)


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_metric_values_equal_independent_runs(base, fwd):
    dv = pj.derived(base)
    # the explicit PRB parameters are the fitted table's values at theta_c
    np.testing.assert_allclose(fwd.param_values["gamma"], float(dv.gamma), rtol=1e-15)
    res = pj.paper_circle(base, **SCENE)
    m = pj.scene_metrics(res)
    np.testing.assert_allclose(fwd.values["radial_error_min_m"], m["radial_error_min_m"],
                               rtol=1e-9)
    np.testing.assert_allclose(fwd.values["torque_peak_Nm"], np.abs(res.tau).max(), rtol=1e-12)
    f = pj.modes_scene(base, model="double1r")["frequencies_hz"]
    # the lowest locked L2 mode is a repeated pair (three-fold symmetry)
    np.testing.assert_allclose(f[0], f[1], rtol=1e-9)
    np.testing.assert_allclose(fwd.values["base_frequency_hz"], f[0], rtol=1e-10)


def test_forward_mode_vs_central_differences(fwd):
    x0 = np.array([fwd.param_values[n] for n in PARAMS])
    fd = _fd(fwd.evaluate, x0)
    np.testing.assert_allclose(fwd.jacobian, fd, rtol=2e-5, atol=1e-12)
    # the entries are not trivially zero: each parameter moves the radial error and frequency
    for i in (0, 2):
        assert np.all(np.abs(fwd.normalized[i]) > 1e-6), fwd.metrics[i]
    # normalised: (p / m) dm/dp
    v = np.array([fwd.values[m] for m in METRICS])
    np.testing.assert_allclose(fwd.normalized, fwd.jacobian * x0[None] / v[:, None], rtol=1e-14)
    # the base frequency of a spring-dominated mode goes as t^(3/2) and E^(1/2)
    j = METRICS.index("base_frequency_hz")
    assert 1.4 < fwd.normalized[j, PARAMS.index("t")] <= 1.5
    np.testing.assert_allclose(fwd.normalized[j, PARAMS.index("E")], 0.5, rtol=1e-9)


def test_cli_sensitivity_writes_table(tmp_path, fwd, capsys):
    out = tmp_path / "s"
    argv = ["sensitivity", "--scene", "paper-circle", "--model", "reduced", "--torque-model",
            "rigid", "--metrics", ",".join(METRICS), "--params", ",".join(PARAMS),
            "--t-end", "0.3", "--n-out", "7", "--rtol", "1e-11", "--atol", "1e-13",
            "--out", str(out)]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "Normalised sensitivities" in text and "gamma" in text
    data = json.loads((out / "sensitivity.json").read_text())
    got = {(r["metric"], r["parameter"]): r["normalized"] for r in data["rows"]}
    for i, m in enumerate(METRICS):
        for j, n in enumerate(PARAMS):
            np.testing.assert_allclose(got[m, n], fwd.normalized[i, j], rtol=1e-12)
    assert (out / "sensitivity.csv").read_text().count("\n") == len(PARAMS) * len(METRICS) + 1


@pytest.mark.parametrize("bad, message", [
    (["--params", "t,nope"], "unknown parameter 'nope'"),
    (["--metrics", "radial_error_rms"], "unknown metric"),
])
def test_cli_sensitivity_user_errors(tmp_path, capsys, bad, message):
    assert main(["sensitivity", *bad, "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("scene, model, torque_model", [
    ("paper-circle", "reduced", "reduced"),
    ("paper-circle", "rigid", "rigid"),
    ("servo-circle", "reduced", "reduced"),
])
def test_radial_error_of_a_model_that_follows_its_input_is_refused(scene, model, torque_model,
                                                                   paper_circle_L1):
    # Independent check first (the session's compiled L1 scene): L1 under its own
    # inverse-dynamics torques tracks the circle to the integrator's tolerance, so its radial
    # error is the solver's error, not the robot's.
    for m in ("radial_error_max_m", "radial_error_min_m"):
        assert abs(paper_circle_L1.metrics[m]) < 1e-9, m
    with pytest.raises(pj.PPRError, match="integrator's error"):
        pj.sensitivity(scene, model=model, torque_model=torque_model,
                       metrics=("radial_error_min_m", "torque_peak_Nm"))
    # the other metrics of the same scene are still physics, and accepted
    metric_function(scene, model=model, torque_model=torque_model, metrics=("torque_peak_Nm",))


def test_cli_sensitivity_refuses_a_model_that_follows_its_input(tmp_path, capsys):
    argv = ["sensitivity", "--model", "reduced", "--torque-model", "reduced",
            "--out", str(tmp_path / "x")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "integrator's error" in err and "double1r" in err


@pytest.mark.slow
def test_reverse_mode_equals_forward_mode(base, fwd):
    rev = pj.sensitivity("paper-circle", base, mode="rev", parameters=PARAMS, metrics=METRICS,
                         **SCENE)
    np.testing.assert_allclose(rev.jacobian, fwd.jacobian, rtol=1e-8, atol=1e-14)


@pytest.mark.slow
def test_reverse_mode_on_a_path_with_knots_matches_forward_mode_and_differences(base):
    """Reverse mode differentiates the solve on the forward pass's recorded steps
    (`simulate_core`); a `PathScene` on uneven waypoints steps to the spline's knots
    (`SceneInput.step_ts`), so the recorded grid holds clipped steps too. L2 under L1's
    torques along a loop nobody tuned: reverse equals forward mode, three checkpoints (nearly
    every step recomputed) give the Jacobian of a thousand (none recomputed) to rounding, and
    forward mode agrees with central differences of the compiled metrics. A chosen number of
    checkpoints runs diffrax's checkpointed reverse pass, the default the lean loop's
    (`_simulate._lean_reverse`): two programs, which agree to 2e-11 relative (measured), so the
    schedules are compared within diffrax's and each pass against forward mode. Slow: four L2
    programs, about 4 min."""
    tk = np.array([0.0, 0.13, 0.29, 0.41, 0.62, 0.80])
    poses = np.array([0.45, 0.2598, 0.0]) + np.column_stack(
        [0.02 * np.sin(7 * tk), 0.015 * np.cos(5 * tk) - 0.015, 0.03 * tk * np.sin(9 * tk)])
    # natural ends: no acceleration at t = 0, so the quasi-static start holds
    scene = pj.PathScene(pj.Waypoints(tk, poses, bc="natural"), drive="torque", name="loop")
    names = ["t", "gamma", "l1"]
    kw = dict(model="double1r", parameters=names, t_end=0.8, n_out=9, rtol=1e-11, atol=1e-13,
              metrics=("position_error_max_m", "phi_error_rms_rad", "torque_peak_Nm"))
    fwd = pj.sensitivity(scene, base, mode="fwd", **kw)
    rev = pj.sensitivity(scene, base, mode="rev", **kw)
    rev3 = pj.sensitivity(scene, base, mode="rev", checkpoints=3, **kw)
    rev_all = pj.sensitivity(scene, base, mode="rev", checkpoints=1000, **kw)
    np.testing.assert_allclose(rev.jacobian, fwd.jacobian, rtol=1e-8, atol=1e-14)
    np.testing.assert_allclose(rev_all.jacobian, fwd.jacobian, rtol=1e-8, atol=1e-14)
    np.testing.assert_allclose(rev3.jacobian, rev_all.jacobian, rtol=1e-12, atol=0)
    x0 = np.array([fwd.param_values[n] for n in names])
    np.testing.assert_allclose(fwd.jacobian, _fd(fwd.evaluate, x0), rtol=1e-4, atol=1e-14)
    assert np.all(np.abs(fwd.normalized) > 1e-3)  # every parameter moves every metric
