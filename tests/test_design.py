"""`ppr_jax.design` against closed forms derived on paper (benchmarks/design.py, tier 1), its
multipliers against the closed form's derivatives, the refusal of bad bounds and infeasible
specifications, and the designed robot's parameter file.

Tier 1, one strip pivot carrying a link (the catalogue's `pivot_*` metrics): a straight strip
of length L = r theta_c, width w, thickness t bent by a pure moment has stiffness K = E I/L,
I = w t^3/12, and surface stress sigma = E t theta/(2 L) at the rotation theta; it carries the
connecting link, J = m3 (l3^2/3 + b_r^2/12) about its end, at f = sqrt(K/J)/(2 pi).
Maximise f over (t, r, w) subject to sigma(stroke) <= sigma_a: at fixed L and w, f grows with
t as t^(3/2) and sigma as t, so the stress bound is active, t = 2 sigma_a L/(E stroke); there
K = 2 w sigma_a^3 L^2/(3 E^2 stroke^3) grows with w and L, so r and w sit on their upper
bounds. f* grows as sigma_a^(3/2), L and w^(1/2), whence the multipliers
d f*/d sigma_a = 1.5 f*/sigma_a, d f*/d r_hi = f*/r_hi, d f*/d w_hi = f*/(2 w_hi).
Assumed: the strip massless, the drive link held, the link rigid, small strains.
"""

import math

import equinox as eqx
import numpy as np
import pytest

import ppr_jax as pj
from ppr_jax._kinematics import _ik_path_jit
from ppr_jax._models import Reduced
from tests.helpers import DATA, DESIGN_SPEC

E, RHO_M, L3, B_R, T_R, THETA_C = 71.0e9, 2780.0, 0.366, 0.023, 0.010, 1.88
SIGMA_A, STROKE = 100e6, 0.3
BOUNDS = {"t": (1e-4, 1e-3), "r": (0.01, 0.04), "w": (0.01, 0.03)}


def link_inertia(t_r=T_R):
    m3 = RHO_M * L3 * B_R * t_r
    return m3 * (L3**2 / 3 + B_R**2 / 12)


def pivot_frequency(t, r, w, t_r=T_R):
    L = r * THETA_C
    K = E * w * t**3 / (12 * L)
    return math.sqrt(K / link_inertia(t_r)) / (2 * math.pi)


def tier1_closed_form():
    r, w = BOUNDS["r"][1], BOUNDS["w"][1]
    t = 2 * SIGMA_A * r * THETA_C / (E * STROKE)
    return t, r, w, pivot_frequency(t, r, w)


@pytest.fixture(scope="module")
def tier1():
    return pj.design(BOUNDS, "pivot_frequency_hz",
                     [pj.Constraint("pivot_stress_Pa", upper=SIGMA_A)], stroke=STROKE)


def test_tier1_reaches_the_closed_form(tier1):
    t, r, w, f = tier1_closed_form()
    assert BOUNDS["t"][0] < t < BOUNDS["t"][1]  # the closed form's optimum is inside t's box
    assert tier1.objective["value"] == pytest.approx(f, rel=1e-6)
    assert tier1.x["t"] == pytest.approx(t, rel=1e-6)
    assert tier1.x["r"] == pytest.approx(r, rel=1e-9)
    assert tier1.x["w"] == pytest.approx(w, rel=1e-9)
    # on the stress bound, and the start was below the optimum
    (c,) = tier1.constraints
    assert c["active"] and c["value"] == pytest.approx(SIGMA_A, rel=1e-8)
    assert tier1.objective["start_value"] < f
    assert tier1.feasible


def test_tier1_multipliers_are_the_closed_forms_derivatives(tier1):
    *_, f = tier1_closed_form()
    (c,) = tier1.constraints
    assert c["multiplier"] == pytest.approx(1.5 * f / SIGMA_A, rel=1e-6)
    bounds = {(b["variable"], b["side"]): b["multiplier"] for b in tier1.active_bounds}
    assert set(bounds) == {("r", "upper"), ("w", "upper")}
    assert bounds["r", "upper"] == pytest.approx(f / BOUNDS["r"][1], rel=1e-6)
    assert bounds["w", "upper"] == pytest.approx(f / (2 * BOUNDS["w"][1]), rel=1e-6)


def test_tier1_gradient_is_the_closed_forms(tier1):
    """The JAX Jacobian at the optimum against the closed form's derivatives: f ~ t^1.5
    r^-0.5 w^0.5, sigma ~ t/r."""
    t, r, w, f = tier1_closed_form()
    J = np.asarray(tier1.verification["gradient_check"]["jacobian"])
    np.testing.assert_allclose(J[0], [1.5 * f / t, -0.5 * f / r, 0.5 * f / w], rtol=1e-6)
    np.testing.assert_allclose(J[1], [SIGMA_A / t, -SIGMA_A / r, 0.0], rtol=1e-6, atol=1e-6)


def test_tier1_verification(tier1):
    v = tier1.verification
    assert v["ok"]
    assert v["kkt_residual"] < 1e-8
    assert v["gradient_check"]["worst"] < 1e-6
    g = v["grid"]
    assert g["kind"] == "grid" and g["points"] == 21**3
    # a grid point is feasible only strictly inside the stress bound: it cannot beat the optimum
    assert g["best_objective"] <= tier1.objective["value"]
    assert -g["gap"] <= 0.06 and g["ok"]
    # the grid's best, checked by hand: the best feasible grid point of the same box
    axes = [np.linspace(lo, hi, 21) for lo, hi in BOUNDS.values()]
    best = max(pivot_frequency(t, r, w) for t in axes[0] for r in axes[1] for w in axes[2]
               if E * t * STROKE / (2 * r * THETA_C) <= SIGMA_A * (1 + 1e-8))
    assert g["best_objective"] == pytest.approx(best, rel=1e-12)


def test_tier1_history_and_starts(tier1):
    assert len(tier1.starts) == pj._names.DESIGN_STARTS
    assert all(s["feasible"] for s in tier1.starts)
    h = tier1.history
    assert h[0]["x"] == tier1.x_start and len(h) >= 2
    assert h[-1]["objective"] == pytest.approx(tier1.objective["value"], rel=1e-9)


def test_minimum_mass_for_a_frequency_closed_form():
    """Minimise the moving mass over (t, t_r) subject to pivot_frequency_hz >= f_min: the link
    thickness t_r goes to its lower bound (mass and inertia fall with it), the strip thickness
    to the frequency bound, t^3 = 12 L J (2 pi f_min)^2/(E w); the mass's multiplier
    d m*/d f_min = 3 rho_m w L dt*/df_min = 2 rho_m w L t*/f_min (t* ~ f_min^(2/3))."""
    f_min, w, r = 2.0, 0.026, 0.020
    L = r * THETA_C
    t_r = 0.005
    t = (12 * L * link_inertia(t_r) * (2 * math.pi * f_min) ** 2 / (E * w)) ** (1 / 3)
    d = pj.design({"t": (1e-4, 1e-3), "t_r": (t_r, 0.02)},
                  pj.Objective("moving_mass_kg", "min"),
                  [{"metric": "pivot_frequency_hz", "lower": f_min}])
    assert d.x["t"] == pytest.approx(t, rel=1e-6)
    assert d.x["t_r"] == pytest.approx(t_r, rel=1e-9)
    (c,) = d.constraints
    assert c["active"] and c["side"] == "lower"
    assert c["multiplier"] == pytest.approx(2 * RHO_M * w * L * t / f_min, rel=1e-5)
    assert d.verification["ok"]


