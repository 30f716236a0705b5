"""Command line interface `ppr-jax` (docs/cli.md)."""

from __future__ import annotations

import argparse
import csv
import json
import os
import sys
import time

import numpy as np

from ._checks import PPRError


def _reference(scene):
    """The values the scene's paper figure reports (`AbstractScene.reference`), or None."""
    from ._scenes import SCENE_CLASSES

    cls = SCENE_CLASSES.get(scene)
    return dict(cls.reference) if cls is not None and cls.reference else None


def _parse_sets(items, scene):
    from ._params import parse_value
    from ._scenes import scene_params

    kw = {}
    for item in items or []:
        if "=" not in item:
            raise PPRError(f"--set expects NAME=VALUE, got {item!r}")
        name, value = item.split("=", 1)
        name = name.strip()
        kw[name] = parse_value(name, value)
    return scene_params(scene, **kw)


def _params_dict(params):
    import dataclasses

    out = {}
    for f in dataclasses.fields(params):
        v = getattr(params, f.name)
        out[f.name] = None if v is None else (v if isinstance(v, (int, str)) else float(v))
    return out


def _derived_dict(params):
    import dataclasses

    from ._prb import derived

    dv = derived(params)
    return {f.name: float(getattr(dv, f.name)) for f in dataclasses.fields(dv)}


def _log(msg):
    print(msg, file=sys.stderr, flush=True)


def _models(text, default):
    names = [m.strip() for m in (text or default).split(",") if m.strip()]
    from ._models import MODELS

    for m in names:
        if m not in MODELS:
            raise PPRError(f"unknown model {m!r}; allowed: {', '.join(MODELS)}")
    return names


def cmd_simulate(args):
    from ._plots import scene_figures
    from ._report import run_scene
    from ._scenes import check_scene_args, modes_scene
    from ._trajectory import Circle

    scene = args.scene
    params = _parse_sets(args.set, scene)
    check_out_dir(args.out)
    if scene == "modes":
        models = _models(args.model, "reduced,double1r")
        res = []
        for m in models:
            for act in ("locked", "free"):
                _log(f"modes: {m}, actuators {act} ...")
                res.append(modes_scene(params, model=model_from_args(args, m),
                                       actuators=act))
        summary = {"scene": scene, "params": _params_dict(params), "modes": res}
        _write_json(os.path.join(args.out, "summary.json"), summary)
        for r in res:
            f = ", ".join(f"{x:.4g}" for x in r["frequencies_hz"]) or "none (no free coordinate)"
            print(f"{r['model']:>9s} actuators {r['actuators']:>6s}: {f} Hz")
        print(f"wrote {args.out}/summary.json")
        return 0
    models = _models(args.model, "rigid,reduced,double1r")
    kw = dict(t_end=args.t_end, n_out=args.n_out, solver=args.solver, rtol=args.rtol,
              atol=args.atol, max_steps=args.max_steps)
    results, failed = [], {}
    traj = Circle()
    # Every argument checked before the first compilation.
    objs = [model_from_args(args, m) for m in models]
    check_scene_args(args.t_end, args.n_out, args.rtol, args.atol, args.max_steps)

    def write():
        # After every model: a failing or interrupted later model keeps what finished.
        summary = {
            "scene": scene,
            "torque_model": args.torque_model if scene == "paper-circle" else None,
            "t_end_s": args.t_end,
            "n_out": args.n_out,
            "params": _params_dict(params),
            "derived": _derived_dict(params),
            "models": {r.model: dict(r.metrics, solver=r.solver) for r in results},
            "beam": ({"elements": args.elements, "strip_dynamics": args.strip_dynamics,
                      "strip_loss_s": args.strip_loss}
                     if "beam" in models else None),
            "failed": failed,
            "paper_reference": _reference(scene),
        }
        _write_json(os.path.join(args.out, "summary.json"), summary)
        if results:
            _write_csv(os.path.join(args.out, "trajectory.csv"), results)

    for i, m in enumerate(models):
        _log(f"[{i + 1}/{len(models)}] {scene}: model {m} (compiling, then running) ...")
        t0 = time.perf_counter()
        try:
            r = run_scene(scene, params, model=objs[i], torque_model=args.torque_model,
                          program_dir=getattr(args, "program_dir", None), **kw)
        except PPRError as err:
            failed[m] = " ".join(str(err).split())
            _log(f"      {m} failed: {failed[m]}")
            write()
            continue
        _log(f"      done in {time.perf_counter() - t0:.1f} s (compile {r.timing['compile_s']:.1f} s, "
             f"run {r.timing['run_s'] * 1e3:.1f} ms, {r.metrics['num_steps']} steps)")
        results.append(r)
        write()
    if results:
        scene_figures(results, args.out, np.asarray(traj.center), float(traj.radius))
        _print_table(scene, results, args)
        print(f"wrote {args.out}/summary.json, trajectory.csv, trajectory.png, angle.png, "
              f"radial_error.png")
    if failed:
        raise PPRError(f"{len(failed)} of {len(models)} models failed ({', '.join(failed)}); "
                       f"see above and {args.out}/summary.json")
    return 0


