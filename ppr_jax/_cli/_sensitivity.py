"""`ppr-jax sensitivity`: derivatives of a scene's metrics with respect to the parameters."""

from __future__ import annotations

import json
import math
import os

from .._files import write_file
from .._names import KINEMATIC_MODELS, MODEL_NAMES, SENSITIVITY_METRICS
from ._common import (
    _log,
    _out_dir,
    _write_rows,
    scene_command,
)


def cmd_sensitivity(args):
    from .._studies import allowed_metrics, sensitivity
    from ._common import (
        _parse_sets,
        check_commands_from_args,
        model_from_args,
        options_from_args,
        scene_from_args,
    )

    scene = scene_from_args(args)
    params = _parse_sets(args.set, scene, getattr(args, "params_file", None))
    check_commands_from_args(scene, params, args)
    _out_dir(args.out)
    names = None
    if args.params:
        names = [s.strip() for s in args.params.split(",") if s.strip()]
    metrics = None  # the scene path's default
    if args.metrics:
        metrics = tuple(s.strip() for s in args.metrics.split(",") if s.strip())
    # Names checked before the (long) compilation starts.
    from .._studies import FLOAT_PARAMS

    for n in names or []:
        if n not in FLOAT_PARAMS:
            raise ValueError(f"unknown parameter {n!r}; allowed: {', '.join(FLOAT_PARAMS)}")
    allowed = allowed_metrics(scene.trajectory(), "sensitivity")
    for m in metrics or ():
        if m not in allowed:
            raise ValueError(f"unknown metric {m!r}; allowed: {', '.join(allowed)}")
    from .._scenes import check_scene_args

    check_scene_args(args.t_end, args.n_out, args.rtol, args.atol, args.max_steps)
    _log(f"sensitivity {scene.name} ({args.model}, {args.mode} mode): compiling and running ...")
    s = sensitivity(
        scene, params, mode=args.mode, model=model_from_args(args, args.model),
        frequency_model=args.frequency_model,
        parameters=names, metrics=metrics, options=options_from_args(args),
        program_dir=getattr(args, "program_dir", None),
    )
    rows = s.rows()
    cols = ["metric", "parameter", "metric_value", "parameter_value", "derivative", "normalized"]
    _write_rows(os.path.join(args.out, "sensitivity.csv"), rows, cols)
    with write_file(os.path.join(args.out, "sensitivity.json")) as f:
        clean = [{k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                  for k, v in r.items()} for r in rows]
        json.dump({"settings": s.info, "mode": s.mode, "timing": s.timing, "values": s.values,
                   "parameters": s.param_values, "rows": clean}, f, indent=2)
    print(f"\nNormalised sensitivities (p / m) dm/dp, scene {scene.name}, model {s.info['model']} "
          f"(input of {s.info['input_model']}; base frequency of {s.info['frequency_model']}, "
          f"locked), {s.mode} mode")
    for line in header_lines(s.metrics):
        print(line)
    print(f"{'value':>10s} " + " ".join(f"{s.values[m]:{WIDTH}.6g}" for m in s.metrics))
    for j, p in enumerate(s.parameters):
        print(f"{p:>10s} " + " ".join(f"{s.normalized[i, j]:{WIDTH}.4g}"
                                      for i in range(len(s.metrics))))
    print(f"compile {s.timing['compile_s']:.1f} s, run (values and derivatives) "
          f"{s.timing['run_s'] * 1e3:.1f} ms")
    print(f"wrote {args.out}/sensitivity.csv, sensitivity.json")
    return 0


#: width of a metric's column in the printed table (a header line at most one less: two spaces
#: between columns)
WIDTH = 15


def header_lines(metrics) -> list:
    """The printed table's header: each metric's whole name (underscores as spaces) wrapped
    over as many lines as the longest needs, right-aligned in its column of `WIDTH` and
    bottom-aligned above its numbers, "parameter" on the last line. (Cut to the column's width,
    radial_error_max_m and radial_error_min_m both read "radial error m".)"""
    import textwrap

    wrapped = [textwrap.wrap(m.replace("_", " "), WIDTH - 1) for m in metrics]
    n = max((len(w) for w in wrapped), default=1)
    wrapped = [[""] * (n - len(w)) + w for w in wrapped]
    lines = []
    for k in range(n):
        head = "parameter" if k == n - 1 else ""
        lines.append((f"{head:>10s} " + " ".join(f"{w[k]:>{WIDTH}s}" for w in wrapped)).rstrip())
    return lines


def add_sensitivity(sub, parents, fmt):
    kinematic = list(KINEMATIC_MODELS)
    s = scene_command(
        sub, "sensitivity", parents, fmt,
        help="normalised sensitivities (p/m) dm/dp of the paper's metrics to every parameter",
        description="d(metric)/d(parameter) of " + ", ".join(SENSITIVITY_METRICS) + " by "
                    "automatic differentiation through the scene (forward or reverse mode), "
                    "printed as normalised sensitivities and written to sensitivity.csv/json.",
        model_help="the model whose response is measured (L0 or L1 under its own torques "
                   "follows the circle exactly: its radial error is the solver's, and is "
                   "refused)",
        torque_help="the model whose inverse dynamics (or kinematics) gives a torque-driven "
                    "scene's torques (or a --path's input without a command log)")
    s.add_argument("--frequency-model", default="double1r",
                   choices=[n for n in MODEL_NAMES if n not in kinematic],
                   help="the model whose first locked natural frequency is the base frequency")
    s.add_argument("--mode", default="fwd", choices=["fwd", "rev"],
                   help="forward (jacfwd) or reverse (jacrev) mode")
    s.add_argument("--params", default=None, help="comma list of parameters (default: all)")
    s.add_argument("--metrics", default=None, help="comma list of metrics (default: all)")
    s.add_argument("--out", required=True, help="output directory")
    s.set_defaults(func=cmd_sensitivity)
