"""One self-contained HTML report of an identification: what was fitted to what, the estimates
with both kinds of interval, what the data determine, how well the model explains and predicts
the data, the figures, and everything needed to reproduce it (data files and their hashes,
versions, the command)."""

from __future__ import annotations

import hashlib
import html
import math
import os
from typing import Optional, Sequence

import numpy as np

from ..._files import write_file
from .._html import fmt as _g, image as _image, page, table as _table


def _sha256(path: str) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _starts_html(fit) -> str:
    """The preflight's verdict and the starts: a forced fit past a refusal, an automatic
    multi-start and why, and how the starts ended."""
    esc = html.escape
    q, h = fit.quality or {}, fit.history
    out = []
    pre = h.get("preflight")
    if pre:
        out.append(f"<p>Preflight (identifiability at the initial guess, noise as stated, "
                   f"{_g(pre['run_s'], 3)} s): "
                   + (f"<span class='bad'>not identifiable: {esc(', '.join(pre['refused']))}; "
                      f"fitted anyway (force)</span>" if pre["refused"] else
                      "every combination identifiable or poorly identifiable") + ".</p>")
    if q.get("escalated"):
        out.append(f"<p>Starts (auto): {esc(q['escalated'])}; "
                   f"{esc(h['escalation']['note'])}.</p>")
    st = q.get("starts")
    if st:
        out.append(f"<p>Starts: {st['n']} fitted, {st['reached_best']} reached the best "
                   f"minimum" + (f"; {esc(st['note'])}" if st["note"] else "") + ".</p>")
    return "\n".join(out)


def write_report(fit, path: str, *, figures: Sequence[str] = (), data_files: Sequence[str] = (),
                 command: Optional[str] = None, profiles: Optional[list] = None) -> str:
    """Write `path`, one self-contained HTML file (figures embedded) of the `Identification`
    `fit`.

    **Arguments:**

    - `fit`: the `Identification`.
    - `path`: the file to write (`report.html`).
    - `figures`: PNG files to embed (`identification_figures`, `profile_figure`).
    - `data_files`: the measured files, listed with their sha256.
    - `command`: the exact command that made the fit.
    - `profiles`: `fit.profile(name)` results, whose intervals join the estimates table.

    **Returns:** `path`.
    """
    from ..._programs import dependency_versions
    from ._problem import noise_text

    esc = html.escape
    q = fit.quality or {}
    prof = {p["name"]: p for p in (profiles or [])}
    rows = []
    for i, n in enumerate(fit.names):
        e, s = float(fit.estimate[i]), float(fit.std[i])
        pr = prof.get(n)
        rows.append([n, _g(e), _g(s, 3), f"[{_g(fit.ci95[i, 0])}, {_g(fit.ci95[i, 1])}]",
                     f"[{_g(fit.ci95_log[i, 0])}, {_g(fit.ci95_log[i, 1])}]",
                     "-" if pr is None else f"[{_g(pr['ci'][0])}, {_g(pr['ci'][1])}]",
                     _g(float(fit.initial[i]))])
    parts = [
        f"<h1>Identification of {esc(', '.join(fit.names))}</h1>",
        f"<p>Model <code>{esc(fit.model)}</code>, scene <code>{esc(fit.scene)}</code>, "
        f"{len(fit.experiment_names)} experiment(s): {esc(', '.join(fit.experiment_names))}. "
        f"Driven by {esc(fit.actuation)}.</p>",
        ("<p class='ok'>The fit can be trusted: the model explains the data (residual scale "
         f"s = {_g(math.sqrt(fit.sigma2), 4)}; 1 = noise as stated).</p>" if q.get("ok") else
         "<p class='bad'>The fit cannot be trusted: "
         + esc("; ".join(q.get("problems", []))) + ".</p>"),
        f"<p>Stop: {esc(str(fit.history.get('stop')))} after "
        f"{esc(str(fit.history.get('iterations')))} iterations; compile "
        f"{_g(fit.history.get('compile_s', float('nan')), 3)} s, fit "
        f"{_g(fit.history.get('run_s', float('nan')), 3)} s.</p>",
        _starts_html(fit),
        "<h2>Estimates</h2>",
        _table(["unknown", "estimate", "std", "95 % (linearised)", "95 % (log)",
                "95 % (profile)", "initial"], rows),
        "<h2>Correlation</h2>",
        _table([""] + list(fit.names),
               [[n] + [_g(v, 3) for v in np.asarray(fit.correlation)[i]]
                for i, n in enumerate(fit.names)]),
        "<h2>What the data determine</h2>",
        _table(["combination", "relative std", "status"],
               [[c["expression"], f"{c['relative_std'] * 100:.3g} %", c["status"]]
                for c in fit.identifiability["combinations"]]),
        f"<p>Condition number {_g(fit.identifiability['condition_number'], 3)}. "
        f"{esc(fit.identifiability.get('note') or '')}</p>",
    ]
    if fit.measurement:
        parts += ["<h2>Measurement model</h2>",
                  _table(["nuisance", "estimate", "std", "unit"],
                         [[n, _g(v["estimate"], 4), _g(v["std"], 2), v["unit"]]
                          for n, v in fit.measurement["values"].items()])]
    if fit.initial_state:
        rows = []
        for en, row in fit.initial_state["experiments"].items():
            for k, v in row.items():
                rows.append([en, k, _g(v.get("estimate", v["offset"]), 6), _g(v["std"], 2),
                             v["unit"]])
        parts += ["<h2>Initial state</h2>",
                  _table(["experiment", "quantity", "value", "std", "unit"], rows)]
    parts += ["<h2>Residuals</h2>",
              _table(["experiment", "samples", "RMS x (mm)", "RMS y (mm)", "RMS phi (mrad)"],
                     [[e["name"], e["n"], _g(e["rms_x_m"] * 1e3, 4), _g(e["rms_y_m"] * 1e3, 4),
                       _g(e["rms_phi_rad"] * 1e3, 4)]
                      if not e.get("held_out") else [e["name"], 0, "held out", "", ""]
                      for e in fit.residual_stats["experiments"]]),
              f"<p>Stated noise: {noise_text(fit.noise)}.</p>"]
    v = fit.validation
    if v:
        verdict = ("<span class='ok'>generalises</span>" if v["generalises"] else
                   "<span class='bad'>does not generalise</span>")
        parts += ["<h2>Validation</h2>",
                  f"<p>Held out: {esc(v['held_out'])} ({v['samples']} samples). Residual scale "
                  f"{_g(v['residual_scale'], 4)} against {_g(v['train_residual_scale'], 4)} on "
                  f"the fitted samples: the model {verdict}.</p>",
                  _table(["experiment", "samples", "RMS position (mm)", "RMS phi (mrad)"],
                         [[e["name"], e["n"], _g(e["rms_position_m"] * 1e3, 4),
                           _g(e["rms_phi_rad"] * 1e3, 4)] for e in v["experiments"]])]
    if figures:
        parts += ["<h2>Figures</h2>"] + [_image(p) for p in figures]
    prov = [[os.path.abspath(p), _sha256(p)] for p in data_files]
    parts += ["<h2>Provenance</h2>",
              _table(["data file", "sha256"], prov) if prov else "",
              f"<p>Versions: <code>{esc(dependency_versions())}</code></p>",
              f"<p>Command: <code>{esc(command)}</code></p>" if command else ""]
    with write_file(path, "w", encoding="utf-8") as f:
        f.write(page(f"ppr_jax identification: {', '.join(fit.names)}", parts))
    return path