def _print_table(scene, results, args):
    ref = _reference(scene) or {}
    hdr = (f"{'model':>10s} {'e_r max':>9s} {'e_r min':>9s} {'e_r mean':>9s} {'max|e_r|/R':>10s} "
           f"{'|dphi| max':>10s} {'d_end max':>9s} {'d_end min':>9s} {'d_end mean':>10s} "
           f"{'rel':>6s} {'resid':>8s} {'steps':>6s} {'run':>8s}")
    units = (f"{'':>10s} {'mm':>9s} {'mm':>9s} {'mm':>9s} {'%':>10s} {'mrad':>10s} {'deg':>9s} "
             f"{'deg':>9s} {'deg':>10s} {'%':>6s} {'m':>8s} {'':>6s} {'ms':>8s}")
    print(f"\nScene {scene} (t = {float(results[0].params.t) * 1e3:.2f} mm); radial error "
          f"e_r = |(x,y) - c| - R against the nominal circle (eq 55); d_end = difference of chain "
          f"1's joint end rotations")
    print(hdr)
    print(units)
    for r in results:
        m = r.metrics
        print(f"{r.model:>10s} {m['radial_error_max_m'] * 1e3:9.4f} {m['radial_error_min_m'] * 1e3:9.4f} "
              f"{m['radial_error_mean_m'] * 1e3:9.4f} {m['radial_error_max_relative_percent']:10.4f} "
              f"{m['phi_error_max_rad'] * 1e3:10.4f} {m['end_rotation_diff_max_deg']:9.4f} "
              f"{m['end_rotation_diff_min_deg']:9.4f} {m['end_rotation_diff_mean_deg']:10.4f} "
              f"{m['end_rotation_diff_max_relative_percent']:6.2f} "
              f"{m['constraint_residual_max_m']:8.1e} {m['num_steps']:6d} {r.timing['run_s'] * 1e3:8.2f}")
    if ref:
        print(f"{'paper':>10s} {ref['radial_error_max_m'] * 1e3:9.4f} {ref['radial_error_min_m'] * 1e3:9.4f} "
              f"{ref['radial_error_mean_m'] * 1e3:9.4f} {ref['radial_error_max_relative_percent']:10.4f}"
              f"   ({ref['source']})")
    for r in results:
        if r.metrics["radial_error_max_relative_percent"] > 20:
            print(f"note: {r.model} runs far off the circle ({r.metrics['radial_error_max_relative_percent']:.0f}% "
                  f"of R): open-loop torques of another model amplify the mismatch (L0's pin is about "
                  f"half as stiff as the double-1R joint); use --torque-model {r.model} for its own torques")


def _write_json(path, obj):
    with open(path, "w") as f:
        json.dump(obj, f, indent=2)


def _write_csv(path, results):
    from ._metrics import radial_error
    from ._trajectory import Circle

    c = Circle()
    center, R = np.asarray(c.center), float(c.radius)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["model", "t", "x", "y", "phi", "e_r", "tau_1", "tau_2", "tau_3",
                    "end_rot_1", "end_rot_2"])
        r0 = results[0]
        er = np.asarray(radial_error(r0.X_nominal, center, R))
        for k in range(len(r0.ts)):
            w.writerow(["nominal", r0.ts[k], *r0.X_nominal[k], er[k], "", "", "", "", ""])
        for r in results:
            er = np.asarray(radial_error(r.X, center, R))
            for k in range(len(r.ts)):
                w.writerow([r.model, r.ts[k], *r.X[k], er[k], *r.tau[k], *r.end_rot[k]])


