"""Run: python benchmarks/identify_strip.py (writes benchmarks/results/identify_strip.json).

Data from L2 on the actual strip (joint_geometry='strip', MODEL.md 3a), the motors commanded
by the centre-line L1 inverse kinematics (what a user of the paper's model sends), fitted by L2
on the centre lines: what do the PRB parameters become?"""
import argparse
import json
import os
import time

import jax
import jax.numpy as jnp
import numpy as np

import ppr_jax as pj
from ppr_jax._robot import Robot
from ppr_jax._scenes import prepare

cl = pj.scene_params("servo-circle")
dv = pj.derived(cl)
cl = cl.replace(K_theta=float(dv.K_theta), gamma=float(dv.gamma))
strip = cl.replace(joint_geometry="strip")
ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
ap.add_argument("--t-end", type=float, default=2.0,
                help="seconds of data (default 2, the published run); shorter only to check "
                     "that the script runs (tests/test_benchmarks_run.py), not for results")
T_END, RATE = ap.parse_args().t_end, 100.0
ts = jnp.linspace(0.0, T_END, int(T_END * RATE) + 1)
# the strip robot under the commands of the centre-line robot: the scene's run with the
# scene's commands computed for `cl`
call = prepare("servo-circle", strip, "double1r",
               pj.SceneOptions(t_end=T_END, n_out=len(ts), solver="tsit5", max_steps=100_000))
scene, model, robot, opts = call.args
t0 = time.perf_counter()
res = jax.jit(lambda: scene.run(model, robot, opts, scene.commands(
    model, Robot(cl), opts.trajectory, opts.times(), opts.panels).actuation))()
X, ok = res.X, res.result == pj.RESULTS.successful
print("data sim", time.perf_counter() - t0, bool(ok), flush=True)
rng = np.random.default_rng(0)
noise = (1e-4, 1e-3)
Xn = np.asarray(X).copy()
Xn[:, :2] += noise[0] * rng.standard_normal((len(ts), 2))
Xn[:, 2] += noise[1] * rng.standard_normal(len(ts))
exp = pj.experiment(np.asarray(ts), Xn, name="strip-robot")
out = {"truth": {"joint_geometry": "strip", "t": 5e-4, "K_theta": float(dv.K_theta),
                 "gamma": float(dv.gamma)},
       "experiment": {"t_end_s": T_END, "rate_hz": RATE, "noise": noise}}
for names in (("K_theta",), ("K_theta", "gamma")):
    t0 = time.perf_counter()
    # as documented: past the preflight, and no automatic refit of a poor fit (force, one start)
    fit = pj.identify(exp, names, model="double1r", scene="servo-circle", params=cl, noise=noise,
                      fit_options=pj.FitOptions(force=True, starts=1))
    print(fit.table(), flush=True)
    out[",".join(names)] = {**fit.to_dict(), "wall_s": time.perf_counter() - t0}
# the centre-line model with its own (table) parameters on the same data
fit0 = pj.identify(exp, ("K_theta",), model="double1r", scene="servo-circle", params=cl,
                   noise=noise, fit_options=pj.FitOptions(max_iter=0, force=True, starts=1))
out["centerline_defaults_residual_stats"] = fit0.residual_stats
print(fit0.residual_stats, flush=True)
OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", "identify_strip.json")
json.dump(out, open(OUT, "w"), indent=2, default=str)
print("wrote", OUT)
