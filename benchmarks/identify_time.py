"""Benchmark identification: two parameters (t, K_theta) with L2 from one paper-length (7.54 s)
servo-circle experiment at 100 Hz with Optotrak-like noise (0.1 mm, 1 mrad).

Protocol: the data come from the public scene (`servo_circle`, L2, t = 0.5 mm) plus seeded
noise; the fit starts 10 % / 20 % off. The first fit includes the compilation of the
residual-and-Jacobian function (reported by the fit as compile_s, its first call); a second fit
from the same start on the same compiled function gives the run time after compilation.
Writes benchmarks/results/identify_time.json.

Run: python benchmarks/identify_time.py [--t-end 7.54] [--rate 100]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import jax

import ppr_jax as pj

HERE = os.path.dirname(os.path.abspath(__file__))
OUT = os.path.join(HERE, "results")


def main(t_end: float, rate: float):
    os.makedirs(OUT, exist_ok=True)
    truth = pj.scene_params("servo-circle")
    truth = truth.replace(K_theta=float(pj.derived(truth).K_theta))
    t0 = time.perf_counter()
    exp = pj.synthesize("servo-circle", "double1r", truth, noise_pos=1e-4, noise_phi=1e-3,
                        rate=rate, t_end=t_end, seed=0)
    synth_s = time.perf_counter() - t0
    start = {"t": 0.9 * float(truth.t), "K_theta": 1.2 * float(truth.K_theta)}
    runs = []
    for k in range(2):
        t0 = time.perf_counter()
        # the pair on purpose (the preflight refuses it without force)
        fit = pj.identify(exp, ("t", "K_theta"), model="double1r", scene="servo-circle",
                          initial=start, fit_options=pj.FitOptions(force=True))
        wall = time.perf_counter() - t0
        runs.append({"wall_s": wall, "first_call_s (compile + one evaluation)":
                     fit.history["compile_s"], "iterations_run_s": fit.history["run_s"],
                     "iterations": fit.history["iterations"],
                     "evaluations": fit.history["evaluations"], "stop": fit.history["stop"]})
    out = {
        "machine": platform.processor() or platform.machine(), "cpu_count": os.cpu_count(),
        "jax": jax.__version__, "devices": [str(d) for d in jax.devices()],
        "experiment": {"scene": "servo-circle", "model": "double1r", "t_end_s": t_end,
                       "rate_hz": rate, "samples": exp.n, "noise_pos_m": 1e-4,
                       "noise_phi_rad": 1e-3},
        "unknowns": list(fit.names),
        "synth_s (scene compile + run)": synth_s,
        "first_fit": runs[0],
        "second_fit_after_compile": runs[1],
        "estimates": fit.to_dict()["unknowns"],
        "truth": {"t": float(truth.t), "K_theta": float(truth.K_theta)},
        "stiffness_combination": fit.identifiability["combinations"][0],
        "weak_combination": fit.identifiability["combinations"][-1],
        "residual_stats": fit.residual_stats["experiments"][0],
    }
    path = os.path.join(OUT, "identify_time.json")
    with open(path, "w") as f:
        json.dump(out, f, indent=2)
    print(json.dumps(out, indent=2))
    print(f"wrote {path}")


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--t-end", type=float, default=7.54)
    ap.add_argument("--rate", type=float, default=100.0)
    a = ap.parse_args()
    main(a.t_end, a.rate)
