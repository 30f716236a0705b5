"""Figures of the benchmark suite, drawn from its JSON (`benchmarks/run.py` and
`notebooks/benchmarks.ipynb` both call these). Each function takes the part's loaded JSON and a
directory to write PNGs into (None: only return the figures)."""

from __future__ import annotations

import os

import numpy as np

MODEL_LABEL = {"rigid": "L0 rigid", "reduced": "L1 reduced", "double1r": "L2 double-1R",
               "beam": "L3 beam (quasi-static)"}
SOLVER_STYLE = {"tsit5": "o-", "dopri5": "^-", "dopri8": "s--", "kvaerno5": "d:"}
SOLVER_COLOUR = {"tsit5": "C3", "dopri5": "C0", "dopri8": "C1", "kvaerno5": "C2"}


def _plt():
    import matplotlib

    if os.environ.get("MPLBACKEND") is None and not _in_notebook():
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _in_notebook() -> bool:
    try:
        from IPython import get_ipython

        return get_ipython() is not None
    except ImportError:
        return False


def _save(fig, out_dir, name):
    if out_dir is not None:
        fig.savefig(os.path.join(out_dir, name), dpi=120)


def _floor(e):
    # An error of exactly 0 (the reference point itself) cannot go on a log axis.
    return max(e, 1e-16)


def work_precision(data: dict, out_dir=None) -> list:
    """One figure per scene: error against run time, a panel per model, a line per solver."""
    plt = _plt()
    figs = []
    rows = [r for r in data["rows"] if "error_m" in r]
    for scene in sorted({r["scene"] for r in rows}):
        models = [m for m in MODEL_LABEL if any(r["model"] == m and r["scene"] == scene
                                                for r in rows)]
        fig, axes = plt.subplots(1, len(models), figsize=(3.6 * len(models), 3.6),
                                 squeeze=False)
        for ax, model in zip(axes[0], models):
            sel = [r for r in rows if r["scene"] == scene and r["model"] == model]
            for solver in [s for s in SOLVER_STYLE if any(r["solver"] == s for r in sel)]:
                pts = sorted((_floor(r["error_m"]), r["run_s"] * 1e3) for r in sel
                             if r["solver"] == solver)
                e, t = np.array(pts).T
                ax.loglog(e, t, SOLVER_STYLE.get(solver, "x"), label=solver,
                          color=SOLVER_COLOUR.get(solver))
            for r in sel:
                if r["solver"].startswith("none"):  # L0/L1 motion-driven: no ODE, exact
                    ax.text(0.5, 0.5, f"no ODE\n{r['run_s'] * 1e3:.1f} ms", ha="center",
                            va="center", transform=ax.transAxes)
                    ax.set_xticks([])
                    ax.set_yticks([])
            ax.set_title(MODEL_LABEL[model], fontsize=10)
            ax.set_xlabel("max position error (m)")
            ax.grid(True, which="both", alpha=0.3)
            if ax.get_lines():
                ax.legend(fontsize=7)
        axes[0][0].set_ylabel("run time (ms)")
        fig.suptitle(f"{scene}, {data['t_end_s']:g} s: work-precision "
                     f"({data['machine']['backend']})", fontsize=11)
        fig.tight_layout()
        _save(fig, out_dir, f"work_precision_{scene}.png")
        figs.append(fig)
    return figs


def contenders(data: dict, out_dir=None):
    """L2 paper-circle: this library against MuJoCo and scipy, error against run time."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.8, 4.6))
    colour = {"ppr_jax": "C0", "mujoco": "C3", "scipy": "C2"}
    style = {"tsit5": "o-", "dopri5": "^-", "dopri8": "s-", "RK4": "D-", "RK4 stages": "v-",
             "DOP853": "o--", "Radau": "s--", "LSODA": "^--"}
    rows = [r for r in data["rows"] if r.get("error_m") is not None]
    for tool in ("ppr_jax", "mujoco", "scipy"):
        for method in sorted({r["method"] for r in rows if r["tool"] == tool}):
            pts = sorted((_floor(r["error_m"]), r["run_s"] * 1e3) for r in rows
                         if r["tool"] == tool and r["method"] == method)
            e, t = np.array(pts).T
            ax.loglog(e, t, style.get(method, "x-"), color=colour[tool], label=f"{tool} {method}")
    for err in sorted({m["error_m"] for m in data.get("matched", [])}):
        ax.axvline(err, color="0.6", lw=0.8, ls=":")
    ax.set_xlabel("max platform position error (m)")
    ax.set_ylabel("run time (ms)")
    ax.set_title(f"L2 {data['scene']}, {data['t_end_s']:g} s ({data['machine']['backend']})",
                 fontsize=11)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    _save(fig, out_dir, "contenders.png")
    return fig


def batch(data: dict, out_dir=None):
    """Trajectories per second against batch size, with the loop-of-singles line."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.2, 4.2))
    rows = data["rows"]
    for i, (model, rtol) in enumerate(sorted({(r["model"], r["rtol"]) for r in rows})):
        sel = sorted((r["batch"], r["trajectories_per_s"]) for r in rows
                     if r["model"] == model and r["rtol"] == rtol)
        b, tps = np.array(sel).T
        ax.loglog(b, tps, "o-", color=f"C{i}", label=f"{MODEL_LABEL[model]}, rtol {rtol:g}")
        single = [r for r in rows if r["model"] == model and r["rtol"] == rtol and r["batch"] == 1]
        if single:
            ax.axhline(single[0]["trajectories_per_s"], color=f"C{i}", ls=":", lw=0.8)
    ax.set_xlabel("batch size")
    ax.set_ylabel("trajectories / s")
    ax.set_title(f"{data['scene']}, {data['t_end_s']:g} s; dotted: loop of single runs",
                 fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    _save(fig, out_dir, "batch_scaling.png")
    return fig