def cmd_torques(args):
    import jax
    import jax.numpy as jnp

    from ._actuation import InverseDynamicsTorque
    from ._models import get_model
    from ._trajectory import Circle

    from ._checks import check_number

    params = _parse_sets(args.set, "paper-circle")
    check_number("t_end", args.t_end, 0.0, 1e5, "s", open_lo=True)
    check_number("n_out", args.n_out, 2, 10_000_000, integer=True)
    check_out_dir(args.out)
    model = get_model(args.model)
    if model.actuated_index is not None:
        raise PPRError(f"torques: inverse dynamics along eq 55 needs model rigid or reduced, "
                         f"not {model.name!r}")
    ts = jnp.linspace(0.0, args.t_end, args.n_out)
    from ._kinematics import inverse_kinematics

    # Reachability and singularity along the whole path first: a clear error, never NaN torques.
    inverse_kinematics(params, jax.vmap(Circle())(ts), model)
    tau = jax.jit(jax.vmap(InverseDynamicsTorque(model, params, Circle())))(ts)
    tau = np.asarray(tau)
    if not np.all(np.isfinite(tau)):
        raise PPRError("inverse dynamics produced non-finite torques (singular configuration)")
    path = os.path.join(args.out, "torques.csv")
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["t", "tau_1", "tau_2", "tau_3"])
        for k in range(len(ts)):
            w.writerow([float(ts[k]), *tau[k]])
    print(f"max |tau| = {np.abs(tau).max():.6g} N m; wrote {path}")
    return 0


def cmd_modes(args):
    from ._scenes import modes_scene

    params = _parse_sets(args.set, "modes")
    X = None if args.pose is None else [float(v) for v in args.pose.split(",")]
    r = modes_scene(params, model=model_from_args(args, args.model), actuators=args.actuators,
                    X=X)
    if args.json:
        print(json.dumps(r, indent=2))
    else:
        f = ", ".join(f"{x:.6g}" for x in r["frequencies_hz"]) or "none"
        print(f"{r['model']} actuators {r['actuators']}: {f} Hz\n{r['note']}")
    return 0


def _prb_at_kappa0(args, tab):
    from ._prb_table import prb_parameters

    k = float(args.kappa0)
    g, rho, K = prb_parameters(k)
    kk = np.asarray(tab["kappa0"])
    out = {
        "kappa0": k,
        "gamma": float(g),
        "rho": float(rho),
        "K_theta": float(K),
        "source": "cubic spline of the shipped elastica-fitted table (ppr_jax/data/prb_table.json)",
        "table_tip_error_max": float(np.interp(k, kk, tab["tip_error_max"])),
        "table_load_error_max": float(np.interp(k, kk, tab["load_error_max"])),
        "error_note": "tip error in units of the beam length; load error relative to the largest "
                      "torque of the load direction; linear interpolation between table rows",
    }
    if args.fit:
        from ._prb_fit import fit_prb

        f = fit_prb(k)
        out["fit"] = {name: float(getattr(f, name)) for name in f._fields}
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        for key, v in out.items():
            print(f"{key:>22s} = {v}")
    if args.figure:
        _prb_figure(args.figure, tab)
    return 0


_TABLE_SUMMARY = ("gamma", "rho", "K_theta", "theta_i", "tip_error_max", "load_error_max")


def _print_prb_table(tab, as_json):
    if as_json:
        out = {"source": "ppr_jax/data/prb_table.json", "meta": tab["meta"],
               "columns": [k for k in tab if k != "meta"]}
        out.update({k: [float(v) for v in tab[k]] for k in out["columns"]})
        print(json.dumps(out, indent=2))
        return
    print("PRB parameters of an initially curved cantilever, fitted to the elastica "
          "(ppr_jax/data/prb_table.json); nondimensional, K = rho K_theta EI/l; "
          "prb-table --kappa0 K interpolates")
    print(f"{'kappa0':>7s} " + " ".join(f"{name:>15s}" for name in _TABLE_SUMMARY))
    for i, k in enumerate(tab["kappa0"]):
        print(f"{k:7.3f} " + " ".join(f"{tab[name][i]:15.6g}" for name in _TABLE_SUMMARY))