def test_designed_robot_parameter_file(tier1, tmp_path):
    """The designed robot's file, read back as --params-file reads it, gives the optimum's
    objective by the closed form."""
    path = tier1.to_params_file(str(tmp_path / "designed.toml"))
    p = pj.load_params(path)
    for name, value in tier1.x.items():
        assert float(getattr(p, name)) == value
    assert pivot_frequency(float(p.t), float(p.r), float(p.w)) == pytest.approx(
        tier1.objective["value"], rel=1e-12)
    # the JSON report holds the same optimum
    import json

    data = json.loads(open(tier1.save(str(tmp_path / "design.json"))).read())
    assert data["x"] == tier1.x and data["params"]["t"] == tier1.x["t"]


@pytest.mark.parametrize("variables, words", [
    ({"t": (-1e-4, 1e-3)}, ["'t'", "strip thickness", "[1e-06, 0.01] m"]),
    ({"t": (0.0, 1e-3)}, ["'t'", "lower bound 0", "[1e-06, 0.01] m"]),
    ({"theta_c": (1.0, 4.0)}, ["'theta_c'", "upper bound 4", "[0.001, 3] rad"]),
    ({"t": (1e-3, 1e-4)}, ["'t'", "must be below"]),
    ({"t": (1e-4, float("nan"))}, ["'t'", "finite"]),
    ({"thickness": (1e-4, 1e-3)}, ["'thickness'", "allowed"]),
    ({"sigma": (-1, 1)}, ["'sigma'", "allowed"]),
    ({}, ["non-empty"]),
])
def test_bad_bounds_are_refused(variables, words):
    with pytest.raises(pj.DesignError) as info:
        pj.design(variables, "pivot_frequency_hz")
    for w in words:
        assert w in str(info.value)


def test_bad_goals_are_refused():
    with pytest.raises(pj.DesignError, match="unknown design metric 'speed'"):
        pj.design(BOUNDS, "speed")
    with pytest.raises(pj.DesignError, match="scene="):
        pj.design(BOUNDS, "radial_error_max_m")
    with pytest.raises(pj.DesignError, match="scene="):
        pj.design(BOUNDS, "strip_stress_peak_Pa")
    with pytest.raises(pj.DesignError, match="stroke"):
        pj.design(BOUNDS, "pivot_frequency_hz", [pj.Constraint("pivot_stress_Pa", upper=1e8)])
    with pytest.raises(pj.DesignError, match=r"stroke = 4"):
        pj.design(BOUNDS, "pivot_frequency_hz", [pj.Constraint("pivot_stress_Pa", upper=1e8)],
                  stroke=4.0)
    with pytest.raises(pj.DesignError, match="upper or a lower"):
        pj.Constraint("pivot_stress_Pa")
    with pytest.raises(pj.DesignError, match="optimizer"):
        pj.design(BOUNDS, "pivot_frequency_hz", optimizer="cma")


def test_infeasible_specification_names_the_constraint():
    """An allowable below the least stress the box allows (t and r at their best bounds):
    the error names the constraint and the violation at that point."""
    sigma_a = 1e6
    least = E * BOUNDS["t"][0] * STROKE / (2 * BOUNDS["r"][1] * THETA_C)
    assert least > sigma_a
    with pytest.raises(pj.DesignError) as info:
        pj.design(BOUNDS, "pivot_frequency_hz",
                  [pj.Constraint("pivot_stress_Pa", upper=sigma_a)], stroke=STROKE)
    msg = str(info.value)
    assert "pivot_stress_Pa <= 1e+06" in msg and "cannot be met" in msg
    best = info.value.result
    assert best.x["t"] == pytest.approx(BOUNDS["t"][0], rel=1e-9)
    assert best.x["r"] == pytest.approx(BOUNDS["r"][1], rel=1e-9)
    assert best.constraints[0]["violation_abs"] == pytest.approx(least - sigma_a, rel=1e-9)
    assert f"{least - sigma_a:.6g}" in msg
    assert "not run" in best.summary() and not best.feasible


#: tier 1 (`tier1_closed_form`: SIGMA_A and STROKE) with a verification grid of 1000 points
SPEC = DESIGN_SPEC + "grid = 1000\n"


def design_cli(tmp_path, spec_text):
    """`ppr-jax design --spec` of `spec_text` into tmp_path/out: (design.json's data, out)."""
    import json

    from ppr_jax._cli import main

    spec = tmp_path / "spec.toml"
    spec.write_text(spec_text)
    out = tmp_path / "out"
    assert main(["design", "--spec", str(spec), "--out", str(out)]) == 0
    return json.loads((out / "design.json").read_text()), out


def test_cli_design_writes_the_report_and_the_designed_robot(tmp_path, capsys):
    """`ppr-jax design --spec` on tier 1: design.json holds the closed-form optimum, and the
    designed robot's file, read as --params-file reads it, reproduces the objective."""
    data, out = design_cli(tmp_path, SPEC)
    *_, f = tier1_closed_form()
    assert data["objective"]["value"] == pytest.approx(f, rel=1e-6)
    assert data["verification"]["ok"] and data["verification"]["grid"]["points"] == 1000
    p = pj.load_params(str(out / "designed.toml"))
    assert pivot_frequency(float(p.t), float(p.r), float(p.w)) == pytest.approx(
        data["objective"]["value"], rel=1e-12)
    assert "pivot_frequency_hz" in capsys.readouterr().out
    # the MJCF describes the robot the parameter file does
    assert (out / "designed.xml").read_text() == pj.to_mjcf(p)
    # the report: self-contained (figures as base64 PNG, nothing fetched), the closed form's
    # multiplier on the stress bound, 1.5 f*/sigma_a, in its constraints table
    page = (out / "report.html").read_text()
    assert page.count("src=\"data:image/png;base64,") >= 3
    assert "http" not in page.split("<body>")[1].split("Versions")[0]
    assert f"{1.5 * f / SIGMA_A:.4g}" in page
    for heading in ("Optimum against start", "Sensitivity of the optimum to each bound",
                    "History", "Verification"):
        assert heading in page


