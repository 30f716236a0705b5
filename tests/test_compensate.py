"""Compensation (`ppr_jax.compensate`): the commands of the model's inverse, checked against
what the library did not make.

- The independent scipy L2 (benchmarks/contenders/scipy_l2.py: 12 absolute coordinates, the
  loop closures as Lagrange multipliers) driven by the compensated angles, and separately by
  the compensated torques, of a figure eight nobody here chose (0.5 mm strips, 1 s at 100 Hz,
  the orientation moving too) follows the path at least 100 times closer than when driven by
  the nominal commands (L1's inverse kinematics and inverse dynamics). Both runs start from the
  library's state (the inverse's own at t = 0; the quasi-static start of the nominal commands):
  the commands and the start are all the two share.
- The command line's round trip: `compensate` writes the log that `simulate --path --torques`
  reads, and the replay reports the reduced error.
- The uncertainty band holds the tracking error of robots sampled from the covariance.
"""

import json
import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ppr_jax as pj
from benchmarks.contenders import scipy_l2
from ppr_jax._robot import Robot
from ppr_jax._statics import inverse_path

T_END, RATE = 1.0, 100.0
TS = np.linspace(0.0, T_END, int(T_END * RATE) + 1)
EIGHT = pj.Fourier(mean=[0.45, 0.15 * np.sqrt(3), 0.0], cos=[[0.0, 0.0, 0.02], [0.0, 0.0, 0.0]],
                   sin=[[0.08, 0.0, 0.0], [0.0, 0.05, 0.0]], omega=2.0)


@pytest.fixture(scope="module")
def setting():
    params = pj.scene_params("servo-circle")  # 0.5 mm strips, as the robot of the experiment
    X = np.asarray(jax.vmap(EIGHT)(jnp.asarray(TS)))
    return params, X


def _scipy_run(params, start, angles=None, torque=None):
    model = scipy_l2.L2Model(params, torque, angles=angles)
    sol = scipy_l2.simulate(model, model.state_from_library(*start), TS, "DOP853", 1e-10, 1e-12)
    assert sol.status == 0
    return sol.y[9:12].T  # the platform pose (x, y, phi) of the 24 states


def _miss(X, Xs):
    return np.linalg.norm(Xs[:, :2] - X[:, :2], axis=1).max(), np.abs(Xs[:, 2] - X[:, 2]).max()


