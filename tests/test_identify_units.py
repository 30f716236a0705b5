"""Identification of data in the wrong units or from another robot: refused before anything is
compiled, naming the column and the factor (before, they ended in "failed at t = 0.00055 ...
loosen tolerances or raise max_steps", where t was the strip thickness, after minutes of
compiling). The compiled residual is replaced by a tripwire: nothing here compiles a
simulation."""

from types import SimpleNamespace

import numpy as np
import pytest

import ppr_jax as pj
from ppr_jax._data import example_path
from ppr_jax._studies._identify import _run
from ppr_jax._studies._identify._fit import _check_ok


class Compiled(Exception):
    pass


@pytest.fixture
def tripwire(monkeypatch):
    def fail(*a, **k):
        raise Compiled

    monkeypatch.setattr(_run, "_residual_and_jacobian", fail)


@pytest.fixture(scope="module")
def example():
    """The library's servo-circle example (L2 data in SI units with th_i and tau_i)."""
    e = pj.load_csv(example_path())
    return tuple(np.asarray(v) for v in (e.ts, e.X, e.th, e.tau))


def _exp(example, X=1.0, th=None, tau=None):
    ts, X0, th0, tau0 = example
    return pj.experiment(ts, X0 * X, th0 if th is None else th(th0),
                         tau0 if tau is None else tau(tau0))


MEASURED = dict(scene="servo-circle", actuation="measured")
TORQUES = dict(scene="paper-circle")  # driven by the file's torques


@pytest.mark.parametrize("kw, change, match", [
    (MEASURED, dict(th=np.degrees),
     r"column th_1 looks like degrees read as radians: it is 57.3 times .*'th_1\[deg\]'"),
    (MEASURED, dict(th=lambda th: th * [1, 1e3, 1]),
     r"column th_2 looks like mrad read as radians: it is 1000 times .*--angle-unit mrad"),
    (MEASURED, dict(th=lambda th: th + [0, 0, 0.8]),
     r"column th_3 is 0.80. rad from the angle this robot needs .*far from any state the model "
     r"reaches"),
    (TORQUES, dict(tau=lambda tau: tau * 1e3),
     r"column tau_1 reaches 507.8 N m .* 1064 times the joint springs' stiffness .*far from any "
     r"state the model reaches; probably N mm read as N m \(a factor 1000\)"),
    # poses scaled 1.8 x: the first one is already far from where the scene starts (StartError,
    # checked first), the others out of reach
    (dict(scene="servo-circle"), dict(X=[1.8, 1.8, 1.0]),
     r"sample 1 \(t = 0 s\): the file's first pose .* is 486.2 mm .* from where the "
     r"servo-circle scene starts.*the data do not come from that experiment"),
])
def test_wrong_units_named_before_compiling(example, tripwire, kw, change, match):
    with pytest.raises((pj.DataError, pj.StartError), match=match):
        pj.identify(_exp(example, **change), ("t",), model="double1r", **kw)


@pytest.mark.parametrize("kw", [MEASURED, TORQUES, dict(scene="servo-circle")])
def test_plausible_data_pass_the_check(example, tripwire, kw):
    """The same data in SI units reach the compiled residual (the check refuses nothing real:
    the measured angles are within 2 mrad of the nominal inverse kinematics, the torques about
    1 K)."""
    with pytest.raises(Compiled):
        pj.identify(_exp(example), ("t",), model="double1r", **kw)


def _prob(**kw):
    """A stand-in problem: t as the one unknown, log-bounded in [0.1, 3] mm."""
    base = dict(names=("t", "K_theta"), lo=np.array([1e-4, 0.5]), hi=np.array([3e-3, 5.0]),
                log=(True, False), model=SimpleNamespace(name="double1r"),
                scene="paper-circle",
                options=SimpleNamespace(rtol=1e-8, atol=1e-9, max_steps=100000), tau=np.ones(3),
                th=None, n_init=0, experiment_names=("lab",))
    return SimpleNamespace(**(base | kw))


def test_failed_simulation_names_the_parameter():
    """A failure at the start names the thickness with its meaning and unit (it read 'failed at
    t = 0.00055', which looks like a time) and puts the data first; a failure during the fit
    keeps the solver's advice."""
    z = np.zeros(2)  # the middle of the bounds: t = sqrt(0.1 * 3) mm, K_theta = 2.75
    with pytest.raises(pj.IdentificationError) as err:
        _check_ok(np.array([1]), z, _prob(), start=True)
    msg = str(err.value)
    assert "strip thickness t = 0.547723 mm" in msg and "PRB stiffness coefficient K_theta = " \
        "2.75" in msg
    assert "driven by the measured torques" in msg
    assert "failed at the start of the fit, before anything was fitted" in msg
    assert "the data are far from any state the model reaches from this start" in msg
    assert "units" in msg and msg.index("units") < msg.index("loosen")
    assert "t = 0.000547" not in msg
    with pytest.raises(pj.IdentificationError, match=r"experiment 'lab' .*failed at strip "
                       r"thickness t = 0.547723 mm, .*\(rtol 1e-08"):
        _check_ok(np.array([1]), z, _prob(), start=False)
    _check_ok(np.array([0]), z, _prob(), start=True)  # a success passes


def test_identified_robot_without_an_assembled_state_keeps_the_toml(tmp_path, capsys):
    """A fitted robot whose chains cannot reach the home pose has no assembled state for the
    MJCF: identified.toml is still written, identified_l2.xml is skipped with one line naming
    why (to_mjcf's PPRError would otherwise end the command after the fit)."""
    from ppr_jax._cli._identify import _write_robot

    params = pj.scene_params("servo-circle").replace(l1=0.1, l3=0.1)
    fit = SimpleNamespace(names=("t",), model="double1r", experiment_names=("run0",),
                          params=params, quality={"residual_scale": 1.0, "problems": [],
                                                  "preflight_not_identifiable": []})
    paths = _write_robot(str(tmp_path), fit)
    assert [p.rsplit("/", 1)[-1] for p in paths] == ["identified.toml"]
    assert float(pj.load_params(paths[0]).l1) == 0.1
    assert not (tmp_path / "identified_l2.xml").exists()
    err = capsys.readouterr().err
    assert "identified_l2.xml not written" in err and "out of the chains' reach" in err
