"""`ppr-jax design` in a first process and a second: what a designer waits.

The specification is `benchmarks/design.py --robot`'s: the strips' t in [0.2, 0.6] mm for the
highest locked frequency (L2, home) with the strips' peak PRB stress over the first 0.5 s of
servo-circle (51 output times) at most 250 MPa, 2 starts from 8 candidates, a 64-point grid and
the L3 re-score (N = 4). Each repeat runs `ppr-jax design --spec` in a fresh process on an empty
cache directory (first), then again on that cache (second): the program store and JAX's
persistent cache as a user's second run finds them. With `--base CHECKOUT` the same runs of a
second checkout are interleaved with this one's (one interpreter, the checkouts on
`PYTHONPATH`, as `latency.py`). Recorded: the wall of each process (minimum of the repeats),
`Design.timing` of the fastest, the optimum's t (the checkouts must agree to rounding), and
second over first. `--closed-form` times the closed-form tier 1 instead (no scene: seconds,
for a quick check). Writes benchmarks/results/design_latency.json.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time

from latency import CLI, Checkout, machine

HERE = os.path.dirname(os.path.abspath(__file__))
OUT = os.path.join(HERE, "results", "design_latency.json")

SCENE_SPEC = """[variables]
t = [2e-4, 6e-4]

[objective]
maximize = "base_frequency_hz"

[[constraints]]
metric = "strip_stress_peak_Pa"
upper = 250e6

[settings]
scene = "servo-circle"
t_end = 0.5
n_out = 51
starts = 2
candidates = 8
grid = 64
"""

CLOSED_FORM_SPEC = """[variables]
t = [1e-4, 1e-3]
r = [0.01, 0.04]
w = [0.01, 0.03]

[objective]
maximize = "pivot_frequency_hz"

[[constraints]]
metric = "pivot_stress_Pa"
upper = 1e8

[settings]
stroke = 0.3
"""


def one(c: Checkout, spec: str) -> dict:
    """A first and a second process of `ppr-jax design --spec` on one fresh cache."""
    d = tempfile.mkdtemp(prefix="ppr_jax_design_latency_")
    try:
        path = os.path.join(d, "spec.toml")
        with open(path, "w") as f:
            f.write(spec)
        out = {}
        for kind in ("first", "second"):
            r = c.run(CLI, ["design", "--spec", path, "--out", os.path.join(d, kind)],
                      env={"PPR_JAX_CACHE_DIR": os.path.join(d, "cache")})
            with open(os.path.join(d, kind, "design.json")) as f:
                res = json.load(f)
            out[kind] = {"wall_s": r["wall_s"], "ppr_jax_checked": r["checked"],
                         "timing": res["timing"], "x": res["x"],
                         "objective": res["objective"]["value"]}
        store = os.path.join(d, "cache", "ppr_jax_programs")
        out["stored"] = sorted(os.listdir(store)) if os.path.isdir(store) else []
        return out
    finally:
        shutil.rmtree(d, ignore_errors=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--new", default=os.path.dirname(HERE), help="the checkout measured")
    ap.add_argument("--base", default=None, help="a second checkout to compare against")
    ap.add_argument("--python", default=sys.executable)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--closed-form", action="store_true",
                    help="the closed-form tier 1 instead of the scene design")
    ap.add_argument("--out", default=OUT)
    args = ap.parse_args(argv)
    spec = CLOSED_FORM_SPEC if args.closed_form else SCENE_SPEC
    pycache = tempfile.mkdtemp(prefix="ppr_jax_design_latency_pycache_")
    checkouts = ([Checkout("base", args.base, args.python, pycache)] if args.base else [])
    checkouts.append(Checkout("new", args.new, args.python, pycache))
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    runs = {c.label: [] for c in checkouts}
    try:
        for c in checkouts:  # bytecode for every module, untimed
            c.run(CLI, ["--help"])
        for i in range(args.repeats):
            for c in checkouts:
                r = one(c, spec)
                runs[c.label].append(r)
                print(f"{i} {c.label}: first {r['first']['wall_s']:.1f} s, second "
                      f"{r['second']['wall_s']:.1f} s", flush=True)
    finally:
        shutil.rmtree(pycache, ignore_errors=True)
    rows = {}
    for label, rs in runs.items():
        best = {k: min(rs, key=lambda r: r[k]["wall_s"])[k] for k in ("first", "second")}
        rows[label] = {
            "first_wall_s": best["first"]["wall_s"], "second_wall_s": best["second"]["wall_s"],
            "second_over_first": best["second"]["wall_s"] / best["first"]["wall_s"],
            "first_walls_s": [r["first"]["wall_s"] for r in rs],
            "second_walls_s": [r["second"]["wall_s"] for r in rs],
            "first_timing": best["first"]["timing"], "second_timing": best["second"]["timing"],
            "x": best["first"]["x"], "objective": best["first"]["objective"],
            "stored": rs[0]["stored"],
        }
    data = {
        "machine": machine(), "load_average": {"start": load0, "end": os.getloadavg()},
        "checkouts": {c.label: c.describe() for c in checkouts},
        "spec": spec, "what": ("wall of `ppr-jax design --spec` in a fresh process on an empty "
                               "cache (first) and again on it (second); minimum of the "
                               "repeats, checkouts interleaved"),
        "repeats": args.repeats, "duration_s": time.perf_counter() - t0, "rows": rows,
    }
    if "base" in rows:
        b, n = rows["base"], rows["new"]
        data["x_rel_diff"] = {k: abs(n["x"][k] - b["x"][k]) / abs(b["x"][k]) for k in n["x"]}
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(data, f, indent=1)
    for label, r in rows.items():
        print(f"{label}: first {r['first_wall_s']:.1f} s, second {r['second_wall_s']:.1f} s "
              f"(ratio {r['second_over_first']:.2f})")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
