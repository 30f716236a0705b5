"""`ppr-jax torques`: the inverse-dynamics torques along the nominal path as CSV."""

from __future__ import annotations

import csv
import os

from .._files import write_file
from .._names import KINEMATIC_MODELS
from ._common import (
    _parse_sets,
    check_out_dir,
)


def cmd_torques(args):
    import numpy as np

    from .._scenes import nominal_torques

    params = _parse_sets(args.set, "paper-circle", getattr(args, "params_file", None))
    check_out_dir(args.out)
    ts, tau = nominal_torques(params, model=args.model, t_end=args.t_end, n_out=args.n_out,
                              program_dir=getattr(args, "program_dir", None))
    path = os.path.join(args.out, "torques.csv")
    with write_file(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["t", "tau_1", "tau_2", "tau_3"])
        for k in range(len(ts)):
            w.writerow([float(ts[k]), *tau[k]])
    print(f"max |tau| = {np.abs(tau).max():.6g} N m; wrote {path}")
    return 0


def _add_torques(sub, parents, fmt):
    kinematic = list(KINEMATIC_MODELS)
    t = sub.add_parser("torques", formatter_class=fmt,
        parents=[parents["params"], parents["circle_times"]],
        help="inverse-dynamics torques along eq 55 as CSV")
    t.add_argument("--model", default="reduced", choices=kinematic,
                   help="the kinematic model (L0 rigid, L1 reduced) whose inverse dynamics "
                        "gives the torques")
    t.add_argument("--out", required=True, metavar="DIR",
                   help="output directory: DIR/torques.csv (t, tau_1..tau_3 in s and N m)")
    t.set_defaults(func=cmd_torques)
