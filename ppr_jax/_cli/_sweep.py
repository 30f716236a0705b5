"""`ppr-jax sweep`: a scene over a design of parameter values; CSV/Parquet, figures."""

from __future__ import annotations

import json
import math
import os

from .._files import save_figure, write_file
from ._common import _out_dir, _write_rows, scene_command


def parse_vary(items) -> dict:
    """``NAME=LO:HI:N`` (N evenly spaced values, ends included) or ``NAME=V1,V2,...`` ->
    {name: values}."""
    import numpy as np

    from .._studies import FLOAT_PARAMS

    out = {}
    for item in items or []:
        if "=" not in item:
            raise ValueError(f"--vary expects NAME=LO:HI:N or NAME=V1,V2,..., got {item!r}")
        name, spec = (s.strip() for s in item.split("=", 1))
        if name not in FLOAT_PARAMS:
            raise ValueError(f"--vary: cannot vary {name!r}; allowed: {', '.join(FLOAT_PARAMS)}")
        if name in out:
            raise ValueError(f"--vary: {name!r} given twice")
        try:
            if ":" in spec:
                parts = spec.split(":")
                if len(parts) != 3:
                    raise ValueError
                lo, hi, n = float(parts[0]), float(parts[1]), int(parts[2])
                if n < 1:
                    raise ValueError
                vals = np.linspace(lo, hi, n)
            else:
                vals = np.array([float(v) for v in spec.split(",") if v.strip()])
        except ValueError:
            raise ValueError(f"--vary {name}: cannot read {spec!r} (LO:HI:N with N >= 1, or a "
                             f"comma list of numbers)") from None
        if vals.size == 0 or not np.all(np.isfinite(vals)):
            raise ValueError(f"--vary {name}: values must be finite numbers, got {spec!r}")
        out[name] = vals
    if not out:
        raise ValueError("sweep needs at least one --vary NAME=LO:HI:N")
    return out


def _write_parquet(path, rows, columns) -> bool:
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return False
    with write_file(path, "wb") as f:
        pq.write_table(pa.table({c: [r[c] for r in rows] for c in columns}), f)
    return True


def sweep_figures(result, out_dir) -> list:
    """One PNG per varied parameter: every metric against it (failed members left out).
    Returns the paths written."""
    import matplotlib
    import numpy as np

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # the sweep's own metric columns (the radial error for a circle, the tracking error else)
    fixed = {"member", "status", "reason", "result_code", "num_steps", *result.varied}
    metric_cols = [c for c in result.columns if c not in fixed]
    ok = result.ok
    paths = []
    ncol = 4
    nrow = math.ceil(len(metric_cols) / ncol)
    for name in result.varied:
        fig, axs = plt.subplots(nrow, ncol, figsize=(3.2 * ncol, 2.6 * nrow), squeeze=False)
        x = np.array([r[name] for r in ok])
        for ax, m in zip(axs.flat, metric_cols):
            y = np.array([r[m] for r in ok])
            ax.plot(x, y, ".", ms=4)
            ax.set_xlabel(name)
            ax.set_title(m, fontsize=8)
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3)
        for ax in list(axs.flat)[len(metric_cols):]:
            ax.axis("off")
        fig.suptitle(f"sweep {result.info['scene']} ({result.info['model']}): metrics vs {name} "
                     f"({len(ok)} ok, {len(result.failed)} failed)", fontsize=9)
        fig.tight_layout()
        p = os.path.join(out_dir, f"metrics_vs_{name}.png")
        save_figure(fig, p, dpi=110)
        plt.close(fig)
        paths.append(p)
    return paths


