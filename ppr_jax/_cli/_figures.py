"""Figures of a scene run (trajectory, angle, radial or position error), written by
`simulate`: the commanded (nominal) path against the simulated one."""

from __future__ import annotations

import os

import numpy as np

from .._files import save_figure
from .._metrics import radial_error

#: a model whose radial error exceeds this (m) is drawn on its own panel
FAR_OFF_M = 0.02


def _figure(figsize):
    """A matplotlib `Figure` on the Agg canvas (files only), imported when a figure is drawn.
    Not pyplot: its import (the backends' machinery, about 0.7 s) is most of a figure's cost,
    and a file needs no figure manager."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    FigureCanvasAgg(fig)
    return fig


def _split(results, center, radius):
    """(near, far, error per result): the radial error about a circle's `center`, else (center
    None) the distance from the commanded position; host-side numpy (no XLA program per
    operation)."""
    if center is not None:
        er = {id(r): radial_error(np.asarray(r.X), np.asarray(center), float(radius), xp=np)
              for r in results}
    else:
        er = {id(r): np.linalg.norm(np.asarray(r.X)[:, :2] - np.asarray(r.X_nominal)[:, :2],
                                    axis=-1) for r in results}
    far = [r for r in results if np.nanmax(np.abs(er[id(r)])) > FAR_OFF_M]
    near = [r for r in results if r not in far]
    return near, far, er


def _panels(groups, ylabel, title, series):
    """One panel per non-empty group (near models, then far ones on their own scale)."""
    groups = [(name, g) for name, g in groups if g]
    fig = _figure((6.5, 3.2 * len(groups)))
    axs = fig.subplots(len(groups), 1, squeeze=False)
    for ax, (name, g) in zip(axs[:, 0], groups):
        for r in g:
            t, y = series(r)
            ax.plot(t, y, lw=1, label=r.model)
        ax.axhline(0, color="k", lw=0.5)
        ax.set_ylabel(ylabel)
        ax.set_title(f"{title}{name}", fontsize=10)
        ax.legend(fontsize=8)
    axs[-1, 0].set_xlabel("t (s)")
    return fig


def scene_figures(results, out_dir: str, center, radius) -> list[str]:
    """Write trajectory.png, angle.png and, for a circle (`center`, `radius`), radial_error.png,
    else position_error.png, for a list of scene reports. Returns the paths."""
    paths = []
    r0 = results[0]
    circle = center is not None
    near, far, er = _split(results, center, radius)
    off = " (far off the circle: own scale)" if circle else " (far off the path: own scale)"
    groups = [("", near), (off, far)] if near else [("", far)]

    # Trajectory: the whole picture, and the near models' deviation from the nominal pose (mm)
    # where it is visible.
    ncol = 2 if near else 1
    fig = _figure((5.5 * ncol, 5))
    axs = fig.subplots(1, ncol, squeeze=False)
    ax = axs[0, 0]
    ax.plot(r0.X_nominal[:, 0], r0.X_nominal[:, 1], "k--", lw=1.5,
            label="nominal (eq 55)" if circle else "commanded")
    for r in results:
        ax.plot(r.X[:, 0], r.X[:, 1], lw=1, label=r.model)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title(f"{r0.scene}: platform trajectory", fontsize=10)
    ax.legend(fontsize=8)
    if near:
        ax = axs[0, 1]
        for r in near:
            d = (r.X[:, :2] - r.X_nominal[:, :2]) * 1e3
            ax.plot(d[:, 0], d[:, 1], lw=1, label=r.model)
        ax.plot([0], [0], "k+", ms=10)
        ax.set_xlabel("x - x_nominal (mm)")
        ax.set_ylabel("y - y_nominal (mm)")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title("position error" + (" (models within 20 mm)" if far else ""), fontsize=10)
        ax.legend(fontsize=8)
    paths.append(_save(fig, out_dir, "trajectory.png"))

    fig = _panels(groups, "phi - phi_nominal (mrad)", f"{r0.scene}: platform angle error",
                  lambda r: (r.ts, (r.X[:, 2] - r.X_nominal[:, 2]) * 1e3))
    paths.append(_save(fig, out_dir, "angle.png"))

    if circle:
        fig = _panels(groups, "e_r (mm)", f"{r0.scene}: radial error |(x, y) - c| - R",
                      lambda r: (r.ts, er[id(r)] * 1e3))
        paths.append(_save(fig, out_dir, "radial_error.png"))
    else:
        fig = _panels(groups, "|(x, y) - commanded| (mm)", f"{r0.scene}: position error",
                      lambda r: (r.ts, er[id(r)] * 1e3))
        paths.append(_save(fig, out_dir, "position_error.png"))
    return paths


def _save(fig, out_dir, name):
    path = os.path.join(out_dir, name)
    fig.tight_layout()
    save_figure(fig, path, dpi=120)
    return path
