"""`ppr-jax modes`: natural frequencies about a static equilibrium."""

from __future__ import annotations

import json

from .._names import MODEL_NAMES
from ._common import (
    _parse_sets,
    model_from_args,
)


def cmd_modes(args):
    from .._scenes import modes_scene

    params = _parse_sets(args.set, "modes", getattr(args, "params_file", None))
    X = None if args.pose is None else [float(v) for v in args.pose.split(",")]
    r = modes_scene(params, model=model_from_args(args, args.model), actuators=args.actuators,
                    X=X, program_dir=getattr(args, "program_dir", None))
    if args.json:
        print(json.dumps(r, indent=2))
    else:
        f = ", ".join(f"{x:.6g}" for x in r["frequencies_hz"]) or "none"
        print(f"{r['model']} actuators {r['actuators']}: {f} Hz\n{r['note']}")
    return 0


def _add_modes(sub, parents, fmt):
    m = sub.add_parser("modes", formatter_class=fmt,
        parents=[parents["params"], parents["model"]],
        help="natural frequencies about a static equilibrium (Hz)")
    m.add_argument("--model", default="double1r", choices=list(MODEL_NAMES))
    m.add_argument("--actuators", default="locked", choices=["locked", "free"])
    m.add_argument("--pose", default=None, help="x,y,phi (default: home)")
    m.add_argument("--json", action="store_true")
    m.set_defaults(func=cmd_modes)
