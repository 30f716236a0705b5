"""Run: python benchmarks/identify_strip.py (writes benchmarks/results/identify_strip.json).

Data from L2 on the actual strip (joint_geometry='strip', MODEL.md 3a), the motors commanded
by the centre-line L1 inverse kinematics (what a user of the paper's model sends), fitted by L2
on the centre lines: what do the PRB parameters become?"""
import json, os, time, types
import jax, jax.numpy as jnp, numpy as np
import ppr_jax as pj
from ppr_jax import _identify as I
from ppr_jax._robot import Robot

cl = pj.scene_params("servo-circle")
dv = pj.derived(cl)
cl = cl.replace(K_theta=float(dv.K_theta), gamma=float(dv.gamma))
strip = cl.replace(joint_geometry="strip")
T_END, RATE = 2.0, 100.0
ts = jnp.linspace(0.0, T_END, int(T_END * RATE) + 1)
ns = types.SimpleNamespace(model=pj.get_model("double1r"), rtol=jnp.asarray(1e-8), atol=jnp.asarray(1e-10),
                           scene="servo-circle", equal_links=Robot(strip).equal_links,
                           solver=pj._simulate.get_solver("tsit5"), max_steps=100_000)
t0 = time.perf_counter()
X, ok = jax.jit(lambda: I._pose_one(ns, strip, Robot(cl), ts, None, None, jnp.zeros(6)))()
print("data sim", time.perf_counter() - t0, bool(ok), flush=True)
rng = np.random.default_rng(0)
noise = (1e-4, 1e-3)
Xn = np.asarray(X).copy()
Xn[:, :2] += noise[0] * rng.standard_normal((len(ts), 2))
Xn[:, 2] += noise[1] * rng.standard_normal(len(ts))
exp = pj.experiment(np.asarray(ts), Xn, name="strip-robot")
out = {"truth": {"joint_geometry": "strip", "t": 5e-4, "K_theta": float(dv.K_theta), "gamma": float(dv.gamma)},
       "experiment": {"t_end_s": T_END, "rate_hz": RATE, "noise": noise}}
for names in (("K_theta",), ("K_theta", "gamma")):
    t0 = time.perf_counter()
    fit = pj.identify(exp, names, model="double1r", params=cl, noise=noise)
    print(fit.table(), flush=True)
    out[",".join(names)] = {**fit.to_dict(), "wall_s": time.perf_counter() - t0}
# the centre-line model with its own (table) parameters on the same data
fit0 = pj.identify(exp, ("K_theta",), model="double1r", params=cl, noise=noise, max_iter=0)
out["centerline_defaults_residual_stats"] = fit0.residual_stats
print(fit0.residual_stats, flush=True)
OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", "identify_strip.json")
json.dump(out, open(OUT, "w"), indent=2, default=str)
print("wrote", OUT)
