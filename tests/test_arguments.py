"""Bad arguments to the studies and their files: each a `PPRError` subclass naming the argument
(and the file) and what is allowed, raised before anything is compiled, never a TypeError,
IndexError, OverflowError or numpy's ValueError from deep inside; on the command line one line
and exit status 2. Every case here fails before any XLA program is built, so the file is cheap."""

import numpy as np
import pytest

import ppr_jax as pj
from ppr_jax._cli import main
from ppr_jax._studies import load_design_spec
from tests.helpers import DESIGN_SPEC

BOUNDS = {"t": (1e-4, 1e-3), "r": (0.01, 0.04), "w": (0.01, 0.03)}
HUGE = 10**400


@pytest.fixture(scope="module")
def exp():
    """Five samples at home with torques: enough to reach identify's argument checks."""
    ts = np.linspace(0.0, 0.04, 5)
    X = np.tile([0.45, 0.26, 0.0], (5, 1))
    return pj.experiment(ts, X, tau=np.zeros((5, 3)), name="home")


IDENTIFY = [
    # (keywords, error class, words the message must hold)
    (dict(initial={"t": None}), pj.IdentificationError, ["initial value of 't'", "None",
                                                         "[1e-06, 0.01] m"]),
    (dict(initial={"t": [3e-4]}), pj.IdentificationError, ["initial value of 't'", "[0.0003]"]),
    (dict(initial={"t": HUGE}), pj.IdentificationError, ["initial value of 't'",
                                                         "401 digits"]),
    (dict(initial=5), pj.IdentificationError, ["initial must be a mapping", "int"]),
    (dict(bounds={"t": (1e-4,)}), pj.IdentificationError, ["bounds of 't'", "(lo, hi)",
                                                           "(0.0001,)"]),
    (dict(bounds={"t": 1e-4}), pj.IdentificationError, ["bounds of 't'", "(lo, hi)"]),
    (dict(bounds={"t": ("a", "b")}), pj.IdentificationError, ["bounds of 't'",
                                                              "two finite numbers"]),
    (dict(bounds={"t": (1e-4, 1e-3, 5)}), pj.IdentificationError, ["bounds of 't'",
                                                                   "(0.0001, 0.001, 5)"]),
    (dict(bounds={"t": (1e-4, HUGE)}), pj.IdentificationError, ["bounds of 't'"]),
    (dict(bounds={"t": (1e-3, 1e-4)}), pj.IdentificationError, ["bounds of 't'",
                                                                "must satisfy"]),
    (dict(bounds=[1e-4, 1e-3]), pj.IdentificationError, ["bounds must be a mapping"]),
    (dict(fit_options=pj.FitOptions(nuisance=5)), pj.IdentificationError,
     ["nuisance", "bias, delay"]),
    (dict(fit_options=pj.FitOptions(nuisance=["bias", "drift"])), pj.IdentificationError,
     ["'drift'", "bias, delay"]),
    (dict(params="x"), pj.IdentificationError, ["params must be a RobotParams", "str"]),
    (dict(commands=3), pj.IdentificationError, ["commands must be a RobotParams"]),
    (dict(fixed={"E": HUGE}), pj.IdentificationError, ["'E'", "401 digits"]),
    (dict(fixed={"E": "abc"}), pj.IdentificationError, ["'E'", "'abc'"]),
    (dict(unknowns=5), pj.IdentificationError, ["unknowns", "allowed"]),
    (dict(fit_options=pj.FitOptions(seed=HUGE)), pj.IdentificationError,
     ["seed", "401 digits"]),
    (dict(fit_options={"seed": 1}), pj.IdentificationError,
     ["fit_options must be a FitOptions", "dict"]),
    (dict(options=pj.SceneOptions(), rtol=1e-8), pj.PPRError, ["identify", "not both"]),
    (dict(options={"rtol": 1e-8}), pj.PPRError, ["must be a SceneOptions", "dict"]),
]


@pytest.mark.parametrize("kw, error, words", IDENTIFY,
                         ids=[",".join(f"{k}={v!r}"[:30] for k, v in c[0].items())
                              for c in IDENTIFY])