@pytest.mark.parametrize("drive", ["motion", pytest.param("torque", marks=pytest.mark.slow)])
def test_scipy_l2_follows_the_compensated_commands(setting, drive):
    params, X = setting
    comp = pj.compensate(EIGHT, "double1r", params, drive=drive,
                         options=pj.SceneOptions(t_end=T_END), verify=False)
    assert comp.ts.shape == TS.shape and comp.change < 1e-8 and comp.flags == ()
    l2, robot = pj.get_model("double1r"), Robot(params)
    z0, zd0, *_ = inverse_path(l2, robot, EIGHT, np.array([0.0]))
    start = (np.asarray(z0[0]), np.asarray(zd0[0]))
    if drive == "motion":
        after = _scipy_run(params, start, angles=scipy_l2.AnglesSpline(TS, comp.commands))
        nominal = pj.InverseKinematicsAngles(pj.Reduced(), robot, EIGHT)
        act = pj.MotionDriven(nominal)
        before_cmd = dict(angles=scipy_l2.AnglesSpline(
            TS, np.asarray(jax.vmap(nominal)(jnp.asarray(TS)))))
    else:
        after = _scipy_run(params, start, torque=scipy_l2.TorqueSpline(TS, comp.commands))
        nominal = pj.InverseDynamicsTorque(pj.Reduced(), robot, EIGHT)
        act = pj.TorqueDriven(nominal)
        before_cmd = dict(torque=scipy_l2.TorqueSpline(
            TS, np.asarray(jax.vmap(nominal)(jnp.asarray(TS)))))
    zb, zdb = pj.quasi_static_state(l2, params, EIGHT, 0.0, act)
    before = _scipy_run(params, (np.asarray(zb), np.asarray(zdb)), **before_cmd)
    miss_before, phi_before = _miss(X, before)
    miss_after, phi_after = _miss(X, after)
    # the nominal commands miss by a tenth of a millimetre (motion 2.8e-4 m, torque 8e-5 m)
    assert miss_before > 3e-5
    assert miss_after * 100 < miss_before, (miss_after, miss_before)
    assert phi_after * 100 < phi_before, (phi_after, phi_before)


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_the_inverse_of_a_clamped_move_holds_from_its_start(setting):
    """A rest-to-rest move (a cosine time law: its acceleration jumps at both ends) sampled at
    100 Hz and splined clamped, as `load_path` splines a file at rest at both ends: its
    inverse was refused at t = 0 ("no inverse") while the inverse's grid reached across the
    jump (`Waypoints.kinks`), or 2 % off. Now the independent scipy L2, at the inverse's states
    under its torques, accelerates the platform as the path does from the first sample on,
    and driven by its angles from its first state follows the path 100 times closer than
    under the nominal angles."""
    params, _ = setting
    u = (1.0 - np.cos(np.pi * TS / T_END)) / 2.0
    X = np.array([0.42, 0.24, -0.01]) + u[:, None] * np.array([0.05, 0.03, 0.03])
    path = pj.Waypoints(TS, X)  # clamped
    l2, robot = pj.get_model("double1r"), Robot(params)
    z, zd, _, tau, change, _, failed = (np.asarray(a) for a in
                                        inverse_path(l2, robot, path, TS))
    assert not failed.any()
    Xdd = np.asarray(jax.vmap(jax.jacfwd(jax.jacfwd(path)))(jnp.asarray(TS)))
    assert np.abs(Xdd[0, :2]).max() > 0.1  # m/s^2: the jump at t = 0 is real
    err = []
    for k in range(TS.shape[0]):
        m = scipy_l2.L2Model(params, lambda t, k=k: tau[k])
        acc = m.rhs(TS[k], m.state_from_library(z[k], zd[k]))[21:23]
        err.append(np.abs(acc - Xdd[k, :2]).max())
    err = np.array(err)
    # observed 6e-8 m/s^2 at the first samples (2 % of the path's 0.25 m/s^2 while the grid
    # reached across the jump), 5e-8 after them
    assert err[:3].max() < 1e-5 * np.abs(Xdd[0, :2]).max(), err[:3]
    assert err[3:-3].max() < 1e-5 * np.abs(Xdd[:, :2]).max(), err[3:-3].max()
    # and its angles, replayed from its start, follow the path: 2.7e-7 m against 9.5e-5 m
    # under the nominal angles (with the start of a grid across the jump: 3e-4 m)
    after = _scipy_run(params, (z[0], zd[0]), angles=scipy_l2.AnglesSpline(TS, z[:, 3:]))
    nominal = pj.InverseKinematicsAngles(pj.Reduced(), robot, path)
    zb, zdb = pj.quasi_static_state(l2, params, path, 0.0, pj.MotionDriven(nominal))
    before = _scipy_run(params, (np.asarray(zb), np.asarray(zdb)), angles=scipy_l2.AnglesSpline(
        TS, np.asarray(jax.vmap(nominal)(jnp.asarray(TS)))))
    miss_after, miss_before = _miss(X, after)[0], _miss(X, before)[0]
    assert miss_after * 100 < miss_before, (miss_after, miss_before)


