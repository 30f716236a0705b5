"""Quasi-static L3 in practice: convergence in N, its run time, and every model against it.

1. Convergence: paper-circle (t = 0.3 mm, 7.54 s, L1's centre-line torques) and servo-circle
   (t = 0.5 mm) of `QuasiStaticBeam(N)` for N = 4, 8, 16, 32 (Dopri8, rtol 1e-9): the scene
   metrics, their relative change on doubling N and the observed order
   log2(|m_N - m_N/2| / |m_2N - m_N|).
2. Speed: paper-circle at N = 16 with the fastest setting whose metrics stay within 0.1 % of the
   tight run (compilation apart, best of 3 runs).
3. Validation against converged L3 (the largest N): L0 (rigid), L1 (reduced), L2 (double1r) on
   the paper's centre-line PRB joint and L1/L2 on the strip geometry (MODEL.md 3a), on both
   scenes, plus L3 itself under the strip-geometry L1 torques; the metrics of each, their
   difference to L3's, the largest distance of each model's platform from L3's; modes (locked,
   free) and the platform's static compliance at home.

Writes benchmarks/results/l3_validation.json and l3_validation_<scene>.png (radial error of
every model and of L3 over time). Run: python benchmarks/l3_validation.py [--quick]
(about 15 min on two cores; --quick: N = 4, 8 and 2 s scenes, about 5 min).
"""

from __future__ import annotations

import argparse
import json
import pathlib
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

import ppr_jax as pj

OUT = pathlib.Path(__file__).parent / "results"
METRICS = ("radial_error_max_m", "radial_error_min_m", "radial_error_mean_m",
           "radial_error_max_relative_percent", "phi_error_max_rad", "end_rotation_diff_max_deg")
TIGHT = dict(solver="dopri8", rtol=1e-9, atol=1e-11)
WRENCH = jnp.array([0.4, -0.3, 0.004])  # N, N, N m: the static compliance load


CIRCLE = pj.Circle()


def e_r(result):
    """Radial error (m) of a scene result over time."""
    X = np.asarray(result.X)
    return np.hypot(*(X[:, :2] - np.asarray(CIRCLE.center)).T) - float(CIRCLE.radius)


def run(scene, params, model, t_end, n_out, repeats=1, **solve):
    solve = {**TIGHT, **solve}
    r = pj.run_scene(
        scene,
        params,
        model=model,
        repeats=repeats,
        options=pj.SceneOptions(t_end=t_end, n_out=n_out, max_steps=400_000, **solve),
    )
    m = {k: float(r.metrics[k]) for k in METRICS + ("num_steps",)}
    return r, m, r.timing


def convergence(scene, Ns, t_end, n_out):
    params = pj.scene_params(scene)
    rows, results = [], {}
    for N in Ns:
        r, m, tm = run(scene, params, pj.QuasiStaticBeam(N), t_end, n_out)
        results[N] = r
        rows.append(dict(N=N, metrics=m, compile_s=tm["compile_s"], run_s=tm["run_s"]))
        print(scene, N, json.dumps(rows[-1]), flush=True)
    for a, b in zip(rows[:-1], rows[1:]):
        b["relative_change_percent"] = {
            k: 100 * abs(b["metrics"][k] - a["metrics"][k]) / max(abs(b["metrics"][k]), 1e-300)
            for k in METRICS}
    for a, b, c in zip(rows[:-2], rows[1:-1], rows[2:]):
        c["observed_order"] = {
            k: float(np.log2(abs(b["metrics"][k] - a["metrics"][k])
                             / max(abs(c["metrics"][k] - b["metrics"][k]), 1e-300)))
            for k in METRICS}
    return rows, results


def speed(N, t_end, n_out, reference):
    params = pj.scene_params("paper-circle")
    out = []
    for solver, rtol in (("dopri8", 1e-5), ("dopri8", 1e-6), ("tsit5", 1e-5), ("tsit5", 1e-6)):
        r, m, tm = run("paper-circle", params, pj.QuasiStaticBeam(N), t_end, n_out, repeats=3,
                       solver=solver, rtol=rtol, atol=rtol * 1e-2)
        dev = max(abs(m[k] - reference[k]) / max(abs(reference[k]), 1e-300) for k in METRICS)
        out.append(dict(N=N, solver=solver, rtol=rtol, compile_s=tm["compile_s"],
                        run_s=tm["run_s"], steps=m["num_steps"],
                        metrics_max_relative_deviation=dev))
        print("speed", json.dumps(out[-1]), flush=True)
    return out


def validation(scene, l3_result, N, t_end, n_out):
    params = pj.scene_params(scene)
    strip = params.replace(joint_geometry="strip")
    cases = [("L0 rigid", params, "rigid"), ("L1 reduced", params, "reduced"),
             ("L2 double1r", params, "double1r"), ("L1 reduced, strip joint", strip, "reduced"),
             ("L2 double1r, strip joint", strip, "double1r")]
    # L3 ignores joint_geometry, but the scene's drive does not: under the strip-joint L1's
    # torques (paper-circle) or inverse-kinematics angles (servo-circle), the reference for the
    # strip-joint models
    drive = "torques" if scene == "paper-circle" else "angles"
    cases.append((f"L3 (N = {N}) under strip-joint L1 {drive}", strip, pj.QuasiStaticBeam(N)))
    X3 = np.asarray(l3_result.result.X)
    rows, series = [], {"t": np.asarray(l3_result.result.ts).tolist(),
                        f"L3 (N = {N})": e_r(l3_result.result).tolist()}
    l3m = {k: float(l3_result.metrics[k]) for k in METRICS}
    for name, p, model in cases:
        r, m, tm = run(scene, p, model, t_end, n_out)
        X = np.asarray(r.result.X)
        rows.append(dict(
            model=name, metrics=m, difference_to_l3={k: m[k] - l3m[k] for k in METRICS},
            platform_distance_to_l3_max_m=float(np.max(np.hypot(*(X[:, :2] - X3[:, :2]).T))),
            phi_difference_to_l3_max_rad=float(np.max(np.abs(X[:, 2] - X3[:, 2]))),
            run_s=tm["run_s"]))
        series[name] = e_r(r.result).tolist()
        print(scene, json.dumps(rows[-1]), flush=True)
    return dict(l3_metrics=l3m, models=rows, radial_error_series_m=series), series


