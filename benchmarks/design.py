"""Design with gradients (issue 40), tier 1: the closed form.

One strip pivot carrying a link (the catalogue's `pivot_*` metrics, `ppr_jax._studies._design.
_catalogue`): maximise its first natural frequency f = sqrt(K/J)/(2 pi), K = E w t^3/(12 L),
L = r theta_c, J the connecting link's inertia about the joint, over the strip's (t, r, w),
subject to its bending stress sigma = E t stroke/(2 L) <= sigma_a at a given stroke. Closed form
(derived in tests/test_design.py): the stress bound is active, t* = 2 sigma_a L/(E stroke), and
r, w on their upper bounds; f* grows as sigma_a^1.5, L and w^0.5, so the multipliers are
d f*/d sigma_a = 1.5 f*/sigma_a, d f*/d r_hi = f*/r_hi, d f*/d w_hi = f*/(2 w_hi). Assumed:
the strip massless, pure-moment bending, the drive link held, the link rigid, small strains.

For each optimiser (SLSQP, trust-constr): the relative error of the optimum's objective and
thickness against the closed form (goal: 1e-6), of the multipliers, the verification (KKT
residual, gradient against finite differences, the 21^3 grid's gap), iterations and
evaluations per start, and the time of a whole `design` call: the first in the process (it
compiles the problem's three programs) and the fastest of `--repeats` after it (every result
is a NumPy array: the device work has finished when `design` returns).
`--robot` adds a robot-level design on a scene (no closed form; verified by its own finite
differences and grid): the first locked frequency (L2) maximised over t in [0.2, 0.6] mm
subject to the strips' peak PRB stress over the first 0.5 s of servo-circle (51 output times)
<= 250 MPa, 2 starts from 8 candidates, a 64-point grid; its cold call (compilation of the
scene's forward-mode Jacobian and batch) and one warm call.

Tier 2, a closed-form elastica optimum: one strip of the robot (length L = r theta_c, rest
curvature 1/r) clamped at one end and loaded by an end moment M = 0.05 N m, by the library's
elastica (`ppr_jax.elastica`, the catalogue's `strip_tip_rotation_rad`,
`strip_elastica_stress_Pa`): minimise its peak bending stress subject to a tip rotation of at
least theta* = 1 rad (a large deflection) over (t, r, w) in [0.1, 1] mm x [10, 40] mm x
[5, 30] mm. Under a pure end moment the curvature changes uniformly by M/EI whatever the rest
curvature, so the tip turns by exactly M L/(E I), I = w t^3/12 (the strip bends into another
circular arc), and the stress is 6 M/(w t^2) everywhere. The rotation bound is active:
w t^3 = 12 M L/(E theta*); the stress 6 M t/(w t^3) then falls with t, so w sits on its upper
bound, t* = (12 M L/(E theta* w_hi))^(1/3), and it falls as L^(-2/3), so r sits on its upper
bound: sigma* = 6 M/(w_hi t*^2), with multipliers d sigma*/d theta* = (2/3) sigma*/theta*,
d sigma*/d w_hi = -sigma*/(3 w_hi), d sigma*/d r_hi = -(2/3) sigma*/r_hi. No PRB model: the
elastica is exact to its RK4 grid (about 1e-13 at this curvature).
Writes benchmarks/results/design.json.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import time
from pathlib import Path

import jax
import numpy as np

import ppr_jax as pj

OUT = Path(__file__).resolve().parent / "results" / "design.json"

E, RHO_M, L3, B_R, T_R, THETA_C = 71.0e9, 2780.0, 0.366, 0.023, 0.010, 1.88
SIGMA_A, STROKE = 100e6, 0.3
BOUNDS = {"t": (1e-4, 1e-3), "r": (0.01, 0.04), "w": (0.01, 0.03)}


def closed_form() -> dict:
    r, w = BOUNDS["r"][1], BOUNDS["w"][1]
    L = r * THETA_C
    t = 2 * SIGMA_A * L / (E * STROKE)
    m3 = RHO_M * L3 * B_R * T_R
    J = m3 * (L3**2 / 3 + B_R**2 / 12)
    f = math.sqrt(E * w * t**3 / (12 * L) / J) / (2 * math.pi)
    return {"t": t, "r": r, "w": w, "f": f, "d_f_d_sigma_a": 1.5 * f / SIGMA_A,
            "d_f_d_r_hi": f / r, "d_f_d_w_hi": f / (2 * w)}


def run(optimizer: str):
    return pj.design(BOUNDS, "pivot_frequency_hz",
                     [pj.Constraint("pivot_stress_Pa", upper=SIGMA_A)], stroke=STROKE,
                     optimizer=optimizer)


def tier1(optimizer: str, repeats: int) -> dict:
    cf = closed_form()
    t0 = time.perf_counter()
    d = run(optimizer)
    first = time.perf_counter() - t0
    warm = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        d = run(optimizer)
        warm.append(time.perf_counter() - t0)
    bounds = {(b["variable"], b["side"]): b["multiplier"] for b in d.active_bounds}
    (c,) = d.constraints
    rel = lambda a, b: abs(a / b - 1)  # noqa: E731
    f_err = rel(d.objective["value"], cf["f"])
    v = d.verification
    return {
        "optimizer": optimizer, "closed_form": cf, "optimum": d.x,
        "objective": d.objective["value"],
        "objective_rel_error": f_err, "t_rel_error": rel(d.x["t"], cf["t"]),
        "stress_active": c["active"], "stress_at_optimum_Pa": c["value"],
        "multiplier_rel_error": {
            "sigma_a": rel(c["multiplier"], cf["d_f_d_sigma_a"]) if c["active"] else None,
            "r_hi": rel(bounds["r", "upper"], cf["d_f_d_r_hi"]) if ("r", "upper") in bounds
            else None,
            "w_hi": rel(bounds["w", "upper"], cf["d_f_d_w_hi"]) if ("w", "upper") in bounds
            else None},
        "kkt_residual": v["kkt_residual"], "gradient_fd_rel_error": v["gradient_check"]["worst"],
        "grid": {k: v["grid"][k] for k in ("kind", "points", "best_objective", "gap", "ok")},
        "verification_ok": v["ok"],
        "meets_1e-6": bool(f_err <= 1e-6),
        "starts": [{"iterations": s["iterations"], "evaluations": s["evaluations"],
                    "message": s["message"]} for s in d.starts],
        "evaluations_total": d.info["evaluations"], "jacobians_total": d.info["jacobians"],
        "first_call_s": first, "warm_call_s": min(warm) if warm else None,
        "warm_timing": d.timing,
    }


T2_M, T2_THETA = 0.05, 1.0
T2_BOUNDS = {"t": (1e-4, 1e-3), "r": (0.01, 0.04), "w": (0.005, 0.03)}


def tier2_closed_form() -> dict:
    r, w = T2_BOUNDS["r"][1], T2_BOUNDS["w"][1]
    L = r * THETA_C
    t = (12 * T2_M * L / (E * T2_THETA * w)) ** (1 / 3)
    s = 6 * T2_M / (w * t**2)
    return {"t": t, "r": r, "w": w, "sigma": s, "d_sigma_d_theta": 2 / 3 * s / T2_THETA,
            "d_sigma_d_w_hi": -s / (3 * w), "d_sigma_d_r_hi": -2 / 3 * s / r}


def tier2(repeats: int) -> dict:
    def run():
        return pj.design(T2_BOUNDS, {"minimize": "strip_elastica_stress_Pa"},
                         [pj.Constraint("strip_tip_rotation_rad", lower=T2_THETA)],
                         strip_load=(0.0, 0.0, T2_M), grid=1000)

    cf = tier2_closed_form()
    t0 = time.perf_counter()
    d = run()
    first = time.perf_counter() - t0
    warm = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        d = run()
        warm.append(time.perf_counter() - t0)
    rel = lambda a, b: abs(a / b - 1)  # noqa: E731
    bounds = {(b["variable"], b["side"]): b["multiplier"] for b in d.active_bounds}
    (c,) = d.constraints
    v = d.verification
    err = rel(d.objective["value"], cf["sigma"])
    return {"closed_form": cf, "optimum": d.x, "objective_Pa": d.objective["value"],
            "objective_rel_error": err, "t_rel_error": rel(d.x["t"], cf["t"]),
            "rotation_at_optimum_rad": c["value"], "rotation_active": c["active"],
            "multiplier_rel_error": {
                "theta": rel(c["multiplier"], cf["d_sigma_d_theta"]),
                "w_hi": rel(bounds.get(("w", "upper"), 0.0), cf["d_sigma_d_w_hi"]),
                "r_hi": rel(bounds.get(("r", "upper"), 0.0), cf["d_sigma_d_r_hi"])},
            "kkt_residual": v["kkt_residual"],
            "gradient_fd_rel_error": v["gradient_check"]["worst"],
            "grid": {k: v["grid"][k] for k in ("kind", "points", "best_objective", "gap", "ok")},
            "verification_ok": v["ok"], "meets_1e-6": bool(err <= 1e-6),
            "starts": [{"iterations": s["iterations"], "evaluations": s["evaluations"]}
                       for s in d.starts],
            "first_call_s": first, "warm_call_s": min(warm) if warm else None,
            "warm_timing": d.timing}


T3_PERIOD = 2.0  # s: one turn of the paper's circle, against its 7.54 s
T3_BOUNDS = {"t": (2e-4, 8e-4), "w": (0.010, 0.030), "r": (0.010, 0.040),
             "theta_c": (1.2, 2.4), "l1": (0.30, 0.45), "l3": (0.30, 0.45)}
T3_STRESS, T3_TORQUE, T3_SINGULAR = 250e6, 5.0, 0.1
T3_MAX_ITER = 100
#: the goal: evaluations (values and Jacobian) per start
T3_MAX_JACOBIANS = 50


def tier3() -> dict:
    """The paper's robot, six variables (the strips' t, w, r, theta_c; both link lengths): its
    first locked frequency (L2, home) maximised subject to, over one turn of the paper's circle
    in 2 s (servo-circle's angles, L1: forward kinematics and inverse dynamics), the strips'
    peak PRB stress <= 250 MPa, the actuators' peak torque <= 5 N m, a singularity margin
    >= 0.1 and the path in reach; verified on 10,000 Sobol designs in one batched call and
    re-scored with L3. No closed form: the grid and the finite differences are the check.
    The stress and torque peaks and the path margins reach the optimiser as one constraint per
    output time and spring, actuator or chain (`sampled_metrics`). Passed: feasible, verified
    (KKT residual, finite differences, the Sobol sample within 1 %) with at most
    `T3_MAX_JACOBIANS` evaluations per start; the L3 re-score is reported, not required."""
    import jax.numpy as jnp

    from ppr_jax._trajectory import Circle

    opts = pj.SceneOptions(t_end=T3_PERIOD, n_out=101,
                           trajectory=Circle(omega=jnp.asarray(2 * math.pi / T3_PERIOD)))

    def run():
        return pj.design(T3_BOUNDS, "base_frequency_hz",
                         [pj.Constraint("strip_stress_peak_Pa", upper=T3_STRESS),
                          pj.Constraint("torque_peak_Nm", upper=T3_TORQUE),
                          pj.Constraint("path_singularity_margin", lower=T3_SINGULAR)],
                         scene="servo-circle", model="reduced", options=opts, starts=4,
                         candidates=64, max_iter=T3_MAX_ITER, grid=10_000)

    def timed():
        t0 = time.perf_counter()
        try:
            d, error = run(), None
        except pj.DesignError as err:  # an infeasible end is a result too: record it
            d, error = err.result, str(err)
        return d, error, time.perf_counter() - t0

    d, error, first = timed()
    if error is None:
        d, error, warm = timed()
    else:
        warm = None
    v = d.verification
    return {"variables": T3_BOUNDS, "period_s": T3_PERIOD, "max_iter": T3_MAX_ITER,
            "error": error, "optimum": d.x, "start": d.x_start,
            "objective_hz": d.objective["value"], "start_objective_hz": d.objective["start_value"],
            "constraints": d.constraints, "active_bounds": d.active_bounds,
            "kkt_residual": v.get("kkt_residual"),
            "gradient_fd_rel_error": v.get("gradient_check", {}).get("worst"),
            "grid": {k: v["grid"][k] for k in ("kind", "points", "best_objective", "gap", "ok",
                                              "seconds") if k in v["grid"]} if "grid" in v
            else None,
            "l3": v.get("l3"), "verification_ok": v["ok"], "mode": d.info["mode"],
            "starts": [{"iterations": s["iterations"], "evaluations": s["evaluations"],
                        "jacobians": s["jacobians"],
                        "objective": s["objective"], "feasible": s["feasible"],
                        "max_violation": s["max_violation"], "message": s["message"],
                        "optimum": s["optimum"]} for s in d.starts],
            "jacobians_per_start_max": max(s["jacobians"] for s in d.starts),
            "constraint_rows": d.info.get("constraint_rows"),
            "passed": bool(error is None and v["ok"] and max(s["jacobians"] for s in d.starts)
                           <= T3_MAX_JACOBIANS),
            "first_call_s": first, "warm_call_s": warm, "timing": d.timing}


def tier3_markdown(data: dict) -> str:
    """The measured part of docs/design.md's tier-3 section, from design_tier3.json (`data`):
    the page holds exactly this text between `<!-- design-tier3 -->` and
    `<!-- /design-tier3 -->` (tests/test_design.py checks it)."""
    t, m = data["tier3"], data["machine"]
    x = t["optimum"]
    load = sorted({round(v) for v in (m["load_average_at_start"] + m.get("load_average_at_end",
                                                                          []))})
    units = {"Pa": "Hz/Pa", "Nm": "Hz/(N m)"}
    cons = []
    for c in t["constraints"]:
        rel = "<=" if c["side"] == "upper" else ">="
        if c["active"]:
            cons.append(f"`{c['metric']}` {rel} {c['bound']:g} binds on "
                        f"{c.get('active_samples', 1)} samples (multiplier "
                        f"{c['multiplier']:.3g} "
                        f"{units.get(c['metric'].rsplit('_', 1)[-1], 'Hz')})")
        else:
            cons.append(f"`{c['metric']}` = {c['value']:.3g} (slack)")
    bounds = ", ".join(f"{b['variable']} on its {b['side']} bound ({b['multiplier']:.3g} Hz/"
                       f"{pj.PARAM_RANGES[b['variable']][2]})" for b in t["active_bounds"])
    g, tm = t["grid"], t["timing"]
    jac = [s["jacobians"] for s in t["starts"]]
    l3 = t.get("l3") or {}
    lines = [
        f"Measured on {m['cpus']} CPU cores shared with other work (load average "
        f"{load[0]}-{load[-1]}), {'passed' if t.get('passed') else 'NOT passed'}:",
        "",
        f"- optimum {t['objective_hz']:.4g} Hz (the best screened start "
        f"{t['start_objective_hz']:.4g} Hz): t = {x['t'] * 1e3:.3g} mm, w = {x['w'] * 1e3:.3g} "
        f"mm, r = {x['r'] * 1e3:.3g} mm, theta_c = {x['theta_c']:.3g} rad, "
        f"l1 = {x['l1']:.3g} m, l3 = {x['l3']:.3g} m; {bounds}.",
        "- constraints: " + "; ".join(cons) + f" ({t.get('constraint_rows')} constraint rows "
        f"for the optimiser in all).",
        f"- verification: KKT residual {t['kkt_residual']:.1e}, the JAX gradient against finite "
        f"differences {t['gradient_fd_rel_error']:.1e} (relative, per sample), the "
        f"{g['points']:,} Sobol designs' best feasible {g['best_objective']:.4g} Hz "
        f"({-g['gap']:.0%} below the optimum) in one batched call of {g['seconds']:.0f} s.",
        f"- {len(jac)} starts, {min(jac)}-{max(jac)} evaluations (values and Jacobian, "
        f"{t['mode']} mode) each, against the goal of {T3_MAX_JACOBIANS}.",
    ]
    if l3:
        ms = l3.get("metrics", {})
        lines.append("- L3 (N = " + str(l3.get("n_elements")) + "): " + ", ".join(
            f"`{n}` {v['l3']:.3g} against the PRB's {v['prb']:.3g} ({v['relative']:.0%}, band "
            f"{v['band']:.0%})" for n, v in ms.items()) + "; " + (
            "inside the PRB model's error band." if l3.get("within") else
            "outside the PRB model's error band (the centre-line chain's geometry, above)."))
    lines.append(
        f"- time: {t['first_call_s']:.0f} s for the first call (compilation), "
        f"{t['warm_call_s']:.0f} s warm: screening {tm['screen_s']:.1f} s, optimisation "
        f"{tm['optimise_s']:.1f} s, verification {tm['verify_s']:.0f} s"
        + (f", L3 re-score {tm['l3_s']:.0f} s" if "l3_s" in tm else "") + ".")
    return "\n".join(lines) + "\n"


def robot_scene() -> dict:
    def run():
        return pj.design({"t": (2e-4, 6e-4)}, "base_frequency_hz",
                         [pj.Constraint("strip_stress_peak_Pa", upper=250e6)],
                         scene="servo-circle", model="double1r",
                         options=pj.SceneOptions(t_end=0.5, n_out=51), starts=2, candidates=8,
                         grid=64)
    t0 = time.perf_counter()
    d = run()
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    d = run()
    warm = time.perf_counter() - t0
    (c,) = d.constraints
    v = d.verification
    return {"optimum": d.x, "objective_hz": d.objective["value"],
            "start_objective_hz": d.objective["start_value"],
            "stress_Pa": c["value"], "stress_active": c["active"],
            "multiplier_hz_per_Pa": c["multiplier"], "kkt_residual": v["kkt_residual"],
            "gradient_fd_rel_error": v["gradient_check"]["worst"],
            "grid": {k: v["grid"][k] for k in ("kind", "points", "best_objective", "gap", "ok")},
            "verification_ok": v["ok"], "mode": d.info["mode"],
            "starts": [{"iterations": s["iterations"], "evaluations": s["evaluations"]}
                       for s in d.starts],
            "first_call_s": first, "warm_call_s": warm, "warm_timing": d.timing}


def machine() -> dict:
    try:
        load = os.getloadavg()
    except OSError:
        load = None
    return {"date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
            "backend": jax.default_backend(), "python": platform.python_version(),
            "load_average_at_start": load,
            "versions": {"jax": jax.__version__, "numpy": np.__version__,
                         "scipy": __import__("scipy").__version__}}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--optimizers", default="slsqp,trust-constr")
    ap.add_argument("--robot", action="store_true", help="add the robot-level design on a scene")
    ap.add_argument("--no-tier2", action="store_true", help="leave out tier 2 (the elastica)")
    ap.add_argument("--tier3-only", action="store_true",
                    help="run tier 3 (the paper's robot, six variables) alone, into "
                         "results/design_tier3.json")
    args = ap.parse_args(argv)
    info = machine()
    if args.tier3_only:
        t3 = tier3()
        info["load_average_at_end"] = os.getloadavg()
        path = OUT.parent / "design_tier3.json"
        path.write_text(json.dumps({"machine": info, "tier3": t3}, indent=2, default=str)
                        + "\n")
        print(tier3_markdown(json.loads(path.read_text())))
        print(f"tier 3: f* {t3['objective_hz']:.6g} Hz (start {t3['start_objective_hz']:.6g}), "
              f"verification {t3['verification_ok']}, first call {t3['first_call_s']:.1f} s, "
              f"warm {t3['warm_call_s']} s; {t3['error'] or 'feasible'}; wrote {path}")
        return
    rows = [tier1(o, args.repeats) for o in args.optimizers.split(",")]
    t2 = None if args.no_tier2 else tier2(min(args.repeats, 2))
    robot = robot_scene() if args.robot else None
    try:
        info["load_average_at_end"] = os.getloadavg()
    except OSError:
        pass
    out = {"machine": info, "tier1": rows, "tier2": t2, "robot_scene": robot,
           "passed": {r["optimizer"]: r["meets_1e-6"] and r["verification_ok"] for r in rows}}
    if t2 is not None:
        out["passed"]["tier2"] = t2["meets_1e-6"] and t2["verification_ok"]
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(out, indent=2) + "\n")
    for r in rows:
        print(f"{r['optimizer']}: f* {r['objective']:.10g} Hz, rel error "
              f"{r['objective_rel_error']:.2e} (t {r['t_rel_error']:.2e}), verification "
              f"{r['verification_ok']}, first call "
              f"{r['first_call_s']:.2f} s, warm {r['warm_call_s']:.3f} s")
    if t2:
        print(f"tier 2 (elastica): sigma* {t2['objective_Pa']:.10g} Pa, rel error "
              f"{t2['objective_rel_error']:.2e} (t {t2['t_rel_error']:.2e}), verification "
              f"{t2['verification_ok']}, first call {t2['first_call_s']:.1f} s, warm "
              f"{t2['warm_call_s']:.2f} s")
    if robot:
        print(f"robot on servo-circle: t* {robot['optimum']['t']:.6g} m, f "
              f"{robot['objective_hz']:.6g} Hz, verification {robot['verification_ok']}, "
              f"first call {robot['first_call_s']:.1f} s, warm {robot['warm_call_s']:.1f} s")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