def test_identify_arguments(exp, kw, error, words):
    with pytest.raises(error) as info:
        pj.identify(exp, **kw)
    for w in words:
        assert w in str(info.value), (w, str(info.value))


def test_identify_takes_one_unknown_or_nuisance_as_a_string(exp):
    """A string is one name, not a sequence of letters ('bias' is not b, i, a, s): the
    check passes and the call goes on to the next one (a bound outside t's range here)."""
    with pytest.raises(pj.IdentificationError, match=r"bounds of 't' must satisfy"):
        pj.identify(exp, "t", bounds={"t": (1e-9, 1e-3)},
                    fit_options=pj.FitOptions(nuisance="bias"))


DESIGN = [
    (dict(constraints=5), ["constraints must be a sequence", "5"]),
    (dict(pose="home"), ["pose must be (x, y, phi)", "'home'"]),
    (dict(pose=(0.45, 0.26)), ["pose must be (x, y, phi)"]),
    (dict(seed=-1), ["seed = -1", "[0, 9.22337e+18]"]),
    (dict(seed=1.5), ["seed must be an integer"]),
    (dict(stroke=HUGE), ["stroke", "401 digits"]),
    (dict(grid="many"), ["grid must be an integer", "'many'"]),
    (dict(strip_load=(1.0, "x", 0.0)), ["strip_load", "(fx, fy, m)"]),
    (dict(model="l2"), ["model", "unknown model 'l2'"]),
    (dict(scene="circle"), ["scene", "unknown scene 'circle'"]),
    (dict(params="x"), ["params must be a RobotParams"]),
    (dict(options={"t_end": 1.0}), ["options must be a SceneOptions"]),
    (dict(variables={"t": (1e-4, HUGE)}), ["'t'", "401 digits"]),
    (dict(variables={"t": (1e-4, 1e-3, 5e-3)}), ["'t'", "two finite numbers"]),
    (dict(constraints=[{"metric": "pivot_frequency_hz", "upper": HUGE}]),
     ["upper bound", "401 digits"]),
]


@pytest.mark.parametrize("kw, words", DESIGN,
                         ids=[",".join(f"{k}={v!r}"[:30] for k, v in c[0].items())
                              for c in DESIGN])
def test_design_arguments(kw, words):
    kw = {"variables": BOUNDS, **kw}
    with pytest.raises(pj.DesignError) as info:
        pj.design(kw.pop("variables"), "pivot_frequency_hz", **kw)
    for w in words:
        assert w in str(info.value), (w, str(info.value))


@pytest.mark.parametrize("make, words", [
    (lambda: pj.Constraint("pivot_stress_Pa", upper=HUGE), ["upper bound", "401 digits"]),
    (lambda: pj.Constraint("pivot_stress_Pa", lower=-HUGE), ["lower bound", "401 digits"]),
    (lambda: pj.Constraint("pivot_stress_Pa", avoid=(1.0, HUGE)), ["avoid", "(lo, hi)"]),
    (lambda: pj.Constraint("pivot_stress_Pa", avoid=(1.0, 2.0, 3.0)), ["avoid", "(lo, hi)"]),
])
def test_constraint_arguments(make, words):
    with pytest.raises(pj.DesignError) as info:
        make()
    for w in words:
        assert w in str(info.value), (w, str(info.value))


def test_robot_params_huge_integers_and_strings():
    with pytest.raises(pj.PPRError, match=r"'E' \(Young's modulus\) = inf is not finite "
                                          r"\(an integer beyond"):
        pj.RobotParams(E=HUGE)
    with pytest.raises(pj.PPRError, match=r"'E' \(Young's modulus\) = an integer of 401 "
                                          r"digits"):
        pj.RobotParams().replace(E=HUGE)
    with pytest.raises(pj.PPRError, match=r"'E' \(Young's modulus\) must be a number, got "
                                          r"'abc'"):
        pj.RobotParams().replace(E="abc")
    assert float(pj.RobotParams(E=70 * 10**9).E) == 7e10  # an ordinary integer is a number


