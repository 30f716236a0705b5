"""Identification of the experiment that the data describe (no scene of the paper): the file's
own actuated angles drive the model along its own poses, from the state its first samples give.

The data come from the independent NumPy/scipy L2 (benchmarks/contenders), never from the
library's own simulation: a robot whose gamma (0.80) differs from the PRB table's start
(0.8314), on a non-circular path (a two-harmonic Fourier path, nothing like eq 55's circle),
commanded by a controller with another gamma (0.85) and recorded with tracker noise. One file
(1 s at 100 Hz) serves the API fit and the command line, so that both share one compiled
simulation and Jacobian.

The refusals of a first sample that cannot start the model (`StartError`) are made before the
simulation is compiled: the module's guard fails any test that reaches it."""

import json
import math
import os

import numpy as np
import pytest

import ppr_jax as pj
from benchmarks.contenders import known_truth

T_END, RATE = 1.0, 100.0
NOISE = (1e-4, 1e-3)  # m, rad: an Optotrak's
GAMMA = 0.80  # the robot's
#: the robot's other parameters, as the issue's call sets them (--set t=0.5e-3 --set K_theta=2.5)
BASE = dict(t=0.5e-3, K_theta=2.5)


def fourier_path():
    """A non-circular commanded path: two harmonics in x, y and phi, 6.3 s period."""
    return pj.Fourier([0.45, 0.26, 0.0], [[0.06, 0.0, 0.03], [0.015, 0.01, 0.0]],
                      [[0.0, 0.05, 0.0], [0.0, 0.015, 0.01]], 1.0)


@pytest.fixture(scope="module")
def data_file(tmp_path_factory):
    """(path of the tracker file, Experiment): the independent L2's samples with noise on the
    pose (the angles are the commands the robot followed exactly, as encoders give them)."""
    base = pj.RobotParams(**BASE)
    ts, X, th = known_truth.servo_data(base.replace(gamma=GAMMA), base.replace(gamma=0.85),
                                       t_end=T_END, rate=RATE, path=fourier_path())
    exp = known_truth.noisy(ts, X, th, *NOISE, 0.0, seed=5)
    path = str(tmp_path_factory.mktemp("own") / "own_path.csv")
    pj.write_csv(path, exp, comments=["independent scipy L2, Fourier path, gamma 0.80"])
    return path, pj.load_csv(path)


@pytest.fixture
def no_compile(monkeypatch):
    """Fail the test if identification reaches its compiled simulation."""
    from ppr_jax._studies._identify import _run

    def guard(*args, **kw):
        raise AssertionError("the simulation was reached: the refusal came too late")

    monkeypatch.setattr(_run, "_residual_and_jacobian", guard)


@pytest.fixture(scope="module")
def own_fit(data_file):
    """The L2 fit of gamma to the file, with no scene."""
    _, exp = data_file
    return pj.identify(exp, ("gamma",), model="double1r", params=pj.RobotParams(**BASE),
                       noise=NOISE)


def test_identifies_gamma_of_independent_data_on_own_path(own_fit):
    """No scene: the file's angles drive L2 along the file's poses; gamma is recovered within
    two standard deviations, the residuals are the noise, and the report says what drove the
    fit. The start is the file's: the paper's circle starts 27 mm away."""
    fit = own_fit
    assert fit.history["stop"] == "converged", fit.table()
    est, std = fit.estimate[0], fit.std[0]
    assert std > 0 and abs(est - GAMMA) < 2 * std, fit.table()
    assert abs(fit.initial[0] - GAMMA) > 10 * std  # the start was far, in units of the std
    assert 0.8 < math.sqrt(fit.sigma2) < 1.25, fit.table()
    assert "own measured actuated angles" in fit.actuation and "own path" in fit.actuation
    assert fit.scene == "experiment's own"


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_the_fit_compensates_its_path(own_fit):
    """The identification compensates a path: its robot, and the band over its covariance
    (L1 motion: the kinematics move with gamma; the band's coverage: test_compensate.py)."""
    fit = own_fit
    comp = pj.compensate(fourier_path(), "reduced", fit, drive="motion",
                         options=pj.SceneOptions(t_end=0.5))
    assert float(comp.before.params.gamma) == float(fit.params.gamma)
    assert comp.band["names"] == ["gamma"] and comp.band["half_width"].max() > 0


