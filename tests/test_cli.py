"""The command line as a user runs it (in-process, through `ppr_jax._cli.main`)."""

import csv
import json
import os

import numpy as np
import pytest

from ppr_jax._cli import main


def test_prb_json_lists_every_derived_quantity(capsys):
    assert main(["prb", "--json", "--set", "t=0.5e-3"]) == 0
    out = json.loads(capsys.readouterr().out)
    for k in ["r_i", "l", "kappa0", "s", "Theta_i", "Theta_0", "r2", "K", "r1", "r3", "psi0",
              "R1", "R3", "K0", "gamma", "rho", "K_theta"]:
        assert k in out["derived"]
    assert out["params"]["t"] == 0.5e-3
    assert len(out["predeflection_home_rad"]["reduced_per_pivot"]) == 3


@pytest.mark.parametrize(
    "args,msg",
    [
        (["prb", "--set", "t=-1"], "'t'"),
        (["prb", "--set", "thickness=1"], "allowed:"),
        (["prb", "--set", "t"], "NAME=VALUE"),
        (["prb", "--set", "gamma=abc"], "cannot read"),
        (["torques", "--model", "reduced", "--set", "a=3", "--out", "x"], "unreachable"),
    ],
)
def test_bad_input_is_a_clear_error(capsys, tmp_path, args, msg):
    args = [a if a != "x" else str(tmp_path) for a in args]
    assert main(args) == 2
    assert msg in capsys.readouterr().err


def test_torques_csv(tmp_path, capsys):
    assert main(["torques", "--out", str(tmp_path)]) == 0
    with open(tmp_path / "torques.csv") as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["t", "tau_1", "tau_2", "tau_3"]
    tau = np.array(rows[1:], dtype=float)
    assert tau.shape == (755, 4) and np.all(np.isfinite(tau))


def test_modes_json(capsys):
    assert main(["modes", "--model", "reduced", "--actuators", "free", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["frequencies_hz"][0] < 0 and len(out["unstable_growth_rates_per_s"]) == 1


def test_simulate_writes_summary_csv_and_figures(tmp_path, capsys, paper_circle_L1):
    out = tmp_path / "run"
    assert main(["simulate", "--model", "reduced", "--t-end", "2.0", "--out", str(out)]) == 0
    for f in ["summary.json", "trajectory.csv", "trajectory.png", "angle.png", "radial_error.png"]:
        assert os.path.getsize(out / f) > 0
    s = json.loads((out / "summary.json").read_text())
    m = s["models"]["reduced"]
    assert abs(m["radial_error_max_m"]) < 1e-6 and m["num_steps"] > 0
    assert s["paper_reference"]["radial_error_max_m"] == 2.41e-3
    with open(out / "trajectory.csv") as f:
        header = next(csv.reader(f))
    assert header[:5] == ["model", "t", "x", "y", "phi"]
    assert "Scene paper-circle" in capsys.readouterr().out


def test_prb_table_kappa0_and_figure(tmp_path, capsys):
    png = tmp_path / "prb.png"
    assert main(["prb-table", "--kappa0", "0", "--json", "--figure", str(png)]) == 0
    cap = capsys.readouterr()
    out = json.loads(cap.out)
    assert abs(out["gamma"] - 0.85) < 0.02 and abs(out["K_theta"] - 2.65) < 0.1
    assert png.stat().st_size > 0
    assert "deprecated" not in cap.err
    assert main(["prb-table", "--kappa0", "2.5"]) == 2
    assert "[0.0, 2.0]" in capsys.readouterr().err


def test_prb_kappa0_and_figure(tmp_path, capsys):
    """The old spelling `prb --kappa0/--figure` still works: a notice, then prb-table's output."""
    png = tmp_path / "prb.png"
    assert main(["prb", "--kappa0", "0", "--json", "--figure", str(png)]) == 0
    cap = capsys.readouterr()
    out = json.loads(cap.out)
    assert abs(out["gamma"] - 0.85) < 0.02 and abs(out["K_theta"] - 2.65) < 0.1
    assert png.stat().st_size > 0
    notice = [line for line in cap.err.splitlines() if "deprecated" in line]
    assert len(notice) == 1 and "prb-table" in notice[0]
    assert main(["prb-table", "--kappa0", "0", "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == out
    assert main(["prb", "--kappa0", "2.5"]) == 2
    assert "[0.0, 2.0]" in capsys.readouterr().err
    # Without --kappa0, --figure alone wrote only the figure, as before the split.
    png.unlink()
    assert main(["prb", "--figure", str(png), "--json"]) == 0
    assert png.stat().st_size > 0 and capsys.readouterr().out == ""


def test_prb_table_without_kappa0_prints_the_table(tmp_path, capsys):
    from ppr_jax._prb_table import prb_table

    tab = prb_table()
    assert main(["prb-table"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[1].split()[:4] == ["kappa0", "gamma", "rho", "K_theta"]
    rows = np.array([line.split() for line in lines[2:]], dtype=float)
    assert rows.shape == (len(tab["kappa0"]), 7)
    np.testing.assert_allclose(rows[:, 0], tab["kappa0"], atol=1e-3)
    np.testing.assert_allclose(rows[:, 3], tab["K_theta"], rtol=1e-5)

    assert main(["prb-table", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert "load_range" in out["meta"]
    for name in ("kappa0", "gamma", "rho", "K_theta", "tip_error_max", "load_error_max"):
        np.testing.assert_array_equal(out[name], tab[name])

    png = tmp_path / "table.png"
    assert main(["prb-table", "--figure", str(png)]) == 0  # only the figure
    assert png.stat().st_size > 0 and capsys.readouterr().out == ""

    assert main(["prb-table", "--fit"]) == 2
    assert "--fit needs --kappa0" in capsys.readouterr().err


def test_prb_derived_quantities_do_not_print_the_deprecation_notice(capsys):
    assert main(["prb", "--json"]) == 0
    cap = capsys.readouterr()
    assert "derived" in json.loads(cap.out) and "deprecated" not in cap.err


def test_modes_of_the_beam_model_from_the_cli(capsys):
    """Quasi-static strips by default (9 coordinates, 6 free when locked, for every N); the full
    strip dynamics on request (3 + 3N coordinates); the robot's modes agree."""
    assert main(["modes", "--model", "beam", "--elements", "3", "--json"]) == 0
    qs = json.loads(capsys.readouterr().out)
    assert qs["model"] == "beam" and qs["n_free_coordinates"] == 9 - 3
    assert main(["modes", "--model", "beam", "--elements", "3", "--strip-dynamics", "full",
                 "--json"]) == 0
    full = json.loads(capsys.readouterr().out)
    assert full["n_free_coordinates"] == 3 + 3 * 3 - 3
    assert all(np.isfinite(qs["frequencies_hz"]))
    np.testing.assert_allclose(qs["frequencies_hz"], full["frequencies_hz"][:6], rtol=3e-3)
    assert main(["modes", "--model", "beam", "--elements", "0"]) == 2
    with pytest.raises(SystemExit):  # argparse: not one of the choices
        main(["modes", "--model", "beam", "--strip-dynamics", "implicit"])


def test_prb_table_fit(capsys):
    """--fit refits the one curvature from the elastica; it reproduces the shipped table row."""
    assert main(["prb-table", "--kappa0", "0", "--fit", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["fit"]["kappa0"] == 0.0
    for name in ("gamma", "rho", "K_theta"):
        assert abs(out["fit"][name] - out[name]) < 1e-6, name
