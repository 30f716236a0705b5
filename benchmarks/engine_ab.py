"""The engine's speed rows, this tree against another checkout, in one run on one machine.

    python benchmarks/engine_ab.py --checkout /path/to/base [--label-base c4893c8] [--quick]

Each measurement runs in a fresh process per checkout (``PYTHONPATH`` set to it), base and this
tree interleaved, each pair twice; a row keeps the minimum of each side:

- `run`: warm `paper-circle` (7.54 s, the scene's default options) of L0, L1, L2 and the
  quasi-static L3 (N = 4): the fastest of 5 runs after the compiled first one, and its steps;
- `batch`: L1 batches of 1,024 and L2 of 64 (strip thickness over 0.28-0.40 mm), at the batch
  benchmark's settings (rtol 1e-6, atol 1e-8) and at the scene's defaults: trajectories/s;
- `sensitivity`: L2 `paper-circle` over 1 s, the default metrics with respect to every float
  parameter, forward and reverse mode, against the forward run of the same options;
- `compile`: the first `solve_scene` of L0-L2 in a process with no persistent cache (tracing,
  lowering and XLA's compilation: what a user waits for before the first answer).

Writes `benchmarks/results/engine_ab.json` (each row: base, new, new/base and, where the
issue sets one, the goal and whether it is met).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

_PRELUDE = r"""
import json, os, sys, time
import jax
jax.config.update("jax_enable_x64", True)
import numpy as np
import ppr_jax as pj

def best(fn, repeats):
    out = fn(); jax.block_until_ready(out)
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter(); out = fn(); jax.block_until_ready(out)
        ts.append(time.perf_counter() - t0)
    return min(ts), out
"""

_RUN = _PRELUDE + r"""
models = sys.argv[1].split(",")
out = {}
for m in models:
    model = pj.QuasiStaticBeam(4) if m == "beam_qs" else m
    o = pj.SceneOptions()
    s, r = best(lambda: pj.solve_scene("paper-circle", model=model, options=o), 5)
    out[m] = dict(run_s=s, steps=int(r.num_steps))
print(json.dumps(out))
"""

_BATCH = _PRELUDE + r"""
model, B, mode = sys.argv[1], int(sys.argv[2]), sys.argv[3]
base = pj.scene_params("paper-circle")
ps = pj.stack_params([base.replace(t=float(t)) for t in np.linspace(0.28e-3, 0.40e-3, B)])
o = (pj.SceneOptions(rtol=1e-6, atol=1e-8, max_steps=400_000) if mode == "bench"
     else pj.SceneOptions())
s, r = best(lambda: pj.solve_scene("paper-circle", ps, model=model, options=o), 2)
print(json.dumps(dict(run_s=s, trajectories_per_s=B / s, ok=bool(np.all(np.asarray(r.ok))))))
"""

_SENS = _PRELUDE + r"""
o = pj.SceneOptions(t_end=1.0, n_out=101)
fwd, _ = best(lambda: pj.solve_scene("paper-circle", model="double1r", options=o), 5)
out = dict(forward_run_s=fwd)
for mode in ("fwd", "rev"):
    runs = [pj.sensitivity("paper-circle", model="double1r", mode=mode, options=o)
            for _ in range(3)]
    out[mode + "_run_s"] = min(s.timing["run_s"] for s in runs)
