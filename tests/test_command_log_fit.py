"""A command log against the path it drives, checked before anything is compiled: its time span
must cover the path's (`check_log_covers`), and an angle log's angles must belong to the robot's
assembly mode at the path's poses (`check_assembly_mode`, identification's check too). Each
refusal is a `PPRError` subclass naming the file in the API, and one line with exit status 2 on
the command line, for every command that takes a log (`simulate`, `sweep`, `sensitivity`,
`synth`). Every test here is host-side: a guard fails any that reaches a scene's compiled run.
"""

import numpy as np
import pytest

import ppr_jax as pj
from ppr_jax._assembly import HostGeometry

CENTER = np.array([0.45, 0.26, 0.0])


def _poses(ts):
    """A figure eight about the workspace centre (SI), within 30 mm and 0.03 rad."""
    w = 2 * np.pi
    return CENTER + np.column_stack([0.03 * np.sin(w * ts), 0.02 * np.sin(2 * w * ts),
                                     0.03 * np.sin(w * ts)])


def _write(path, header, rows):
    np.savetxt(path, rows, delimiter=",", fmt="%.17g", comments="", header=header)
    return str(path)


def _angles(ts, mode="own", chains=(0, 1, 2), params=None):
    """L1's actuated angles (n, 3) for the poses at ts, in the robot's assembly mode or, for
    `chains`, in the other one (the elbow orientation of RobotParams(sigma=+1))."""
    own, other, _ = HostGeometry(pj.RobotParams() if params is None else params).ik(_poses(ts))
    th = own.copy()
    if mode == "other":
        th[:, list(chains)] = np.unwrap(other[:, list(chains)], axis=0)
    return th


@pytest.fixture
def files(tmp_path):
    """(path file 0-1 s at 100 Hz, {name: log file})."""
    ts = np.linspace(0.0, 1.0, 101)
    path = _write(tmp_path / "path.csv", "time,x,y,phi", np.column_stack([ts, _poses(ts)]))
    half = ts[ts <= 0.5 + 1e-9]
    late = ts + 0.2  # stamped 0.2-1.2 s: the same commands, another clock's start
    logs = {
        "full": _write(tmp_path / "full.csv", "time,th_1,th_2,th_3",
                       np.column_stack([ts, _angles(ts)])),
        "half": _write(tmp_path / "half.csv", "time,th_1,th_2,th_3",
                       np.column_stack([half, _angles(half)])),
        "late": _write(tmp_path / "late.csv", "time,th_1,th_2,th_3",
                       np.column_stack([late, _angles(ts)])),
        "torque_half": _write(tmp_path / "torque_half.csv", "time,tau_1,tau_2,tau_3",
                              np.column_stack([half, np.zeros((half.size, 3))])),
        "other": _write(tmp_path / "other.csv", "time,th_1,th_2,th_3",
                        np.column_stack([ts, _angles(ts, "other")])),
        "chain2": _write(tmp_path / "chain2.csv", "time,th_1,th_2,th_3",
                         np.column_stack([ts, _angles(ts, "other", chains=(1,))])),
        "degrees": _write(tmp_path / "degrees.csv", "time,th_1,th_2,th_3",
                          np.column_stack([ts, np.degrees(_angles(ts))])),
    }
    return path, logs


@pytest.fixture
def no_run(monkeypatch):
    """Fail the test if a scene's run is traced (the refusal came after compilation began)."""
    from ppr_jax._scenes._base import AbstractScene

    def guard(*args, **kw):
        raise AssertionError("a scene's run was traced: the refusal came too late")

    monkeypatch.setattr(AbstractScene, "run", guard)


# ---------------------------------------------------------------------------------------------
# The span


def test_a_log_that_does_not_cover_its_path_is_refused(files, no_run):
    path, logs = files
    traj = pj.load_path(path)
    full = pj.load_commands(logs["full"])
    pj.PathScene(traj, drive="motion", command_log=full)  # covers: accepted
    with pytest.raises(pj.CommandLogError,
                       match=r"half.csv: the command log spans t = 0 to 0.5 s but the path "
                             r"path.csv spans t = 0 to 1 s: it ends 0.5 s before it"):
        pj.PathScene(traj, drive="motion", command_log=pj.load_commands(logs["half"]))
    with pytest.raises(pj.CommandLogError,
                       match=r"late.csv: the command log spans t = 0.2 to 1.2 s .* it starts "
                             r"0.2 s after it"):
        pj.PathScene(traj, drive="motion", command_log=pj.load_commands(logs["late"]))
    with pytest.raises(pj.CommandLogError, match=r"torque_half.csv: .* ends 0.5 s before"):
        pj.PathScene(traj, drive="torque", command_log=pj.load_commands(logs["torque_half"]))
    # a PPRError and a DataError, as every refused file
    assert issubclass(pj.CommandLogError, pj.DataError)


