"""Full L3 (strip inertia and modes kept) against L3 with quasi-static strips on a short window.

paper-circle (t = 0.3 mm, L1's centre-line torques) over the first T seconds (default 0.2 s), both
from the same quasi-static initial state, at N = 4 and 8: the largest distance between the two
platforms, their radial errors, and the run times (Tsit5, rtol 1e-8; the full model is
stiff: its step is set by the strip modes, kHz). Compare the difference with the L2-L3
differences of `l3_validation.py`. Writes benchmarks/results/l3_full_vs_quasi_static.json.
Run: python benchmarks/l3_full_vs_quasi_static.py [--t-end 0.2] (about 5 min on two cores).
"""

from __future__ import annotations

import argparse
import json
import pathlib

import numpy as np

import ppr_jax as pj

OUT = pathlib.Path(__file__).parent / "results"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--t-end", type=float, default=0.2)
    ap.add_argument("--elements", default="4,8")
    args = ap.parse_args()
    params = pj.scene_params("paper-circle")
    n_out = int(round(args.t_end * 500)) + 1
    rows = []
    for N in (int(n) for n in args.elements.split(",")):
        res = {}
        for kind, model in (("quasi-static", pj.QuasiStaticBeam(N)), ("full", pj.Beam(N))):
            r = pj.run_scene(
                "paper-circle",
                params,
                model=model,
                options=pj.SceneOptions(
                    t_end=args.t_end,
                    n_out=n_out,
                    solver="tsit5",
                    rtol=1e-8,
                    atol=1e-10,
                    max_steps=2_000_000,
                ),
            )
            res[kind] = r
            print(N, kind, r.timing, int(r.result.num_steps), flush=True)
        Xq, Xf = (np.asarray(res[k].result.X) for k in ("quasi-static", "full"))
        row = dict(
            N=N, t_end_s=args.t_end,
            platform_distance_max_m=float(np.max(np.hypot(*(Xq[:, :2] - Xf[:, :2]).T))),
            phi_difference_max_rad=float(np.max(np.abs(Xq[:, 2] - Xf[:, 2]))),
            platform_displacement_from_nominal_max_m=float(np.max(np.hypot(
                *(Xq[:, :2] - np.asarray(res["quasi-static"].result.X_nominal)[:, :2]).T))),
            run_s={k: res[k].timing["run_s"] for k in res},
            compile_s={k: res[k].timing["compile_s"] for k in res},
            steps={k: int(res[k].result.num_steps) for k in res},
        )
        rows.append(row)
        print(json.dumps(row), flush=True)
        OUT.mkdir(parents=True, exist_ok=True)
        (OUT / "l3_full_vs_quasi_static.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
