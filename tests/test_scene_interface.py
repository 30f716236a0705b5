"""The scene interface: a user's own scene (here a straight line, not a circle) runs through the
same `AbstractScene.run` as the built-in ones, and failures are told by their cause."""

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ppr_jax as pj
from tests.helpers import OneSidedStart, SmoothLine


class Line(eqx.Module):
    """A straight segment from `start` to `end` (x, y, phi) with a cosine time law over
    `duration` seconds (rest to rest): the closed form the test compares with."""

    start: jax.Array = eqx.field(default_factory=lambda: jnp.array([0.40, 0.27, 0.0]))
    end: jax.Array = eqx.field(default_factory=lambda: jnp.array([0.49, 0.24, 0.03]))
    duration: float = 1.0

    def __call__(self, t):
        s = 0.5 * (1 - jnp.cos(jnp.pi * jnp.clip(t / self.duration, 0.0, 1.0)))
        return self.start + s * (self.end - self.start)


class LineScene(pj.AbstractScene):
    """Torques of L1's inverse dynamics along the line (exact, not tabulated)."""

    name: ClassVar[str] = "line"
    thickness: ClassVar[float] = 0.3e-3
    reference: ClassVar[dict] = {}
    drive: ClassVar[str] = "torque"

    @property
    def input_model(self):
        return pj.Reduced()

    def trajectory(self):
        return Line()

    def commands(self, model, robot, traj, ts, panels):
        return pj.SceneInput(pj.TorqueDriven(pj.InverseDynamicsTorque(pj.Reduced(), robot, traj)))

    def follows_its_input(self, model):
        return "its own inverse-dynamics torques" if model.name == "reduced" else ""


OPTIONS = pj.SceneOptions(t_end=1.0, n_out=21)


def _closed_form(ts):
    line = Line()
    s = 0.5 * (1 - np.cos(np.pi * np.clip(ts / line.duration, 0.0, 1.0)))
    return np.asarray(line.start) + s[:, None] * (np.asarray(line.end) - np.asarray(line.start))


@pytest.fixture(scope="module")
def line_report():
    return pj.run_scene(
        LineScene(),
        model="reduced",
        options=pj.SceneOptions(t_end=OPTIONS.t_end, n_out=OPTIONS.n_out),
    )


def test_own_scene_with_a_line_follows_the_closed_form(line_report):
    """L1 driven by its own inverse-dynamics torques follows the path it was computed for: the
    pose at every output time is the closed-form line to the integrator's tolerance."""
    r = line_report.result
    assert r.ok and r.scene == "line" and r.model == "reduced"
    ref = _closed_form(np.asarray(r.ts))
    err = np.abs(np.asarray(r.X) - ref).max()
    assert err < 1e-7, err
    # and the gap is the integrator's: it shrinks with the tolerance (same program: tolerances
    # are inputs)
    tight = pj.solve_scene(LineScene(), model="reduced",
                           options=pj.SceneOptions(t_end=1.0, n_out=21, rtol=1e-11, atol=1e-13))
    err_tight = np.abs(np.asarray(tight.X) - ref).max()
    assert err_tight < err / 20, (err_tight, err)
    # the nominal pose the result carries is the scene's path
    np.testing.assert_allclose(r.X_nominal, ref, rtol=0, atol=1e-15)
    # the path moves: a wrong scene (a held pose) would not pass the comparison above
    assert np.abs(ref[-1] - ref[0]).max() > 0.02


