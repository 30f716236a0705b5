"""Run: python benchmarks/identify_l3.py [--elements 8] [--t-end 2] (about 5 min on the 2-core
CPU; writes benchmarks/results/identify_l3.json).

The "real robot" is L3 with quasi-static strips (`pj.QuasiStaticBeam(N)`: the strip's elastica
at every instant, no PRB model at all), t = 0.5 mm, its motors commanded by the centre-line L1
inverse kinematics of the servo circle (what a user of the paper's model sends). Its platform is
sampled like an Optotrak (100 Hz, 0.1 mm / 1 mrad noise, seed 0) and fitted by L2:

- on the link centre lines (the paper's model, `joint_geometry="centerline"`): with its table
  parameters, with K_theta free, with K_theta and gamma free;
- on the actual strip geometry (`joint_geometry="strip"`, MODEL.md 3a): with its table
  parameters and with K_theta free.

What do the PRB parameters become, and how good is each fit (s, the residual RMS against the
noise)? This is what a user of the paper's model would get from a real robot."""
import argparse
import json
import os
import time

import numpy as np

import ppr_jax as pj

ap = argparse.ArgumentParser()
ap.add_argument("--elements", type=int, default=8)
ap.add_argument("--t-end", type=float, default=2.0)
args = ap.parse_args()

cl = pj.scene_params("servo-circle")
dv = pj.derived(cl)
cl = cl.replace(K_theta=float(dv.K_theta), gamma=float(dv.gamma))
strip = cl.replace(joint_geometry="strip")
NOISE, RATE = (1e-4, 1e-3), 100.0
OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", "identify_l3.json")

t0 = time.perf_counter()
exp = pj.synthesize("servo-circle", pj.QuasiStaticBeam(args.elements), cl, noise_pos=NOISE[0],
                    noise_phi=NOISE[1], rate=RATE, t_end=args.t_end, seed=0, name="l3-robot")
t_data = time.perf_counter() - t0
print(f"L3 data (N = {args.elements}): {t_data:.1f} s", flush=True)
out = {"truth": {"model": f"QuasiStaticBeam({args.elements})", "t": float(cl.t)},
       "experiment": {"scene": "servo-circle", "t_end_s": args.t_end, "rate_hz": RATE,
                      "noise": NOISE, "seed": 0, "data_s (with compile)": t_data},
       "table": {"K_theta": float(dv.K_theta), "gamma": float(dv.gamma)}, "fits": []}
for geometry, base in (("centerline", cl), ("strip", strip)):
    for names in ((), ("K_theta",), ("K_theta", "gamma")):
        if geometry == "strip" and len(names) == 2:
            continue
        t0 = time.perf_counter()
        fit = pj.identify(exp, names or ("K_theta",), model="double1r", scene="servo-circle",
                          params=base,
                          noise=NOISE,
                          # as documented: no preflight refusal, no automatic refit of a
                          # poor fit (the table reports them as they are)
                          fit_options=pj.FitOptions(max_iter=50 if names else 0, force=True,
                                                    starts=1))
        wall = time.perf_counter() - t0
        print(geometry, names or "(table values)", flush=True)
        print(fit.table(), flush=True)
        d = fit.to_dict()
        row = {"joint_geometry": geometry, "unknowns": list(names), "wall_s": wall,
               "s": float(np.sqrt(d["sigma2"])), "residual_stats": d["residual_stats"]}
        if names:
            row.update(estimates=d["unknowns"], identifiability=d["identifiability"])
        out["fits"].append(row)
        json.dump(out, open(OUT, "w"), indent=1, default=str)
print("wrote", OUT)