def test_a_log_may_miss_half_a_sample_step_at_either_end(files):
    path, _ = files
    traj = pj.load_path(path)
    ts = np.linspace(0.004, 0.996, 100)  # step 0.01 s: 0.004 s short at both ends, allowed
    log = pj.CommandLog(pj.Waypoints(ts, np.zeros((ts.size, 3))), "torque")
    pj.check_log_covers(traj, log)
    short = pj.CommandLog(pj.Waypoints(ts - 0.002, np.zeros((ts.size, 3))), "torque")
    with pytest.raises(pj.CommandLogError, match=r"ends 0.006 s before it \(allowed 0.5 "
                                                 r"sample step, 0.00501 s\)"):
        pj.check_log_covers(traj, short)


def test_a_path_without_samples_is_covered_over_the_horizon(files):
    """A formula path (a `Line`): the log must span the run's horizon [0, t_end]."""
    _, logs = files
    line = pj.Line(CENTER, CENTER + 0.01, 1.0)
    log = pj.load_commands(logs["half"])
    pj.check_log_covers(line, log, t_end=0.5)
    with pytest.raises(pj.CommandLogError, match=r"half.csv: .* but the run spans t = 0 to "
                                                 r"0.8 s: it ends 0.3 s before it"):
        pj.check_log_covers(line, log, t_end=0.8)


