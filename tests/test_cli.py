"""The command line as a user runs it (in-process, through `ppr_jax._cli.main`)."""

import csv
import json
import os

import numpy as np
import pytest

from ppr_jax._cli import main


def test_prb_json_derived_quantities_equal_the_closed_forms(capsys):
    """`prb --json --set t=0.5e-3`: every derived quantity against MODEL.md section 3's closed
    forms, written out here from the Table 1 parameters (and the printed gamma, K_theta, which
    come from the elastica table); the --set thickness reaches I and K; the pre-deflection at home
    against the triangle of each chain, |E_i - A_i| = (a - h)/sqrt(3)."""
    assert main(["prb", "--json", "--set", "t=0.5e-3"]) == 0
    out = json.loads(capsys.readouterr().out)
    d = out["derived"]
    assert out["params"]["t"] == 0.5e-3
    a, h, t_p, l1, l3, b_r, t_r, r, th_c, w, t, E, rho_m = (
        0.9, 0.08, 0.025, 0.366, 0.366, 0.023, 0.010, 0.020, 1.88, 0.026, 0.5e-3, 71e9, 2780.0)
    g, Kt = d["gamma"], d["K_theta"]
    assert 0.8 < g < 0.85 and 2.5 < Kt < 2.7  # between the straight beam's 0.85 / 2.65 and below
    r_i = r + b_r / 2
    l_h = r_i * th_c / 2
    k0 = th_c / 2
    a_i, b_i = r_i * np.sin(k0), r_i * (1 - np.cos(k0))
    s = (1 - g) * l_h
    Th_i = np.arctan2(b_i, a_i - s)
    Th_0 = 2 * Th_i + np.pi - th_c
    rho = np.hypot(a_i - s, b_i) / l_h
    I_s, L = w * t**3 / 12, r * th_c
    m1 = rho_m * l1 * b_r * t_r
    m2 = rho_m * w * t * L
    m4 = rho_m * np.sqrt(3) / 4 * h**2 * t_p
    want = {
        "r_i": r_i, "l": 2 * l_h, "l_h": l_h, "kappa0": k0, "a_i": a_i, "b_i": b_i, "s": s,
        "Theta_i": Th_i, "Theta_0": Th_0, "rho": rho, "I_s": I_s, "L": L,
        "K": 2 * E * I_s * rho * Kt / L,
        "r2": rho * l_h * np.sqrt(2 * (1 - np.cos(Th_0))),  # eq 8
        "r1": l1 + s, "r3": l3 + s, "psi0": th_c / 2,
        "R1": l1 + r_i * np.tan(th_c / 2), "R3": l3 + r_i * np.tan(th_c / 2), "K0": E * I_s / L,
        "m1": m1, "I1": m1 * (l1**2 + b_r**2) / 12, "m3": m1, "I3": m1 * (l3**2 + b_r**2) / 12,
        "m2": m2, "m4": m4, "I4": m4 * h**2 / 12, "rho_E": h / np.sqrt(3),
    }
    for k, v in want.items():
        np.testing.assert_allclose(d[k], v, rtol=1e-12, err_msg=k)
    # with default rho, r2 also equals 2 r_i sin(kappa0) - 2 s cos(kappa0) (MODEL.md section 3)
    np.testing.assert_allclose(d["r2"], 2 * r_i * np.sin(k0) - 2 * s * np.cos(k0), rtol=1e-12)
    np.testing.assert_allclose(d["I2"], m2 * d["r2"]**2 / 12, rtol=1e-12)
    # Pre-deflection at home: chain i spans |E_i - A_i| = (a - h)/sqrt(3). L1: (2 r1 cos v + r2)
    # = that distance, each pivot deflected by (theta_c - 2 v)/2. L0: the pin's turn pi - alpha
    # of the triangle (R1, R3, distance) against its rest turn theta_c.
    dist = (a - h) / np.sqrt(3)
    v = np.arccos((dist - want["r2"]) / (2 * want["r1"]))
    pd = out["predeflection_home_rad"]
    np.testing.assert_allclose(pd["reduced_per_pivot"], [(th_c - 2 * v) / 2] * 3, rtol=1e-9)
    R1 = want["R1"]
    alpha = np.arccos((2 * R1**2 - dist**2) / (2 * R1**2))
    np.testing.assert_allclose(pd["rigid_per_pin"], [th_c - (np.pi - alpha)] * 3, rtol=1e-9)


