"""`ppr-jax synth`: a synthetic measurement file from a scene."""

from __future__ import annotations

import os

from .._names import T_END
from ._common import (
    _log,
    _name_values,
    scene_command,
)


def cmd_synth(args):
    from .._data import write_csv
    from .._scenes import scene_params
    from .._studies import check_synth_args, synthesize
    from ._common import check_commands_from_args, model_from_args, scene_from_args

    scene = scene_from_args(args)
    params = scene_params(scene)
    if getattr(args, "params_file", None):
        from .._params_file import load_params

        params = load_params(args.params_file, params)
    params = params.replace(**_name_values(args.set, "--set"))
    check_commands_from_args(scene, params, args)
    check_synth_args(args.noise_pos, args.noise_phi, args.rate, args.t_end)
    _log(f"synth: {scene.name} with {args.model}, {args.t_end} s at {args.rate} Hz (compiling, "
         f"then running) ...")
    exp = synthesize(scene, model_from_args(args, args.model), params,
                     noise_pos=args.noise_pos, noise_phi=args.noise_phi, rate=args.rate,
                     t_end=args.t_end, seed=args.seed,
                     name=os.path.splitext(os.path.basename(args.out))[0], solver=args.solver,
                     rtol=args.rtol, atol=args.atol, max_steps=args.max_steps,
                     program_dir=getattr(args, "program_dir", None))
    sets = " ".join(args.set or []) or "scene defaults"
    write_csv(args.out, exp, length_unit=args.length_unit, angle_unit=args.angle_unit, comments=[
        f"synthetic tracker data from ppr_jax: scene {scene.name}, model {args.model}, "
        f"parameters: {sets}",
        f"Gaussian noise: {args.noise_pos:g} m on x and y, {args.noise_phi:g} rad on phi, seed "
        f"{args.seed}; {args.rate:g} Hz; th_i noise-free; tau: applied or reaction torques",
    ])
    print(f"wrote {args.out} ({exp.n} samples)")
    return 0


def add_synth(sub, parents, fmt):
    p = scene_command(
        sub, "synth", parents, fmt, uses=("params", "model", "solve", "files"),
        scene="servo-circle",
        help="write a synthetic tracker CSV (a scene plus Gaussian noise)",
        description="Simulate a scene with a model and write what a tracker would record: the "
                    "platform pose at --rate Hz with Gaussian noise (seeded), the actuated "
                    "angles and torques, in the CSV format that 'identify' reads.",
        model_help="the model simulated: its platform poses are what the tracker records",
        torque_help="the model whose inverse dynamics (or kinematics) gives a torque-driven "
                    "scene's torques (or a --path's input without a command log)")
    p.add_argument("--noise-pos", type=float, default=0.1e-3, help="position noise std (m)")
    p.add_argument("--noise-phi", type=float, default=1e-3, help="angle noise std (rad)")
    p.add_argument("--rate", type=float, default=100.0, help="sample rate (Hz)")
    p.add_argument("--t-end", type=float, default=None,
                   help=f"duration (s); default {T_END:g}, or the last time of a --path file")
    p.add_argument("--seed", type=int, default=0, help="random seed of the noise")
    p.add_argument("--length-unit", default="mm", choices=["m", "mm"], help="unit of x, y")
    p.add_argument("--angle-unit", default="rad", choices=["rad", "mrad", "deg"],
                   help="unit of phi and th_i")
    p.add_argument("--out", required=True, metavar="FILE.csv", help="the CSV file written")
    p.set_defaults(func=cmd_synth)