_static = None


def _static_eq(model, p, z, w):
    global _static
    if _static is None:  # compiled (eager, the Newton iteration costs minutes at N = 32)
        import equinox as eqx
        _static = eqx.filter_jit(
            lambda m, p, z, w: pj.static_equilibrium(m, p, z, locked=True, wrench=w)[0])
    return _static(model, p, z, w)


def statics_and_modes(N):
    params = pj.scene_params("paper-circle")
    strip = params.replace(joint_geometry="strip")
    out = []
    for name, p, model in (("L2 double1r", params, pj.Double1R()),
                           ("L2 double1r, strip joint", strip, pj.Double1R()),
                           (f"L3 (N = {N})", params, pj.QuasiStaticBeam(N))):
        robot = pj.Robot(p)
        z0 = model.coords_from_pose(robot, pj.home_pose(p))
        z_a = _static_eq(model, p, z0, jnp.zeros(3))
        z_b = _static_eq(model, p, z_a, WRENCH)
        row = dict(model=name,
                   platform_displacement_under_wrench=np.asarray(z_b[:3] - z_a[:3]).tolist())
        for act in ("locked", "free"):
            row[f"modes_{act}_hz"] = np.asarray(pj.modes(model, p, actuators=act).freq_hz).tolist()
        out.append(row)
        print("statics", json.dumps(row), flush=True)
    ref = np.asarray(out[-1]["platform_displacement_under_wrench"])
    for row in out:
        d = np.asarray(row["platform_displacement_under_wrench"])
        row["compliance_ratio_to_l3"] = float(np.linalg.norm(d) / np.linalg.norm(ref))
    return out


def plot(series_by_scene, path_prefix):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    for scene, series in series_by_scene.items():
        fig, ax = plt.subplots(figsize=(8, 4.5))
        t = np.asarray(series["t"])
        ref = [k for k in series if k != "t"][0]  # converged L3 under the centre-line drive
        for name, e in series.items():
            if name == "t":
                continue
            ax.plot(t, 1e3 * np.asarray(e), lw=2.2 if name.startswith("L3") else 1.2,
                    label=name, color="k" if name == ref else None,
                    ls="--" if name.startswith("L3") and name != ref else "-")
        ax.set_xlabel("t (s)")
        ax.set_ylabel("radial error e_r (mm)")
        ax.set_title(f"{scene}: every model against converged L3 (quasi-static strips)")
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(f"{path_prefix}_{scene}.png", dpi=120)
        plt.close(fig)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--speed-only", action="store_true",
                    help="re-measure part 2 only, into the existing JSON (about 2 min)")
    ap.add_argument("--plot-only", action="store_true", help="redraw the figures from the JSON")
    ap.add_argument("--statics-only", action="store_true",
                    help="re-measure part 3's statics and modes only, into the existing JSON")
    args = ap.parse_args()
    OUT.mkdir(parents=True, exist_ok=True)
    if args.speed_only:
        path = OUT / "l3_validation.json"
        res = json.loads(path.read_text())
        ref = res["convergence_paper-circle"][-2]["metrics"]
        res["speed"] = speed(16, 7.54, 755, ref)
        path.write_text(json.dumps(res, indent=1))
        return
    if args.plot_only:
        res = json.loads((OUT / "l3_validation.json").read_text())
        plot({sc: res[f"validation_{sc}"]["radial_error_series_m"]
              for sc in ("paper-circle", "servo-circle")}, str(OUT / "l3_validation"))
        return
    if args.statics_only:
        path = OUT / "l3_validation.json"
        res = json.loads(path.read_text())
        res["statics_and_modes"] = statics_and_modes(32)
        path.write_text(json.dumps(res, indent=1))
        return
    Ns = (4, 8) if args.quick else (4, 8, 16, 32)
    t_end = {"paper-circle": 2.0 if args.quick else 7.54,
             "servo-circle": 2.0 if args.quick else 7.54}
    t0 = time.time()
    res = dict(machine=platform.processor() or platform.machine(), jax=jax.__version__,
               backend=jax.default_backend(), tight_solver=TIGHT, quick=args.quick)
    series = {}
    for scene in ("paper-circle", "servo-circle"):
        n_out = int(round(t_end[scene] * 100)) + 1
        rows, results = convergence(scene, Ns, t_end[scene], n_out)
        res[f"convergence_{scene}"] = rows
        if scene == "paper-circle":
            res["speed"] = speed(16 if not args.quick else 8, t_end[scene], n_out,
                                 rows[-2 if not args.quick else -1]["metrics"])
        v, series[scene] = validation(scene, results[Ns[-1]], Ns[-1], t_end[scene], n_out)
        res[f"validation_{scene}"] = v
        _save(res, args.quick)
    res["statics_and_modes"] = statics_and_modes(Ns[-1])
    res["total_s"] = time.time() - t0
    _save(res, args.quick)
    plot(series, str(OUT / ("l3_validation_quick" if args.quick else "l3_validation")))
    print(f"done in {res['total_s']:.0f} s")


def _save(res, quick):
    name = "l3_validation_quick.json" if quick else "l3_validation.json"
    (OUT / name).write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