@pytest.mark.slow
def test_designed_robot_reproduces_its_scene_objective_in_ppr_jax_simulate(tmp_path, capsys):
    """The peak actuator torque of L1 over 0.5 s of servo-circle minimised over t (no ODE:
    forward kinematics and inverse dynamics); `ppr-jax simulate --params-file designed.toml`
    of the same scene and model reports the optimum's objective."""
    import json

    from ppr_jax._cli import main

    data, out = design_cli(tmp_path, """
[variables]
t = [2e-4, 6e-4]
[objective]
minimize = "torque_peak_Nm"
[settings]
scene = "servo-circle"
model = "reduced"
t_end = 0.5
n_out = 26
starts = 1
candidates = 8
grid = 16
""")
    capsys.readouterr()
    sim = tmp_path / "sim"
    assert main(["simulate", "--scene", "servo-circle", "--model", "reduced", "--t-end", "0.5",
                 "--n-out", "26", "--params-file", str(out / "designed.toml"),
                 "--out", str(sim)]) == 0
    summary = json.loads((sim / "summary.json").read_text())
    assert summary["models"]["reduced"]["torque_peak_Nm"] == pytest.approx(
        data["objective"]["value"], rel=1e-9)


def test_cli_design_bad_spec_is_one_line(tmp_path, capsys):
    from ppr_jax._cli import main

    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC.replace("t = [1e-4, 1e-3]", "t = [0.0, 1e-3]"))
    assert main(["design", "--spec", str(spec), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "'t'" in err and "[1e-06, 0.01] m" in err and "Traceback" not in err
    spec.write_text(SPEC + "\n[extra]\nx = 1\n")
    assert main(["design", "--spec", str(spec), "--out", str(tmp_path / "o")]) == 2
    assert "unknown section" in capsys.readouterr().err


@pytest.mark.slow
def test_designed_robot_reproduces_its_base_frequency_in_ppr_jax_modes(tmp_path, capsys):
    """The robot's first locked frequency (L2) maximised over t under the strip pivot's stress
    bound: the frequency grows with t, so t* is the stress bound's closed form
    2 sigma_a r theta_c/(E stroke); `ppr-jax modes --params-file` of the designed robot gives the
    optimum's objective."""
    import json

    from ppr_jax._cli import main

    data, out = design_cli(tmp_path, f"""
[variables]
t = [2e-4, 4e-4]
[objective]
maximize = "base_frequency_hz"
[[constraints]]
metric = "pivot_stress_Pa"
upper = {SIGMA_A!r}
[settings]
stroke = {STROKE!r}
starts = 2
candidates = 8
grid = 64
""")
    t_star = 2 * SIGMA_A * 0.020 * THETA_C / (E * STROKE)
    assert data["x"]["t"] == pytest.approx(t_star, rel=1e-6)
    assert data["verification"]["ok"]
    capsys.readouterr()
    assert main(["modes", "--params-file", str(out / "designed.toml"), "--json"]) == 0
    modes = json.loads(capsys.readouterr().out)
    assert modes["frequencies_hz"][0] == pytest.approx(data["objective"]["value"], rel=1e-6)


# --- the catalogue: path margins, torques, compliance -------------------------------------------
#
# servo-circle's circle on a robot with a = 0.6 m and l1 = l3 = 0.45 m: as the platform side h
# grows the path's start (x = 0.55 m, y = 0.26 m) nears a type-II singularity of L1 and crosses
# it near h = 0.137 m (det S changes sign at the first samples). The margins are re-derived here
# from `inverse_kinematics`' S (numpy determinant, the library's check `path_singular`), not from
# the catalogue's code.

SING_BASE = dict(a=0.6, l1=0.45, l3=0.45)


def singular_margin_by_hand(h, n_out=101, t_end=7.54):
    """Least relative det S (translations scaled by r1) along servo-circle's path, signed
    positive at home, from the library's inverse kinematics at each pose and numpy."""
    from ppr_jax._trajectory import Circle

    p = pj.scene_params("servo-circle").replace(h=h, **SING_BASE)
    robot = pj.Robot(p)
    ts = np.linspace(0.0, t_end, n_out)
    circle = Circle()
    X = np.array([np.asarray(circle(t)) for t in ts])
    r1 = float(robot.r1)

    def rel(S):
        Sn = np.asarray(S) * np.array([r1, r1, 1.0])[None, :]
        return np.linalg.det(Sn) / np.prod(np.linalg.norm(Sn, axis=0))

    s0 = np.sign(rel(pj.inverse_kinematics(p, np.asarray(pj.home_pose(robot))).S))
    # inverse_kinematics' batch, unchecked (it refuses a singular pose)
    S = np.asarray(_ik_path_jit(Reduced(), robot, X).S)
    return min(s0 * rel(s) for s in S)


def test_path_margins_against_the_inverse_kinematics():
    from ppr_jax._studies._catalogue import path_margins
    from ppr_jax._trajectory import Circle

    X = np.array([np.asarray(Circle()(t)) for t in np.linspace(0.0, 7.54, 101)])
    margins = eqx.filter_jit(path_margins)
    for h in (0.1, 0.15):
        p = pj.scene_params("servo-circle").replace(h=h, **SING_BASE)
        reach, sing = margins(Reduced(), pj.Robot(p), X)
        assert float(sing) == pytest.approx(singular_margin_by_hand(h), rel=1e-9)
        assert float(reach) > 0.4
    assert float(sing) < 0  # h = 0.15 crosses


@pytest.mark.slow
def test_path_through_a_singularity_is_never_the_optimum():
    # maximise the moving mass (it grows with h): unconstrained, h would reach 0.2 m, whose path
    # crosses the singularity. With a margin of 0.05 the optimum stops where the margin binds.
    opts = pj.SceneOptions(t_end=7.54, n_out=101)
    p0 = pj.scene_params("servo-circle").replace(**SING_BASE)
    d = pj.design({"h": (0.08, 0.2)}, {"maximize": "moving_mass_kg"},
                  [pj.Constraint("path_singularity_margin", lower=0.05)], params=p0,
                  scene="servo-circle", options=opts, grid=200)
    assert singular_margin_by_hand(0.2) < 0  # the unconstrained optimum's path crosses
    h = d.x["h"]
    assert 0.08 < h < 0.137
    # the margin by hand is 0.05 at the optimum: bisection on it gives the same h
    lo, hi = 0.08, 0.137
    for _ in range(25):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if singular_margin_by_hand(mid) > 0.05 else (lo, mid)
    assert h == pytest.approx(lo, rel=1e-6)
    (c,) = [c for c in d.constraints if c["metric"] == "path_singularity_margin"]
    assert c["active"] and c["multiplier"] < 0  # raising a lower bound costs mass
    assert d.verification["ok"]
    # the implicit reach margin was added and holds
    (r,) = [c for c in d.constraints if c["metric"] == "path_reach_margin"]
    assert r["bound"] > 0 and r["value"] > 0.4


@pytest.mark.slow
def test_every_design_past_a_singularity_or_out_of_reach_is_infeasible():
    opts = pj.SceneOptions(t_end=7.54, n_out=101)
    p0 = pj.scene_params("servo-circle").replace(**SING_BASE)
    assert singular_margin_by_hand(0.15) < 0
    with pytest.raises(pj.DesignError, match="path_singularity_margin >= 1e-06") as err:
        pj.design({"h": (0.15, 0.2)}, {"maximize": "moving_mass_kg"}, params=p0,
                  scene="servo-circle", options=opts, grid=50)
    assert not err.value.result.feasible
    # links too short for the circle (the default robot, l1 = l3 = 0.2-0.25 m): out of reach
    with pytest.raises(pj.DesignError, match="path_(reach|singularity)_margin >= 1e-06") as err:
        pj.design({"l1": (0.15, 0.2), "l3": (0.15, 0.2)}, {"minimize": "moving_mass_kg"},
                  scene="servo-circle", options=opts, grid=50)
    (r,) = [c for c in err.value.result.constraints if c["metric"] == "path_reach_margin"]
    assert r["violation"] > 0.2  # 1 - |cos| of the closure angle is -0.29 at l1 = l3 = 0.2 m


@pytest.mark.slow
def test_torque_rms_and_peak_over_a_scene():
    # L1 under servo-circle: forward kinematics and inverse dynamics, no ODE; the torques' RMS
    # and peak re-derived with numpy from the scene's own run at the optimum
    opts = pj.SceneOptions(t_end=0.5, n_out=26)
    d = pj.design({"t": (2e-4, 6e-4)}, {"minimize": "torque_rms_Nm"},
                  [pj.Constraint("torque_peak_Nm", upper=100.0)], scene="servo-circle",
                  model="reduced", options=opts, grid=64)
    res = pj.solve_scene("servo-circle", d.params, model="reduced", options=opts)
    tau = np.asarray(res.tau)
    assert d.metrics["torque_rms_Nm"] == pytest.approx(np.sqrt(np.mean(tau**2)), rel=1e-9)
    assert d.metrics["torque_peak_Nm"] == pytest.approx(np.max(np.abs(tau)), rel=1e-9)
    assert d.verification["gradient_check"]["ok"]
    assert d.verification["grid"]["ok"]


@pytest.mark.slow
def test_static_compliance_against_a_small_load():
    # the compliance at home against the displacement of the locked robot (L2) under a small
    # wrench, by the library's static equilibrium
    from ppr_jax._models import get_model

    p0 = pj.RobotParams(t=0.5e-3)
    d = pj.design({"t": (3e-4, 7e-4)}, {"minimize": "compliance_xy_m_per_N"},
                  [pj.Constraint("compliance_phi_rad_per_Nm", upper=1e3)], params=p0, grid=50)
    assert d.x["t"] == pytest.approx(7e-4, rel=1e-9)  # stiffer strips
    model, robot = get_model("double1r"), pj.Robot(d.params)
    z0 = model.coords_from_pose(robot, pj.home_pose(robot))
    zeq, _ = pj.static_equilibrium(model, robot, z0, locked=True)
    disp = []
    for wrench in ([1e-3, 0, 0], [0, 1e-3, 0], [0, 0, 1e-4]):
        z, _ = pj.static_equilibrium(model, robot, zeq, locked=True, wrench=np.array(wrench))
        disp.append(np.asarray(z[:3] - zeq[:3]) / max(wrench))
    C = np.array(disp).T
    lam = np.linalg.eigvalsh((C[:2, :2] + C[:2, :2].T) / 2)
    assert d.metrics["compliance_xy_m_per_N"] == pytest.approx(lam[-1], rel=1e-4)
    assert d.metrics["compliance_phi_rad_per_Nm"] == pytest.approx(C[2, 2], rel=1e-4)


# --- the optimum re-scored with the quasi-static L3 ------------------------------------------


def test_rescore_of_closed_forms_needs_no_model(tier1):
    l3 = tier1.verification["l3"]
    assert l3["within"] and l3["metrics"] == {} and "no metric" in l3["note"]
    # the band is the shipped PRB fit's torque error at kappa0 = theta_c/2 (docs/prb_fit.md:
    # 19 % at Table 1's kappa0 = 0.94)
    assert l3["kappa0"] == pytest.approx(THETA_C / 2)
    assert l3["band"] == pytest.approx(0.19, abs=0.01)


@pytest.mark.slow
@pytest.mark.parametrize("geometry, within", [("strip", True), ("centerline", False)])
def test_rescore_with_l3_against_modes_and_the_band(geometry, within):
    # the base frequency grows with t: t* on its upper bound. L3's value at t* against
    # `ppr_jax.modes` of QuasiStaticBeam(4) (eigenvalues, not the design's Rayleigh quotient);
    # the PRB chain on the strip's own geometry lies within the band (8 % in stiffness,
    # docs/models.md), the paper's centre-line chain (2.3 times softer) does not
    from ppr_jax._models import QuasiStaticBeam

    p0 = pj.RobotParams(t=0.5e-3, joint_geometry=geometry)
    d = pj.design({"t": (3e-4, 7e-4)}, "base_frequency_hz", params=p0, grid=20, starts=1,
                  candidates=4)
    assert d.x["t"] == pytest.approx(7e-4, rel=1e-9)
    l3 = d.verification["l3"]
    m = l3["metrics"]["base_frequency_hz"]
    f3 = pj.modes(QuasiStaticBeam(4), pj.Robot(d.params)).freq_hz[0]
    assert m["l3"] == pytest.approx(float(f3), rel=1e-6)
    assert m["prb"] == pytest.approx(d.objective["value"], rel=1e-12)
    assert m["band"] == pytest.approx(1 - math.sqrt(1 - l3["band"]), rel=1e-12)
    assert l3["within"] is within and l3["objective_within"] is within


# --- tier 2: a closed-form elastica optimum --------------------------------------------------
#
# One strip (length L = r theta_c, rest curvature 1/r) under a pure end moment M: its curvature
# changes uniformly by M/EI, so the tip turns by exactly M L/(E I), I = w t^3/12, and the stress
# is 6 M/(w t^2) everywhere. Minimising the stress subject to a tip rotation >= theta*: the
# rotation bound is active, w t^3 = 12 M L/(E theta*); w and r on their upper bounds;
# t* = (12 M L/(E theta* w_hi))^(1/3), sigma* = 6 M/(w_hi t*^2) (benchmarks/design.py).

T2_M, T2_THETA = 0.05, 1.0
T2_BOUNDS = {"t": (1e-4, 1e-3), "r": (0.01, 0.04), "w": (0.005, 0.03)}


def test_elastica_metrics_are_the_pure_moment_arc():
    import jax

    from ppr_jax._prb import derived
    from ppr_jax._studies._catalogue import strip_elastica

    p = pj.RobotParams(t=0.28e-3, w=0.02, r=0.03)
    rot, sig = jax.jit(lambda p: strip_elastica(p, derived(p), (0.0, 0.0, T2_M)))(p)
    L, I = 0.03 * THETA_C, 0.02 * 0.28e-3**3 / 12
    assert T2_M * L / (E * I) > 1.0  # a large deflection
    assert float(rot) == pytest.approx(T2_M * L / (E * I), rel=1e-9)
    assert float(sig) == pytest.approx(6 * T2_M / (0.02 * 0.28e-3**2), rel=1e-9)


@pytest.mark.slow
def test_tier2_elastica_optimum_is_the_closed_form():
    d = pj.design(T2_BOUNDS, {"minimize": "strip_elastica_stress_Pa"},
                  [pj.Constraint("strip_tip_rotation_rad", lower=T2_THETA)],
                  strip_load=(0.0, 0.0, T2_M), grid=1000)
    r, w = T2_BOUNDS["r"][1], T2_BOUNDS["w"][1]
    t = (12 * T2_M * r * THETA_C / (E * T2_THETA * w)) ** (1 / 3)
    s = 6 * T2_M / (w * t**2)
    assert d.objective["value"] == pytest.approx(s, rel=1e-6)
    assert d.x["t"] == pytest.approx(t, rel=1e-6)
    (c,) = d.constraints
    assert c["active"] and c["multiplier"] == pytest.approx(2 / 3 * s / T2_THETA, rel=1e-5)
    b = {(x["variable"], x["side"]): x["multiplier"] for x in d.active_bounds}
    assert b["w", "upper"] == pytest.approx(-s / (3 * w), rel=1e-5)
    assert b["r", "upper"] == pytest.approx(-2 / 3 * s / r, rel=1e-5)
    assert d.verification["ok"]


def test_elastica_metrics_need_a_load():
    with pytest.raises(pj.DesignError, match="strip_load"):
        pj.design(T2_BOUNDS, {"minimize": "strip_elastica_stress_Pa"})


# --- sampled constraints: a peak over times and springs as one constraint per sample ------------


def test_sampled_constraints_are_the_bounds_on_the_extremes_side():
    from ppr_jax._studies._design._constraints import sampled_constraints

    def sides(*cs):
        return [(0, c, s, b) for c in cs for s, b in c.sides()]

    stress = pj.Constraint("strip_stress_peak_Pa", upper=1e8)
    torque_low = pj.Constraint("torque_peak_Nm", lower=0.1)  # max >= b: not every sample
    margin = pj.Constraint("path_singularity_margin", lower=0.1)
    rms = pj.Constraint("torque_rms_Nm", upper=1.0)  # not a peak
    metrics = ["base_frequency_hz", "strip_stress_peak_Pa", "torque_peak_Nm",
               "path_singularity_margin", "torque_rms_Nm"]
    got = sampled_constraints(metrics, sides(stress, torque_low, margin, rms))
    assert got == ("strip_stress_peak_Pa", "path_singularity_margin")
    # the objective's metric stays one value (its extreme) even when also constrained
    assert sampled_constraints(["strip_stress_peak_Pa"], sides(stress)) == ()


def test_reduce_takes_each_blocks_extreme_and_its_row():
    from ppr_jax._studies._design._problem import Problem

    prob = Problem(names=["t"], lo=np.zeros(1), hi=np.ones(1),
                   metrics=("base_frequency_hz", "strip_stress_peak_Pa",
                            "path_singularity_margin"),
                   base=None, stroke=0.0, ctx=None, mode="fwd", equal_links=True,
                   samples=("strip_stress_peak_Pa", "path_singularity_margin"))
    prob._sizes = np.array([1, 3, 2])
    R = np.array([5.0, 1.0, 7.0, 2.0, 0.4, 0.3])
    J = np.arange(6.0)[:, None]
    v, Jk = prob.reduce(R, J)
    np.testing.assert_array_equal(v, [5.0, 7.0, 0.3])  # max of the stresses, min of the margins
    np.testing.assert_array_equal(Jk[:, 0], [0.0, 2.0, 5.0])  # the extreme sample's rows
    V = prob.reduce(np.stack([R, R[::-1], np.where(np.arange(6) == 2, np.nan, R)]))
    np.testing.assert_array_equal(V[1], [0.3, 7.0, 1.0])
    assert np.isnan(V[2, 1]) and V[2, 2] == 0.3  # a NaN sample makes its metric NaN


@pytest.mark.slow
def test_tied_stress_peaks_at_the_optimum_are_a_kkt_point():
    """The paper's robot on its circle in 2 s (benchmark tier 3 on a coarser path): the first
    locked frequency maximised under the strips' peak stress. The peak is a max over times and
    springs; several samples reach the bound together at the optimum (the three chains alike),
    where the max has a kink. Given as one constraint per sample, the optimum is a KKT point
    (the multipliers of the tied samples add up), the gradient check passes per sample, and the
    sum of their multipliers is the optimum's own derivative in the allowable (a second design
    at a relaxed bound)."""
    import jax.numpy as jnp

    from ppr_jax._trajectory import Circle

    opts = pj.SceneOptions(t_end=2.0, n_out=31, trajectory=Circle(omega=jnp.asarray(math.pi)))
    bounds = {"t": (2e-4, 8e-4), "w": (0.010, 0.030), "r": (0.010, 0.040),
              "theta_c": (1.2, 2.4), "l1": (0.30, 0.45), "l3": (0.30, 0.45)}

    def run(sigma_a):
        return pj.design(bounds, "base_frequency_hz",
                         [pj.Constraint("strip_stress_peak_Pa", upper=sigma_a),
                          pj.Constraint("torque_peak_Nm", upper=5.0)],
                         scene="servo-circle", model="reduced", options=opts, starts=2,
                         candidates=16, grid=256, l3_elements=None)

    d = run(250e6)
    v = d.verification
    assert d.info["mode"] == "fwd" and "strip_stress_peak_Pa" in d.info["sampled_constraints"]
    (s,) = [c for c in d.constraints if c["metric"] == "strip_stress_peak_Pa"]
    assert s["active"] and s["value"] == pytest.approx(250e6, rel=1e-8)
    assert v["kkt_residual"] <= 1e-5 and v["gradient_check"]["ok"] and v["grid"]["ok"]
    assert all(st["jacobians"] <= 50 for st in d.starts)
    relaxed = run(251e6)
    df = relaxed.objective["value"] - d.objective["value"]
    assert df == pytest.approx(s["multiplier"] * 1e6, rel=2e-2)


def test_docs_tier3_block_is_generated_from_the_benchmark_json():
    """docs/design.md's tier-3 measurements are `benchmarks/design.py`'s `tier3_markdown` of
    benchmarks/results/design_tier3.json, never typed by hand."""
    import importlib.util
    import json
    import pathlib

    root = pathlib.Path(__file__).resolve().parents[1]
    spec = importlib.util.spec_from_file_location("design_bench", root / "benchmarks" / "design.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    data = json.loads((root / "benchmarks" / "results" / "design_tier3.json").read_text())
    page = (root / "docs" / "design.md").read_text()
    block = page.split("<!-- design-tier3 -->\n", 1)[1].split("<!-- /design-tier3 -->", 1)[0]
    assert block.strip() == bench.tier3_markdown(data).strip()


# --- a band to avoid: metric <= lo or metric >= hi -------------------------------------------
#
# Tier 1 with its frequency kept out of a band around the closed-form optimum f*: the stress
# bound caps f at f*, so no design lies above a band (0.9 f*, 1.1 f*) and the optimum is its
# lower edge, f = 0.9 f* (d f*/d lo = 1); a band (0.5 f*, 0.8 f*) below f* leaves f* feasible
# above it. The least moving mass over (t, t_r) with the pivot frequency outside (lo, hi) has
# an optimum on each side: above, f = hi with t_r on its lower bound and
# t^3 = 12 L J (2 pi hi)^2/(E w) (d m*/d hi = 2 rho_m w L t*/hi, as for a lower bound f >= hi);
# below, t on its lower bound and the link thickened until f = lo, J ~ t_r, so
# t_r = t_r,min (f(t_min, t_r,min)/lo)^2, which costs far more mass.

# tier 1's specification (SPEC) with a band on its frequency, its edges LO and HI
BAND_SPEC = SPEC.replace("[settings]", """[[constraints]]
metric = "pivot_frequency_hz"
avoid = [LO, HI]

[settings]""")


def test_band_above_the_reach_lands_on_its_lower_edge(tmp_path, capsys):
    """`ppr-jax design --spec` with a band around f*: design.json holds the lower edge, its
    multipliers (1 on lo: the closed form; 0 on hi), the verification; the report names the
    band and both edges; d f*/d lo against the optimum of a second design with lo moved."""
    *_, f = tier1_closed_form()
    lo, hi = 0.9 * f, 1.1 * f
    data, out = design_cli(tmp_path, BAND_SPEC.replace("LO", repr(lo)).replace("HI", repr(hi)))
    assert data["objective"]["value"] == pytest.approx(lo, rel=1e-6)
    band = [c for c in data["constraints"] if c["side"] == "avoid"]
    assert len(band) == 1 and len(data["constraints"]) == 2
    (b,) = band
    assert b["bound"] == [lo, hi] and b["edge"] == "lower" and b["active"]
    assert b["value"] == pytest.approx(lo, rel=1e-8) and b["violation"] <= 1e-8
    assert b["multipliers"]["lower"] == pytest.approx(1.0, rel=1e-6)
    assert b["multipliers"]["upper"] == pytest.approx(0.0, abs=1e-9)
    assert b["multiplier"] == b["multipliers"]["lower"]
    v = data["verification"]
    assert v["ok"] and v["kkt_residual"] < 1e-8
    assert v["grid"]["best_objective"] <= lo * (1 + 1e-8)
    stdout = capsys.readouterr().out
    assert f"pivot_frequency_hz outside ({lo:g}, {hi:g})" in stdout and "lower side" in stdout
    page = (out / "report.html").read_text()
    assert "pivot_frequency_hz outside" in page
    assert "band lower edge" in page and "band upper edge" in page
    # the edge moved: the optimum follows it at the rate the multiplier says
    dlo = 1e-2 * lo  # f* = lo: no truncation error; the optimum is on the edge to ~1e-9
    moved = pj.design(BOUNDS, "pivot_frequency_hz",
                      [pj.Constraint("pivot_stress_Pa", upper=SIGMA_A),
                       {"metric": "pivot_frequency_hz", "avoid": (lo + dlo, hi)}],
                      stroke=STROKE, grid=1000, l3_elements=None)
    fd = (moved.objective["value"] - data["objective"]["value"]) / dlo
    assert fd == pytest.approx(b["multipliers"]["lower"], rel=1e-5)


def test_band_below_the_optimum_leaves_it_and_the_starts_cover_both_sides():
    """A band below f*: the optimum is tier 1's (the band inactive, both its multipliers 0,
    the stress's 1.5 f*/sigma_a), and a start below the band stopped on its lower edge: the
    screening gave each side a start."""
    t, r, w, f = tier1_closed_form()
    lo, hi = 0.5 * f, 0.8 * f
    d = pj.design(BOUNDS, "pivot_frequency_hz",
                  [pj.Constraint("pivot_stress_Pa", upper=SIGMA_A),
                   pj.Constraint("pivot_frequency_hz", avoid=(lo, hi))],
                  stroke=STROKE, grid=1000, l3_elements=None)
    assert d.objective["value"] == pytest.approx(f, rel=1e-6)
    assert d.x["t"] == pytest.approx(t, rel=1e-6)
    s, b = d.constraints
    assert s["active"] and s["multiplier"] == pytest.approx(1.5 * f / SIGMA_A, rel=1e-6)
    assert not b["active"] and b["edge"] == "upper"
    assert b["multipliers"] == {"lower": 0.0, "upper": 0.0}
    assert d.verification["ok"]
    below = [st for st in d.starts
             if pivot_frequency(st["start"]["t"], st["start"]["r"], st["start"]["w"])
             < (lo + hi) / 2]
    assert below and any(st["feasible"] and st["objective"] == pytest.approx(lo, rel=1e-6)
                         for st in below)


def test_band_least_mass_on_its_upper_edge_and_the_lower_sides_local_optimum():
    """The least moving mass with the pivot frequency outside (lo, hi): the optimum on the upper
    edge, its multiplier d m*/d hi the closed form's and a finite difference of the optimum; the
    start the screening gave the lower side ends at that side's own (heavier) optimum."""
    f_lo, f_hi, w, r, t_r = 0.1, 2.0, 0.026, 0.020, 0.005
    L = r * THETA_C
    t_min = 1e-4
    assert f_lo < pivot_frequency(t_min, r, w, t_r) < f_hi  # the lightest corner is in the band

    def run(hi):
        return pj.design({"t": (t_min, 1e-3), "t_r": (t_r, 0.02)},
                         pj.Objective("moving_mass_kg", "min"),
                         [pj.Constraint("pivot_frequency_hz", avoid=(f_lo, hi))], grid=400,
                         l3_elements=None)

    d = run(f_hi)
    t = (12 * L * link_inertia(t_r) * (2 * math.pi * f_hi) ** 2 / (E * w)) ** (1 / 3)
    assert d.x["t"] == pytest.approx(t, rel=1e-6)
    assert d.x["t_r"] == pytest.approx(t_r, rel=1e-9)
    (c,) = d.constraints
    assert c["edge"] == "upper" and c["active"]
    assert c["multipliers"]["upper"] == pytest.approx(2 * RHO_M * w * L * t / f_hi, rel=1e-5)
    assert abs(c["multipliers"]["lower"]) <= 1e-9 * c["multipliers"]["upper"]
    assert d.verification["ok"]
    # the lower side's own optimum, from the start the screening gave it: heavier
    t_r_lo = t_r * (pivot_frequency(t_min, r, w, t_r) / f_lo) ** 2
    lower = [st for st in d.starts if st["feasible"]
             and st["optimum"]["t_r"] == pytest.approx(t_r_lo, rel=1e-6)]
    assert lower and lower[0]["optimum"]["t"] == pytest.approx(t_min, rel=1e-9)
    assert lower[0]["objective"] > d.objective["value"]
    # d m*/d hi against the optimum of a second design with the edge moved
    dhi = 1e-4 * f_hi
    fd = (run(f_hi + dhi).objective["value"] - d.objective["value"]) / dhi
    assert fd == pytest.approx(c["multipliers"]["upper"], rel=1e-4)


def test_band_g_and_its_derivatives():
    from ppr_jax._studies._design._goals import band_g

    lo, hi = 2.0, 5.0
    m = np.array([0.5, 2.0, 3.0, 3.5, 5.0, 7.0])
    g, dm, dlo, dhi = band_g(m, lo, hi)
    np.testing.assert_allclose(g, (m - lo) * (m - hi) / 9.0)
    assert g[1] == g[4] == 0.0 and g[3] == -0.25 and np.all(g[[0, 5]] > 0)
    h = 1e-6
    for d, fd in ((dm, (band_g(m + h, lo, hi)[0] - band_g(m - h, lo, hi)[0]) / (2 * h)),
                  (dlo, (band_g(m, lo + h, hi)[0] - band_g(m, lo - h, hi)[0]) / (2 * h)),
                  (dhi, (band_g(m, lo, hi + h)[0] - band_g(m, lo, hi - h)[0]) / (2 * h))):
        np.testing.assert_allclose(d, fd, rtol=1e-7, atol=1e-9)
    # on the edges: the distance from the edge over the width
    assert dm[1] == pytest.approx(-1 / 3) and dlo[1] == pytest.approx(1 / 3) and dhi[1] == 0
    assert dm[4] == pytest.approx(1 / 3) and dhi[4] == pytest.approx(-1 / 3) and dlo[4] == 0


def test_band_in_the_spec_and_as_a_dict(tmp_path):
    from ppr_jax._studies import load_design_spec
    from ppr_jax._studies._design._constraints import sampled_constraints
    from ppr_jax._studies._design._goals import as_constraints

    (c,) = as_constraints([{"metric": "pivot_frequency_hz", "avoid": [4, 6.5]}])
    assert c == pj.Constraint("pivot_frequency_hz", avoid=(4.0, 6.5))
    assert c.avoid == (4.0, 6.5) and c.sides() == [("avoid", (4.0, 6.5))]
    spec = tmp_path / "spec.toml"
    spec.write_text(BAND_SPEC.replace("LO", "4.0").replace("HI", "6.5"))
    got = load_design_spec(str(spec))
    assert got["constraints"][1] == {"metric": "pivot_frequency_hz", "avoid": [4.0, 6.5]}
    assert as_constraints(got["constraints"])[1] == c
    # a band on a peak over samples stays on the peak (one value), not on every sample
    band = pj.Constraint("strip_stress_peak_Pa", avoid=(1e8, 2e8))
    assert sampled_constraints(["base_frequency_hz", "strip_stress_peak_Pa"],
                               [(1, band, *band.sides()[0])]) == ()


@pytest.mark.parametrize("fields, words", [
    ({"avoid": (6.0, 4.0)}, ["'pivot_frequency_hz'", "lo < hi", "lo = 6 >= hi = 4"]),
    ({"avoid": (4.0, 4.0)}, ["'pivot_frequency_hz'", "lo = 4 >= hi = 4"]),
    ({"avoid": (4.0, float("inf"))}, ["'pivot_frequency_hz'", "two finite numbers"]),
    ({"avoid": (4.0,)}, ["'pivot_frequency_hz'", "(lo, hi)"]),
    ({"avoid": "4-6"}, ["'pivot_frequency_hz'", "(lo, hi)"]),
    ({"avoid": (4.0, "6")}, ["'pivot_frequency_hz'", "(lo, hi)"]),
    ({"avoid": (4.0, 6.0), "lower": 1.0}, ["'pivot_frequency_hz'", "second constraint"]),
])
def test_bad_bands_are_refused(fields, words, tmp_path):
    from ppr_jax._studies import load_design_spec

    with pytest.raises(pj.DesignError) as info:
        pj.Constraint("pivot_frequency_hz", **fields)
    for w in words:
        assert w in str(info.value)
    # in a specification: the file and the same words
    text = BAND_SPEC.replace("avoid = [LO, HI]", "\n".join(
        f"{k} = {list(v) if isinstance(v, tuple) else v!r}".replace("'", '"')
        for k, v in fields.items()))
    spec = tmp_path / "spec.toml"
    spec.write_text(text)
    with pytest.raises(pj.DesignError) as info:
        load_design_spec(str(spec))
    assert str(spec) in str(info.value) and words[0] in str(info.value)


def test_band_no_design_can_leave_is_infeasible_naming_it():
    """A band over every frequency the box reaches under the stress bound: the error names the
    band and the distance to its nearer edge at the best point found."""
    *_, f = tier1_closed_form()
    with pytest.raises(pj.DesignError) as info:
        pj.design(BOUNDS, "pivot_frequency_hz",
                  [pj.Constraint("pivot_stress_Pa", upper=SIGMA_A),
                   pj.Constraint("pivot_frequency_hz", avoid=(0.0, 2 * f))],
                  stroke=STROKE, grid=64)
    msg = str(info.value)
    assert f"pivot_frequency_hz outside (0, {2 * f:g})" in msg and "cannot be met" in msg
    b = info.value.result.constraints[1]
    assert b["violation_abs"] == pytest.approx(min(b["value"], 2 * f - b["value"]), rel=1e-12)


def test_band_over_every_reachable_value_is_infeasible_on_the_command_line(tmp_path, capsys):
    """A band (0, 1e12) covers every frequency the box reaches: the least one, at the box's
    corner (t, w lowest, r highest), is inside it, and the band's smooth constraint g is -4e-14
    there, inside the optimiser's own tolerance. Feasibility is judged on the metric against
    the band's edges: `ppr-jax design` exits 2 with one line naming the band and the value,
    and writes design.json, report.html and designed.toml marked INFEASIBLE (no MJCF)."""
    import json

    from ppr_jax._cli import main
    from ppr_jax._studies._design._goals import band_g
    from ppr_jax._studies._design._optimise import FEAS_TOL

    f_least = pivot_frequency(BOUNDS["t"][0], BOUNDS["r"][1], BOUNDS["w"][0])
    g = band_g(f_least, 0.0, 1e12)[0]
    assert -FEAS_TOL < g < 0  # the smooth form calls it met; the edges do not
    spec = tmp_path / "spec.toml"
    spec.write_text(BAND_SPEC.replace("LO", "0.0").replace("HI", "1e12"))
    out = tmp_path / "out"
    assert main(["design", "--spec", str(spec), "--out", str(out)]) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("ppr-jax:")]
    assert len(err) == 1 and err[0].startswith("ppr-jax: error: "), err
    assert "cannot be met: constraint pivot_frequency_hz outside (0, 1e+12)" in err[0]
    assert f"pivot_frequency_hz = {f_least:.6g} lies inside the band" in err[0]
    assert "marked INFEASIBLE" in err[0]
    data = json.loads((out / "design.json").read_text())
    assert data["feasible"] is False and "lies inside the band" in data["infeasibility"]
    (b,) = [c for c in data["constraints"] if c["side"] == "avoid"]
    assert b["value"] == pytest.approx(f_least, rel=1e-9) and b["violation"] > FEAS_TOL
    assert data["x"]["t"] == pytest.approx(BOUNDS["t"][0], rel=1e-9)
    assert data["x"]["r"] == pytest.approx(BOUNDS["r"][1], rel=1e-9)
    robot = (out / "designed.toml").read_text().splitlines()
    assert robot[1].startswith("# WARNING: INFEASIBLE design") and "(0, 1e+12)" in robot[1]
    assert "INFEASIBLE" in (out / "report.html").read_text()
    assert not (out / "designed.xml").exists()


@pytest.mark.slow
def test_design_on_a_path_from_a_file_equals_the_design_on_its_formula(tmp_path):
    """Design off the paper's circles: the strips' t and w for the highest locked frequency
    under a stress bound along a two-harmonic Fourier path, driven by L1's inverse-kinematics
    angles of the formula, and again along the same path sampled at 100 Hz, written as a CSV
    file, read back with `load_path` (a natural spline) and torque-driven through the knot
    table. Both optima are verified (KKT, gradient, grid), the stress bound binds in both, and
    the two agree to 1e-6 relative: the spline is a second formulation of the path (its error
    at 100 Hz is far below that), and the drive differs."""
    import jax
    import jax.numpy as jnp

    fourier = pj.Fourier([0.45, 0.26, 0.0], [[0.06, 0.0, 0.03], [0.015, 0.01, 0.0]],
                         [[0.0, 0.05, 0.0], [0.0, 0.015, 0.01]], 1.0)
    ts = np.arange(0.0, 1.0 + 1e-9, 0.01)
    X = np.asarray(jax.vmap(fourier)(jnp.asarray(ts)))
    path = tmp_path / "fourier.csv"
    np.savetxt(path, np.column_stack([ts, X]), delimiter=",", header="time,x,y,phi",
               comments="", fmt="%.17g")
    scenes = (pj.PathScene(fourier, drive="motion", name="fourier"),
              pj.PathScene(pj.load_path(str(path), bc="natural"), drive="torque", name="file"))
    designs = [pj.design({"t": (2e-4, 8e-4), "w": (0.010, 0.030)}, "base_frequency_hz",
                         [pj.Constraint("strip_stress_peak_Pa", upper=250e6)], scene=s,
                         model="reduced", options=pj.SceneOptions(t_end=1.0, n_out=21),
                         starts=1, candidates=8, grid=64, l3_elements=None)
               for s in scenes]
    for d in designs:
        assert d.verification["ok"], d.summary()
        (stress,) = [c for c in d.constraints if c["metric"] == "strip_stress_peak_Pa"]
        assert stress["active"], d.summary()
        assert d.objective["value"] > 1.5 * d.objective["start_value"], d.summary()
    a, b = designs
    np.testing.assert_allclose(b.objective["value"], a.objective["value"], rtol=1e-6)
    for n in ("t", "w"):
        np.testing.assert_allclose(b.x[n], a.x[n], rtol=1e-6, err_msg=n)


def _circle_csv(path, t_end=7.54, n=378):
    """The servo-circle's nominal circle sampled as a path file (m, rad)."""
    from ppr_jax._trajectory import Circle

    ts = np.linspace(0.0, t_end, n)
    X = np.array([np.asarray(Circle()(t)) for t in ts])
    rows = ["time[s],x[m],y[m],phi[rad]"] + [",".join(repr(float(v)) for v in (t, *x))
                                              for t, x in zip(ts, X)]
    path.write_text("\n".join(rows) + "\n")
    return ts, X


SING_SPEC = (DATA / "design_path_singularity.toml").read_text()


def test_cli_design_on_a_path_file_refuses_before_compiling(tmp_path, capsys):
    """`ppr-jax design --path`: a specification that names a scene as well, and a command log
    shorter than the path, are one line and exit 2, before anything compiles."""
    from ppr_jax._cli import main

    _circle_csv(tmp_path / "circle.csv", t_end=1.0, n=51)
    spec = tmp_path / "spec.toml"
    spec.write_text(SING_SPEC.replace("grid = 200", 'grid = 200\nscene = "servo-circle"'))
    argv = ["design", "--spec", str(spec), "--path", str(tmp_path / "circle.csv"), "--out",
            str(tmp_path / "o")]
    assert main(argv) == 2
    assert "name two scenes" in capsys.readouterr().err
    spec.write_text(SING_SPEC)
    ts = np.linspace(0.0, 0.5, 26)
    th = np.tile([1.3, 3.5, -0.45], (26, 1))
    (tmp_path / "half.csv").write_text(
        "time[s],th_1[rad],th_2[rad],th_3[rad]\n"
        + "".join(",".join(repr(float(v)) for v in (t, *r)) + "\n" for t, r in zip(ts, th)))
    assert main(argv + ["--angles", str(tmp_path / "half.csv")]) == 2
    assert "spans t = 0 to 0.5 s" in capsys.readouterr().err


REACH_SPEC = (DATA / "design_path_reach.toml").read_text()


@pytest.mark.slow
def test_cli_design_on_a_path_file(tmp_path):
    """`ppr-jax design --path circle.csv`: the lightest drive links that keep servo-circle's
    circle, read from a file, within reach by a margin; the same design on the registered
    scene (its exact circle) finds the same links."""
    import json

    from ppr_jax._cli import main

    _circle_csv(tmp_path / "circle.csv")
    spec = tmp_path / "spec.toml"
    spec.write_text(REACH_SPEC)
    out = tmp_path / "out"
    assert main(["design", "--spec", str(spec), "--path", str(tmp_path / "circle.csv"),
                 "--out", str(out)]) == 0
    data = json.loads((out / "design.json").read_text())
    ref = pj.design({"l1": (0.15, 0.3)}, {"minimize": "moving_mass_kg"},
                    [pj.Constraint("path_reach_margin", lower=0.05)], scene="servo-circle",
                    options=pj.SceneOptions(t_end=7.54), grid=100)
    assert 0.15 < ref.x["l1"] < 0.3
    assert data["x"]["l1"] == pytest.approx(ref.x["l1"], rel=1e-4)
