"""Profile-likelihood against linearised intervals on a paper-length experiment.

The data of `identify_time.py` (L2 servo circle, 7.54 s at 100 Hz, t = 0.5 mm, Optotrak-like
noise 0.1 mm / 1 mrad, seed 0). Two fits: K_theta alone with t fixed at its true value (a
thickness measured with a micrometer), and t with K_theta (both unknown). For each unknown the
linearised 95 % interval (Student t on the Gauss-Newton standard error), its log form, and the
profile-likelihood interval (`Identification.profile`), and whether each holds the truth.
Writes benchmarks/results/identify_profile.json. About 5 min on two idle cores (two
compilations of about 40 s, the profiles 10-150 evaluations of 1.6 s).

Run: python benchmarks/identify_profile.py [--t-end 7.54]
"""

from __future__ import annotations

import argparse
import json
import os
import time

import ppr_jax as pj

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")


def main(t_end: float):
    truth = pj.scene_params("servo-circle")
    truth = truth.replace(K_theta=float(pj.derived(truth).K_theta))
    exp = pj.synthesize("servo-circle", "double1r", truth, noise_pos=1e-4, noise_phi=1e-3,
                        rate=100.0, t_end=t_end, seed=0)
    rows = []
    for unknowns in (("K_theta",), ("t", "K_theta")):
        start = {"t": 0.9 * float(truth.t), "K_theta": 1.2 * float(truth.K_theta)}
        t0 = time.perf_counter()
        fit = pj.identify(exp, unknowns, model="double1r", scene="servo-circle", params=truth,
                          initial={k: start[k] for k in unknowns},
                          # t with K_theta: profiled on purpose, past the preflight
                          fit_options=pj.FitOptions(force=True))
        fit_s = time.perf_counter() - t0
        for i, name in enumerate(unknowns):
            pr = fit.profile(name)
            v = float(getattr(truth, name))
            ci = pr["ci"]
            rows.append({
                "unknowns": list(unknowns), "name": name, "truth": v,
                "estimate": float(fit.estimate[i]), "std": float(fit.std[i]),
                "linearised": pr["linearised"], "linearised_log": fit.ci95_log[i].tolist(),
                "profile": ci, "profile_open": pr["open"],
                "profile_limited_by_bounds_of": pr["limited_by_bounds_of"],
                "truth_in_linearised": pr["linearised"][0] <= v <= pr["linearised"][1],
                "truth_in_profile": ((ci[0] is None or ci[0] <= v)
                                     and (ci[1] is None or v <= ci[1])),
                "profile_evaluations": pr["evaluations"], "profile_s": pr["run_s"],
                "fit_s (with compile)": fit_s, "s": fit.sigma2 ** 0.5,
                "combinations": fit.identifiability["combinations"],
            })
            print(json.dumps(rows[-1], default=str)[:600], flush=True)
    os.makedirs(OUT, exist_ok=True)
    with open(os.path.join(OUT, "identify_profile.json"), "w") as f:
        json.dump({"experiment": {"scene": "servo-circle", "model": "double1r",
                                  "t_end_s": t_end, "rate_hz": 100.0, "noise_pos_m": 1e-4,
                                  "noise_phi_rad": 1e-3, "seed": 0},
                   "rows": rows}, f, indent=1)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--t-end", type=float, default=7.54)
    main(ap.parse_args().t_end)
