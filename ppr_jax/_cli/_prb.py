"""`ppr-jax prb` and `ppr-jax prb-table`: the PRB joint's derived quantities and the elastica-
fitted table."""

from __future__ import annotations

import argparse
import json
import sys

from .._files import save_figure
from ._common import (
    _derived_dict,
    _log,
    _params_dict,
    _parse_sets,
)


def _prb_at_kappa0(args, tab):
    import numpy as np

    from .._prb_table import prb_parameters

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
        from .._prb_fit import fit_prb

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
    import numpy as np

    from .._prb_table import prb_parameters

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
    save_figure(fig, path, dpi=120)
    plt.close(fig)
    print(f"wrote {path}", file=sys.stderr)


def cmd_prb_table(args):
    from .._errors import PPRError
    from .._prb_table import prb_table

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
    import numpy as np

    from .._kinematics import predeflection

    if args.kappa0 is not None or args.figure:
        _log("ppr-jax: note: 'prb --kappa0/--fit/--figure' is deprecated; use 'ppr-jax prb-table' "
             "with the same options")
        if args.kappa0 is None:  # as before the split: without --kappa0, only the figure
            args.fit = args.json = False
        return cmd_prb_table(args)
    if args.fit:
        _log("ppr-jax: note: 'prb --fit' without --kappa0 is ignored (deprecated; see 'ppr-jax "
             "prb-table')")
    params = _parse_sets(args.set, "paper-circle", getattr(args, "params_file", None))
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


def _add_prb(sub, parents, fmt):
    r = sub.add_parser("prb", formatter_class=fmt, parents=[parents["params"]],
        help="every derived quantity of the PRB joint (MODEL.md section 3)",
        description="Every derived quantity of the robot's PRB joint (MODEL.md section 3) and the "
                    "pre-deflection at home. The PRB parameters of a curved cantilever from the "
                    "elastica-fitted table are 'ppr-jax prb-table' ('prb --kappa0/--fit/--figure' "
                    "still works as a deprecated alias of it).")
    r.add_argument("--json", action="store_true",
                   help="print the parameters, derived quantities and pre-deflection as JSON "
                        "instead of text")
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
