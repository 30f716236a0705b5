"""How much the start moves each metric and its t-derivative, and the library's sensitivities
against an independent formulation.

    python benchmarks/start_sensitivity.py [--quick]   # -> results/start_sensitivity.json

For L2 (`double1r`) under L1's torques on `paper-circle` (7.54 s, 755 samples, t = 0.3 mm) and
on a torque-driven `PathScene` along a two-harmonic Fourier path (3 s, 301 samples):

- the independent scipy L2 (`contenders/scipy_l2.py`, its own start `quasi_static_start`)
  with three starts: two passes (MODEL.md section 6, the scenes' start), one pass (the
  balance at the rates of L1's inverse kinematics), static (the balance at rest, the actuated
  angles' rate L1's); for each, the metrics and their central differences in t at the step
  `REL_STEP` of t;
- the step-size study of those central differences (two-pass start), relative steps 1e-2 to
  1e-6, whose plateau chose `REL_STEP`;
- the library's `sensitivity` (forward mode) with its two-pass start and, in a second process
  with `ppr_jax._statics.QS_PASSES = 1`, with a one-pass start.

Tolerances rtol 1e-11, atol 1e-13 on both sides. `--quick`: 1.5 s of paper-circle only.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

#: relative central-difference step in t (the step-size study's plateau; see the JSON)
REL_STEP = {"paper-circle": 3e-5, "fourier": 1e-4}
STUDY_STEPS = (1e-2, 3e-3, 1e-3, 3e-4, 1e-4, 3e-5, 1e-5, 3e-6, 1e-6)
TOL = dict(rtol=1e-11, atol=1e-13)
CIRCLE_METRICS = ("radial_error_max_m", "radial_error_min_m", "radial_error_mean_m",
                  "end_rotation_diff_max_deg")
PATH_METRICS = ("position_error_max_m", "position_error_rms_m", "position_error_end_m",
                "phi_error_max_rad", "phi_error_rms_rad", "phi_error_end_rad",
                "end_rotation_diff_max_deg")
STARTS = {"two-pass": 2, "one-pass": 1, "static": 0}


def _scenes(quick):
    import ppr_jax as pj

    fourier = pj.Fourier(mean=[0.45, 0.26, 0.0], cos=[[0.08, 0.0, 0.0], [0.0, 0.02, 0.01]],
                         sin=[[0.0, 0.05, 0.03], [0.0, 0.0, 0.0]], omega=1.0)
    out = {"paper-circle": dict(scene="paper-circle", path=None, metrics=CIRCLE_METRICS,
                                t_end=1.5 if quick else 7.54, n_out=151 if quick else 755)}
    if not quick:
        out["fourier"] = dict(scene=pj.PathScene(fourier, drive="torque", name="fourier"),
                              path=fourier, metrics=PATH_METRICS, t_end=3.0, n_out=301)
    return out


def library_sensitivity(name, quick):
    """The library's values and d/dt (forward mode) in this process."""
    import ppr_jax as pj

    sc = _scenes(quick)[name]
    t0 = time.perf_counter()
    s = pj.sensitivity(sc["scene"], model="double1r", parameters=["t"], metrics=sc["metrics"],
                       t_end=sc["t_end"], n_out=sc["n_out"], **TOL)
    return {"values": s.values, "derivatives": dict(zip(s.metrics, s.jacobian[:, 0].tolist())),
            "wall_s": time.perf_counter() - t0}


def _library_in_process(name, quick, passes):
    """`library_sensitivity` in a fresh process with `QS_PASSES = passes` (the setting is read
    when the program is traced)."""
    code = ("import json, sys; sys.path.insert(0, %r); import ppr_jax._statics as s; "
            "s.QS_PASSES = %d; from benchmarks.start_sensitivity import library_sensitivity; "
            "print(json.dumps(library_sensitivity(%r, %r)))" % (ROOT, passes, name, quick))
    env = dict(os.environ, PYTHONPATH=ROOT)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                         check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def reference(params, sc, rel, passes, base=None):
    """The scipy L2's metrics and their central differences at step rel t (the metrics at t
    computed unless `base` holds them)."""
    from benchmarks.contenders import scipy_l2

    t0 = float(params.t)
    kw = dict(t_end=sc["t_end"], n_out=sc["n_out"], passes=passes, **TOL)
    base = scipy_l2.scene_metrics(params, sc["path"], **kw) if base is None else base
    plus = scipy_l2.scene_metrics(params.replace(t=t0 * (1 + rel)), sc["path"], **kw)
    minus = scipy_l2.scene_metrics(params.replace(t=t0 * (1 - rel)), sc["path"], **kw)
    return ({k: base[k] for k in sc["metrics"]},
            {k: (plus[k] - minus[k]) / (2 * rel * t0) for k in sc["metrics"]},
            plus, minus)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=os.path.join(ROOT, "benchmarks", "results",
                                                  "start_sensitivity.json"))
    args = ap.parse_args()
    import jax

    import ppr_jax as pj

    result = {"machine": {"date": time.strftime("%Y-%m-%d"), "machine": platform.machine(),
                          "cpus": os.cpu_count(), "backend": jax.default_backend(),
                          "jax": jax.__version__},
              "model": "double1r", "input": "L1 inverse-dynamics torques along the path",
              "tolerances": TOL, "starts": {
                  "two-pass": "MODEL.md section 6: the actuated angles balanced at the rates "
                              "and accelerations of their own quasi-static path (the scenes')",
                  "one-pass": "balanced at the rates and accelerations of L1's inverse "
                              "kinematics of the path",
                  "static": "balanced at rest (zero rates and accelerations), rate L1's"},
              "quick": args.quick, "scenes": {}}
    for name, sc in _scenes(args.quick).items():
        params = pj.scene_params(sc["scene"])
        rel = REL_STEP[name]
        entry = {"t_end_s": sc["t_end"], "n_out": sc["n_out"], "t_m": float(params.t),
                 "rel_step": rel, "metrics": list(sc["metrics"]), "reference": {},
                 "step_study": []}
        t = time.perf_counter()
        for start, passes in STARTS.items():
            v, d, _, _ = reference(params, sc, rel, passes)
            entry["reference"][start] = {"values": v, "derivatives": d}
            print(name, start, v, d, flush=True)
        for h in STUDY_STEPS:
            _, d, _, _ = reference(params, sc, h, 2, base=entry["reference"]["two-pass"]["values"])
            entry["step_study"].append({"rel_step": h, "derivatives": d})
            print(name, "step", h, d, flush=True)
        entry["reference_wall_s"] = time.perf_counter() - t
        entry["library"] = {"two-pass": _library_in_process(name, args.quick, 2),
                            "one-pass": _library_in_process(name, args.quick, 1)}
        print(name, "library", entry["library"], flush=True)
        result["scenes"][name] = entry
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(result, f, indent=1)
    print("wrote", args.out)


if __name__ == "__main__":
    main()