print(json.dumps(out))
"""

_COMPILE = _PRELUDE + r"""
m = sys.argv[1]
o = pj.SceneOptions()
t0 = time.perf_counter()
r = pj.solve_scene("paper-circle", model=m, options=o)
jax.block_until_ready(r)
print(json.dumps(dict(first_s=time.perf_counter() - t0)))
"""


def _probe(checkout: str, snippet: str, *args, timeout=1800) -> dict:
    env = dict(os.environ, PYTHONPATH=checkout, EQX_ON_ERROR="nan", JAX_ENABLE_X64="1")
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    env.pop("PPR_JAX_CACHE_DIR", None)
    p = subprocess.run([sys.executable, "-c", snippet, *map(str, args)], capture_output=True,
                       text=True, env=env, timeout=timeout, cwd=checkout)
    if p.returncode != 0:
        return {"failed": (p.stderr.strip().splitlines() or ["?"])[-1]}
    return json.loads(p.stdout.strip().splitlines()[-1])


def _pair(base: str, new: str, snippet: str, *args, rounds: int = 2):
    """(base, new) results of `snippet`, interleaved `rounds` times; numbers keep their
    minimum (or maximum for a rate)."""
    got = {"base": [], "new": []}
    for _ in range(rounds):
        got["base"].append(_probe(base, snippet, *args))
        got["new"].append(_probe(new, snippet, *args))
    return tuple(_merge(got[k]) for k in ("base", "new"))


def _merge(results: list):
    ok = [r for r in results if "failed" not in r]
    if not ok:
        return results[0]
    out = {}
    for k, v in ok[0].items():
        vals = [r[k] for r in ok]
        if isinstance(v, dict):
            out[k] = _merge(vals)
        elif isinstance(v, (bool, int)):  # flags and step counts: the same in every run
            out[k] = v
        elif isinstance(v, float):
            out[k] = max(vals) if k.endswith("per_s") else min(vals)
        else:
            out[k] = v
    return out


def _row(name, base, new, key, goal=None, higher_is_better=False):
    b, n = base.get(key), new.get(key)
    row = {"row": name, "base": b, "new": n}
    if isinstance(b, (int, float)) and isinstance(n, (int, float)) and b:
        row["new_over_base"] = n / b
        if goal is not None:
            row["goal"] = goal
            row["met"] = bool(n / b >= goal if higher_is_better else n / b <= goal)
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkout", required=True, help="the base checkout (a git worktree)")
    ap.add_argument("--new", default=ROOT, help="the new checkout (default: this tree)")
    ap.add_argument("--label-base", default=None, help="the base's commit (default: its HEAD)")
    ap.add_argument("--parts", nargs="+", default=["run", "batch", "sensitivity", "compile"])
    ap.add_argument("--quick", action="store_true", help="L0-L1 only, small batches")
    ap.add_argument("--out", default=os.path.join(HERE, "results", "engine_ab.json"))
    args = ap.parse_args(argv)
    base, new = os.path.abspath(args.checkout), os.path.abspath(args.new)

    def head(path):
        return subprocess.run(["git", "-C", path, "rev-parse", "--short", "HEAD"],
                              capture_output=True, text=True).stdout.strip()

    data = {"machine": {"system": platform.platform(), "cpus": os.cpu_count()},
            "base": args.label_base or head(base), "new": head(new),
            "date": time.strftime("%Y-%m-%d"), "rows": [], "raw": {}}

    def save():
        with open(args.out, "w") as f:
            f.write(json.dumps(data, indent=1) + "\n")

    t0 = time.perf_counter()
    if "run" in args.parts:
        models = "rigid,reduced" if args.quick else "rigid,reduced,double1r,beam_qs"
        b, n = _pair(base, new, _RUN, models)
        data["raw"]["run"] = {"base": b, "new": n}
        for m in models.split(","):
            goal = 0.5 if m == "beam_qs" else 0.2
            row = _row(f"paper-circle {m} warm run (s)", b.get(m, {}), n.get(m, {}), "run_s",
                       goal)
            row["steps"] = [b.get(m, {}).get("steps"), n.get(m, {}).get("steps")]
            data["rows"].append(row)
        save()
    if "batch" in args.parts:
        plan = ([("reduced", 64, "bench")] if args.quick else
                [("reduced", 1024, "bench"), ("reduced", 1024, "defaults"),
                 ("double1r", 64, "defaults")])
        for model, B, mode in plan:
            b, n = _pair(base, new, _BATCH, model, B, mode, rounds=1)
            data["raw"][f"batch-{model}-{B}-{mode}"] = {"base": b, "new": n}
            goal = 5.0 if (model, mode) != ("reduced", "bench") else None
            row = _row(f"batch {model} x{B} ({mode}) trajectories/s", b, n,
                       "trajectories_per_s", goal, higher_is_better=True)
            if (model, mode) == ("reduced", "bench") and isinstance(n.get("trajectories_per_s"),
                                                                     float):
                row["goal_absolute"] = 10_000
                row["met"] = n["trajectories_per_s"] >= 10_000
            data["rows"].append(row)
            save()
    if "sensitivity" in args.parts and not args.quick:
        b, n = _pair(base, new, _SENS, rounds=1)
        data["raw"]["sensitivity"] = {"base": b, "new": n}
        for mode in ("fwd", "rev"):
            rb = b.get(f"{mode}_run_s", float("nan")) / b.get("forward_run_s", float("nan"))
            rn = n.get(f"{mode}_run_s", float("nan")) / n.get("forward_run_s", float("nan"))
            row = {"row": f"sensitivity {mode} / forward run (L2, 1 s)", "base": rb, "new": rn}
            row["goal"] = rb if mode == "fwd" else 3.0
            row["met"] = bool(rn <= row["goal"]) if rn == rn else False
            data["rows"].append(row)
        save()
    if "compile" in args.parts:
        for m in ("rigid", "reduced") if args.quick else ("rigid", "reduced", "double1r"):
            b, n = _pair(base, new, _COMPILE, m, rounds=1)
            data["raw"][f"compile-{m}"] = {"base": b, "new": n}
            data["rows"].append(_row(f"paper-circle {m} first call, no cache (s)", b, n,
                                     "first_s"))
            save()
    data["wall_s"] = time.perf_counter() - t0
    save()
    for r in data["rows"]:
        print(json.dumps(r))


if __name__ == "__main__":
    main()