def test_cli_identify_without_scene(data_file, tmp_path, capsys):
    """`ppr-jax identify --data F --model double1r --unknown gamma --set t=0.5e-3 --set
    K_theta=2.5` (the issue's call) on the file: exit 0, the std reported, the truth within
    two of them."""
    from ppr_jax._cli import main

    path, _ = data_file
    out = str(tmp_path / "fit")
    rc = main(["identify", "--data", path, "--model", "double1r", "--unknown", "gamma",
               "--set", "t=0.5e-3", "--set", "K_theta=2.5", "--noise-pos", str(NOISE[0]),
               "--noise-phi", str(NOISE[1]), "--out", out])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    assert "gamma" in captured.out and "std" in captured.out
    summary = json.load(open(f"{out}/estimates.json"))
    g = summary["unknowns"]["gamma"]
    assert g["std"] > 0 and abs(g["estimate"] - GAMMA) < 2 * g["std"], g
    assert "own measured actuated angles" in captured.err


def test_deprecated_keywords_warn_and_give_the_same_fit(data_file):
    """The keywords `identify` took before `FitOptions` and `SceneOptions` (`max_iter`,
    `starts`, `rtol`) still work for one release: a `DeprecationWarning` naming the new
    spelling, and the numbers of `fit_options=FitOptions(...)`, `options=SceneOptions(...)`
    to the last bit. `max_iter=0`: the statistics at the start, one evaluation of the module's
    compiled program each."""
    import warnings

    _, exp = data_file
    new = _identify(exp, fit_options=pj.FitOptions(max_iter=0, starts=1),
                    options=pj.SceneOptions(rtol=1e-9))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        old = _identify(exp, max_iter=0, starts=1, rtol=1e-9)
    texts = [str(w.message) for w in caught if w.category is DeprecationWarning]
    assert any("fit_options=FitOptions(max_iter=..., starts=...)" in t for t in texts), texts
    assert any("options=SceneOptions(rtol=...)" in t for t in texts), texts
    # the warnings point at the caller's line, not into the library
    assert all(w.filename == __file__ for w in caught if w.category is DeprecationWarning)
    assert new.history["iterations"] == old.history["iterations"] == 0
    for name in ("estimate", "std", "residuals", "jacobian", "covariance", "fitted"):
        np.testing.assert_array_equal(np.asarray(getattr(old, name)),
                                      np.asarray(getattr(new, name)), err_msg=name)
    assert old.sigma2 == new.sigma2 and old.table() == new.table()


# ---------------------------------------------------------------------------------------------
# Refusals before anything is compiled
# ---------------------------------------------------------------------------------------------


def _identify(exp, **kw):
    return pj.identify(exp, ("gamma",), model="double1r", params=pj.RobotParams(**BASE),
                       noise=NOISE, **kw)


def _refused_start(exp, match, **kw):
    """`_identify(exp, **kw)` refused before anything is compiled: a `StartError` matching
    `match`."""
    with pytest.raises(pj.StartError, match=match):
        _identify(exp, **kw)


def test_refuses_angles_that_put_the_platform_elsewhere(data_file, no_compile):
    """The poses 40 mm off the angles' (another tracker frame): refused naming the file, the
    sample, the time and the distance."""
    _, exp = data_file
    X = np.asarray(exp.X).copy()
    X[:, 0] += 0.04
    bad = pj.experiment(exp.ts, X, th=exp.th, name=exp.name)
    with pytest.raises(pj.StartError) as info:
        _identify(bad)
    msg = str(info.value)
    assert msg.startswith(f"{exp.name}: sample 1 (t = 0 s)"), msg
    assert "the actuated angles put the platform at" in msg
    d = float(msg.split(" mm and ")[0].split(", ")[-1])
    assert 39 < d < 41, msg  # mm: the offset, found by the check's forward kinematics