@pytest.mark.parametrize("command", ["simulate", "sweep", "sensitivity", "synth"])
def test_cli_refuses_a_short_log_in_one_line(files, tmp_path, capsys, no_run, command):
    from ppr_jax._cli import main

    path, logs = files
    extra = {"sweep": ["--vary", "t=0.2e-3,0.4e-3"], "sensitivity": [],
             "simulate": ["--out", str(tmp_path / "o")],
             "synth": ["--out", str(tmp_path / "s.csv")]}[command]
    if command in ("sweep", "sensitivity"):
        extra = extra + ["--out", str(tmp_path / "o")]
    assert main([command, "--path", path, "--angles", logs["half"], *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "half.csv: the command log spans t = 0 to 0.5 s" in err[0], err


# ---------------------------------------------------------------------------------------------
# The assembly mode


def test_angles_of_the_other_assembly_mode_are_refused_before_a_run(files, no_run):
    path, logs = files
    params = pj.RobotParams()
    traj = pj.load_path(path)
    opts = pj.SceneOptions(t_end=1.0, n_out=11)
    own = pj.PathScene(traj, drive="motion", command_log=pj.load_commands(logs["full"]))
    own.check_commands(params, traj, 1.0)  # the robot's own mode: accepted
    for name, chain in (("other", 1), ("chain2", 2)):
        scene = pj.PathScene(traj, drive="motion", command_log=pj.load_commands(logs[name]))
        with pytest.raises(pj.AssemblyModeError,
                           match=rf"{name}.csv: sample at t = 0 s: the actuated angle "
                                 rf"th_{chain} = .* belongs to the other assembly mode of chain "
                                 rf"{chain} \(elbow orientation sigma = \+1\) .*101 of 101 "
                                 rf"samples.*set sigma=1"):
            pj.solve_scene(scene, params, model="double1r", options=opts)
    # the same angles are the robot's own for a robot assembled the other way
    other = pj.PathScene(traj, drive="motion", command_log=pj.load_commands(logs["other"]))
    other.check_commands(params.replace(sigma=1), traj, 1.0)


@pytest.mark.parametrize("study", ["sweep", "sensitivity", "design"])
def test_the_studies_refuse_angles_of_the_other_mode(files, no_run, study):
    """The API's studies make the scenes' check of their commands before compiling."""
    path, logs = files
    scene = pj.PathScene(pj.load_path(path), drive="motion",
                         command_log=pj.load_commands(logs["chain2"]))
    opts = pj.SceneOptions(t_end=1.0, n_out=11)
    run = {"sweep": lambda: pj.sweep(scene, vary={"t": [0.2e-3, 0.4e-3]}, options=opts),
           "sensitivity": lambda: pj.sensitivity(scene, parameters=["t"], options=opts),
           "design": lambda: pj.design({"t": (0.2e-3, 0.6e-3)}, "position_error_max_m",
                                       scene=scene, options=opts)}[study]
    with pytest.raises(pj.AssemblyModeError, match=r"chain2.csv: sample at t = 0 s: .*th_2"):
        run()


#: a base side at which the default robot's own angles along `_poses` belong to chain 3's other
#: assembly mode (the poses still in reach)
A_OTHER = 0.45


def test_each_member_of_a_batch_is_judged_in_its_own_mode(files, no_run):
    """The assembly mode is each robot's: the full log's angles are the default robot's own,
    and for a member with the base side `A_OTHER` chain 3's other mode's (the host inverse
    kinematics of both elbows says so, independently of the check). A batch whose first member
    fits is refused naming the member that does not; a sweep's validation refuses that member
    alone, with the reason."""
    path, logs = files
    traj = pj.load_path(path)
    scene = pj.PathScene(traj, drive="motion", command_log=pj.load_commands(logs["full"]))
    p0, p1 = pj.RobotParams(), pj.RobotParams().replace(a=A_OTHER)
    ts = np.linspace(0.0, 1.0, 101)
    own, other, c = HostGeometry(p1).ik(_poses(ts))
    th = _angles(ts)
    assert np.all(np.abs(c) < 1)  # in reach
    assert np.all(np.abs(th[:, 2] - other[:, 2]) < np.abs(th[:, 2] - own[:, 2]))
    opts = pj.SceneOptions(t_end=1.0, n_out=11)
    with pytest.raises(pj.AssemblyModeError, match=r"batch member 1: full.csv: sample at t = 0 "
                                                   r"s: .*th_3 .* other assembly mode of chain 3"):
        pj.run_scene(scene, pj.stack_params([p0, p1]), model="reduced", options=opts)
    from ppr_jax._studies import validate_members

    plist, reasons = validate_members(scene, p0, {"a": [float(p0.a), A_OTHER]},
                                      trajectory=traj, t_end=1.0)
    assert reasons[0] == "" and plist[0] is not None
    assert plist[1] is None and "other assembly mode of chain 3" in reasons[1], reasons


def test_an_experiment_in_the_other_mode_is_refused_by_the_scene_it_makes(no_run):
    """`experiment_scene` of a file whose angles belong to the other mode: `solve_scene`
    refuses it (the API's path from a measured experiment to a run)."""
    ts = np.linspace(0.0, 1.0, 101)
    exp = pj.experiment(ts, _poses(ts), th=_angles(ts, "other", chains=(2,)), name="exp.csv")
    with pytest.raises(pj.AssemblyModeError, match=r"exp.csv: sample at t = 0 s: .*th_3 .* "
                                                   r"other assembly mode of chain 3"):
        pj.solve_scene(pj.experiment_scene(exp), model="double1r",
                       options=pj.SceneOptions(t_end=1.0, n_out=11))


def test_angles_in_degrees_are_called_degrees_not_another_mode(files, no_run):
    """Undeclared degrees are beyond two turns: 'probably degrees', before a mode message, in
    a log without the loader's unit check and in identification's check alike."""
    path, logs = files
    traj = pj.load_path(path)
    log = pj.load_commands(logs["degrees"], check_units=False)
    scene = pj.PathScene(traj, drive="motion", command_log=log)
    with pytest.raises(pj.AssemblyModeError, match=r"degrees.csv: sample at t = [\d.]+ s: "
                                                   r"actuated angle .* beyond two turns: "
                                                   r"probably degrees"):
        scene.check_commands(pj.RobotParams(), traj, 1.0)


def test_identification_calls_undeclared_degrees_degrees(no_run):
    """Identification's start check is the same check: degrees, not 'the other assembly
    mode'."""
    ts = np.linspace(0.0, 1.0, 101)
    exp = pj.experiment(ts, _poses(ts), th=np.degrees(_angles(ts)), name="deg.csv")
    with pytest.raises(pj.StartError, match=r"deg.csv: sample \d+ .*probably degrees"):
        pj.identify(exp, ("gamma",), model="double1r", params=pj.RobotParams())


@pytest.mark.parametrize("command", ["simulate", "sweep", "sensitivity", "synth"])
def test_cli_refuses_angles_of_the_other_mode_in_one_line(files, tmp_path, capsys, no_run,
                                                          command):
    from ppr_jax._cli import main

    path, logs = files
    extra = {"sweep": ["--vary", "t=0.2e-3,0.4e-3", "--out", str(tmp_path / "o")],
             "sensitivity": ["--out", str(tmp_path / "o")],
             "simulate": ["--out", str(tmp_path / "o"), "--model", "double1r"],
             "synth": ["--out", str(tmp_path / "s.csv")]}[command]
    assert main([command, "--path", path, "--angles", logs["chain2"], *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "chain2.csv: sample at t = 0 s" in err[0], err
    assert "other assembly mode of chain 2" in err[0], err