@pytest.mark.parametrize(
    "args,msg",
    [
        (["prb", "--set", "t=-1"], "'t'"),
        (["prb", "--set", "thickness=1"], "allowed:"),
        (["prb", "--set", "t"], "NAME=VALUE"),
        (["prb", "--set", "gamma=abc"], "cannot read"),
        (["torques", "--model", "reduced", "--set", "a=3", "--out", "x"], "unreachable"),
        (["modes", "--pose", "1,2"], "--pose expects x,y,phi: three comma-separated numbers "
                                     "(m, m, rad)"),
        (["modes", "--pose", "0.45,0.26,zero"], "--pose expects x,y,phi"),
    ],
)
def test_bad_input_is_a_clear_error(capsys, tmp_path, args, msg):
    args = [a if a != "x" else str(tmp_path) for a in args]
    assert main(args) == 2
    assert msg in capsys.readouterr().err


def test_a_parameter_out_of_range_names_its_range_once(capsys):
    """The parameter, its meaning and its allowed range, said once (it was printed twice: "out
    of its physical range [1e-06, 0.01] m (allowed range [1e-06, 0.01] m)")."""
    assert main(["prb", "--set", "t=-1"]) == 2
    err = capsys.readouterr().err
    assert ("parameter 't' (strip thickness) = -1.0 is out of its allowed range [1e-06, 0.01] m"
            in err), err
    assert err.count("[1e-06, 0.01]") == 1, err


def _eq55(t):
    """The nominal circle of eq 55 (MODEL.md section 6) and its first two time derivatives."""
    w = 5 / 6
    c, s = np.cos(w * t), np.sin(w * t)
    X = np.stack([0.45 + 0.1 * c, 0.15 * np.sqrt(3) + 0.1 * s, -0.05 * s], -1)
    Xd = np.stack([-0.1 * w * s, 0.1 * w * c, -0.05 * w * c], -1)
    Xdd = np.stack([-0.1 * w**2 * c, -0.1 * w**2 * s, 0.05 * w**2 * s], -1)
    return X, Xd, Xdd


def test_torques_csv_equals_the_paper_closed_form_inverse_dynamics(tmp_path, capsys):
    """The CSV's torques against the paper's own closed-form equations of motion (eq 54 with the
    matrices of eqs 30-35, 41, 47, `_paper_eom`, a second formulation beside the library's
    generic one), solved for tau along eq 55 written out here: S^T tau = M_e X'' + C_e X' +
    dU/dX (eq 52: S the actuated rows of J)."""
    import jax
    import jax.numpy as jnp

    from ppr_jax._paper_eom import paper_jacobian, paper_workspace_eom
    from ppr_jax._scenes import scene_params

    assert main(["torques", "--out", str(tmp_path)]) == 0
    assert "max |tau|" in capsys.readouterr().out
    with open(tmp_path / "torques.csv") as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["t", "tau_1", "tau_2", "tau_3"]
    tau = np.array(rows[1:], dtype=float)
    assert tau.shape == (755, 4)
    np.testing.assert_array_equal(tau[:, 0], np.linspace(0.0, 7.54, 755))
    p = scene_params("paper-circle")  # Table 1, t = 0.3 mm

    @jax.jit
    @jax.vmap
    def paper_tau(X, Xd, Xdd):
        Me, CeXd, spring = paper_workspace_eom(p, X, Xd)
        S = paper_jacobian(p, X)[0][jnp.array([0, 3, 6])]
        return jnp.linalg.solve(S.T, Me @ Xdd + CeXd + spring)

    k = np.array([0, 100, 377, 600, 754])
    ref = np.asarray(paper_tau(*(jnp.asarray(v) for v in _eq55(tau[k, 0]))))
    np.testing.assert_allclose(tau[k, 1:], ref, rtol=1e-9, atol=1e-12)  # measured 6e-17 N m
    assert np.abs(ref).max() > 0.05  # torques of 0.1 N m, not a trivial zero