def test_the_inverse_on_a_spline_diverging_at_its_knots_keeps_its_best_pass():
    """A random clamped spline through 9 samples (nobody here chose it) and Table 1's robot
    (0.5 mm strips, gamma 0.85): the inverse's passes diverge at the spline's knots, where its
    jerk jumps (changes 1e-2 rad at the second pass, NaN at the third, which the differences
    spread over the whole grid: compensate refused the path, "no inverse at t = 0"). The
    inverse now keeps the pass that changed least: it fails nowhere, says where it did not
    settle (at a knot), and away from the knots its states are the independent scipy L2's
    balance (the platform's acceleration the path's: observed 2e-5 of its scale from 25 ms
    off a knot on, 7e-2 within 10 ms of one)."""
    from ppr_jax._studies._compensate import CHANGE_TOL, _unsettled

    params = pj.scene_params("paper-circle")
    rng = np.random.default_rng(20261130)
    knots = np.linspace(0.0, 0.8, 9)
    home = np.array([0.45, 0.15 * np.sqrt(3.0), 0.0])
    path = pj.Waypoints(knots, home + rng.uniform(-1.0, 1.0, (9, 3)) * [0.01, 0.01, 0.03])
    ts = np.arange(0.0, 0.8 + 1e-9, 0.005)
    z, zd, _, tau, change, change_t, failed = (
        np.asarray(a) for a in inverse_path(pj.get_model("double1r"), Robot(params), path, ts))
    assert not failed.any() and np.isfinite(change) and change > CHANGE_TOL, change
    near = np.abs(knots - change_t).min()
    assert near <= 0.01, change_t
    flag = _unsettled(path, float(change), float(change_t))
    assert "its knot t = " in flag and "fast for the inverse" not in flag, flag
    Xdd = np.asarray(jax.vmap(jax.jacfwd(jax.jacfwd(path)))(jnp.asarray(ts)))[:, :2]
    off = np.abs(ts[:, None] - knots[None]).min(axis=1) > 0.025
    err = []
    for k in np.nonzero(off)[0]:
        m = scipy_l2.L2Model(params, lambda t, k=k: tau[k])
        err.append(np.abs(m.rhs(ts[k], m.state_from_library(z[k], zd[k]))[21:23] - Xdd[k]).max())
    assert max(err) < 1e-4 * np.abs(Xdd).max(), max(err)


