"""Parameter files (TOML, JSON): the values a user wrote by hand, read back exactly; bad files
named with the cause; the command line's --params-file under --set."""

import json

import numpy as np
import pytest

import ppr_jax as pj
from ppr_jax._cli import main

TOML = """# our robot, measured 2026-11-20
[params]
a = 0.9
t = 0.45e-3          # strip thickness (m)
E = 70e9
gamma = 0.83
sigma = 1
joint_geometry = "strip"
"""


def test_a_hand_written_toml_file_is_read_exactly(tmp_path):
    path = tmp_path / "robot.toml"
    path.write_text(TOML)
    p = pj.load_params(str(path))
    assert (float(p.t), float(p.E), float(p.gamma)) == (0.45e-3, 70e9, 0.83)
    assert (p.sigma, p.joint_geometry) == (1, "strip")
    # names not in the file keep Table 1's values
    assert float(p.l1) == float(pj.RobotParams().l1) and p.K_theta is None


@pytest.mark.parametrize("ext", [".toml", ".json"])
def test_save_and_load_round_trip_every_field(tmp_path, ext):
    p = pj.RobotParams(t=0.37e-3, K_theta=2.61, rho=0.9, c_spring=1e-4, sigma=1)
    path = pj.save_params(p, str(tmp_path / f"robot{ext}"))
    q = pj.load_params(path)
    for name in pj.PARAM_RANGES:
        a, b = getattr(p, name), getattr(q, name)
        assert (a is None and b is None) or float(a) == float(b), name
    assert (q.sigma, q.joint_geometry) == (p.sigma, p.joint_geometry)


@pytest.mark.parametrize("text, match", [
    ('t = 0.02\n', r"t = 0\.02.*\[1e-06, 0\.01\]|t.*0\.01"),
    ('thickness = 3e-4\n', r"unknown name.*thickness"),
    ('t = "thin"\n', r"t = 'thin' is not a number"),
    ('t = \n', r"not valid TOML"),
    # an integer beyond a float's range: named, not an OverflowError traceback
    ('t = 1' + '0' * 400 + '\n',
     r"t = an integer of 401 digits is out of range; allowed: \[1e-06, 0\.01\] m"),
    ('sigma = 1' + '0' * 400 + '\n', r"sigma"),
])
def test_a_bad_file_names_the_cause(tmp_path, text, match):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(pj.PPRError, match=match):
        pj.load_params(str(path))


def test_unknown_extension_and_missing_file(tmp_path):
    with pytest.raises(pj.PPRError, match=r"\.toml, \.json"):
        pj.load_params(str(tmp_path / "robot.yaml"))
    with pytest.raises(pj.PPRError, match="No such file"):
        pj.load_params(str(tmp_path / "missing.json"))


def test_cli_params_file_then_set(tmp_path, capsys):
    """`prb --json` on a file: the file's thickness reaches the derived stiffness (K grows as
    t^3, a closed form), and --set overrides the file."""
    path = tmp_path / "robot.json"
    path.write_text(json.dumps({"t": 0.6e-3, "E": 70e9}))
    assert main(["prb", "--json", "--params-file", str(path)]) == 0
    a = json.loads(capsys.readouterr().out)
    assert a["params"]["t"] == 0.6e-3 and a["params"]["E"] == 70e9
    assert main(["prb", "--json", "--params-file", str(path), "--set", "t=0.3e-3"]) == 0
    b = json.loads(capsys.readouterr().out)
    assert b["params"]["t"] == 0.3e-3
    np.testing.assert_allclose(a["derived"]["K"] / b["derived"]["K"], 8.0, rtol=1e-12)
    assert main(["prb", "--params-file", str(tmp_path / "none.json")]) == 2
    assert "none.json" in capsys.readouterr().err
