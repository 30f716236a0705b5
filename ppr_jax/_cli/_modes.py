"""`ppr-jax modes`: natural frequencies about a static equilibrium."""

from __future__ import annotations

import json

from .._names import MODEL_NAMES
from ._common import (
    _parse_sets,
    frequencies_text,
    model_from_args,
)


def _pose(text):
    """--pose: three comma-separated numbers x,y,phi (m, m, rad), or None."""
    if text is None:
        return None
    parts = text.split(",")
    try:
        X = [float(v) for v in parts]
    except ValueError:
        X = None
    if X is None or len(X) != 3:
        raise ValueError(f"--pose expects x,y,phi: three comma-separated numbers (m, m, rad), "
                         f"e.g. --pose 0.45,0.26,0; got {text!r}")
    return X


def cmd_modes(args):
    from .._scenes import modes_scene

    X = _pose(args.pose)
    params = _parse_sets(args.set, "modes", getattr(args, "params_file", None))
    r = modes_scene(params, model=model_from_args(args, args.model), actuators=args.actuators,
                    X=X, program_dir=getattr(args, "program_dir", None))
    if args.json:
        print(json.dumps(r, indent=2))
    else:
        print(f"{r['model']} actuators {r['actuators']}: "
              f"{frequencies_text(r['frequencies_hz'])}\n{r['note']}")
    return 0


def _add_modes(sub, parents, fmt):
    m = sub.add_parser("modes", formatter_class=fmt,
        parents=[parents["params"], parents["model"]],
        help="natural frequencies about a static equilibrium (Hz)")
    m.add_argument("--model", default="double1r", choices=list(MODEL_NAMES),
                   help="the model linearised about its static equilibrium")
    m.add_argument("--actuators", default="locked", choices=["locked", "free"],
                   help="locked: the actuated angles held (L0 and L1 then have no free "
                        "coordinate); free: zero actuator torque, every coordinate free")
    m.add_argument("--pose", default=None, metavar="x,y,phi",
                   help="the pose near which the equilibrium is sought: x,y,phi in m, m, rad "
                        "(default: home)")
    m.add_argument("--json", action="store_true",
                   help="print the whole result as JSON (frequencies, growth rates of unstable "
                        "modes, eigenvalues, the equilibrium)")
    m.set_defaults(func=cmd_modes)
