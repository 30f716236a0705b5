"""Figures of an identification (matplotlib, Agg backend): measured against fitted trajectory,
and the residuals over time against the stated noise."""

from __future__ import annotations

import os

import numpy as np

from ..._files import save_figure
from .._html import pyplot as _pyplot


def identification_figures(fit, out_dir: str) -> list[str]:
    """Write fit_trajectory.png (x-y path and phi(t), measured dots, fitted lines) and
    fit_residuals.png (x, y in mm and phi in mrad over time, with +-2 noise bands) for an
    `Identification`; returns the paths."""
    plt = _pyplot()
    os.makedirs(out_dir, exist_ok=True)
    paths = []
    names = fit.experiment_names
    fig, axs = plt.subplots(1, 2, figsize=(11, 4.5))
    for k, name in enumerate(names):
        m = np.asarray(fit.mask[k])
        t = np.asarray(fit.ts[k])[m]
        Xm, Xf = np.asarray(fit.measured[k])[m], np.asarray(fit.fitted[k])[m]
        c = f"C{k % 10}"
        axs[0].plot(Xm[:, 0], Xm[:, 1], ".", color=c, ms=2.5, alpha=0.6, label=f"{name} measured")
        axs[0].plot(Xf[:, 0], Xf[:, 1], "-", color=c, lw=1.2, label=f"{name} fitted")
        axs[1].plot(t, Xm[:, 2] * 1e3, ".", color=c, ms=2.5, alpha=0.6)
        axs[1].plot(t, Xf[:, 2] * 1e3, "-", color=c, lw=1.2)
        h = _held(fit, k)
        if h.any():  # the held-out samples and the fit's prediction of them
            th, Xh, Xp = (np.asarray(fit.ts[k])[h], np.asarray(fit.measured[k])[h],
                          np.asarray(fit.fitted[k])[h])
            axs[0].plot(Xh[:, 0], Xh[:, 1], "x", color=c, ms=3, label=f"{name} held out")
            axs[0].plot(Xp[:, 0], Xp[:, 1], "--", color=c, lw=1.2, label=f"{name} predicted")
            axs[1].plot(th, Xh[:, 2] * 1e3, "x", color=c, ms=3)
            axs[1].plot(th, Xp[:, 2] * 1e3, "--", color=c, lw=1.2)
    axs[0].set_xlabel("x (m)")
    axs[0].set_ylabel("y (m)")
    axs[0].set_aspect("equal", adjustable="datalim")
    axs[0].legend(fontsize=7)
    axs[0].set_title(f"platform path, {fit.model}")
    axs[1].set_xlabel("t (s)")
    axs[1].set_ylabel("phi (mrad)")
    axs[1].set_title("platform angle")
    for ax in axs:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    paths.append(_save(fig, out_dir, "fit_trajectory.png"))

    fig, axs = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    scale = (1e3, 1e3, 1e3)
    labels = ("x residual (mm)", "y residual (mm)", "phi residual (mrad)")
    noise = (fit.noise[0], fit.noise[0], fit.noise[1])
    for k, name in enumerate(names):
        for m, style, tag in ((np.asarray(fit.mask[k]), ".-", ""),
                              (_held(fit, k), "x--", " held out")):
            t = np.asarray(fit.ts[k])[m]
            d = (np.asarray(fit.fitted[k]) - np.asarray(fit.measured[k]))[m]
            for j in range(3):
                axs[j].plot(t, d[:, j] * scale[j], style, color=f"C{k % 10}", ms=2, lw=0.5,
                            label=name + tag if j == 0 and m.any() else None)
    for j in range(3):
        if np.isfinite(noise[j]):  # infinite noise: the channel was not fitted
            axs[j].axhspan(-2 * noise[j] * scale[j], 2 * noise[j] * scale[j], color="0.85",
                           zorder=0)
        axs[j].set_ylabel(labels[j])
        axs[j].grid(alpha=0.3)
    axs[0].legend(fontsize=7)
    axs[0].set_title("fitted - measured (grey: +-2 x stated noise)")
    axs[-1].set_xlabel("t (s)")
    fig.tight_layout()
    paths.append(_save(fig, out_dir, "fit_residuals.png"))
    return paths


def _held(fit, k):
    """(m,) the held-out samples of experiment k (none without validation)."""
    held = getattr(fit, "held_out", None)
    return np.zeros(np.shape(fit.mask)[1], bool) if held is None else np.asarray(held[k])


def _save(fig, out_dir, name):
    path = os.path.join(out_dir, name)
    save_figure(fig, path, dpi=110)
    _pyplot().close(fig)
    return path


def profile_figure(profiles: list, path: str) -> str:
    """One panel per profile (`Identification.profile`): the cost rise (S - S_min)/s^2 against
    the unknown, the likelihood-ratio threshold, and the profile and linearised intervals."""
    plt = _pyplot()
    n = len(profiles)
    fig, axs = plt.subplots(1, n, figsize=(4.5 * n, 3.8), squeeze=False)
    for ax, pr in zip(axs[0], profiles):
        v, d = np.asarray(pr["values"]), np.asarray(pr["delta"])
        ax.plot(v, d, "o-", ms=3, label="profile")
        ax.axhline(pr["threshold"], color="k", lw=0.8, ls=":",
                   label=f"{pr['level'] * 100:.0f} % threshold")
        for x in pr["ci"]:
            if x is not None:
                ax.axvline(x, color="C0", lw=0.8)
        for x in pr["linearised"]:
            ax.axvline(x, color="C3", lw=0.8, ls="--")
        ax.plot([], [], color="C3", ls="--", lw=0.8, label="linearised interval")
        ax.set_xlim(v.min(), v.max())
        ax.set_ylim(-0.05 * 4 * pr["threshold"], 4 * pr["threshold"])
        ax.set_xlabel(pr["name"])
        ax.set_ylabel("(S - S_min) / s^2")
        ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path, dpi=120)
    plt.close(fig)
    return path
