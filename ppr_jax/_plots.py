"""Figures of the `simulate` command (matplotlib, Agg backend), after the paper's Fig 8, 9, 12."""

from __future__ import annotations

import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ._metrics import radial_error  # noqa: E402


def scene_figures(results, out_dir: str, center, radius) -> list[str]:
    """Write trajectory.png, angle.png and radial_error.png for a list of `SceneResult`."""
    paths = []
    r0 = results[0]
    t = r0.ts
    fig, ax = plt.subplots(figsize=(5.5, 5))
    ax.plot(r0.X_nominal[:, 0], r0.X_nominal[:, 1], "k--", lw=1.5, label="nominal (eq 55)")
    for r in results:
        ax.plot(r.X[:, 0], r.X[:, 1], lw=1, label=r.model)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title(f"{r0.scene}: platform trajectory")
    ax.legend(fontsize=8)
    paths.append(_save(fig, out_dir, "trajectory.png"))

    fig, ax = plt.subplots(figsize=(6.5, 4))
    ax.plot(t, r0.X_nominal[:, 2], "k--", lw=1.5, label="nominal")
    for r in results:
        ax.plot(r.ts, r.X[:, 2], lw=1, label=r.model)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("phi (rad)")
    ax.set_title(f"{r0.scene}: platform angle")
    ax.legend(fontsize=8)
    paths.append(_save(fig, out_dir, "angle.png"))

    fig, ax = plt.subplots(figsize=(6.5, 4))
    for r in results:
        er = np.asarray(radial_error(r.X, np.asarray(center), float(radius)))
        ax.plot(r.ts, er * 1e3, lw=1, label=r.model)
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("radial error e_r (mm)")
    ax.set_title(f"{r0.scene}: radial error |(x, y) - c| - R")
    ax.legend(fontsize=8)
    paths.append(_save(fig, out_dir, "radial_error.png"))
    return paths


def _save(fig, out_dir, name):
    path = os.path.join(out_dir, name)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
