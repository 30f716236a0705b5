"""`ppr-jax design --spec SPEC.toml`: a design with gradients, its report and the designed
robot's parameter file."""

from __future__ import annotations

import os
import sys

from ._common import _log, _out_dir


def cmd_design(args):
    from .._errors import DesignError
    from .._params import parse_value
    from .._scenes import SceneOptions
    from .._studies import design, load_design_spec
    from ._common import _parse_sets, check_commands_from_args, scene_from_args

    spec = load_design_spec(args.spec)
    settings = dict(spec["settings"])
    scene = settings.get("scene")
    spec_options = dict(spec["options"])
    if getattr(args, "path", None) is not None:
        # your own experiment: the scene of --path (and its command log), as `simulate` runs it
        if scene is not None:
            raise DesignError(f"{args.spec}: [settings] scene = {scene!r} and --path name two "
                              f"scenes; give one")
        args.torque_model = settings.pop("torque_model", None)
        args.t_end = spec_options.get("t_end")
        scene = settings["scene"] = scene_from_args(args)
        spec_options["t_end"] = args.t_end
    path = args.params_file or spec["params_file"]
    base = _parse_sets(None, scene if scene is not None else "modes", path)
    base = base.replace(**spec["params"])
    sets = {}
    for item in args.set or []:
        name, _, value = item.partition("=")
        sets[name.strip()] = parse_value(name.strip(), value)
    base = base.replace(**sets)
    if getattr(args, "path", None) is not None:
        check_commands_from_args(scene, base, args)
    options = SceneOptions().updated(**spec_options) if spec_options else None
    _out_dir(args.out)
    _log(f"design: {', '.join(spec['variables'])} ... compiling and optimising")
    try:
        d = design(spec["variables"], spec["objective"], spec["constraints"], params=base,
                   options=options, program_dir=getattr(args, "program_dir", None), **settings)
    except DesignError as err:
        if err.result is None:
            raise
        # computed but not to be trusted: written and marked (design.json's "feasible",
        # the report's and designed.toml's INFEASIBLE line), not withheld; the exit status 2
        d = err.result
        written = _write(d, args)
        raise DesignError(f"{err} (written, marked INFEASIBLE: {', '.join(written)})") from None
    report, page, robot, mjcf = _write(d, args)
    print(d.summary())
    print(f"wrote {report}, {page}, {robot} (ppr-jax ... --params-file {robot}), {mjcf} (MJCF)")
    return 0


def _write(d, args) -> list:
    """Write a design's design.json, report.html and designed.toml under --out, and for a
    feasible one its MJCF designed.xml (a model file carries no warning). Returns the paths."""
    out = [d.save(os.path.join(args.out, "design.json")),
           d.report(os.path.join(args.out, "report.html"),
                    command="ppr-jax " + " ".join(sys.argv[1:]) if sys.argv else None),
           d.to_params_file(os.path.join(args.out, "designed.toml"))]
    if d.feasible:
        out.append(d.to_mjcf(os.path.join(args.out, "designed.xml")))
    return out


def add_design(sub, parents, fmt):
    d = sub.add_parser(
        "design", formatter_class=fmt, parents=[parents["params"], parents["files"]],
        help="design with gradients: optimise RobotParams fields against a specification",
        description="Optimise design variables (RobotParams fields with bounds) for an "
                    "objective subject to constraints, read from a TOML specification "
                    "(docs/design.md), verify the optimum, and write design.json, "
                    "report.html, the designed robot's parameter file designed.toml and its "
                    "MJCF designed.xml. With --path (and --angles or --torques), the scene is "
                    "your own experiment, as `simulate --path` runs it. The metrics: "
                    "ppr_jax.CATALOGUE (docs/design.md, 'The catalogue').")
    d.add_argument("--spec", required=True, metavar="SPEC.toml",
                   help="the design specification ([variables], [objective], [[constraints]] "
                        "with upper, lower or avoid = [lo, hi], [settings], [params])")
    d.add_argument("--out", default="design_out", help="output directory")
    d.set_defaults(func=cmd_design)