def test_modes_json_equals_a_finite_difference_linearization_of_the_paper_equations(capsys):
    """L1 with free actuators at home: the CLI's eigenvalues, signed frequencies and growth rate
    against the paper's closed-form spring force (eq 54) differenced by central finite
    differences, its mass matrix M_e, and scipy's generalized symmetric eigensolver. By symmetry
    home is the equilibrium; the rotation is unstable (the springs' pre-load), the translation
    pair is stable and degenerate (three-fold symmetry)."""
    import jax
    import jax.numpy as jnp
    import scipy.linalg

    import ppr_jax as pj
    from ppr_jax._paper_eom import paper_workspace_eom

    assert main(["modes", "--model", "reduced", "--actuators", "free", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    z = np.array(out["equilibrium_z"])
    np.testing.assert_allclose(z, [0.45, 0.9 * np.sqrt(3) / 6, 0.0], rtol=0, atol=1e-12)
    p = pj.RobotParams()  # Table 1, as `modes` runs it
    eom = jax.jit(lambda X: paper_workspace_eom(p, X, jnp.zeros(3)))
    Me, _, spring = (np.asarray(v) for v in eom(jnp.asarray(z)))
    assert np.abs(spring).max() < 1e-12  # an equilibrium with zero actuator torque
    h = 1e-6
    Kfd = np.column_stack([(np.asarray(eom(jnp.asarray(z + h * e))[2])
                            - np.asarray(eom(jnp.asarray(z - h * e))[2])) / (2 * h)
                           for e in np.eye(3)])
    lam = scipy.linalg.eigh((Kfd + Kfd.T) / 2, Me, eigvals_only=True)
    np.testing.assert_allclose(out["eigenvalues_rad2_per_s2"], lam, rtol=1e-7)  # measured 4e-11
    np.testing.assert_allclose(out["frequencies_hz"],
                               np.sign(lam) * np.sqrt(np.abs(lam)) / (2 * np.pi), rtol=1e-7)
    assert lam[0] < 0 < lam[1]
    np.testing.assert_allclose(out["unstable_growth_rates_per_s"], [np.sqrt(-lam[0])], rtol=1e-7)
    np.testing.assert_allclose(lam[1], lam[2], rtol=1e-9)


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_simulate_runs_the_full_l3_on_its_own_defaults(tmp_path, capsys):
    """`simulate --model beam --strip-dynamics full` with no solver options runs the full L3 on
    its defaults (KeptKvaerno5 at rtol 1e-4, atol 1e-6: the scenes' rtol 1e-8 would resolve
    the undamped strip vibration for hours), and says so in the summary; a tolerance given on
    the command line is used instead. What it wrote is checked, not only its exit status: the
    nominal rows are eq 55, the e_r column and the summary's radial-error metrics are those
    recomputed here from the CSV's x, y, the L3 starts on the circle, the tighter tolerance
    takes more steps, and the two runs agree far below the L3's deflection from the circle
    (0.37 mm at 50 ms): measured 9e-11 m and 3e-9 rad apart."""
    base = ["simulate", "--model", "beam", "--strip-dynamics", "full", "--elements", "4",
            "--t-end", "0.05", "--n-out", "11"]
    runs = {}
    for tag, extra in (("a", []), ("b", ["--rtol", "1e-6"])):
        assert main(base + extra + ["--out", str(tmp_path / tag)]) == 0
        m = json.loads((tmp_path / tag / "summary.json").read_text())["models"]["beam"]
        with open(tmp_path / tag / "trajectory.csv") as f:
            rows = list(csv.reader(f))
        assert rows[0][:6] == ["model", "t", "x", "y", "phi", "e_r"]
        nom = np.array([r[1:6] for r in rows[1:] if r[0] == "nominal"], dtype=float)
        l3 = np.array([r[1:6] for r in rows[1:] if r[0] == "beam"], dtype=float)
        ts = np.linspace(0.0, 0.05, 11)
        assert nom.shape == l3.shape == (11, 5)
        np.testing.assert_allclose(l3[:, 0], ts, rtol=0, atol=1e-15)
        np.testing.assert_allclose(nom[:, 1:4], _eq55(ts)[0], rtol=0, atol=1e-15)
        e_r = np.hypot(l3[:, 1] - 0.45, l3[:, 2] - 0.15 * np.sqrt(3)) - 0.1
        np.testing.assert_allclose(l3[:, 4], e_r, rtol=0, atol=1e-15)
        np.testing.assert_allclose([m["radial_error_max_m"], m["radial_error_min_m"],
                                    m["radial_error_mean_m"]],
                                   [e_r.max(), e_r.min(), e_r.mean()], rtol=1e-9, atol=1e-18)
        np.testing.assert_allclose(l3[0, 1:4], _eq55(0.0)[0], rtol=0, atol=1e-12)
        assert 1e-4 < e_r.max() < 1e-3  # the strips deflect: a fraction of a millimetre
        runs[tag] = (m, l3)
    (ma, a), (mb, b) = runs["a"], runs["b"]
    assert ma["solver"] == {"name": "kvaerno5-kept", "rtol": 1e-4, "atol": 1e-6}
    assert mb["solver"] == {"name": "kvaerno5-kept", "rtol": 1e-6, "atol": 1e-6}
    assert mb["num_steps"] > ma["num_steps"]  # the tolerance reached the solver
    np.testing.assert_allclose(a[:, 1:3], b[:, 1:3], rtol=0, atol=1e-8)
    np.testing.assert_allclose(a[:, 3], b[:, 3], rtol=0, atol=1e-7)


def test_simulate_writes_summary_csv_and_figures(tmp_path, capsys, paper_circle_L1):
    """L1 driven by its own inverse-dynamics torques: the CSV's nominal rows are eq 55, the
    model's rows follow it to the solver's tolerance; the e_r column and the summary's metrics
    equal the radial error recomputed here from the CSV's x, y; the paper's row is MODEL.md's."""
    out = tmp_path / "run"
    assert main(["simulate", "--model", "reduced", "--t-end", "2.0", "--out", str(out)]) == 0
    for f in ["summary.json", "trajectory.csv", "trajectory.png", "angle.png", "radial_error.png"]:
        assert os.path.getsize(out / f) > 0
    s = json.loads((out / "summary.json").read_text())
    with open(out / "trajectory.csv") as f:
        rows = list(csv.reader(f))
    assert rows[0][:6] == ["model", "t", "x", "y", "phi", "e_r"]
    names = np.array([r[0] for r in rows[1:]])
    assert names.tolist() == ["nominal"] * 755 + ["reduced"] * 755
    nom = np.array([r[1:6] for r in rows[1:756]], dtype=float)
    red = np.array([r[1:6] for r in rows[756:]], dtype=float)
    ts = np.linspace(0.0, 2.0, 755)
    np.testing.assert_allclose(nom[:, 0], ts, rtol=0, atol=1e-15)
    np.testing.assert_allclose(red[:, 0], ts, rtol=0, atol=1e-15)
    X55 = _eq55(ts)[0]
    np.testing.assert_allclose(nom[:, 1:4], X55, rtol=0, atol=1e-15)
    # measured: position 4e-11 m, phi 1.4e-10 rad off eq 55 (rtol 1e-8, atol 1e-10)
    np.testing.assert_allclose(red[:, 1:3], X55[:, :2], rtol=0, atol=1e-9)
    np.testing.assert_allclose(red[:, 3], X55[:, 2], rtol=0, atol=1e-9)
    for tab in (nom, red):
        e_r = np.hypot(tab[:, 1] - 0.45, tab[:, 2] - 0.15 * np.sqrt(3)) - 0.1
        np.testing.assert_allclose(tab[:, 4], e_r, rtol=0, atol=1e-15)
    m = s["models"]["reduced"]
    e_r = red[:, 4]
    np.testing.assert_allclose([m["radial_error_max_m"], m["radial_error_min_m"],
                                m["radial_error_mean_m"], m["radial_error_max_relative_percent"]],
                               [e_r.max(), e_r.min(), e_r.mean(), 100 * np.abs(e_r).max() / 0.1],
                               rtol=1e-9, atol=1e-18)
    assert np.abs(e_r).max() < 1e-9 and m["num_steps"] > 0
    # d_i1 = d_i2 in L1: chain 1's two end rotations are equal
    assert abs(m["end_rotation_diff_max_deg"]) < 1e-9
    # the paper's theory-vs-ADAMS row (MODEL.md section 6); L1 is not compared with it (ADAMS
    # is the strip itself: the paper's 2.41 mm is a model mismatch L1 has no share in)
    ref = s["paper_reference"]
    assert [ref[k] for k in ("radial_error_max_m", "radial_error_min_m", "radial_error_mean_m",
                             "radial_error_max_relative_percent")] == [2.41e-3, -0.99e-3,
                                                                       0.84e-3, 2.41]
    assert [ref[k] for k in ("end_rotation_diff_max_deg", "end_rotation_diff_min_deg",
                             "end_rotation_diff_mean_deg",
                             "end_rotation_diff_max_relative_percent")] == [5.60, -7.62, -0.04,
                                                                            6.60]
    assert "Scene paper-circle" in capsys.readouterr().out


def test_simulate_no_figures_writes_the_same_files_but_the_figures(tmp_path, capsys,
                                                                   paper_circle_L1):
    """`--no-figures`: the summary and CSV equal a run with figures, and no image is written;
    the table is printed before the files are listed."""
    a, b = tmp_path / "a", tmp_path / "b"
    common = ["simulate", "--model", "reduced", "--t-end", "2.0", "--out"]
    assert main(common + [str(a)]) == 0
    capsys.readouterr()
    assert main(common + [str(b), "--no-figures"]) == 0
    out = capsys.readouterr().out
    assert sorted(os.listdir(b)) == ["summary.json", "trajectory.csv"]
    assert (a / "trajectory.csv").read_text() == (b / "trajectory.csv").read_text()
    sa, sb = (json.loads((d / "summary.json").read_text()) for d in (a, b))
    assert sa["models"]["reduced"]["radial_error_max_m"] == sb["models"]["reduced"][
        "radial_error_max_m"]
    assert out.index("Scene paper-circle") < out.index(f"wrote {b}/summary.json, trajectory.csv")
    assert out.rstrip().endswith("trajectory.csv")


def _prb_kappa0_figure(command, tmp_path, capsys):
    """`command --kappa0 0 --json --figure`: the straight strip's gamma and K_theta (the PRB
    table's 0.85 and 2.65) and a figure written: (the captured output, the JSON, the figure)."""
    png = tmp_path / "prb.png"
    assert main([command, "--kappa0", "0", "--json", "--figure", str(png)]) == 0
    cap = capsys.readouterr()
    out = json.loads(cap.out)
    assert abs(out["gamma"] - 0.85) < 0.02 and abs(out["K_theta"] - 2.65) < 0.1
    assert png.stat().st_size > 0
    return cap, out, png


def test_prb_table_kappa0_and_figure(tmp_path, capsys):
    cap, _, _ = _prb_kappa0_figure("prb-table", tmp_path, capsys)
    assert "deprecated" not in cap.err
    assert main(["prb-table", "--kappa0", "2.5"]) == 2
    assert "[0.0, 2.0]" in capsys.readouterr().err


def test_prb_kappa0_and_figure(tmp_path, capsys):
    """The old spelling `prb --kappa0/--figure` still works: a notice, then prb-table's output."""
    cap, out, png = _prb_kappa0_figure("prb", tmp_path, capsys)
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


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
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


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_prb_table_fit(capsys):
    """--fit refits the one curvature from the elastica; it reproduces the shipped table row."""
    assert main(["prb-table", "--kappa0", "0", "--fit", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["fit"]["kappa0"] == 0.0
    for name in ("gamma", "rho", "K_theta"):
        assert abs(out["fit"][name] - out[name]) < 1e-6, name


def test_ctrl_c_is_one_line_naming_what_was_kept(tmp_path, capsys, monkeypatch):
    """Ctrl-C (KeyboardInterrupt) in any command: exit 130, one line on stderr naming the files
    the command had written under --out (none: "nothing written"), no traceback. The command is
    replaced by one that writes a file and is interrupted: nothing is computed."""
    from ppr_jax._cli import _torques

    def interrupted(args):
        os.makedirs(args.out, exist_ok=True)
        with open(os.path.join(args.out, "torques.csv"), "w") as f:
            f.write("t,tau_1\n")
        raise KeyboardInterrupt

    def at_once(args):
        raise KeyboardInterrupt

    out = tmp_path / "run"
    for func, kept in ((at_once, "nothing written"), (interrupted, f"torques.csv in {out}")):
        monkeypatch.setattr(_torques, "cmd_torques", func)
        assert main(["torques", "--out", str(out)]) == 130
        cap = capsys.readouterr()
        assert cap.err.splitlines() == [f"ppr-jax: interrupted; kept: {kept}"], cap.err
    # a file an earlier run wrote under --out is not what this run kept
    os.utime(out / "torques.csv", (0, 0))
    monkeypatch.setattr(_torques, "cmd_torques", at_once)
    assert main(["torques", "--out", str(out)]) == 130
    assert capsys.readouterr().err.splitlines() == ["ppr-jax: interrupted; kept: nothing written"]


def test_ctrl_c_swallowed_by_a_library_is_raised_again(tmp_path, capsys, monkeypatch):
    """A real SIGINT whose KeyboardInterrupt a bare `except:` swallows (JAX's tracing has some)
    is raised again until the command line catches it: exit 130 and the one line, not a command
    that runs to its end with Ctrl-C ignored."""
    import signal
    import time

    from ppr_jax._cli import _torques

    def swallows(args):
        try:
            signal.raise_signal(signal.SIGINT)
            time.sleep(0.5)
        except BaseException:  # noqa: BLE001 (a library's bare except)
            pass
        for _ in range(50):  # 1 s: the repeat comes within 0.2 s, and wakes the sleeper
            time.sleep(0.02)
            naps.append(1)
        return 0

    naps = []
    monkeypatch.setattr(_torques, "cmd_torques", swallows)
    # as in a terminal (a shell's background job, such as a CI script's, ignores SIGINT)
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        assert main(["torques", "--out", str(tmp_path / "run")]) == 130
        assert len(naps) < 50
        assert capsys.readouterr().err.splitlines() == [
            "ppr-jax: interrupted; kept: nothing written"]
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        # a SIGINT ignored by whoever started the process stays ignored
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        naps.clear()
        assert main(["torques", "--out", str(tmp_path / "run")]) == 0
        assert len(naps) == 50 and signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, before)


def test_ctrl_c_where_it_cannot_propagate_prints_no_traceback(tmp_path, capsys, monkeypatch):
    """A KeyboardInterrupt raised where it cannot propagate (JAX's garbage-collection callback,
    a `__del__`) is one Python prints as "Exception ignored in ..." with a traceback: the
    command line passes over it (the interrupt comes again where it propagates), so stderr
    holds the one line alone."""
    import sys

    from ppr_jax._cli import _torques

    class Interrupted:
        def __del__(self):
            raise KeyboardInterrupt

    def interrupted(args):
        Interrupted()  # collected at once: its KeyboardInterrupt cannot propagate
        raise KeyboardInterrupt

    # Python's own hook, which prints (pytest's collects them as warnings)
    monkeypatch.setattr(sys, "unraisablehook", sys.__unraisablehook__)
    monkeypatch.setattr(_torques, "cmd_torques", interrupted)
    assert main(["torques", "--out", str(tmp_path / "run")]) == 130
    assert capsys.readouterr().err.splitlines() == [
        "ppr-jax: interrupted; kept: nothing written"]
    assert sys.unraisablehook is sys.__unraisablehook__


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_sigint_ends_a_running_command_with_one_line(tmp_path):
    """The real signal: `ppr-jax identify` in a subprocess, sent SIGINT once it says it is
    compiling: exit 130, the one line, no traceback. The data must pass identification's checks
    (the library's servo-circle example, its own experiment): a refused file exits at once, and
    a signal that arrives while the interpreter shuts down kills it without the line."""
    import signal
    import subprocess
    import sys

    from ppr_jax._data import example_path

    data = example_path()
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = dict(os.environ, PPR_JAX_CACHE="0", PYTHONPATH=root)
    # As from a terminal: a suite started as a shell's background job ignores SIGINT, and a
    # child inherits an ignored signal (a handler is reset to the default at exec).
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        proc = subprocess.Popen([sys.executable, "-m", "ppr_jax_cli", "identify", "--data",
                                 str(data), "--out", str(tmp_path / "fit")],
                                stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                                env=env, cwd=root)
    finally:
        signal.signal(signal.SIGINT, before)
    try:
        seen = []
        while not seen or ("compiling" not in seen[-1] and seen[-1]):
            seen.append(proc.stderr.readline())
        assert "compiling" in seen[-1], seen
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=300)
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    assert err.strip().splitlines() == ["ppr-jax: interrupted; kept: nothing written"], err


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_sigint_while_compiling_exits_130_with_one_line(tmp_path):
    """The issue's reproducer: `simulate --model double1r` interrupted while its program is
    traced, lowered and compiled, three processes at once, 0.2, 1 and 2 s after each says it
    compiles: each exits 130 with the one line, and nothing of the interpreter's finalisation
    runs after it (`_exit_at_once`). The finalisation raced XLA's threads: the process died
    with SIGSEGV after its line in 3 of 10 such interrupts on the machine the problem was found
    on, 1 in about 40 on a loaded 2-core machine. Its own signal, an exit handler the console
    script is started with, writes a line at every finalisation, and must stay silent."""
    import signal
    import subprocess
    import sys
    import threading
    import time

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = dict(os.environ, PPR_JAX_CACHE="0", PYTHONPATH=root)
    # the console script as `ppr-jax` runs it, with an exit handler registered first
    probe = ("import atexit, runpy, sys; "
             "atexit.register(lambda: print('finalised', file=sys.stderr, flush=True)); "
             "runpy.run_module('ppr_jax_cli', run_name='__main__', alter_sys=True)")
    delays = (0.2, 1.0, 2.0)
    procs, seen = [], [[] for _ in delays]
    # as from a terminal (`test_sigint_ends_a_running_command_with_one_line`)
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        for k in range(len(delays)):
            procs.append(subprocess.Popen(
                [sys.executable, "-c", probe, "simulate", "--model", "double1r",
                 "--t-end", "0.1", "--out", str(tmp_path / f"run{k}")],
                stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env, cwd=root))
    finally:
        signal.signal(signal.SIGINT, before)

    def interrupt(proc, delay, lines):
        while not lines or ("compiling" not in lines[-1] and lines[-1]):
            lines.append(proc.stderr.readline())
        if lines[-1]:
            time.sleep(delay)
            proc.send_signal(signal.SIGINT)

    threads = [threading.Thread(target=interrupt, args=a) for a in zip(procs, delays, seen)]
    try:
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=300)
        errs = [p.communicate(timeout=300)[1] for p in procs]
    finally:
        for p in procs:
            p.kill()
    for proc, lines, err, delay in zip(procs, seen, errs, delays):
        assert "compiling" in lines[-1], lines
        assert proc.returncode == 130, (delay, proc.returncode, err)
        assert err.strip().splitlines() == ["ppr-jax: interrupted; kept: nothing written"], err


def _path_with_a_nan_row(path):
    """A short path file (a slow arc near home) whose fourth data row has an empty cell."""
    ts = np.arange(0.0, 0.2 + 1e-9, 0.01)
    rows = [f"{t:.3f},{0.45 + 0.01 * np.sin(t):.9f},{0.26 + 0.01 * np.cos(t):.9f},0.0"
            for t in ts]
    rows[3] = rows[3].rsplit(",", 1)[0] + ","
    path.write_text("time,x,y,phi\n" + "\n".join(rows) + "\n")
    return str(path)


@pytest.mark.parametrize("command,extra", [
    ("simulate", []), ("sweep", ["--vary", "t=1e-4:2e-4:2"]), ("sensitivity", []),
    ("synth", []), ("compensate", []),
])
def test_every_command_that_reads_a_path_takes_drop_nan(tmp_path, capsys, command, extra):
    """The loaders' refusal of a NaN row advises --drop-nan: every command that reads a --path
    file takes it, and with it the row is dropped (the command then goes on to its next check,
    here the refused thickness, before anything is compiled)."""
    f = _path_with_a_nan_row(tmp_path / "nan.csv")
    out = str(tmp_path / ("o.csv" if command == "synth" else "o"))
    argv = [command, "--path", f, "--set", "t=-1", *extra, "--out", out]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "line 5" in err and "--drop-nan" in err, err
    assert main(argv + ["--drop-nan"]) == 2
    err = capsys.readouterr().err
    assert "'t'" in err and "NaN" not in err, err


@pytest.mark.parametrize("command,extra", [
    ("simulate", []), ("sweep", ["--vary", "t=1e-4:2e-4:2"]), ("sensitivity", []),
    ("synth", []),
])
def test_scene_and_path_given_together_are_refused(tmp_path, capsys, command, extra):
    """--scene and --path are alternatives: both given is one line and exit 2 (the scene was
    silently ignored); the default scene alone stands aside for --path (the command goes on to
    its next check, the refused thickness)."""
    f = _path_with_a_nan_row(tmp_path / "nan.csv")
    out = str(tmp_path / ("o.csv" if command == "synth" else "o"))
    argv = [command, "--path", f, "--drop-nan", "--set", "t=-1", *extra, "--out", out]
    assert main(argv + ["--scene", "servo-circle"]) == 2
    err = capsys.readouterr().err
    assert "--scene servo-circle and --path are alternatives" in err, err
    assert len(err.strip().splitlines()) == 1
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "'t'" in err and "alternatives" not in err, err


@pytest.mark.parametrize("which", ["circle", "path", "long"])
def test_sensitivity_table_headers_name_every_metric_whole(which):
    """The sensitivity table's column headers, read back column by column, are the metrics'
    whole names (they were cut to 14 characters: radial_error_max_m and radial_error_min_m
    both read "radial error m"), and the numbers' columns line up under them."""
    from ppr_jax._cli._sensitivity import WIDTH, header_lines
    from ppr_jax._names import PATH_SENSITIVITY_METRICS, SENSITIVITY_METRICS

    metrics = {"circle": SENSITIVITY_METRICS, "path": PATH_SENSITIVITY_METRICS,
               "long": ("first_locked_natural_frequency_of_the_platform_hz", "t")}[which]
    lines = header_lines(metrics)
    assert lines[-1].startswith(" parameter ")
    for i, m in enumerate(metrics):
        start = 11 + i * (WIDTH + 1)
        words = " ".join(ln[start:start + WIDTH].strip() for ln in lines).split()
        assert " ".join(words) == m.replace("_", " ")
    # a header never runs into its neighbour: the column before the next one is blank
    for ln in lines:
        assert all(ln[11 + i * (WIDTH + 1) - 1:11 + i * (WIDTH + 1) + 1].strip() == ""
                   for i in range(1, len(metrics)) if len(ln) > 11 + i * (WIDTH + 1))


def _help(capsys, command):
    with pytest.raises(SystemExit) as info:
        main([command, "--help"])
    assert info.value.code == 0
    return capsys.readouterr().out


def test_help_texts_say_each_default_once_and_describe_every_option(capsys):
    """Every command's --help: each option has a help text, none ends in a bare "(default:
    None)" or a flag's "(default: False)", a text that states its default gets no second one,
    and torques (which reads no --path) does not speak of a --path file."""
    import argparse

    from ppr_jax._cli._main import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    for name, parser in sub.choices.items():
        for action in parser._actions:
            assert action.help, (name, action.option_strings)
        text = " ".join(_help(capsys, name).split())
        assert "(default: None)" not in text and "(default: False)" not in text, name
    torques = " ".join(_help(capsys, "torques").split())
    assert "--path" not in torques and "default 7.54 (one turn of the paper's circle)" in torques
    simulate = " ".join(_help(capsys, "simulate").split())
    # stated in the text: no second default
    rtol = simulate[simulate.index("--rtol RTOL relative"):simulate.index("--atol ATOL absolute")]
    assert rtol.count("default") == 1, rtol
    loss = simulate[simulate.index("--strip-loss SECONDS Kelvin"):
                    simulate.index("--solver {", simulate.index("--strip-loss SECONDS Kelvin"))]
    assert "default 0 (undamped)" in loss and "(default: 0.0)" not in loss, loss
    # not stated in the text: argparse's, once
    assert "(default: quasi-static)" in simulate and "(default: 755)" in simulate


def test_simulate_runs_each_model_once_and_refuses_an_empty_model_list(tmp_path, capsys,
                                                                         monkeypatch):
    """`--model double1r,double1r,rigid` runs double1r once, then rigid (the order given);
    `--model ""` (or only commas) is refused in one line naming the option, where it silently
    ran the default models. The runs are stubs: nothing is compiled."""
    import ppr_jax._cli._simulate as simulate
    import ppr_jax._scenes as scenes
    from ppr_jax._errors import PPRError

    ran = []

    def run_scene(scene, params, model, **kw):
        ran.append(model.name)
        raise PPRError("not run here")

    monkeypatch.setattr(scenes, "run_scene", run_scene)
    monkeypatch.setattr(simulate, "_derived_dict", lambda params: {})
    out = str(tmp_path / "o")
    assert main(["simulate", "--model", "double1r,double1r, rigid,double1r", "--no-figures",
                 "--out", out]) == 2
    assert ran == ["double1r", "rigid"]
    assert "2 of 2 models failed (double1r, rigid)" in capsys.readouterr().err
    for text in ("", " , "):
        assert main(["simulate", "--model", text, "--out", str(tmp_path / "e")]) == 2
        err = capsys.readouterr().err
        assert f"--model {text!r} names no model" in err and len(err.splitlines()) == 1, err
    assert ran == ["double1r", "rigid"] and not os.path.exists(tmp_path / "e")


@pytest.mark.parametrize("argv", [["modes", "--model", "reduced"],
                                  ["simulate", "--scene", "modes", "--model", "reduced"]])
def test_modes_without_a_free_coordinate_print_no_unit(tmp_path, capsys, monkeypatch, argv):
    """A model with no free coordinate (L1 with its actuators locked) has no frequency: the
    line says "none (no free coordinate)", not "none (no free coordinate) Hz"; frequencies keep
    their unit. The static solve is a stub: nothing is compiled."""
    import ppr_jax._scenes as scenes

    def modes_scene(params, *, model, actuators="locked", **kw):
        freqs = [] if actuators == "locked" else [1.5, 2.25]
        return {"scene": "modes", "model": model.name, "actuators": actuators,
                "frequencies_hz": freqs, "note": "stub"}

    monkeypatch.setattr(scenes, "modes_scene", modes_scene)
    extra = ["--out", str(tmp_path / "o")] if argv[0] == "simulate" else []
    assert main(argv + extra) == 0
    out = capsys.readouterr().out
    assert "locked: none (no free coordinate)\n" in out and "coordinate) Hz" not in out, out
    if argv[0] == "simulate":
        assert "free: 1.5, 2.25 Hz" in out, out


def test_compensate_names_every_file_written_with_its_folder(tmp_path, capsys, monkeypatch):
    """compensate's last line names each file it wrote the same way, with --out's folder
    (the figure was named alone: "wrote D/angles.csv, D/summary.json, tracking_error.png").
    The inversion and the figure are stubs: nothing is compiled."""
    from types import SimpleNamespace

    import ppr_jax._cli._compensate as command
    import ppr_jax._studies as studies

    err = {"position_max": 1e-3, "phi_max": 1e-3}
    comp = SimpleNamespace(kind="angles", ts=[0.0, 0.1], commands=[[0.0] * 3] * 2,
                           model="rigid", drive="motion", method="inversion",
                           summary=lambda: {}, error={"before": err, "after": err},
                           improvement=1.0, flags=[])
    monkeypatch.setattr(studies, "compensate", lambda *a, **kw: comp)

    def figure(path, comp):
        open(path, "w").close()
        return path

    monkeypatch.setattr(command, "error_figure", figure)
    out = os.path.join(str(tmp_path), "comp")
    assert main(["compensate", "--scene", "servo-circle", "--model", "rigid", "--out", out]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    files = [os.path.join(out, f) for f in ("angles.csv", "summary.json", "tracking_error.png")]
    assert last == "wrote " + ", ".join(files), last
    assert all(os.path.exists(f) for f in files)
