"""One self-contained HTML report of a design: the optimum against its start, the active
constraints and bounds with their multipliers, the optimum's sensitivity to every bound, the
optimiser's history, the verification (KKT, finite differences, grid, L3 re-score), with the
figures embedded (the page, tables and figures are those of identification's report,
`_studies._html`)."""

from __future__ import annotations

import html
from typing import Optional

import numpy as np

from ..._files import write_file
from .._html import figure, fmt, page, pyplot, table


def bound_sensitivities(d) -> list:
    """Every bound of the design with d(optimal objective)/d(bound) (0 where inactive) and the
    elasticity (bound/f*) d f*/d bound: [{kind ('variable'|'constraint'), name, side, bound,
    active, multiplier, elasticity}]; a band to avoid gives a row per edge (side 'band lower
    edge', 'band upper edge')."""
    f = d.objective["value"]
    act = {(b["variable"], b["side"]): b["multiplier"] for b in d.active_bounds}
    rows = []
    for n, (lo, hi) in d.bounds.items():
        for side, b in (("lower", lo), ("upper", hi)):
            mu = act.get((n, side), 0.0)
            rows.append({"kind": "variable", "name": n, "side": side, "bound": b,
                         "active": (n, side) in act, "multiplier": mu})
    for c in d.constraints:
        if c["side"] == "avoid":  # a band: each edge its own bound
            rows += [{"kind": "constraint", "name": c["metric"], "side": f"band {edge} edge",
                      "bound": b, "active": c["active"] and c["edge"] == edge,
                      "multiplier": c["multipliers"][edge]}
                     for edge, b in zip(("lower", "upper"), c["bound"])]
            continue
        rows.append({"kind": "constraint", "name": c["metric"], "side": c["side"],
                     "bound": c["bound"], "active": c["active"], "multiplier": c["multiplier"]})
    for r in rows:
        r["elasticity"] = r["multiplier"] * r["bound"] / f if f else float("nan")
    return rows


def _relation(c) -> str:
    return {"upper": "<=", "lower": ">="}.get(c["side"], "outside")


def _bound(c) -> str:
    """A constraint's bound as the table shows it: the value, or a band's (lo, hi)."""
    if c["side"] == "avoid":
        return f"({fmt(c['bound'][0])}, {fmt(c['bound'][1])})"
    return fmt(c["bound"])


def _history_figure(d) -> Optional[str]:
    if not d.history:
        return None
    plt = pyplot()
    it = [h["iteration"] for h in d.history]
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.5))
    a.plot(it, [h["objective"] for h in d.history], "o-")
    a.set_xlabel("iteration")
    a.set_ylabel(d.objective["metric"])
    a.set_title(f"objective ({d.objective['sense']})")
    viol = np.maximum([h["max_violation"] for h in d.history], 1e-16)
    b.semilogy(it, viol, "o-")
    b.set_xlabel("iteration")
    b.set_ylabel("largest violation (relative to its bound)")
    b.set_title("constraints")
    fig.tight_layout()
    return figure(fig, "history.png")


def _optimum_figure(d) -> str:
    plt = pyplot()
    names = list(d.variables)
    pos = np.arange(len(names))
    u = [(d.x[n] - d.bounds[n][0]) / (d.bounds[n][1] - d.bounds[n][0]) for n in names]
    u0 = [(d.x_start[n] - d.bounds[n][0]) / (d.bounds[n][1] - d.bounds[n][0]) for n in names]
    fig, ax = plt.subplots(figsize=(6.5, 0.6 * len(names) + 1.5))
    ax.barh(pos - 0.2, u0, 0.4, label="start")
    ax.barh(pos + 0.2, u, 0.4, label="optimum")
    ax.set_yticks(pos, names)
    ax.set_xlim(0, 1)
    ax.set_xlabel("position in the box, (x - lo)/(hi - lo)")
    ax.legend()
    fig.tight_layout()
    return figure(fig, "optimum_against_start.png")


def _sensitivity_figure(rows) -> str:
    plt = pyplot()
    labels = [f"{r['name']} {r['side']}" for r in rows]
    fig, ax = plt.subplots(figsize=(6.5, 0.35 * len(rows) + 1.5))
    ax.barh(np.arange(len(rows)), [r["elasticity"] for r in rows])
    ax.set_yticks(np.arange(len(rows)), labels)
    ax.axvline(0, color="k", lw=0.5)
    ax.set_xlabel("(bound / f*) d f*/d bound")
    fig.tight_layout()
    return figure(fig, "sensitivity_to_bounds.png")