@pytest.fixture(scope="module")
def eight_csv(tmp_path_factory):
    """The figure eight's samples as a path file (a cubic spline through them, as a user's)."""
    X = np.asarray(jax.vmap(EIGHT)(jnp.asarray(TS)))
    path = tmp_path_factory.mktemp("eight") / "eight.csv"
    rows = ["time[s],x[m],y[m],phi[rad]"] + [
        ",".join(repr(float(v)) for v in (t, *x)) for t, x in zip(TS, X)]
    path.write_text("\n".join(rows) + "\n")
    return path


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_command_line_round_trip(eight_csv, tmp_path):
    """`compensate --path F` writes torques.csv; `simulate --path F --torques` replays it and
    reports the compensated error (L0: cheap to compile; its nominal torques, L1's, take it
    6 cm off the path)."""
    from ppr_jax._cli._main import main

    path = eight_csv
    out, sim = tmp_path / "comp", tmp_path / "sim"
    assert main(["compensate", "--path", str(path), "--model", "rigid", "--drive", "torque",
                 "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert (out / "torques.csv").read_text().startswith("# spline: not-a-knot")
    assert (out / "tracking_error.png").exists()
    assert main(["simulate", "--path", str(path), "--torques", str(out / "torques.csv"),
                 "--model", "rigid", "--out", str(sim)]) == 0
    replay = json.loads((sim / "summary.json").read_text())["models"]["rigid"]
    before, after = summary["position_error_before_m"], summary["position_error_after_m"]
    assert before > 0.01 and after * 100 < before
    # the replay samples its own output times (755 by default): the same error to 1 %
    np.testing.assert_allclose(replay["position_error_max_m"], after, rtol=0.01)


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_band_holds_sampled_robots():
    """The linearised band over a thickness uncertainty (2 %) holds the whole tracking error
    of at least 90 % of robots drawn from it (L1, torque drive: the compensated torques of the
    estimate applied to every drawn robot)."""
    from ppr_jax._studies._compensate import error_band

    params = pj.scene_params("servo-circle")
    opts = pj.SceneOptions(t_end=0.5, n_out=51)
    comp = pj.compensate(EIGHT, "reduced", params, drive="torque", options=opts)
    sd = 0.02 * float(params.t)
    ident = types.SimpleNamespace(names=("t",), estimate=np.array([float(params.t)]),
                                  covariance=np.array([[sd**2]]), params=params)
    band = error_band(ident, pj.get_model("reduced"), EIGHT, "torque", comp.log, opts,
                      comp.after)
    assert band["half_width"].shape == (51, 3) and band["half_width"].max() > 0
    draws = float(params.t) + sd * np.random.default_rng(0).standard_normal(40)
    batch = pj.stack_params([params.replace(t=float(t)) for t in draws])
    rep = pj.run_scene(pj.PathScene(EIGHT, drive="torque", command_log=comp.log), batch,
                       model="reduced", options=opts)
    e = np.asarray(rep.result.X) - np.asarray(rep.result.X_nominal)
    held = np.all(np.abs(e - band["error"]) <= band["half_width"] * (1 + 1e-9) + 1e-15,
                  axis=(1, 2))
    assert held.mean() >= 0.9, held.mean()
    # and the band is not vacuous: the drawn robots' errors span a good part of it
    assert np.abs(e - band["error"]).max() > 0.3 * band["half_width"].max()


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_optimisation_refines_the_inversion(eight_csv):
    """On a path of cubic samples the inverse's torques, splined again, leave L0 3e-5 m off;
    Levenberg-Marquardt on a smooth correction through the simulation takes that at least 3
    times lower, each accepted step lowering the cost. A torque limit below the commands is
    flagged with its first time."""
    path = pj.load_path(str(eight_csv))
    inv = pj.compensate(path, "rigid", None, drive="torque")
    opt = pj.compensate(path, "rigid", None, drive="torque", method="optimise", max_iter=6)
    assert opt.method == "optimise" and opt.fit["iterations"] >= 1
    assert np.all(np.diff(opt.fit["history"]) < 0)
    assert opt.error["after"]["position_max"] * 3 < inv.error["after"]["position_max"]
    limited = pj.compensate(path, "rigid", None, drive="torque", limits={"torque": 1e-3},
                            verify=False)
    assert any(f.startswith("torque limit 0.001 N m exceeded from t = 0 s") for f in
               limited.flags), limited.flags
    with pytest.raises(pj.PPRError, match="method must be one of inversion, optimise"):
        pj.compensate(path, "rigid", None, method="newton")
    for kw, match in (({"knots": 2}, r"knots = 2 is out of its allowed range \[3, "),
                      ({"max_iter": 0}, r"max_iter = 0 is out of its allowed range \[1, "),
                      ({"jacobian": "reverse"}, "jacobian must be one of differences, forward")):
        with pytest.raises(pj.PPRError, match=match):
            pj.compensate(path, "rigid", None, method="optimise", **kw)


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_jacobian_by_differences_is_forward_modes(eight_csv):
    """The optimisation's default Jacobian, forward differences of one vmapped batch of replays,
    is forward mode's through the solve (L0, the torque drive, 12 knots: 36 columns) to 1e-5
    relative."""

    import diffrax

    from ppr_jax._studies import _compensate_fit as F

    path = pj.load_path(str(eight_csv))
    inv = pj.compensate(path, "rigid", None, drive="torque", verify=False)
    ts, knots = inv.ts, 12
    basis = jax.vmap(pj.Waypoints(np.linspace(ts[0], ts[-1], knots), np.eye(knots),
                                  bc="not-a-knot"))(jnp.asarray(ts))
    opts = pj.SceneOptions(t_end=float(ts[-1]), n_out=int(ts.shape[0]),
                           adjoint=diffrax.ForwardMode())
    fit = F._Fit(path=path, u0=jnp.asarray(inv.commands), basis=basis,
                 ts=tuple(float(t) for t in ts), drive="torque", kind="torque",
                 model=pj.get_model("rigid"), options=opts)
    params = pj.PathScene(path, drive="torque").default_params()
    c = jnp.zeros((knots, 3))
    h = F.FD_STEP * float(np.abs(inv.commands).max())
    Jd, code = F._differences(fit, c, params, h)
    Jf = np.asarray(F._jacobian(fit, c, params)).reshape(Jd.shape)
    assert int(code) == 0
    assert np.abs(np.asarray(Jd) - Jf).max() < 1e-5 * np.abs(Jf).max()
    # and it is not trivially so: the columns differ from one another
    assert np.abs(Jf[:, 0] - Jf[:, 1]).max() > 0.1 * np.abs(Jf).max()


def test_readme_row_is_the_benchmarks():
    """README's compensation row is what benchmarks/results/compensate.json holds
    (`scripts/gen_perf.compensate_headline`), not numbers copied by hand."""
    import importlib.util
    import pathlib

    root = pathlib.Path(__file__).resolve().parents[1]
    spec = importlib.util.spec_from_file_location("gen_perf", root / "scripts" / "gen_perf.py")
    gen = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gen)
    row = [ln for ln in (root / "README.md").read_text().splitlines()
           if ln.startswith("| compensation, L2")]
    assert len(row) == 1 and gen.compensate_headline() in row[0], gen.compensate_headline()
    assert "<!-- perf:compensate -->" in (root / "docs" / "compensation.md").read_text()
    assert gen.tables()["compensate"].count("\n| double1r") == 2


def test_a_path_out_of_reach_is_named():
    """A figure eight moved 0.4 m off the workspace: refused naming the first time where the
    model has no inverse, before any simulation."""
    far = pj.Fourier(mean=[0.85, 0.15 * np.sqrt(3), 0.0], cos=EIGHT.cos, sin=EIGHT.sin,
                     omega=2.0)
    with pytest.raises(pj.CompensationError, match=r"rigid model has no inverse on the path "
                                                   r"at t = 0 s"):
        pj.compensate(far, "rigid", None, drive="torque", options=pj.SceneOptions(t_end=T_END))


def test_refusals_name_the_argument():
    """Before any compilation: a batch of robots, a scene that replays a log, an unknown
    drive, command times that do not start at 0."""
    p = pj.scene_params("servo-circle")
    with pytest.raises(pj.PPRError, match="params: one robot, not a batch of 2"):
        pj.compensate(EIGHT, "rigid", pj.stack_params([p, p]))
    log = pj.CommandLog(pj.Waypoints(TS, np.zeros((TS.shape[0], 3)), bc="natural"), "torque")
    with pytest.raises(pj.PPRError, match="replays a command log"):
        pj.compensate(pj.PathScene(EIGHT, command_log=log), "rigid", p)
    with pytest.raises(pj.PPRError, match="drive must be one of motion, torque"):
        pj.compensate(EIGHT, "rigid", p, drive="servo")
    with pytest.raises(pj.PPRError, match="times must be at least 4"):
        pj.compensate(EIGHT, "rigid", p, times=[0.1, 0.2, 0.3, 0.4])


def test_commands_at_a_rate_span_a_sampled_path():
    """At a `rate`, a sampled path's commands span its samples (they spanned the scenes'
    default 7.54 s, beyond a 2 s path, and the replay refused the log as not covering it);
    options' horizon, where given, decides."""
    from ppr_jax._studies._compensate import _grid

    ts = np.linspace(0.0, 2.0, 5)
    path = pj.Waypoints(ts, np.array([0.45, 0.26, 0.0]) + 1e-3 * ts[:, None])
    np.testing.assert_array_equal(_grid(path, None, 50.0), np.linspace(0.0, 2.0, 101))
    np.testing.assert_array_equal(_grid(path, None, None), ts)
    np.testing.assert_array_equal(_grid(path, pj.SceneOptions(t_end=1.0), 50.0),
                                  np.linspace(0.0, 1.0, 51))
    assert _grid(EIGHT, None, 10.0)[-1] == pj.SceneOptions().t_end  # no samples of its own