def test_paths_and_scenes_arguments(tmp_path, exp):
    with pytest.raises(pj.DataError, match=r"check_same_rate: a must have sample times ts"):
        pj.check_same_rate(1, 2)
    with pytest.raises(pj.DataError, match=r"max_gap must be a number, got 'x'"):
        pj.load_path(str(tmp_path / "none.csv"), max_gap="x")
    with pytest.raises(pj.DataError, match=r"min_samples must be an integer"):
        pj.load_commands(str(tmp_path / "none.csv"), min_samples=2.5)
    with pytest.raises(pj.PPRError, match=r"unknown model 'x'"):
        pj.experiment_scene(exp, input_model="x")
    with pytest.raises(pj.PPRError, match=r"input_model must be a kinematic model"):
        pj.experiment_scene(exp, input_model=3)
    assert pj.experiment_scene(exp, input_model="rigid").input_model.name == "rigid"


# --- a design specification: the file and the key named -----------------------------------

SPEC = DESIGN_SPEC


@pytest.mark.parametrize("old, new, words", [
    ("upper = 1e8", "upper = 1" + "0" * 400, ["upper bound", "401 digits"]),
    ("stroke = 0.3", "stroke = 0.3\npose = \"home\"", ["[settings]", "pose", "'home'"]),
    ("stroke = 0.3", "stroke = 0.3\nseed = -1", ["[settings]", "seed = -1"]),
    ("stroke = 0.3", "stroke = 0.3\nt_end = \"long\"", ["[settings]", "t_end"]),
    ("t = [1e-4, 1e-3]", "t = [1e-4, 1" + "0" * 400 + "]", ["'t'", "401 digits"]),
    ("[settings]", "[params]\nE = 1" + "0" * 400 + "\n\n[settings]",
     ["[params]", "E = an integer of 401 digits"]),
    ("[settings]", "[params]\nE = \"abc\"\n\n[settings]", ["[params]", "E = 'abc'",
                                                          "not a number"]),
    ("[settings]", "[params]\nt = -1.0\n\n[settings]",
     ["[params]", "'t'", "allowed range [1e-06, 0.01] m"]),
    ("[settings]", "[params]\nthickness = 1.0\n\n[settings]", ["[params]", "thickness"]),
])
def test_spec_errors_name_the_file_and_the_key(tmp_path, capsys, old, new, words):
    spec = tmp_path / "spec.toml"
    assert SPEC.count(old) == 1
    spec.write_text(SPEC.replace(old, new))
    with pytest.raises(pj.DesignError) as info:
        load_design_spec(str(spec))
    msg = str(info.value)
    for w in [str(spec)] + words:
        assert w in msg, (w, msg)
    # the command line: one line, exit 2, before anything is compiled
    assert main(["design", "--spec", str(spec), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("ppr-jax: error: ") and str(spec) in err[0]


def test_a_byte_order_mark_before_toml_is_skipped(tmp_path):
    """Editors that write a UTF-8 byte-order mark first: the specification and a parameter
    file read as without it."""
    plain, bom = tmp_path / "plain.toml", tmp_path / "bom.toml"
    plain.write_text(SPEC, encoding="utf-8")
    bom.write_bytes(b"\xef\xbb\xbf" + SPEC.encode("utf-8"))
    a, b = load_design_spec(str(plain)), load_design_spec(str(bom))
    assert a == b and a["variables"]["t"] == (1e-4, 1e-3)
    params = tmp_path / "robot.toml"
    params.write_bytes(b"\xef\xbb\xbf" + b"t = 0.0004\nE = 70e9\n")
    p = pj.load_params(str(params))
    assert float(p.t) == 4e-4 and float(p.E) == 7e10
    params_json = tmp_path / "robot.json"
    params_json.write_bytes(b"\xef\xbb\xbf" + b'{"t": 0.0004}')
    assert float(pj.load_params(str(params_json)).t) == 4e-4


def test_identify_refuses_the_same_data_twice(exp):
    """The same experiment given twice (`--data run1.csv --data run1.csv`) would narrow the
    intervals by sqrt 2 as if the noise were new: refused, naming both, before compiling."""
    other = pj.experiment(np.asarray(exp.ts), np.asarray(exp.X), tau=np.asarray(exp.tau),
                          name="copy")
    with pytest.raises(pj.DataError, match=r"experiments 0 \('home'\) and 1 \('copy'\).*sqrt 2"):
        pj.identify([exp, other])