def cmd_sweep(args):
    import jax

    from .._scenes import batch_devices
    from .._studies import sweep
    from ._common import (
        _parse_sets,
        check_commands_from_args,
        model_from_args,
        options_from_args,
        scene_from_args,
    )

    vary = parse_vary(args.vary)
    scene = scene_from_args(args)
    params = _parse_sets(args.set, scene, getattr(args, "params_file", None))
    check_commands_from_args(scene, params, args)
    _out_dir(args.out)
    design, n = ("lhs", args.lhs) if args.lhs is not None else ("grid", None)
    if args.lhs is not None and args.lhs < 1:
        raise ValueError(f"--lhs needs N >= 1, got {args.lhs}")
    devices = None
    if args.devices is None:
        # every local device that divides the chunk (the command asked XLA for one host device
        # per core, `configure_cpu`)
        devices = list(batch_devices(args.chunk)) or None
    elif args.devices:
        avail = jax.local_devices()
        if args.devices > len(avail):
            raise ValueError(
                f"--devices {args.devices}: only {len(avail)} local device(s); on a CPU set "
                f"XLA_FLAGS=--xla_force_host_platform_device_count={args.devices} first")
        devices = avail[: args.devices]
    res = sweep(
        scene, params, vary, design=design, n=n, seed=args.seed,
        model=model_from_args(args, args.model), options=options_from_args(args),
        chunk_size=args.chunk, devices=devices,
        checkpoint_dir=os.path.join(args.out, "chunks"), progress=True,
        program_dir=getattr(args, "program_dir", None),
    )
    _write_rows(os.path.join(args.out, "sweep.csv"), res.rows, res.columns)
    written = ["sweep.csv"]
    if _write_parquet(os.path.join(args.out, "sweep.parquet"), res.rows, res.columns):
        written.append("sweep.parquet")
    fcols = ["member", *res.varied, "status", "reason", "result_code"]
    _write_rows(os.path.join(args.out, "failed.csv"), res.failed, fcols)
    written.append("failed.csv")
    from .._studies import library_digest

    with write_file(os.path.join(args.out, "summary.json")) as f:
        # what the numbers depend on beyond the settings (the chunks' digests hold it too)
        json.dump({"settings": res.info, "library": library_digest(), "timing": res.timing,
                   "n_members": len(res.rows),
                   "n_ok": len(res.ok), "n_failed": len(res.failed),
                   "failed": [{c: r[c] for c in fcols} for r in res.failed]}, f, indent=2)
    written.append("summary.json")
    written += [os.path.basename(p) for p in sweep_figures(res, args.out)]
    print(f"sweep {scene.name} ({res.info['model']}): {len(res.rows)} members, {len(res.ok)} ok, "
          f"{len(res.failed)} failed")
    for r in res.failed[:10]:
        print(f"  member {r['member']} ({', '.join(f'{k}={r[k]:.6g}' for k in res.varied)}): "
              f"{r['reason']}")
    if len(res.failed) > 10:
        print(f"  ... {len(res.failed) - 10} more in failed.csv")
    t = res.timing
    if "per_member_ms" in t:
        print(f"compile {t['compile_s']:.1f} s, {t['per_member_ms']:.2f} ms per member")
    print(f"wrote {args.out}/: {', '.join(written)}")
    return 0


def add_sweep(sub, parents, fmt):
    s = scene_command(
        sub, "sweep", parents, fmt,
        help="run a scene over a grid or Latin hypercube of parameters; tidy table + figures",
        description="Run a scene over a grid (default) or a Latin hypercube (--lhs N) of parameter "
                    "values, in chunks of one compiled vmapped program. Writes sweep.csv (and "
                    "sweep.parquet with pyarrow), failed.csv (members that failed and why), "
                    "summary.json and metrics_vs_NAME.png. Finished chunks are kept in OUT/chunks "
                    "and skipped when the same sweep is run again (resume).",
        model_help="the model swept (L0 or L1 under its own torques follows the circle exactly: "
                   "the sweep warns that its radial errors are the solver's)",
        torque_help="paper-circle: the model whose inverse dynamics gives the torques")
    s.add_argument("--vary", action="append", metavar="NAME=LO:HI:N",
                   help="a parameter to vary: N values from LO to HI, or NAME=V1,V2,...; "
                        "repeatable (the grid is their product)")
    g = s.add_mutually_exclusive_group()
    g.add_argument("--grid", action="store_true", help="the full grid of the --vary values")
    g.add_argument("--lhs", type=int, default=None, metavar="N",
                   help="a Latin hypercube of N members over each --vary range")
    s.add_argument("--seed", type=int, default=0, help="seed of the Latin hypercube")
    s.add_argument("--chunk", type=int, default=64, help="members per compiled batch")
    s.add_argument("--devices", type=int, default=None,
                   help="split each chunk over this many local devices (0: one device; default: "
                        "all local devices, one per CPU core unless PPR_JAX_CPU_DEFAULTS=0, "
                        "where they divide --chunk)")
    s.add_argument("--out", required=True, help="output directory")
    s.set_defaults(func=cmd_sweep)