def test_refuses_angles_of_another_assembly_mode(data_file, no_compile):
    """Chain 2's angle mirrored to the other elbow orientation (the same platform pose)."""
    _, exp = data_file
    from ppr_jax._studies._identify._start import _Geometry

    geo = _Geometry(pj.RobotParams(**BASE))
    th = np.asarray(exp.th).copy()
    for i in range(th.shape[0]):
        own, other, _ = geo.ik(np.asarray(exp.X[i]))
        th[i, 1] = other[1] + (th[i, 1] - own[1])
    bad = pj.experiment(exp.ts, exp.X, th=th, name=exp.name)
    _refused_start(bad, r"sample 1 \(t = 0 s\): the actuated angle th_2 = "
                   r".* belongs to the other assembly mode of chain 2 \(elbow orientation "
                   r"sigma = \+1\)")


def test_refuses_a_pose_out_of_reach(data_file, no_compile):
    _, exp = data_file
    X = np.asarray(exp.X).copy()
    X[:, 1] += 0.5
    bad = pj.experiment(exp.ts, X, th=exp.th, name=exp.name)
    _refused_start(bad, r"sample 1 .*no state of the model reaches the "
                   r"pose .* mm beyond its reach")


def test_refuses_a_paper_scene_that_starts_elsewhere(data_file, no_compile):
    """The issue's case: naming the servo-circle scene for a file on another path."""
    _, exp = data_file
    _refused_start(exp, r"sample 1 \(t = 0 s\): the file's first pose .* is [\d.]+ mm and .* "
                   r"from where the servo-circle scene starts", scene="servo-circle")


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_refuses_torques_that_cannot_hold_the_first_pose(no_compile):
    """A torque log 0.5 N m above the torques that move L1 along the poses: refused (it would
    throw the platform off within 0.1 s); the consistent log passes the same check."""
    import jax
    import jax.numpy as jnp

    from ppr_jax._studies._identify._start import check_starts

    params = pj.RobotParams(**BASE)
    path = fourier_path()
    ts = np.arange(0.0, 0.3, 0.01)
    X = np.asarray(jax.vmap(path)(jnp.asarray(ts)))
    tau = np.asarray(jax.jit(jax.vmap(pj.InverseDynamicsTorque(pj.Reduced(), params, path)))(
        jnp.asarray(ts)))
    good = pj.experiment(ts, X, tau=tau, name="torques.csv")
    check_starts([good], "torque", params, [pj.fit_start(ts, X)])
    bad = pj.experiment(ts, X, tau=tau + np.array([0.5, 0.0, 0.0]), name="torques.csv")
    _refused_start(bad, r"torques.csv: sample 1 \(t = 0 s\): the torques "
                   r".* are not what moves the platform as the first samples do .* "
                   r"[\d.]+ mm and [\d.]+ rad away from the file's first pose")


def test_refuses_data_without_commands_and_commanded_without_scene(data_file, no_compile):
    _, exp = data_file
    pose_only = pj.experiment(exp.ts, exp.X, name=exp.name)
    with pytest.raises(pj.DataError, match=r"own_path: the data hold no actuated angles .* and "
                       r"no torques .*scene='servo-circle'"):
        _identify(pose_only)
    with pytest.raises(pj.IdentificationError, match="without a scene the data's own"):
        _identify(exp, actuation="commanded")


