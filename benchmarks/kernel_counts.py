"""Where reverse mode's cost goes on a CPU: XLA kernels launched, forward run against `jax.grad`.

The L1 `paper-circle` sensitivity (`benchmarks/sensitivity_cost.py`: 7.54 s, rtol 1e-8, L1 under
the rigid model's torques, the scalar `radial_error_min_m` of all 19 parameters) is made of kernels
of a few dozen numbers each, so its time is set by how many kernels XLA's CPU runtime launches, not
by arithmetic.
This script counts them two ways and writes benchmarks/results/kernel_counts.json:

- whole programs: the kernel events of one call of the compiled forward run and of its `grad`,
  from JAX's profiler trace (leaf kernels only: loops and conditionals are containers);
- one right-hand side (the scene's vector field at one state, torques from the scene's table): its
  compiled XLA operations (fusions, dots, copies) in the forward evaluation, a JVP (one tangent of
  the state) and a VJP (cotangents of the state and the robot), with the number of those fusions
  whose root is a zero-padding op (`pad`: the transpose of a slice), and its time per call inside
  a `lax.scan` of 2,000 calls (minimum of repeats).

Run: python benchmarks/kernel_counts.py [--model reduced] [--repeats 25]
"""

from __future__ import annotations

import argparse
import collections
import glob
import json
import os
import platform
import re
import tempfile
import time

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp

from ppr_jax._actuation import InverseDynamicsTorque, TorqueDriven
from ppr_jax._models import get_model
from ppr_jax._robot import Robot
from ppr_jax._scenes import input_panels, scene_params, tabulated as _tabulated_input
from ppr_jax._simulate import _vector_field
from ppr_jax._statics import quasi_static_core
from ppr_jax._studies import explicit_params, metric_function
from ppr_jax._trajectory import Circle

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")
#: profiler events that contain kernels rather than being one
CONTAINERS = ("while", "cond", "Thunk", "call", "end:")


def _kernel_events(compiled, x) -> int:
    """Leaf kernel events of one call of `compiled(x)` in JAX's profiler trace."""
    from jax.profiler import ProfileData

    for _ in range(3):
        jax.block_until_ready(compiled(x))
    with tempfile.TemporaryDirectory() as d:
        with jax.profiler.trace(d):
            jax.block_until_ready(compiled(x))
        pb = glob.glob(f"{d}/**/*.xplane.pb", recursive=True)[0]
        data = ProfileData.from_file(pb)
    n = 0
    for plane in data.planes:
        for line in plane.lines:
            if "python" in line.name:
                continue
            n += sum(1 for ev in line.events if not ev.name.startswith(CONTAINERS))
    return n


def _ops(compiled_text: str) -> dict:
    """Operations of the entry computation that run as kernels, and the pad-rooted fusions."""
    entry = compiled_text[compiled_text.index("ENTRY"):]
    ops = collections.Counter()
    pads = 0
    for line in entry.splitlines()[1:]:
        m = re.match(r"\s*(?:ROOT )?%?\S+ = \S+ (\w[\w-]*)\(", line)
        if m:
            ops[m.group(1)] += 1
        if " fusion(" in line and '/pad"' in line:
            pads += 1
    free = ("parameter", "constant", "bitcast", "get-tuple-element", "tuple")
    return {"kernels": sum(v for k, v in ops.items() if k not in free), "pad_fusions": pads,
            "dots": ops.get("dot", 0)}


def _min_time(fn, args, repeats):
    jax.block_until_ready(fn(*args))
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(fn(*args))
        best = min(best, time.perf_counter() - t)
    return best


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="reduced")
    ap.add_argument("--repeats", type=int, default=25)
    ap.add_argument("--out", default="kernel_counts.json")
    args = ap.parse_args()
    os.makedirs(OUT, exist_ok=True)
    out = {"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
           "jax": jax.__version__, "diffrax": diffrax.__version__,
           "backend": jax.default_backend(), "model": args.model, "torque_model": "rigid",
           "xla_flags": os.environ.get("XLA_FLAGS", "")}

    # Whole programs.
    f, x0, _ = metric_function("paper-circle", model=args.model, torque_model="rigid",
                               rtol=1e-8, atol=1e-10,
                               metrics=("radial_error_min_m",))
    progs = {"forward_run": jax.jit(lambda x: f(x)[0]),
             "grad": jax.jit(jax.grad(lambda x: f(x)[0]))}
    out["programs"] = {}
    for name, fn in progs.items():
        c = fn.lower(x0).compile()
        out["programs"][name] = {"kernel_events": _kernel_events(c, x0),
                                 "run_s": _min_time(c, (x0,), args.repeats)}
    fwd = out["programs"]["forward_run"]
    for row in out["programs"].values():
        row["kernels_per_forward"] = row["kernel_events"] / fwd["kernel_events"]
        row["time_per_forward"] = row["run_s"] / fwd["run_s"]
    print(json.dumps(out["programs"], indent=1), flush=True)

    # One right-hand side, at the scene's initial state.
    model, torque_model = get_model(args.model), get_model("rigid")
    robot = Robot(explicit_params(scene_params("paper-circle")))
    traj, t_end = Circle(), 7.54
    ts = jnp.linspace(0.0, t_end, 755)
    torque, _, _ = _tabulated_input(InverseDynamicsTorque(torque_model, robot, traj), ts,
                                    input_panels(traj, t_end, 755))
    act = TorqueDriven(torque)
    z0, zd0, _ = quasi_static_core(model, robot, traj, ts[0], act)
    y0, w = (z0, zd0), jnp.zeros(3)

    def vf(r, y, t):
        return _vector_field(model, r, act, w, None, t, y)

    def jvp(r, y, t):
        return jax.jvp(lambda yy: vf(r, yy, t), (y,), (y,))

    def vjp(r, y, t):
        out_, pull = jax.vjp(lambda rr, yy: vf(rr, yy, t), r, y)
        return pull(out_)

    n_calls = 2000
    times = jnp.linspace(0.0, 7.0, n_calls)

    def scanned(fn, pick):
        # A carry that depends on each call's result, so that none is hoisted out of the loop.
        def run(r, y):
            def body(c, t):
                res = fn(r, (y[0] + c * 1e-9, y[1]), t)
                return c + pick(res) * 1e-12, None

            return jax.lax.scan(body, 0.0, times)[0]

        return eqx.filter_jit(run)

    picks = {"forward": (vf, lambda d: d[1][0]), "jvp": (jvp, lambda d: d[1][1][0]),
             "vjp": (vjp, lambda g: g[1][0][0])}
    out["rhs"] = {}
    for name, (fn, pick) in picks.items():
        text = eqx.filter_jit(fn).lower(robot, y0, 1.0).compile().compiled.as_text()
        row = _ops(text)
        row["us_per_call"] = _min_time(scanned(fn, pick), (robot, y0), args.repeats) / n_calls * 1e6
        out["rhs"][name] = row
    for row in out["rhs"].values():
        row["kernels_per_forward"] = row["kernels"] / out["rhs"]["forward"]["kernels"]
    print(json.dumps(out["rhs"], indent=1), flush=True)
    path = os.path.join(OUT, args.out)
    with open(path, "w") as fh:
        json.dump(out, fh, indent=2)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