def _verification_html(v) -> list:
    esc = html.escape
    if "grid" not in v:
        return [f"<p class='bad'>Not verified: {esc(str(v.get('skipped', '')))}</p>"]
    g, gc = v["grid"], v["gradient_check"]
    verdict = "<span class='ok'>verified</span>" if v["ok"] else "<span class='bad'>NOT " \
        "verified</span>"
    out = [f"<p>The optimum is {verdict}.</p>",
           table(["check", "value", "tolerance", "passed"],
                 [["KKT residual (relative)", fmt(v["kkt_residual"], 3), fmt(v["kkt_tol"], 3),
                   v["kkt_residual"] <= v["kkt_tol"]],
                  ["JAX gradient against finite differences (worst, relative)",
                   fmt(gc["worst"], 3), fmt(gc["rtol"], 3), gc["ok"]],
                  [f"{g['kind']} of {g['points']} points: best feasible objective",
                   fmt(g.get("best_objective")), "gap " + fmt(g.get("gap"), 3), g["ok"]]])]
    l3 = v.get("l3")
    if l3 is not None:
        cls = "ok" if l3["within"] else "bad"
        out += [f"<h3>Re-scored with the quasi-static L3 (N = {l3['n_elements']})</h3>",
                f"<p>PRB error band {l3['band']:.1%} at kappa0 = {fmt(l3['kappa0'], 3)}: "
                f"{esc(l3['band_source'])}; a frequency's band is 1 - sqrt(1 - e). "
                f"<span class='{cls}'>{esc(l3['note'])}</span>.</p>"]
        if l3["metrics"]:
            out.append(table(["metric", "PRB", "L3", "relative difference", "band", "within"],
                             [[n, fmt(m["prb"]), fmt(m["l3"]), f"{m['relative']:.2%}",
                               f"{m['band']:.1%}", m["within"]]
                              for n, m in l3["metrics"].items()]))
        if l3["constraints_met"]:
            out.append(table(["constraint", "bound", "L3", "met under L3"],
                             [[f"{c['metric']} {_relation(c)}", _bound(c), fmt(c["l3"]), c["met"]]
                              for c in l3["constraints_met"]]))
    return out


def write_design_report(d, path: str, *, command: Optional[str] = None) -> str:
    """Write `path`, one self-contained HTML file (figures embedded as base64 PNG) of the
    `Design` `d`.

    **Arguments:**

    - `d`: the `Design`.
    - `path`: the file to write (`report.html`).
    - `command`: the command that made it, shown as provenance.

    **Returns:** `path`.
    """
    from ..._programs import dependency_versions

    esc = html.escape
    o = d.objective
    sens = bound_sensitivities(d)
    parts = [
        f"<h1>Design: {esc(o['sense'])} {esc(o['metric'])}</h1>",
        f"<p>Variables {esc(', '.join(d.variables))}; optimiser {esc(str(d.info['optimizer']))}"
        f", derivatives {esc(str(d.info['mode']))}-mode; "
        + (f"scene {esc(str(d.info['scene']))} (model {esc(str(d.info.get('model')))}); "
           if d.info.get("scene") else "no scene; ")
        + ("feasible. " if d.feasible else
           f"<span class=bad>INFEASIBLE: {esc(str(d.infeasibility))}</span>. ")
        + f"{fmt(d.timing.get('total_s'), 3)} s.</p>",
        "<h2>Optimum against start</h2>",
        table(["", "start", "optimum", "lower bound", "upper bound"],
              [[n, fmt(d.x_start[n]), fmt(d.x[n]), fmt(d.bounds[n][0]), fmt(d.bounds[n][1])]
               for n in d.variables]
              + [[f"{o['metric']} (objective)", fmt(o["start_value"]), fmt(o["value"]), "", ""]]),
        _optimum_figure(d),
        "<h2>Constraints</h2>",
        table(["constraint", "bound", "value at the optimum", "active",
               "multiplier d f*/d bound"],
              [[f"{c['metric']} {_relation(c)}", _bound(c), fmt(c["value"]),
                (f"{c['active']} ({c['active_samples']} samples)"
                 if c["active"] and c.get("active_samples", 1) > 1 else
                 f"{c['active']} ({c['edge']} side)" if c["side"] == "avoid" else c["active"]),
                fmt(c["multiplier"], 4)]
               for c in d.constraints]) if d.constraints else "<p>None.</p>",
        "<h2>Sensitivity of the optimum to each bound</h2>",
        "<p>d f*/d bound is the multiplier of the bound (0 where it is inactive): what moving "
        "the bound by one unit (SI) changes the optimal objective by, to first order; the "
        "elasticity (bound/f*) d f*/d bound is the relative change per relative change.</p>",
        table(["bound", "value", "active", "d f*/d bound", "elasticity"],
              [[f"{r['kind']} {r['name']} {r['side']}", fmt(r["bound"]), r["active"],
                fmt(r["multiplier"], 4), fmt(r["elasticity"], 4)] for r in sens]),
        _sensitivity_figure(sens),
        "<h2>History</h2>",
    ]
    hist = _history_figure(d)
    parts += [hist] if hist else ["<p>No iterations recorded.</p>"]
    parts += [table(["start", "optimum", "objective", "feasible", "iterations", "message"],
                    [[", ".join(f"{k}={fmt(v, 4)}" for k, v in s["start"].items()),
                      ", ".join(f"{k}={fmt(v, 4)}" for k, v in s["optimum"].items()),
                      fmt(s["objective"]), s["feasible"], s["iterations"], s["message"]]
                     for s in d.starts]),
              "<h2>Verification</h2>"] + _verification_html(d.verification)
    parts += ["<h2>Metrics at the optimum</h2>",
              table(["metric", "value"], [[k, fmt(v)] for k, v in d.metrics.items()])]
    footer = [f"<p>Versions: <code>{esc(dependency_versions())}</code></p>",
              f"<p>Command: <code>{esc(command)}</code></p>" if command else ""]
    with write_file(path, "w", encoding="utf-8") as f:
        f.write(page(f"ppr_jax design: {o['sense']} {o['metric']}", parts, footer))
    return path