def _prb_figure(path, tab):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ._prb_table import prb_parameters

    k = np.linspace(0.0, 2.0, 201)
    g, rho, K = (np.asarray(v) for v in prb_parameters(k))
    fig, axs = plt.subplots(1, 3, figsize=(11, 3.4))
    for ax, v, name in zip(axs, (g, rho, K), ("gamma", "rho", "K_theta")):
        ax.plot(k, v, "-", lw=1.2, label="spline")
        ax.plot(tab["kappa0"], tab[name], "o", ms=3, label="fitted")
        ax.set_xlabel("kappa0 = l/R")
        ax.set_title(name)
        ax.grid(alpha=0.3)
    axs[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    print(f"wrote {path}", file=sys.stderr)


def cmd_prb_table(args):
    from ._prb_table import prb_table

    tab = prb_table()
    if args.kappa0 is not None:
        return _prb_at_kappa0(args, tab)
    if args.fit:
        raise PPRError("--fit needs --kappa0 (it fits that one curvature afresh from the elastica)")
    if args.figure:
        _prb_figure(args.figure, tab)
    if not args.figure or args.json:
        _print_prb_table(tab, args.json)
    return 0


def cmd_prb(args):
    from ._kinematics import predeflection

    if args.kappa0 is not None or args.figure:
        _log("ppr-jax: note: 'prb --kappa0/--fit/--figure' is deprecated; use 'ppr-jax prb-table' "
             "with the same options")
        if args.kappa0 is None:  # as before the split: without --kappa0, only the figure
            args.fit = args.json = False
        return cmd_prb_table(args)
    if args.fit:
        _log("ppr-jax: note: 'prb --fit' without --kappa0 is ignored (deprecated; see 'ppr-jax "
             "prb-table')")
    params = _parse_sets(args.set, "paper-circle")
    out = {"params": _params_dict(params), "derived": _derived_dict(params)}
    pd = predeflection(params)
    out["predeflection_home_rad"] = {
        "reduced_per_pivot": [float(v) for v in np.asarray(pd["reduced"])[:, 0]],
        "rigid_per_pin": [float(v) for v in np.asarray(pd["rigid"])],
    }
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        for k, v in out["derived"].items():
            print(f"{k:>8s} = {v:.8g}")
        print(f"pre-deflection at home: {out['predeflection_home_rad']}")
    return 0


def model_from_args(args, name: str):
    """The model `name` with the `model` parent parser's options (--elements, --strip-dynamics,
    --strip-loss)."""
    from ._models import get_model

    loss = getattr(args, "strip_loss", 0.0)
    if name == "beam" and loss != 0 and args.strip_dynamics != "full":
        raise PPRError(f"--strip-loss {loss:g} needs --strip-dynamics full (quasi-static "
                       "strips have no strip modes to damp)")
    # L0-L2 run beside the beam have no strips: --strip-loss is the beam's alone
    return get_model(name, args.elements, args.strip_dynamics,
                     strip_loss=loss if name == "beam" else 0.0)


def parent_parsers() -> dict:
    """Options shared by several commands, as argparse parent parsers (one definition each):
    `params` (--set), `model` (--model, --elements), `solve` (solver, tolerances, step limit,
    times), `out` (--out). A command takes the ones it needs with `parents=[...]`."""
    from ._params import settable_names
    from ._simulate import SOLVERS

    params = argparse.ArgumentParser(add_help=False)
    params.add_argument("--set", action="append", metavar="NAME=VALUE",
                        help="override a parameter, NAME=VALUE (SI units); repeatable; names: "
                             + ", ".join(settable_names()))
    model = argparse.ArgumentParser(add_help=False)
    model.add_argument("--elements", type=int, default=8, help="beam elements per strip (L3)")
    model.add_argument("--strip-dynamics", default="quasi-static", choices=["quasi-static", "full"],
                       help="L3's strips: in static equilibrium for their clamp poses (9 "
                            "coordinates, fast) or with their own inertia and kHz modes (3 + 3N "
                            "coordinates, stiff: hours for a 7.54 s scene at N >= 8)")
    model.add_argument("--strip-loss", type=float, default=0.0, metavar="SECONDS",
                       help="Kelvin-Voigt material loss of L3's strips with --strip-dynamics "
                            "full: retardation time tau (s), each strip spring damped by "
                            "tau * its stiffness (damping ratio tau*omega/2; 1e-5 damps the "
                            "first strip mode by 7.5%%); default 0 (undamped); the beam's alone")
    solve = argparse.ArgumentParser(add_help=False)
    solve.add_argument("--solver", default=None, choices=list(SOLVERS),
                       help="ODE solver (default: per model, see the docs' Which model page)")
    solve.add_argument("--rtol", type=float, default=1e-8, help="relative tolerance of the solver")
    solve.add_argument("--atol", type=float, default=1e-10, help="absolute tolerance of the solver")
    solve.add_argument("--max-steps", type=int, default=200_000, help="solver step limit")
    times = argparse.ArgumentParser(add_help=False)
    times.add_argument("--t-end", type=float, default=7.54, help="end time (s)")
    times.add_argument("--n-out", type=int, default=755, help="number of output times")
    return {"params": params, "model": model, "solve": solve, "times": times}


def _add_simulate(sub, parents, fmt):
    from ._models import MODELS
    from ._scenes import SCENES

    kinematic = [n for n, c in MODELS.items() if c.actuated_index is None]  # pose = coordinates
    s = sub.add_parser("simulate", formatter_class=fmt,
        parents=[parents[k] for k in ("params", "model", "solve", "times")],
        help="run a scene and write summary.json, trajectory.csv, figures")
    s.add_argument("--scene", default="paper-circle", choices=list(SCENES), help="scene to run")
    s.add_argument("--model", default=None,
                   help="a model (" + ", ".join(MODELS) + ") or a comma list (default: rigid, "
                        "reduced, double1r). beam is L3 with quasi-static strips (see "
                        "--elements, --strip-dynamics)")
    s.add_argument("--torque-model", default="reduced", choices=kinematic,
                   help="paper-circle: the model whose inverse dynamics gives the torques")
    s.add_argument("--out", default="out", help="output directory")
    s.set_defaults(func=cmd_simulate)


def _add_torques(sub, parents, fmt):
    from ._models import MODELS

    kinematic = [n for n, c in MODELS.items() if c.actuated_index is None]
    t = sub.add_parser("torques", formatter_class=fmt,
        parents=[parents["params"], parents["times"]],
        help="inverse-dynamics torques along eq 55 as CSV")
    t.add_argument("--model", default="reduced", choices=kinematic)
    t.add_argument("--out", required=True)
    t.set_defaults(func=cmd_torques)


def _add_modes(sub, parents, fmt):
    from ._models import MODELS

    m = sub.add_parser("modes", formatter_class=fmt,
        parents=[parents["params"], parents["model"]],
        help="natural frequencies about a static equilibrium (Hz)")
    m.add_argument("--model", default="double1r", choices=list(MODELS))
    m.add_argument("--actuators", default="locked", choices=["locked", "free"])
    m.add_argument("--pose", default=None, help="x,y,phi (default: home)")
    m.add_argument("--json", action="store_true")
    m.set_defaults(func=cmd_modes)


def _add_prb(sub, parents, fmt):
    r = sub.add_parser("prb", formatter_class=fmt, parents=[parents["params"]],
        help="every derived quantity of the PRB joint (MODEL.md section 3)",
        description="Every derived quantity of the robot's PRB joint (MODEL.md section 3) and the "
                    "pre-deflection at home. The PRB parameters of a curved cantilever from the "
                    "elastica-fitted table are 'ppr-jax prb-table' ('prb --kappa0/--fit/--figure' "
                    "still works as a deprecated alias of it).")
    r.add_argument("--json", action="store_true")
    # Deprecated alias of prb-table (hidden from the help; forwarded with a notice on stderr).
    r.add_argument("--kappa0", type=float, default=None, help=argparse.SUPPRESS)
    r.add_argument("--fit", action="store_true", help=argparse.SUPPRESS)
    r.add_argument("--figure", default=None, help=argparse.SUPPRESS)
    r.set_defaults(func=cmd_prb)


def _add_prb_table(sub, parents, fmt):
    pt = sub.add_parser("prb-table", formatter_class=fmt,
        help="PRB parameters of an initially curved cantilever (elastica-fitted table)",
        description="PRB parameters gamma, rho, K_theta of an initially curved cantilever of "
                    "nondimensional curvature kappa0 = l/R, from the shipped elastica-fitted table "
                    "(docs/prb_fit.md). With --kappa0: the interpolated values there (and a fresh "
                    "fit with --fit). Without --kappa0: the whole table (text, or JSON with "
                    "--json); with --figure and no --kappa0 only the figure is written, unless "
                    "--json asks for the table too.")
    pt.add_argument("--kappa0", type=float, default=None,
                    help="curvature in [0, 2]: interpolate gamma, rho, K_theta there")
    pt.add_argument("--fit", action="store_true",
                    help="with --kappa0: also fit gamma, rho, K_theta afresh from the elastica "
                         "(a few seconds)")
    pt.add_argument("--json", action="store_true", help="print JSON instead of text")
    pt.add_argument("--figure", default=None, metavar="PNG",
                    help="write gamma, rho, K_theta vs kappa0 (spline and table rows) to PNG")
    pt.set_defaults(func=cmd_prb_table)


#: The commands, in the order `--help` lists them: each entry adds one subparser. A new command
#: is a function `add(sub, parents, fmt)` (in this file or its own module) and one line here.
from ._identify_cli import add_identify, add_synth  # noqa: E402
from ._sweep_cli import add_sensitivity, add_sweep  # noqa: E402

COMMANDS = [
    _add_simulate, _add_torques, _add_modes, _add_prb, _add_prb_table,
    add_sweep, add_sensitivity, add_identify, add_synth,
]


def build_parser():
    fmt = argparse.ArgumentDefaultsHelpFormatter
    p = argparse.ArgumentParser(prog="ppr-jax", description=__doc__, formatter_class=fmt)
    sub = p.add_subparsers(dest="cmd", required=True)
    parents = parent_parsers()
    for add in COMMANDS:
        add(sub, parents, fmt)
    return p


def check_out_dir(path: str) -> str:
    """Make sure the output directory can be written before a long run starts (`PPRError`)."""
    if os.path.exists(path) and not os.path.isdir(path):
        raise PPRError(f"--out {path!r} is a file, not a directory")
    try:
        os.makedirs(path, exist_ok=True)
    except OSError as err:
        raise PPRError(f"--out {path!r}: cannot create the directory ({err.strerror})") from None
    if not os.access(path, os.W_OK):
        raise PPRError(f"--out {path!r}: the directory is not writable")
    return path


def _runtime_message(err: Exception) -> str:
    """The library's own message out of an error raised inside compiled code (equinox's runtime
    errors arrive wrapped in JAX's), without the framework's hints."""
    text = str(err)
    for marker in ("EqxRuntimeError: ", "XlaRuntimeError: "):
        if marker in text:
            text = text.split(marker, 1)[1]
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    keep = [ln for ln in lines if not ln.startswith(("-----", "This error", "Note:", "If this"))]
    return keep[0] if keep else (lines[0] if lines else type(err).__name__)


def main(argv=None) -> int:
    """Run the command line; every user error is one line on stderr and exit status 2."""
    import jax

    args = build_parser().parse_args(argv)
    args.program_dir = None
    if args.cmd == "sweep" and os.environ.get("PPR_JAX_CPU_DEFAULTS", "1") != "0":
        from ._devices import configure_cpu

        try:
            configure_cpu()  # one host device per core: a sweep's chunks split over them
        except PPRError:  # JAX started already (the command called from Python): keep it
            pass
    if os.environ.get("PPR_JAX_CACHE", "1") != "0":
        from ._cache import enable_compilation_cache
        from ._programs import PROGRAM_SUBDIR

        try:
            # Exported scene programs beside the compiled ones: a second run skips tracing too.
            args.program_dir = os.path.join(enable_compilation_cache(), PROGRAM_SUBDIR)
        except OSError as err:  # a read-only home: run without the cache, say so once
            _log(f"ppr-jax: note: compilation cache disabled ({err})")
    try:
        return args.func(args)
    except (PPRError, ValueError) as err:
        msg = str(err)
    except OSError as err:
        msg = f"{err.filename or ''}: {err.strerror or err}".lstrip(": ")
    except jax.errors.JaxRuntimeError as err:
        msg = _runtime_message(err)
    print(f"ppr-jax: error: {' '.join(msg.split())}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
