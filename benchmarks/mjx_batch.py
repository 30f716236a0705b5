"""Batches of L2 robots in MJX (MuJoCo XLA) against ppr_jax: trajectories per second against
batch size, at a stated error.

The MJX model is the suite's MuJoCo model of the L2 robot (`contenders/mujoco_l2.py`: chains as
kinematic trees, loops closed by the stiffest `connect` equalities MuJoCo allows, RK4), one MJCF
per member, put on the device with `mjx.put_model` and stacked along a batch axis; the members
differ as in `benchmarks/run.py`'s batch part (strip thickness spread over 0.28-0.40 mm, so
each member has its own joint stiffness and its own torques). Each member is driven by the
library's `paper-circle` torques held over each step at the step's midpoint (the MuJoCo
contender's "midpoint" inputs), precomputed on the host and not timed, from the library's initial
state. One program: `jax.vmap` over members of a `lax.scan` over output intervals of a
`lax.scan` over MJX steps (`mjx.step`), jit-compiled once per batch size (compile timed apart),
float64 as the library.

Error: member 0's platform position at the output times against the library's L2 run at tight
tolerance (Dopri8, rtol 1e-11): the max over time of |(x, y) - (x, y)_ref| (m).

ppr_jax's side is measured in the same run on the same members and scene: `run_scene` on the
batch (L2 `double1r`, the scene's default solver Tsit5 at each `--rtols`, atol = rtol / 100),
whose timed program includes torque tables, initial states, the adaptive integration and every
output; its error is member 0's against the same reference.

Run: python benchmarks/mjx_batch.py [--sizes 1 8 64] [--dt 1e-3 1e-4] [--t-end 1.0]
(about 9 minutes with the defaults on 2 CPU cores, compilation included)
Writes benchmarks/results/cpu/mjx_batch.json and .png (or results/<backend>/); `--plot-only`
redraws the figure from the JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from _common import label_axes, save_figure  # noqa: E402

import ppr_jax as pj  # noqa: E402
from benchmarks.contenders import library, mujoco_l2  # noqa: E402


def member_inputs(params, dt, t_end, n_out):
    """(MjModel, qpos0, qvel0, tau (n_out - 1, n_sub, 3), step h, n_sub) of one member."""
    interval = t_end / (n_out - 1)
    n_sub = max(int(round(interval / dt)), 1)
    h = interval / n_sub
    n_steps = n_sub * (n_out - 1)
    model = mujoco.MjModel.from_xml_string(mujoco_l2.mjcf(params, dt=h))
    z0, zd0, th, thd = mujoco_l2.library_initial_state(params)
    qpos, qvel = mujoco_l2.mujoco_state(model, th, thd, z0, zd0)
    tau = library.scene_torques(params, (np.arange(n_steps) + 0.5) * h)
    return model, qpos, qvel, tau.reshape(n_out - 1, n_sub, 3), h, n_sub


def batch_program(model: mujoco.MjModel, ix):
    """jit(vmap(run)) over (mjx models, qpos0, qvel0, tau): the platform pose at every output
    time, (B, n_out, 3)."""
    data0 = mjx.make_data(model)

    def run(mx, qpos, qvel, tau):
        d = mjx.forward(mx, data0.replace(qpos=qpos, qvel=qvel))

        def interval(d, tau_j):
            def step(d, u):
                return mjx.step(mx, d.replace(ctrl=u)), None

            d, _ = jax.lax.scan(step, d, tau_j)
            return d, d.qpos[ix]

        _, X = jax.lax.scan(interval, d, tau)
        return jnp.concatenate([qpos[ix][None], X])

    return jax.jit(jax.vmap(run))


def _mjx_row(base, ts, dt, args, n_out, X_ref) -> dict:
    """One MJX batch (members at strip thicknesses ts) at step dt: timing and member 0's
    error against X_ref."""
    B = len(ts)
    t0 = time.perf_counter()
    members = [member_inputs(base.replace(t=float(t)), dt, args.t_end, n_out) for t in ts]
    model, _, _, _, h, n_sub = members[0]
    ix = np.array([mujoco_l2.qpos_index(model)[n] for n in ("x", "y", "phi")])
    mxs = [mjx.put_model(m[0]) for m in members]
    mx = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *mxs)
    qpos = jnp.asarray(np.stack([m[1] for m in members]))
    qvel = jnp.asarray(np.stack([m[2] for m in members]))
    tau = jnp.asarray(np.stack([m[3] for m in members]))
    setup_s = time.perf_counter() - t0
    fn = batch_program(model, ix)
    t1 = time.perf_counter()
    compiled = fn.lower(mx, qpos, qvel, tau).compile()
    compile_s = time.perf_counter() - t1
    X = np.asarray(jax.block_until_ready(compiled(mx, qpos, qvel, tau)))
    runs = []
    for _ in range(args.repeats):
        t2 = time.perf_counter()
        jax.block_until_ready(compiled(mx, qpos, qvel, tau))
        runs.append(time.perf_counter() - t2)
    err = float(np.max(np.linalg.norm(X[0, :, :2] - X_ref[:, :2], axis=-1)))
    return {"tool": "mjx", "batch": B, "dt_s": h, "steps": n_sub * (n_out - 1),
            "setup_s": setup_s, "compile_s": compile_s, "run_s": min(runs),
            "per_robot_ms": min(runs) / B * 1e3, "trajectories_per_s": B / min(runs),
            "member0_position_error_m": err, "finite": bool(np.all(np.isfinite(X)))}


def plot(res: dict, path: str) -> None:
    """Trajectories per second against batch size, one line per tool and setting, labelled with
    member 0's position error."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lines: dict = {}
    for r in res["rows"]:
        key = (f"MJX RK4 dt {r['dt_s']:.0e} s" if r["tool"] == "mjx" else
               f"ppr_jax L2 Tsit5 rtol {r['rtol']:.0e}")
        lines.setdefault(key, []).append(r)
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for key, rows in lines.items():
        rows = sorted(rows, key=lambda r: r["batch"])
        err = max(r["member0_position_error_m"] for r in rows)
        ax.loglog([r["batch"] for r in rows], [r["trajectories_per_s"] for r in rows], "o-",
                  label=f"{key} (error {err:.1e} m)")
    label_axes(ax, "batch size (robots)", "trajectories per second",
               f"L2 paper-circle, {res['t_end_s']:g} s, {res['backend']} ({res['cpus']} cores)")
    save_figure(fig, path)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1, 8, 64])
    ap.add_argument("--dt", type=float, nargs="+", default=[1e-3, 1e-4],
                    help="MJX step sizes (s), one set of rows each")
    ap.add_argument("--t-end", type=float, default=1.0)
    ap.add_argument("--rtols", type=float, nargs="*", default=[1e-6, 1e-8])
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--out", default=None, help="JSON path (default results/<backend>/)")
    ap.add_argument("--plot-only", action="store_true")
    args = ap.parse_args()
    if args.plot_only:
        path = args.out or os.path.join(HERE, "results", jax.default_backend(), "mjx_batch.json")
        with open(path) as fh:
            plot(json.load(fh), path[:-5] + ".png")
        return
    n_out = int(round(args.t_end * 100)) + 1
    base = pj.scene_params("paper-circle")
    out_path = args.out or os.path.join(HERE, "results", jax.default_backend(),
                                        "mjx_batch.json")
    os.makedirs(os.path.dirname(out_path), exist_ok=True)
    res = {"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
           "backend": jax.default_backend(), "jax": jax.__version__,
           "mujoco": mujoco.__version__, "scene": "paper-circle", "t_end_s": args.t_end,
           "n_out": n_out, "dt_requested_s": list(args.dt),
           "members": "strip thickness spread evenly over 0.28-0.40 mm",
           "includes": "MJX rollout only (vmap over members, scan over RK4 steps); MJCF "
                       "compilation, initial states and torques (at each step's midpoint) "
                       "precomputed on the host and not timed",
           "rows": []}

    # the reference for member 0's error: the library's L2 run at tight tolerance
    ref = pj.run_scene(
        "paper-circle",
        base.replace(t=0.28e-3),
        model="double1r",
        options=pj.SceneOptions(
            solver="dopri8", rtol=1e-11, atol=1e-13, t_end=args.t_end, n_out=n_out
        ),
    )
    X_ref = np.asarray(ref.X)

    for B in args.sizes:
        ts = np.linspace(0.28e-3, 0.40e-3, B)
        for dt in args.dt:
            row = _mjx_row(base, ts, dt, args, n_out, X_ref)
            res["rows"].append(row)
            print(json.dumps(row), flush=True)
        params = (base.replace(t=float(ts[0])) if B == 1 else
                  pj.stack_params([base.replace(t=float(t)) for t in ts]))
        for rtol in args.rtols:
            r = pj.run_scene("paper-circle", params, model="double1r", repeats=args.repeats,
                             options=pj.SceneOptions(rtol=rtol, atol=rtol * 1e-2,
                                                     t_end=args.t_end, n_out=n_out))
            X0 = np.asarray(r.X if B == 1 else r.X[0])
            e = float(np.max(np.linalg.norm(X0[:, :2] - X_ref[:, :2], axis=-1)))
            prow = {"tool": "ppr_jax", "batch": B, "rtol": rtol,
                    "compile_s": r.timing["compile_s"], "run_s": r.timing["run_s"],
                    "per_robot_ms": r.timing["run_s"] / B * 1e3,
                    "trajectories_per_s": B / r.timing["run_s"],
                    "member0_position_error_m": e}
            res["rows"].append(prow)
            print(json.dumps(prow), flush=True)
        with open(out_path, "w") as fh:
            json.dump(res, fh, indent=2)
        plot(res, out_path[:-5] + ".png")


if __name__ == "__main__":
    main()
