"""Sharded sweep against one device: the L1 `paper-circle` over strip thickness.

Runs in one process with N host devices (it sets XLA_FLAGS before importing JAX): the same sweep
(`--members` robots, chunks of `--chunk`) on one device and split over N devices with
`shard_map`; checks that the two agree member by member and reports compile and run times (run:
the minimum of `--repeats` sweeps after the first). Writes benchmarks/results/sweep_sharding.json.

Run: python benchmarks/sweep_sharding.py [--devices 2] [--members 64] [--chunk 64] [--t-end 7.54]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--devices", type=int, default=2)
    ap.add_argument("--members", type=int, default=64)
    ap.add_argument("--chunk", type=int, default=64)
    ap.add_argument("--t-end", type=float, default=7.54)
    ap.add_argument("--rtol", type=float, default=1e-8)
    ap.add_argument("--model", default="reduced")
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args()
    if "jax" in sys.modules:
        raise RuntimeError("run as a script: XLA_FLAGS must be set before JAX is imported")
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") +
                               f" --xla_force_host_platform_device_count={args.devices}")
    import jax
    import numpy as np

    import ppr_jax as pj

    vary = {"t": np.linspace(0.28e-3, 0.40e-3, args.members)}
    kw = dict(model=args.model, chunk_size=args.chunk, options=pj.SceneOptions(
        t_end=args.t_end, n_out=755, rtol=args.rtol, atol=args.rtol * 1e-2))
    out = {"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
           "jax": jax.__version__, "backend": jax.default_backend(), "devices": args.devices,
           "members": args.members, "chunk": args.chunk, "t_end_s": args.t_end,
           "model": args.model, "rtol": args.rtol, "rows": {}}
    results = {}
    for name, devs in (("one_device", None), ("sharded", jax.devices()[: args.devices])):
        t0 = time.perf_counter()
        r = pj.sweep("paper-circle", vary=vary, devices=devs, **kw)
        first = time.perf_counter() - t0
        runs = []
        for _ in range(args.repeats):
            t1 = time.perf_counter()
            r = pj.sweep("paper-circle", vary=vary, devices=devs, **kw)
            runs.append(time.perf_counter() - t1 - r.timing["validate_s"])
        run = min(runs)
        results[name] = r
        out["rows"][name] = {"first_call_s": first, "run_s": run,
                             "per_member_ms": run / args.members * 1e3,
                             "trajectories_per_s": args.members / run}
        print(name, json.dumps(out["rows"][name]), flush=True)
    diff = max(abs(a[m] - b[m]) for a, b in zip(results["one_device"].rows,
                                                results["sharded"].rows)
               for m in ("radial_error_max_m", "radial_error_min_m"))
    out["max_abs_difference_m"] = diff
    out["speedup"] = out["rows"]["one_device"]["run_s"] / out["rows"]["sharded"]["run_s"]
    print(f"speed-up {out['speedup']:.2f}x, max difference {diff:.2e} m")
    path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results",
                        "sweep_sharding.json")
    with open(path, "w") as f:
        json.dump(out, f, indent=2)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