def test_metric_table_of_a_path_that_is_not_a_circle(line_report):
    """The circle's radial errors are not reported for a line; the path-generic ones are, and
    agree with the same quantities computed here from the signals."""
    m = line_report.metrics
    assert "radial_error_max_m" not in m
    r = line_report.result
    ref = _closed_form(np.asarray(r.ts))
    pos = np.hypot(*(np.asarray(r.X)[:, :2] - ref[:, :2]).T).max()
    np.testing.assert_allclose(m["position_error_max_m"], pos, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(m["torque_peak_Nm"], np.abs(np.asarray(r.tau)).max(), rtol=1e-14)
    np.testing.assert_allclose(m["constraint_residual_max_m"], np.max(r.residual), rtol=1e-14)


def test_solve_scene_takes_the_scene_instance_and_options(line_report):
    r = pj.solve_scene(LineScene(), model="reduced", options=OPTIONS)
    np.testing.assert_allclose(r.X, line_report.result.X, rtol=0, atol=1e-14)


def test_scene_options_name_the_bad_argument():
    with pytest.raises(pj.PPRError, match=r"rtol.*1e-14.*0\.01"):
        pj.SceneOptions(rtol=0.5).check()
    with pytest.raises(pj.PPRError, match="n_out"):
        pj.solve_scene("paper-circle", options=pj.SceneOptions(n_out=1))


def test_unknown_scene_lists_the_known_ones():
    with pytest.raises(pj.PPRError, match="paper-circle, servo-circle"):
        pj.solve_scene("square")
    for bad in ("paper-circle", "square"):  # by name too: the studies take one registry
        with pytest.raises(pj.PPRError, match="unknown scene 'square'"):
            pj.sweep("square", vary={"t": [3e-4]})
        with pytest.raises(pj.PPRError, match="unknown scene 'square'"):
            pj.sensitivity("square")


def test_a_solver_failure_says_where_it_stopped_not_a_residual():
    """A step budget too small for the horizon: the reason is the solver's, with the last
    output time reached, and no loop-closure residual of the unreached (inf) times."""
    res = pj.paper_circle(model="rigid", t_end=0.5, n_out=11, max_steps=3, throw=False)
    (reason,) = res.failures().values()
    assert "maximum number of solver steps" in reason, reason
    assert "last output time reached is t = " in reason, reason
    assert "nan" not in reason and "inf" not in reason and "residual" not in reason, reason


def test_an_invalid_parameter_inside_a_program_is_named():
    """A parameter set past `RobotParams`' checks (as a transformation may) is reported as an
    invalid parameter naming it and its allowed range, not as a residual."""
    p = eqx.tree_at(lambda q: q.t, pj.scene_params("paper-circle"), jnp.asarray(-1e-3))
    with pytest.raises(pj.SimulationError, match=r"t = -0\.001 m not in \[1e-06, 0\.01\]"):
        pj.paper_circle(p, model="rigid", t_end=0.5, n_out=11, max_steps=3)


# ---------------------------------------------------------------------------------------------
# PathScene: the scene object on a path nobody here chose, through every study
# ---------------------------------------------------------------------------------------------

def _smooth_closed_form(ts):
    line = SmoothLine()
    u = np.clip(ts / line.duration, 0.0, 1.0)
    s = u**3 * (10 - 15 * u + 6 * u**2)
    return np.asarray(line.start) + s[:, None] * (np.asarray(line.end) - np.asarray(line.start))


#: L2 (its strips bend: a physical tracking error) under L1's torques along the line
PATH_SCENE = pj.PathScene(SmoothLine(), drive="torque", name="my-line")
PATH_OPTIONS = pj.SceneOptions(t_end=1.0, n_out=21)


@pytest.fixture(scope="module")
def path_report():
    return pj.run_scene(PATH_SCENE, model="double1r", options=PATH_OPTIONS)


def test_path_scene_l1_follows_its_own_tabulated_torques():
    """A `PathScene` tabulates L1's inverse-dynamics torques along the line; L1 driven by them
    follows the closed-form line to the table's and the integrator's accuracy."""
    r = pj.run_scene(PATH_SCENE, model="reduced", options=pj.SceneOptions(t_end=1.0, n_out=21))
    assert r.result.scene == "my-line"
    ref = _smooth_closed_form(np.asarray(r.ts))
    np.testing.assert_allclose(r.result.X, ref, rtol=0, atol=1e-8)


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_a_given_log_steps_to_its_knots_as_the_scenes_own_log():
    """`AbstractScene.run` with a given actuation (identification's route: the measured
    torques or angles of a log) steps to the log's knots, as the scene run by its own
    `command_log`: L1 under its own inverse-dynamics torques sampled at 25 Hz (C1 Hermite
    pieces, their derivative kinks at every sample) along the line, both routes in one program,
    equal to rounding. Stepping across the knots, the given log's run drifted away from the
    scene's (1e-6 m over 2 s on a 20 Hz log, `SceneInput`)."""
    model, robot = pj.Reduced(), pj.Robot(PATH_SCENE.default_params())
    tk = jnp.linspace(0.0, 1.0, 26)
    log = pj.Interpolated(tk, jax.vmap(pj.InverseDynamicsTorque(model, robot, SmoothLine()))(tk))
    own = pj.PathScene(SmoothLine(), drive="torque", command_log=log)
    opts = PATH_OPTIONS.prepared(model, SmoothLine())

    @eqx.filter_jit
    def both(robot):
        return (own.run(model, robot, opts).X,
                PATH_SCENE.run(model, robot, opts, pj.TorqueDriven(log)).X)

    X_own, X_given = both(robot)
    np.testing.assert_allclose(X_given, X_own, rtol=0, atol=1e-12)
    # and the log drives L1 along the line, to its interpolation error (1e-4 rad)
    np.testing.assert_allclose(X_own, _smooth_closed_form(np.asarray(opts.times())), atol=5e-4)


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_a_path_that_is_not_c2_is_refused():
    """The cosine law's acceleration jumps at the horizon's ends (t = 0 and t = duration): the
    tabulated torques jump too, and the scene says so instead of integrating them."""
    with pytest.raises(pj.SimulationError, match="not twice continuously differentiable"):
        pj.solve_scene(pj.PathScene(Line()), model="reduced", options=PATH_OPTIONS)


def test_path_scene_metrics_are_the_tracking_errors(path_report):
    """L2 leaves the line (its strips bend): the tracking metrics are computed here from the
    signals against the closed-form line, and the circle's radial error is absent."""
    m, r = path_report.metrics, path_report.result
    assert "radial_error_max_m" not in m
    ref = _smooth_closed_form(np.asarray(r.ts))
    d = np.hypot(*(np.asarray(r.X)[:, :2] - ref[:, :2]).T)
    dphi = np.asarray(r.X)[:, 2] - ref[:, 2]
    np.testing.assert_allclose(m["position_error_max_m"], d.max(), rtol=1e-9)
    np.testing.assert_allclose(m["position_error_rms_m"], np.sqrt(np.mean(d**2)), rtol=1e-9)
    np.testing.assert_allclose(m["position_error_end_m"], d[-1], rtol=1e-9)
    np.testing.assert_allclose(m["phi_error_end_rad"], abs(dphi[-1]), rtol=1e-9, atol=1e-15)
    assert 1e-7 < m["position_error_max_m"] < 1e-3, m["position_error_max_m"]


def test_register_scene_runs_by_name(path_report):
    pj.register_scene("my-line", PATH_SCENE)
    try:
        r = pj.solve_scene("my-line", model="double1r", options=PATH_OPTIONS)
        np.testing.assert_allclose(r.X, path_report.result.X, rtol=0, atol=1e-14)
        assert pj.scene_params("my-line").t == PATH_SCENE.thickness
    finally:
        from ppr_jax._scenes import SCENES

        SCENES.pop("my-line")


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_sweep_of_a_path_scene_matches_single_runs(path_report):
    """A sweep of the line over t: the member at the scene's thickness reproduces the single
    run's metrics (batched program against one robot's), a thinner strip leaves the line
    further, and a member whose chains cannot reach the path is reported, not run."""
    t0 = float(PATH_SCENE.thickness)
    res = pj.sweep(PATH_SCENE, vary={"t": [t0, 0.6 * t0]}, model="double1r",
                   options=PATH_OPTIONS, chunk_size=2)
    assert [r["status"] for r in res.rows] == ["ok", "ok"], res.rows
    assert "radial_error_max_m" not in res.columns and "position_error_rms_m" in res.columns
    row = res.rows[0]
    for k in ("position_error_max_m", "position_error_rms_m", "phi_error_max_rad",
              "torque_peak_Nm"):
        np.testing.assert_allclose(row[k], path_report.metrics[k], rtol=1e-7, err_msg=k)
    assert res.rows[1]["position_error_max_m"] > 1.5 * row["position_error_max_m"]
    far = pj.sweep(PATH_SCENE, vary={"l1": [0.05]}, model="double1r", options=PATH_OPTIONS)
    assert far.rows[0]["status"] == "failed" and "nominal path" in far.rows[0]["reason"]


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_sensitivity_of_a_path_scene_against_finite_differences():
    """d(position_error_rms)/dt and d(phi_error_rms)/dt by forward mode through the path scene
    equal central differences of single runs (RMS: smooth in t, no arg-max switching). The
    response rings at the robot's modes, whose phase after 1 s moves fast with t: a step of
    1e-3 t puts 3e-4 of truncation error into the difference quotient of phi (its third
    derivative), 1e-4 t about 1e-5; tight tolerances keep the solver's noise below that."""
    t0 = float(PATH_SCENE.thickness)
    tight = PATH_OPTIONS.updated(rtol=1e-11, atol=1e-13)
    s = pj.sensitivity(PATH_SCENE, model="double1r", parameters=["t"],
                       metrics=["position_error_rms_m", "phi_error_rms_rad"], options=tight)
    assert s.info["scene"] == "my-line"
    h = 1e-4 * t0
    vals = []
    for t in (t0 + h, t0 - h):
        r = pj.run_scene(PATH_SCENE, PATH_SCENE.default_params(t=t), model="double1r",
                         options=pj.SceneOptions(t_end=1.0, n_out=21, rtol=1e-11, atol=1e-13))
        vals.append([r.metrics["position_error_rms_m"], r.metrics["phi_error_rms_rad"]])
    fd = (np.asarray(vals[0]) - np.asarray(vals[1])) / (2 * h)
    np.testing.assert_allclose(s.jacobian[:, 0], fd, rtol=1e-4)
    assert abs(fd[0]) > 0


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_path_scene_motion_drive_and_synthesize():
    """The motion drive: L1's angles along the line prescribed; L0 and L1 need no integrator
    (kinematics), L2 integrates. `synthesize` samples the scene object like a registered one."""
    scene = pj.PathScene(SmoothLine(), drive="motion", name="my-line-servo", thickness=0.5e-3)
    assert not scene.needs_integrator(pj.Reduced()) and scene.needs_integrator(pj.Double1R())
    exp = pj.synthesize(scene, "reduced", noise_pos=0.0, noise_phi=0.0, rate=20.0, t_end=1.0)
    np.testing.assert_allclose(exp.X, _smooth_closed_form(np.asarray(exp.ts)), rtol=0,
                               atol=1e-10)


def test_path_scene_refuses_bad_members():
    with pytest.raises(pj.PPRError, match="drive must be one of torque, motion"):
        pj.PathScene(Line(), drive="servo")
    with pytest.raises(pj.PPRError, match="input_model must be a kinematic model"):
        pj.PathScene(Line(), input_model=pj.Double1R())
    with pytest.raises(pj.PPRError, match="thickness"):
        pj.PathScene(Line(), thickness=-1.0)
    log = pj.CommandLog(pj.Waypoints(np.linspace(0, 1, 5), np.zeros((5, 3))), "angles")
    with pytest.raises(pj.PPRError, match="command_log holds angles but drive='torque'"):
        pj.PathScene(Line(), drive="torque", command_log=log)


def _write_experiment_file(path, scene, rate=1000.0):
    """A controller's file of the smooth line: time, the commanded poses and the actuated
    angles L1's inverse kinematics commands for them (the file a user brings)."""
    ts = np.arange(0.0, 1.0 + 1e-9, 1.0 / rate)
    X = _smooth_closed_form(ts)
    robot = pj.Robot(scene.default_params())
    th = np.asarray(jax.vmap(pj.InverseKinematicsAngles(pj.Reduced(), robot, SmoothLine()))(
        jnp.asarray(ts)))
    # Full precision: the motion drive takes th'' from the log's spline, where a rounding of
    # the samples to 10 digits (1e-9 rad) is amplified by 1/h^2 (1e-3 rad/s^2 at 1 kHz) and
    # moves L2's tracking error by 2 %.
    np.savetxt(path, np.column_stack([ts, X, th]), delimiter=",", fmt="%.17g", comments="",
               header="time,x,y,phi,th_1,th_2,th_3")
    return path


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_cli_simulate_your_own_experiment(tmp_path):
    """`ppr-jax simulate --path F --angles F`: the commanded poses and the commanded angles of
    a file drive L2 (no scene of the paper's); the result agrees with the same experiment as
    a `PathScene` of the exact line driven by L1's exact inverse-kinematics angles as its
    command log (evaluated at every stage: the file's splines of 1 kHz samples against the
    functions they sample),
    and the CSV and figures are the path's (position error, not the circle's radial error)."""
    import json

    from ppr_jax._cli import main

    scene = pj.PathScene(SmoothLine(), drive="motion", name="line", thickness=0.5e-3)
    f = _write_experiment_file(tmp_path / "line.csv", scene)
    out = tmp_path / "out"
    rc = main(["simulate", "--path", str(f), "--angles", str(f), "--model", "double1r",
               "--n-out", "21", "--set", "t=0.5e-3", "--out", str(out)])
    assert rc == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["drive"] == "motion" and summary["t_end_s"] == 1.0
    got = summary["models"]["double1r"]
    # The file's splines are clamped: at rest before t = 0, so the start is the hold's balance
    # (`Waypoints.kinks`); the exact line's jerk jumps at t = 0, and its start is taken the
    # same way (a central stencil across that jump gives the mean of the rates before and
    # after it: position_error_max 8.6 % higher).
    line = OneSidedStart(SmoothLine())
    exact = pj.InverseKinematicsAngles(pj.Reduced(), pj.Robot(scene.default_params()), line)
    ref = pj.run_scene(pj.PathScene(line, drive="motion", command_log=exact,
                                    thickness=0.5e-3), model="double1r",
                       options=PATH_OPTIONS).metrics
    assert "radial_error_max_m" not in got
    # The same angles tabulated by the scene: 2 % off while the start read the table's
    # extrapolation before t = 0 (tests/test_horizon.py), 0.4 % while a panel spanned the
    # move's start at t = 0 (where its third derivative jumps); t0 is now a panel boundary.
    tab = pj.run_scene(pj.PathScene(line, drive="motion", name="line", thickness=0.5e-3),
                       model="double1r", options=PATH_OPTIONS).metrics
    for k in ("position_error_max_m", "position_error_rms_m", "phi_error_max_rad"):
        np.testing.assert_allclose(got[k], ref[k], rtol=1e-3, err_msg=k)
        np.testing.assert_allclose(tab[k], ref[k], rtol=1e-3, err_msg=k)
    assert (out / "position_error.png").exists() and not (out / "radial_error.png").exists()
    assert (out / "trajectory.csv").read_text().splitlines()[0].split(",")[5] == "e_pos"


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_cli_simulate_a_file_cut_out_of_a_motion(tmp_path):
    """`ppr-jax simulate --path F` on a figure eight sampled at 100 Hz that starts and ends
    mid-motion (nobody here chose it: not a circle, not at rest). With the loaders' default
    `--bc auto` the file is splined with natural ends, so L2's quasi-static start finds its
    balance (with clamped ends the spline stops the path at t = 0 within one sample step and
    the start failed: "the quasi-static initial state was not found"). The nominal path in
    trajectory.csv is scipy's natural spline through the samples (an independent
    interpolation), and L2 under L1's torques stays within a few millimetres of it (1.1 mm: a
    loop a second, faster than the paper's circle)."""
    import csv
    import json

    from scipy.interpolate import CubicSpline

    from ppr_jax._cli import main

    ts = np.arange(0.0, 0.3 + 1e-9, 0.01)
    w = 2 * np.pi
    X = np.column_stack([0.5 + 0.025 * np.cos(w * ts + 0.4), 0.27 + 0.012 * np.sin(2 * w * ts),
                         0.03 * np.cos(w * ts + 0.4)])
    f = tmp_path / "eight.csv"
    np.savetxt(f, np.column_stack([ts, X]), delimiter=",", fmt="%.17g", comments="",
               header="time,x,y,phi")
    out = tmp_path / "out"
    assert main(["simulate", "--path", str(f), "--model", "double1r", "--t-end", "0.2",
                 "--n-out", "21", "--out", str(out)]) == 0
    got = json.loads((out / "summary.json").read_text())["models"]["double1r"]
    assert 0 < got["position_error_max_m"] < 3e-3, got
    with open(out / "trajectory.csv") as fh:
        rows = [r for r in csv.DictReader(fh) if r["model"] == "nominal"]
    t = np.array([float(r["t"]) for r in rows])
    nominal = np.array([[float(r[k]) for k in ("x", "y", "phi")] for r in rows])
    np.testing.assert_allclose(nominal, CubicSpline(ts, X, bc_type="natural", axis=0)(t),
                               rtol=0, atol=1e-12)


def test_cli_command_log_options_are_checked(tmp_path, capsys):
    from ppr_jax._cli import main

    f = _write_experiment_file(tmp_path / "line.csv", PATH_SCENE)
    assert main(["simulate", "--angles", str(f), "--out", str(tmp_path / "o")]) == 2
    assert "--angles needs --path" in capsys.readouterr().err
    assert main(["simulate", "--path", str(f), "--angles", str(f), "--torques", str(f),
                 "--out", str(tmp_path / "o")]) == 2
    assert "not both" in capsys.readouterr().err


@pytest.mark.slow
def test_identify_gamma_on_the_line_scene_from_independent_data():
    """`identify` with the Line scene (a straight rest-to-rest move, not a circle) as the
    experiment's scene: tracker data of an L2 robot (gamma 0.80) under the scene's torques
    (L1's inverse dynamics along the line for the nominal robot, gamma 0.8314), made by the
    independent scipy L2 (benchmarks/contenders/scipy_l2.py: absolute coordinates, Lagrange
    multipliers) from the library's quasi-static start, with tracker noise. The fit, started at
    the nominal gamma, recovers the truth within two of its reported standard deviations.
    Slow: L2 and its Jacobian compile in a minute or more."""
    from benchmarks.contenders import known_truth, scipy_l2

    base = pj.RobotParams(t=0.5e-3, K_theta=2.5)
    truth = base.replace(gamma=0.80)
    noise = (1e-5, 1e-4)
    line = Line()
    torque = pj.InverseDynamicsTorque(pj.Reduced(), pj.Robot(base), line)
    exact = jax.jit(lambda t: torque(t))
    z0, zd0 = pj.quasi_static_state(pj.Double1R(), pj.Robot(truth), line, 0.0,
                                    pj.TorqueDriven(torque))
    model = scipy_l2.L2Model(truth, lambda t: np.asarray(exact(jnp.asarray(t, jnp.float64))))
    ts = np.arange(51) / 100.0  # 0.5 s at 100 Hz
    sol = scipy_l2.simulate(model, model.state_from_library(np.asarray(z0), np.asarray(zd0)),
                            ts, "DOP853", 1e-11, 1e-13)
    assert sol.status == 0
    X = sol.y[9:12].T
    noisy = known_truth.noisy(ts, X, np.zeros_like(X), *noise, 0.0, seed=3)
    exp = pj.experiment(noisy.ts, noisy.X, name="line, independent L2")
    fit = pj.identify(exp, ("gamma",), model="double1r", scene=LineScene(), params=base,
                      commands=base, noise=noise)
    assert fit.history["stop"] == "converged", fit.table()
    est, std = fit.estimate[0], fit.std[0]
    assert 0 < std < 0.01 and abs(est - 0.80) < 2 * std, fit.table()
    assert abs(fit.initial[0] - 0.80) > 3 * std  # the start was away from the truth
    assert 0.7 < np.sqrt(fit.sigma2) < 1.4, fit.table()


def test_options_enter_run_scene_as_one_object(line_report):
    """`run_scene` takes its options as one `SceneOptions`; the fields as keywords still work
    for one release with a `DeprecationWarning`, and both at once are refused."""
    with pytest.warns(DeprecationWarning, match="options=SceneOptions"):
        old = pj.run_scene(LineScene(), model="reduced", t_end=OPTIONS.t_end,
                           n_out=OPTIONS.n_out)
    np.testing.assert_array_equal(old.result.X, line_report.result.X)
    with pytest.raises(pj.PPRError, match="not both"):
        pj.run_scene(LineScene(), model="reduced", options=OPTIONS, t_end=1.0)
    with pytest.raises(TypeError, match="run_scene.. got an unexpected keyword argument 't_stop'"):
        pj.run_scene(LineScene(), model="reduced", t_stop=1.0)
    with pytest.raises(pj.PPRError, match="must be a SceneOptions"):
        pj.paper_circle(options={"t_end": 1.0})


def test_prepared_options_are_built_once_and_follow_every_field():
    """`SceneOptions.prepared` gives back one object for equal options, model and default
    trajectory (a warm call builds no modules), and a different one where any of them differs;
    options holding arrays are prepared afresh, with the same values."""
    from ppr_jax._scenes._options import SceneOptions
    from ppr_jax._scenes._registry import get_scene

    L1, L2 = pj.get_model("reduced"), pj.get_model("double1r")
    traj = get_scene("paper-circle").trajectory()
    a = SceneOptions(t_end=1.0).prepared(L1, traj)
    assert SceneOptions(t_end=1.0).prepared(L1, traj) is a
    assert float(a.t_end) == 1.0 and a.panels == 8 and a.trajectory is traj
    for other in (SceneOptions(t_end=2.0).prepared(L1, traj),
                  SceneOptions(t_end=1.0, rtol=1e-7).prepared(L1, traj),
                  SceneOptions(t_end=1.0).prepared(L2, traj),
                  SceneOptions(t_end=1.0).prepared(L1, pj.Circle())):
        assert other is not a
    assert float(SceneOptions(t_end=1.0, rtol=1e-7).prepared(L1, traj).rtol) == 1e-7
    b = SceneOptions(t_end=jnp.asarray(1.0)).prepared(L1, traj)
    assert b is not a and float(b.t_end) == 1.0 and b.panels == a.panels