def test_identify_keywords_refused_by_name(data_file, no_compile):
    """A keyword `identify` never took is a `TypeError` naming it; a fit option given both in
    `fit_options` and as its old keyword is refused; `n_elements` (now the model's:
    `get_model("beam", n_elements=...)`) warns and still reaches the model's check. All before
    anything is compiled."""
    _, exp = data_file
    with pytest.raises(TypeError, match=r"unexpected keyword argument\(s\) 'max_iters', 'tol'"):
        _identify(exp, max_iters=3, tol=1e-3)
    with pytest.raises(pj.IdentificationError, match=r"either as fit_options=FitOptions\(\.\.\.\) "
                       r"or as keywords \(force\), not both"):
        _identify(exp, fit_options=pj.FitOptions(), force=True)
    with pytest.warns(DeprecationWarning, match=r"model=get_model\('beam', n_elements=\.\.\.\)"):
        with pytest.raises(pj.PPRError, match=r"elements .* = 1 is out of its allowed range"):
            pj.identify(exp, ("gamma",), model="beam", n_elements=1)


def test_cli_refusal_is_one_line_exit_2(data_file, tmp_path, capsys):
    from ppr_jax._cli import main

    _, exp = data_file
    X = np.asarray(exp.X).copy()
    X[:, 0] += 0.04
    path = str(tmp_path / "shifted.csv")
    pj.write_csv(path, pj.experiment(exp.ts, X, th=exp.th, name="shifted"))
    out = str(tmp_path / "o")
    assert main(["identify", "--data", path, "--unknown", "gamma", "--set", "t=0.5e-3",
                 "--set", "K_theta=2.5", "--out", out]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    # the progress line, then the refusal: one line naming the file, the sample and the distance
    assert len(err) == 2 and err[-1].startswith("ppr-jax: error: "), err
    assert f"error: {path}: sample 1 (t = 0 s)" in err[-1] and "mm and" in err[-1], err
    assert not os.path.exists(f"{out}/estimates.json")


def test_experiment_scene_runs_the_file(data_file):
    """The same scene, public: `experiment_scene` of the file, run with `run_scene` on L1
    (no integrator: forward kinematics of the file's angles), follows the file's poses to the
    model's accuracy (a few mm: L1 is not the robot) and starts at the file's first pose."""
    _, exp = data_file
    scene = pj.experiment_scene(exp)
    assert scene.drive == "motion" and scene.name == exp.name
    rep = pj.run_scene(
        scene,
        pj.RobotParams(**BASE).replace(gamma=GAMMA),
        model="reduced",
        options=pj.SceneOptions(t_end=float(exp.ts[-1]), n_out=exp.n),
    )
    X = np.asarray(rep.result.X)
    assert np.max(np.hypot(*(X[:, :2] - np.asarray(exp.X)[:, :2]).T)) < 5e-3
    with pytest.raises(pj.DataError, match="hold no actuated angles"):
        pj.experiment_scene(pj.experiment(exp.ts, exp.X, name="poses only"))


@pytest.mark.slow
def test_two_experiments_on_different_paths_fitted_jointly():
    """Two files of the independent L2, one on the Fourier path, one on a straight line (a
    rest-to-rest move), each driven by its own angles from its own start, fitted jointly: gamma
    within two standard deviations, the residuals the noise."""
    base = pj.RobotParams(**BASE)
    truth, nominal = base.replace(gamma=GAMMA), base.replace(gamma=0.85)
    line = pj.Line([0.40, 0.22, -0.02], [0.50, 0.30, 0.03], 0.8)
    exps = []
    for k, (path, t_end) in enumerate([(fourier_path(), 0.6), (line, 0.8)]):
        ts, X, th = known_truth.servo_data(truth, nominal, t_end=t_end, rate=RATE, path=path)
        exps.append(known_truth.noisy(ts, X, th, *NOISE, 0.0, seed=10 + k, name=f"path {k}"))
    fit = pj.identify(exps, ("gamma",), model="double1r", params=base, noise=NOISE)
    assert abs(fit.estimate[0] - GAMMA) < 2 * fit.std[0], fit.table()
    assert 0.8 < math.sqrt(fit.sigma2) < 1.25, fit.table()
    assert "each experiment's own" in fit.actuation
