"""The performance tables of the documentation, generated from `benchmarks/results/*.json`.

    python scripts/gen_perf.py            # print every table as Markdown

The docs build (`docs/hooks.py`) replaces each `<!-- perf:NAME -->` marker of a page with
`tables()[NAME]`, so the published numbers are always those of the JSON checked in. Only the
standard library is used (no JAX): the docs build stays fast.
"""

from __future__ import annotations

import functools
import json
import math
import os

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RESULTS = os.path.join(ROOT, "benchmarks", "results")

#: errors (m) at which solvers and tools are compared (as benchmarks/run.py)
MATCHED_ERRORS_M = (2e-8, 1e-10)
MODEL_ORDER = ("rigid", "reduced", "double1r", "beam")


def _load(*parts):
    path = os.path.join(RESULTS, *parts)
    if not os.path.exists(path):
        return None
    with open(path) as f:
        return json.load(f)


def _from_json(*parts):
    """A table's decorator: the benchmark JSON at `parts` (`_load`) given to it as `d`, the table
    "" where that benchmark has not been run."""
    def wrap(fn):
        @functools.wraps(fn)
        def table() -> str:
            d = _load(*parts)
            return "" if d is None else fn(d)
        return table
    return wrap


def _table(header, rows) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(out)


def _section(title: str, script: str, text: str, header, rows) -> str:
    """A study's paragraph: its title, the benchmark script that measured it, `text`, then the
    table of `rows` under `header`."""
    return f"**{title}** (`benchmarks/{script}`): {text}\n\n" + _table(header, rows)


def _ms(s) -> str:
    return f"{1e3 * s:.1f} ms" if s < 1 else f"{s:.2f} s"


def _machine(d) -> str:
    """One line naming where and when a result was measured."""
    m = d.get("machine", d)
    date = str(m.get("date", ""))[:10]
    jax = m.get("versions", {}).get("jax") or m.get("jax", "?")
    what = f"{m.get('backend', 'cpu').upper()}, {m.get('cpus', '?')} cores, JAX {jax}"
    return f"*Measured: {what}{', ' + date if date else ''}.*"


def interp_time(pts, err):
    """Time at error `err` on a work-precision line `pts` [(error, time)]: the cheapest point at
    or below `err`, interpolated in log-log with its neighbour above `err` where one exists
    (the rule of benchmarks/run.py)."""
    below = [p for p in pts if p[0] <= err]
    if not below:
        return None
    above = [p for p in pts if p[0] > err]
    e1, t1 = max(below, key=lambda p: p[0])
    if not above:
        return t1
    e0, t0 = min(above, key=lambda p: p[0])
    w = (math.log(err) - math.log(e0)) / (math.log(e1) - math.log(e0))
    return math.exp(math.log(t0) + w * (math.log(t1) - math.log(t0)))


def work_precision(backend="cpu") -> str:
    d = _load(backend, "work_precision.json")
    if d is None:
        return "*No work-precision results for this backend.*"
    rows = d["rows"]
    header = ["scene", "model"] + [f"fastest at {e:g} m" for e in MATCHED_ERRORS_M] + [
        "compile (per solver)"]
    out = []
    for scene in ("paper-circle", "servo-circle"):
        for model in MODEL_ORDER:
            mine = [r for r in rows if r["scene"] == scene and r["model"] == model]
            if not mine:
                continue
            cells = []
            for err in MATCHED_ERRORS_M:
                best = None
                for solver in sorted({r["solver"] for r in mine}):
                    pts = [(r["error_m"], r["run_s"]) for r in mine if r["solver"] == solver]
                    if solver.startswith("none"):  # no ODE: one exact point
                        t = pts[0][1]
                    else:
                        t = interp_time([p for p in pts if p[0] > 0], err)
                    if t is not None and (best is None or t < best[1]):
                        best = (solver, t)
                cells.append(f"{_ms(best[1])} ({best[0].replace('none (no ODE)', 'no ODE')})"
                             if best else "-")
            comp = {}
            for r in mine:
                if r["solver"].startswith("none") or not r.get("compile_s"):
                    continue
                comp[r["solver"]] = min(comp.get(r["solver"], 1e9), r["compile_s"])
            comp_txt = ", ".join(f"{s} {c:.0f} s" for s, c in comp.items()) or "-"
            out.append([scene, model] + cells + [comp_txt])
    note = (f"Error: {d['error']}, against {d['reference']}; {d['t_end_s']} s, "
            f"{d['n_out']} output times; L3 (`beam`) with N = {d.get('l3_elements', '?')}.")
    return _table(header, out) + "\n\n" + note + " " + _machine(d)


def contenders() -> str:
    d = _load("cpu", "contenders.json")
    if d is None:
        return "*No contender results.*"
    rows = [[f"{r['error_m']:g} m", f"{r['tool']} ({r['method']})", _ms(r["run_s"]),
             f"{r['ratio_to_ppr_jax']:.2f}"] for r in d["matched"]]
    note = (f"L2 (`{d['model']}`) `{d['scene']}`, {d['t_end_s']} s; reference: "
            f"{d['reference']}. Each tool's fastest method at the matched error.")
    return (_table(["error", "tool (fastest method)", "run", "/ ppr_jax"], rows) + "\n\n" + note
            + " " + _machine(d))


def compile_times() -> str:
    d = _load("cpu", "compile.json")
    if d is None:
        return "*No compile results.*"
    rows = []
    for r in d["rows"]:
        c, f, s = r["cold"], r["first"], r["second"]
        rows.append([r["model"], f"{c['compile_s']:.1f} s", f"{f['first_result_s']:.1f} s",
                     f"{s['compile_s']:.1f} s / {s['first_result_s']:.1f} s",
                     _ms(s["run_s"])])
    header = ["model", "cold compile", "first process: first result",
              "second process: load / first result", "run"]
    return _table(header, rows) + f"\n\n{d['scene']}; {d['what']}. " + _machine(d)


def compile_budget() -> str:
    d = _load("compile_budget.json")
    if d is None or not d.get("rows"):
        return "*No compile budget results.*"
    rows = []
    for r in d["rows"]:
        w = r["whole"]
        name = r["model"] + (f" (N = {r['elements']})" if r.get("elements") else "")

        def part(*names):
            for n in names:
                if n in r["parts"]:
                    lines = w["attribution"].get(n, {}).get("expanded_lines", 0)
                    return (f"{r['parts'][n]['compile_s']:.1f} s, "
                            f"{100 * lines / w['expanded_lines']:.0f} %")
            return "-"

        rows.append([name, r["scene"], f"{w['trace_lower_s']:.1f} s",
                     f"{w['compile_s']:.1f} s", _ms(w["run_s"]),
                     f"{w['stablehlo_lines']:,} ({w['expanded_lines']:,})",
                     f"{w['rhs']['eom']['copies_inlined']}",
                     f"{w['while_ops_inlined']} / {w['case_ops_inlined']}",
                     part("input"), part("start"), part("integration", "kinematics"),
                     part("outputs")])
    header = ["model", "scene", "trace + lower", "XLA compile", "run", "StableHLO lines "
              "(inlined)", "EOM copies", "while / case", "input", "start",
              "integration (or kinematics)", "outputs"]
    note = ("A fresh process per row (`benchmarks/compile_budget.py`), no persistent cache: the "
            "whole scene program's tracing and lowering, XLA compilation and run (minimum of "
            "repeats); its StableHLO lines, and in parentheses with every private function "
            "counted once per call path (XLA inlines them); the copies of the equations of "
            "motion (`_eom_terms_jit`) and the loops and branches after inlining. Each part of "
            "`AbstractScene.run` compiled alone (its XLA seconds) and its share of the whole "
            "program's inlined lines, attributed by each op's source location; the rest is "
            "the precondition checks and the jit boundary.")
    if d.get("note"):
        note += " " + d["note"]
    return _table(header, rows) + "\n\n" + note + " " + _machine(d)


def latency() -> str:
    d = _load("latency.json")
    if d is None or not d.get("rows"):
        return "*No latency results.*"
    sides = [k for k in ("base", "new") if k in d.get("checkouts", {})]
    names = {k: f"{k} ({(d['checkouts'][k].get('commit') or '?')[:7]})" for k in sides}

    def cell(r):
        if r is None:
            return "-"
        c = f"{r['wall_s']:.2f} s"
        if r.get("compile_s") is not None:
            c += f" (compile {r['compile_s']:.1f} s)"
        if r.get("first_fit_s") is not None:
            c += f" (fits {r['first_fit_s']:.1f} / {r['second_fit_s']:.1f} s)"
        return c

    rows = [[r["name"]] + [cell(r.get(k)) for k in sides] for r in d["rows"]]
    table = _table(["what"] + [names[k] for k in sides], rows)

    def num(v):
        return "-" if v is None else f"{v:.3g}"

    grows, notes = [], []
    for g in d.get("goals", []):
        what = g["goal"] + (f" ({g.get('model') or g.get('mode')})"
                            if g.get("model") or g.get("mode") else "")
        grows.append([what, num(g["value"]), num(g.get("base_value")), f"{g['limit']:.3g}",
                      "met" if g["met"] else ("not met" if g["met"] is not None else "-")])
        if g.get("bound"):
            notes.append(f"- {what}: bounded by {g['bound']}.")
    levers = {}
    for g in d.get("goals", []):
        if g.get("lever"):
            levers.setdefault(g["goal"], g["lever"])
    notes += [f"- Lever, {k}: {v}." for k, v in levers.items()]
    goals = _table(["goal", "new", "base", "limit", ""], grows)
    note = f"{d['scene']}; {d['what']}."
    if d.get("note"):
        note += " " + d["note"]
    return (table + "\n\n" + goals + "\n\n" + "\n".join(notes) + "\n\n" + note + " "
            + _machine(d))


def batch(backend="cpu") -> str:
    d = _load(backend, "batch.json")
    if d is None:
        return "*No batch results for this backend.*"
    rows = [[r["model"], f"{r['rtol']:g}", r["batch"], _ms(r["run_s"] / r["batch"]),
             f"{r['trajectories_per_s']:,.0f}",
             f"{r['compile_s']:.0f} s" if (r.get("compile_s") or 0) > 0.5 else "(compiled)"]
            for r in d["rows"]]
    header = ["model", "rtol", "batch", "per robot", "trajectories/s", "compile"]
    note = f"`{d['scene']}`, {d['t_end_s']} s; members: {d['members']}."
    flags = d["machine"].get("xla_flags")
    if flags:
        note += f" `XLA_FLAGS={flags}`."
    return _table(header, rows) + "\n\n" + note + " " + _machine(d)


def mjx_batch() -> str:
    d = _load("cpu", "mjx_batch.json")
    if d is None:
        return "*No MJX results (needs the `bench` extra).*"
    cols = {}
    for r in d["rows"]:
        if r["tool"] == "mjx":
            key = f"MJX RK4 dt {r['dt_s']:g} s"
        else:
            key = f"ppr_jax {r.get('solver', 'tsit5')} rtol {r.get('rtol', 0):g}"
        cols.setdefault(key, {})[r["batch"]] = r
    batches = sorted({r["batch"] for r in d["rows"]})
    header = ["batch"] + [
        f"{k} (error {max(r['member0_position_error_m'] for r in v.values()):.1e} m)"
        for k, v in cols.items()]
    rows = [[b] + [f"{v[b]['trajectories_per_s']:.3g}" if b in v else "-" for v in cols.values()]
            for b in batches]
    note = (f"Trajectories per second, `{d['scene']}` over {d['t_end_s']} s; MuJoCo "
            f"{d['mujoco']}, JAX {d['jax']}, {d['cpus']} cores. Timed: {d['includes']}")
    return _table(header, rows) + "\n\n" + note


def studies() -> str:
    out = []
    s = _load("sweep_sharding.json")
    if s is not None:
        rows = [[k.replace("_", " "), f"{v['per_member_ms']:.2f} ms",
                 f"{v['trajectories_per_s']:.0f}", f"{v['first_call_s']:.1f} s"]
                for k, v in s["rows"].items()]
        out.append(_section(
            "Sharded sweep", "sweep_sharding.py",
            f"{s['members']} `{s['model']}` paper-circle robots, rtol {s['rtol']:g}, over "
            f"{s['devices']} host devices: {s['speedup']:.2f}x; the two agree to "
            f"{s['max_abs_difference_m']:.1e} m.",
            ["run", "per robot", "trajectories/s", "first call"], rows))
    c = _load("sensitivity_cost.json")
    if c is not None:
        rows = [[k.replace("_", " "), _ms(v["run_s"]), f"{v['ratio_to_forward_run']:.1f}",
                 f"{v['compile_s']:.1f} s", f"{v['memory']['temp_bytes'] / 1e6:.2f} MB"]
                for k, v in c["rows"].items()]
        out.append(_section(
            "Sensitivity cost", "sensitivity_cost.py",
            f"`{c['model']}` paper-circle under the `{c['torque_model']}` torques, rtol "
            f"{c['rtol']:g}; the scalar is `{c['scalar']}` of all {c['n_parameters']} "
            f"parameters.",
            ["program", "run", "/ forward run", "compile", "XLA temp memory"], rows))
    k = _load("kernel_counts.json")
    if k is not None:
        p = k["programs"]
        rows = [[name, f"{v['kernels']}", f"{v['kernels_per_forward']:.1f}",
                 f"{v['pad_fusions']}", f"{v['us_per_call']:.1f} us"]
                for name, v in k["rhs"].items()]
        out.append(_section(
            "Kernel counts", "kernel_counts.py",
            f"a forward run launches {p['forward_run']['kernel_events']:,} XLA CPU kernels, its "
            f"`grad` {p['grad']['kernel_events']:,} ({p['grad']['kernels_per_forward']:.1f}x, "
            f"against {p['grad']['time_per_forward']:.1f}x the time). One right-hand side:",
            ["pass", "kernels", "/ forward", "zero-padding fusions", "time"], rows))
    t = _load("identify_time.json")
    if t is not None:
        f1, f2 = t["first_fit"], t["second_fit_after_compile"]
        e = t["experiment"]
        out.append(f"**Identification** (`benchmarks/identify_time.py`): `{e['model']}` "
                   f"{e['scene']}, {e['t_end_s']} s at {e['rate_hz']:g} Hz, unknowns "
                   f"{', '.join(t['unknowns'])}. First fit {f1['wall_s']:.1f} s "
                   f"(compilation and one evaluation "
                   f"{f1['first_call_s (compile + one evaluation)']:.1f} s, "
                   f"{f1['iterations']} iterations {f1['iterations_run_s']:.1f} s); a second "
                   f"fit on the compiled function {f2['wall_s']:.1f} s.")
    return "\n\n".join(out)


def engine_ab() -> str:
    """The engine issue's speed rows: this tree against its base commit, in one run on one
    machine each (`benchmarks/engine_ab.py`, `engine_ab*.json`: one file a machine)."""
    names = sorted(f for f in os.listdir(RESULTS) if f.startswith("engine_ab") and
                   f.endswith(".json"))
    out = []
    for name in names:
        d = _load(name)
        m = d["machine"]
        where = m.get("what") or f"{m.get('cpus')} cores"
        rows = []
        for r in d["rows"]:
            b, n = r.get("base"), r.get("new")
            cells = [_num(b), _num(n), f"{r['new_over_base']:.2f}" if "new_over_base" in r
                     else "-"]
            if "goal_absolute" in r:
                goal = f">= {r['goal_absolute']:,}"
            elif "goal" in r:
                ratio = "ratio" if "/ forward run" in r["row"] else "new / base"
                more = r["row"].endswith("trajectories/s")
                goal = f"{ratio} {'>=' if more else '<='} {r['goal']:.3g}"
            else:
                goal = "-"
            met = {True: "met", False: "not met"}.get(r.get("met"), "-")
            rows.append([r["row"], *cells, goal, met])
        notes = "".join(f"\n- {note}" for note in d.get("notes", []))
        out.append(f"`{name}`: {d['base']} (base) against {d['new']} (new), {d['date']}, "
                   f"{where}; jax {m.get('jax')}.\n\n"
                   + _table(["row", "base", "new", "new / base", "goal", ""], rows)
                   + (f"\n{notes}" if notes else ""))
    return "\n\n".join(out) if out else "*No A/B results.*"


def _num(x) -> str:
    if not isinstance(x, (int, float)) or x != x:
        return "-"
    return f"{x:.3g}" if abs(x) < 1000 else f"{x:,.0f}"


#: the engine profile's parts as the docs name them (benchmarks/kernel_counts.py, PARTS)
ENGINE_PART_NAMES = {
    "dispatch": "dispatch", "input_table": "input table", "start": "quasi-static start",
    "solver_start": "solver's start", "outputs": "outputs at the output times",
    "status_fixed": "status", "other_fixed": "other",
    "rhs_eom": "RHS: equations of motion", "rhs_mass_solve": "RHS: mass-matrix solve",
    "rhs_loop_closure": "RHS: loop closure", "rhs_spring_solve": "RHS: spring / strip solve",
    "input_lookup": "input table lookup", "rk_stages": "Runge-Kutta stages",
    "error_controller": "error estimate, step-size controller",
    "saving": "saving at output times", "loop_status": "status checks, loop",
}


def _us(us) -> str:
    return f"{us / 1e3:.1f} ms" if us >= 1e3 else f"{us:.1f} us"


def _element_ops(r) -> str:
    """A right-hand side's elementwise arithmetic as traced and as compiled (the compiled count
    holds XLA's recomputation of a value in each fusion that uses it)."""
    rhs = r.get("rhs", {})
    if "traced_element_ops" not in rhs:
        return "-"
    t, c = rhs["traced_element_ops"], rhs["compiled_element_ops"]
    return f"{t:,}, {c:,} ({c / t:.2f}x)"


def engine_profile() -> str:
    """Where a `paper-circle` run's kernels and time go, per model, before and after
    (benchmarks/kernel_counts.py --all-models, `engine_profile.json`)."""
    d = _load("engine_profile.json")
    if d is None:
        return "*No engine profile results.*"
    sides = [s for s in ("before", "after") if s in d]
    label = {s: f"{s} ({(d[s].get('commit') or '?')[:7]})" for s in sides}
    last = d[sides[-1]]["models"]
    models = [m for m in MODEL_ORDER if m in last and "error" not in last[m]]

    def row_of(side, m):
        r = d[side]["models"].get(m)
        return None if r is None or "error" in r else r

    def both(m, fn):
        cells = [fn(row_of(s, m)) if row_of(s, m) else "-" for s in sides]
        return " / ".join(cells)

    head = ["model", "steps", "run", "kernel events", "kernels a step", "a step",
            "one right-hand side", "its element operations: traced, compiled"]
    rows = []
    for m in models:
        rows.append([
            m, both(m, lambda r: f"{r['steps']:,}"),
            both(m, lambda r: _ms(r["run_s"])),
            both(m, lambda r: f"{r['kernel_events']:,}"),
            both(m, lambda r: f"{r['kernels_per_step']:.0f}" if "kernels_per_step" in r else "-"),
            both(m, lambda r: f"{r['us_per_step']:.1f} us" if "us_per_step" in r else "-"),
            both(m, lambda r: (f"{r['rhs']['kernels']} kernels, {r['rhs']['us_per_call']:.1f} us"
                               if "kernels" in r.get("rhs", {}) else "-")),
            both(m, _element_ops),
        ])
    out = []
    if len(sides) > 1:
        out.append("Each cell: " + " / ".join(label[s] for s in sides) + ".\n")
    out.append(_table(head, rows))
    ratios = d.get("ratios", {})
    if ratios:
        rrows = [[m] + [f"{ratios[m][k]:.2f}" if k in ratios[m] else "-"
                        for k in ("run_s", "kernel_events", "kernels_per_step", "us_per_step")]
                 for m in models if m in ratios]
        out.append(f"After / before ({label['after']} over {label['before']}):\n\n"
                   + _table(["model", "run", "kernel events", "kernels a step", "a step"], rrows))
    grows = [[g["goal"], g["model"], "-" if g["ratio"] is None else f"{g['ratio']:.2f}",
              f"{g['limit']:g}", {True: "met", False: "not met", None: "-"}[g["met"]]]
             for g in d.get("goals", [])]
    if grows:
        out.append("Goals:\n\n" + _table(["goal", "model", "after / before", "limit", ""],
                                          grows))

    def part_table(kind):
        names = [p for p, v in d["parts"].items() if v["kind"] == kind]
        prows = []
        for p in names:
            cells = []
            for m in models:
                vals = []
                for s in sides:
                    r = row_of(s, m)
                    if r is None:
                        vals.append("-")
                        continue
                    v = r[kind].get(p) if kind == "fixed" else r["step"].get(p)
                    if v is None:
                        vals.append("-")
                    elif p == "dispatch":
                        vals.append(_us(v["us"]))
                    elif kind == "fixed":
                        vals.append(f"{v['kernels']:,} k, {_us(v['us'])}")
                    else:
                        vals.append(f"{v['kernels_per_step']:.0f} k, {_us(v['us_per_step'])}")
                cells.append(" / ".join(vals))
            if any(c.replace("-", "").replace("/", "").strip() for c in cells):
                prows.append([ENGINE_PART_NAMES.get(p, p)] + cells)
        return _table(["part"] + models, prows)

    out.append("Once a run (kernel events `k` and time, per run):\n\n" + part_table("fixed"))
    arows = []
    for key, name in (("input_s", "the scene's input (table and path checks)"),
                      ("outputs_s", "the per-output quantities")):
        cells = [both(m, lambda r: _ms(r["alone"][key])
                      if key in r.get("alone", {}) else "-") for m in models]
        if any(c.replace("-", "").replace("/", "").strip() for c in cells):
            arows.append([name] + cells)
    if arows:
        arows.append(["the whole run"] + [both(m, lambda r: _ms(r["run_s"])) for m in models])
        out.append("The two largest of those, each compiled and timed alone (the profiler's "
                   "shares above understate them: it lengthens every kernel it records, the "
                   "step's short ones several times over, the outputs' long ones hardly at "
                   "all; inside the run the path checks may overlap the solve):\n\n"
                   + _table(["part"] + models, arows))
    out.append("In every step of the solver (kernel events `k` and time, per step):\n\n"
               + part_table("step"))
    notes = [f"`paper-circle`, the scene's defaults (L1 torques, {last[models[0]]['t_end_s']:g} s, "
             f"{last[models[0]]['n_out']} output times, each model's default solver and "
             "tolerances)" if models else "`paper-circle`"]
    notes += [r["note"] for m in models if (r := last[m]).get("note")]
    text = ("; ".join(notes) + ". *Kernels a step*, *a step*: the run against the same program "
            f"over {last[models[0]]['short']['t_end_s']:g} s, their difference over the "
            "difference of their steps (no attribution). The parts: each kernel event of a "
            "profiled run attributed to the Python call stack XLA keeps for its instruction, "
            "its time the part's share of the profiled run (its kernels' durations, the time "
            "between kernels spread evenly over all of them) "
            "applied to the unprofiled run less its dispatch; the *dispatch* is a compiled "
            "call of the same arguments that computes nothing. Run times: minimum of repeats, "
            f"`{d['command']}` ({d['runtime_s'] / 60:.0f} min).") if models else ""
    if d.get("note"):
        text += " " + d["note"]
    out.append(text + " " + _machine(d))
    return "\n\n".join(out)


@_from_json("engine_profile_batch.json")
def engine_profile_batch(d) -> str:
    """Where a batch's time goes, per model, before and after (benchmarks/kernel_counts.py
    --all-models --batch B, `engine_profile_batch.json`): the run and its parts' times, then the
    kernels that take the most of the newer side's time."""
    sides = [s for s in ("before", "after") if s in d]
    label = {s: f"{s} ({(d[s].get('commit') or '?')[:7]})" for s in sides}
    out = []
    for m in MODEL_ORDER:
        rows = {s: d[s]["models"].get(m) for s in sides}
        if any(r is None or "error" in r for r in rows.values()):
            continue
        last = rows[sides[-1]]
        runs = " against ".join(
            f"{_ms(rows[s]['run_s'])} ({rows[s]['trajectories_per_s']:,.0f} trajectories/s, "
            f"{label[s]})" for s in sides)
        names = [p for p in d["parts"] if any(p in rows[s]["parts"] for s in sides)]
        names.sort(key=lambda p: -last["parts"].get(p, {}).get("s", 0.0))
        prows = [[ENGINE_PART_NAMES.get(p, p)] + [
            (f"{_ms(v['s'])} ({100 * v['share']:.0f} %)" if (v := rows[s]["parts"].get(p))
             else "-") for s in sides] for p in names]
        trows = [[f"`{k['kernel']}`", ENGINE_PART_NAMES.get(k["part"], k["part"]),
                  f"`{k['where']}`", f"{k['events']:,}", f"{100 * k['share']:.1f} %"]
                 for k in last["top"]]
        out.append(f"**{m}**, {last['batch']:,} robots: {runs}.\n\n"
                   + _table(["part"] + [label[s] for s in sides], prows)
                   + f"\n\nThe kernels that take the most of {label[sides[-1]]}'s time:\n\n"
                   + _table(["kernel", "part", "innermost function", "events", "share"], trows))
    first = next(iter(d["after"]["models"].values()))
    rtol = first.get("rtol")
    settings = "the scene's defaults" if rtol is None else f"rtol {rtol:g}, atol {rtol / 100:g}"
    flags = d.get("machine", {}).get("xla_flags") or "XLA's default flags"
    text = (f"`paper-circle` at {settings}, the members' strip thickness spread over "
            f"{first['t_range_m'][0] * 1e3:.2f}-{first['t_range_m'][1] * 1e3:.2f} mm, mapped "
            "as the library maps a batch on one device (`map_members`: chunks of vmapped "
            f"members), {flags}; a part's time is its share of the profiled run applied to "
            f"the unprofiled one (minimum of repeats). `{d['command']}` "
            f"({d['runtime_s'] / 60:.0f} min). " + _machine(d))
    return "\n\n".join(out + [text])


def l3() -> str:
    d = _load("l3_validation.json")
    out = []
    if d is not None:
        rows = [[r["N"], r["solver"], f"{r['rtol']:g}", _ms(r["run_s"]), f"{r['steps']:.0f}",
                 f"{100 * r['metrics_max_relative_deviation']:.3g} %"] for r in d["speed"]]
        out.append("**Quasi-static L3, paper-circle, 7.54 s** (`benchmarks/l3_validation.py`; "
                   "deviation: the largest relative change of a metric against the tight "
                   f"{d['tight_solver']['solver']} run at rtol {d['tight_solver']['rtol']:g}):"
                   "\n\n" + _table(["N", "solver", "rtol", "run", "steps", "deviation"], rows))
    m = _load("l3_implicit.json")
    if m is not None:
        rows = []
        for r in m["runs"]:
            done = "run_s" in r
            rows.append([r["N"], f"{r['strip_loss_s']:g} s", f"{r['t_end_s']:g} s", r["solver"],
                         f"{r['rtol']:g}", _ms(r["run_s"]) if done else "did not finish",
                         r.get("steps", "-"), f"{r['error_m']:.1e} m" if done else "-",
                         f"{r['compile_s']:.0f} s" if r.get("compile_s", 0) > 1 else "",
                         "16-core host" if "host" in r else "2-core"])
        out.append("**Full L3 (strip dynamics), the start of paper-circle** "
                   "(`benchmarks/l3_implicit.py`; error against a Dopri8 run at rtol 1e-8 or "
                   "tighter; compare rows of the same machine only; these rows started from "
                   "the quasi-static balance before the strips were moved onto their slow "
                   "path, so their strip modes rang from t = 0):\n\n"
                   + _table(["N", "strip loss", "window", "solver", "rtol", "run", "steps",
                             "error", "compile", "machine"], rows))
    return "\n\n".join(out)


def l3_scene() -> str:
    w = _load("l3_whole_scene.json")
    if w is None or not w.get("runs"):
        return ""
    rows = [[q.get("scene", "paper-circle"), f"{q['N']}", "quasi-static", q["solver"],
             f"{q['rtol']:g}", _ms(q["run_s"]), "1", f"{q['steps']}", "-", "-", "-",
             f"{q['compile_s']:.0f} s"] for q in w["quasi_static"]]
    def key(r):
        return r.get("scene", "paper-circle"), r["N"], r["strip_loss_s"]

    def solver_error(r):
        # the platform's distance to the tightest run of the same scene, N and strip loss:
        # the solver's own error (the distance to the quasi-static L3 is mostly physics)
        ref = min((x for x in w["runs"] if key(x) == key(r)), key=lambda x: x["rtol"])
        if ref is r:
            return "reference" if len([x for x in w["runs"] if key(x) == key(r)]) > 1 else "-"
        d = max(math.hypot(a[0] - b[0], a[1] - b[1]) for a, b in zip(r["X"], ref["X"]))
        return f"{d:.1e} m"

    rows += [[r.get("scene", "paper-circle"), f"{r['N']}", f"full, loss {r['strip_loss_s']:g} s",
              r["solver"], f"{r['rtol']:g}",
              _ms(r["run_s"]), f"{r['run_over_quasi_static']:.1f}",
              f"{r['steps']} ({r['rejected']} rejected)",
              f"{100 * r['metrics_max_relative_deviation']:.2g} %",
              f"{r['platform_distance_max_m']:.1e} m", solver_error(r),
              f"{r['compile_s']:.0f} s"]
             for r in w["runs"]]
    return ("**Full L3 over a whole scene (7.54 s)** (`benchmarks/l3_whole_scene.py`; "
            "the full L3 from its slow-path start against the quasi-static L3 of the same N: "
            "run time as a multiple of the quasi-static one, largest relative change of a "
            "trajectory metric, largest platform distance; solver error: the largest platform "
            "distance to the tightest run of the same scene, N and strip loss; figure "
            "`l3_whole_scene.png`)\n\n"
            + _machine(w) + "\n\n"
            + _table(["scene", "N", "strips", "solver", "rtol", "run", "x quasi-static", "steps",
                      "metrics", "platform", "solver error", "compile"], rows))


@_from_json("implicit_l2.json")
def implicit(d) -> str:
    rows = [[f"{r['t_mm']:g}", r["solver"], f"{r['rtol']:g}", r["steps"],
             f"{r['rejected']} ({100 * r['rejected_fraction']:.1f} %)", _ms(r["run_s"]),
             f"{r['error_position_m']:.1e} m"] for r in d["rows"] if r.get("ok")]
    return ("**L2 servo-circle, 1 s, explicit against implicit** (`benchmarks/implicit_l2.py`; "
            "error against Dopri8 at rtol 1e-12; `kvaerno5-diffrax` is diffrax's own stage "
            "solve and controller, for comparison):\n\n"
            + _table(["t (mm)", "solver", "rtol", "steps", "rejected", "run", "error"], rows))


#: the day the implicit solvers' stage solve (`StageChord`) and PI controller landed: Kvaerno5
#: results measured before it show the old stage solve's rejections (git log -S StageChord)
STAGE_SOLVE_DATE = "2026-11-26"


def _percent_range(fractions) -> str:
    lo, hi = 100 * min(fractions), 100 * max(fractions)
    return f"{lo:.0f} %" if round(lo) == round(hi) else f"{lo:.0f}-{hi:.0f} %"


def kvaerno_l0_l2() -> str:
    """Kvaerno5 on L0-L2 in words, from the JSON: its rejected steps and its time against the
    fastest explicit solver at the error it reached (work-precision), its rejected steps in the
    implicit benchmark (`implicit_l2.json`), and whether the work-precision rows predate the
    current stage solve."""
    d = _load("cpu", "work_precision.json")
    if d is None:
        return ""
    rows = [r for r in d["rows"] if r["model"] in MODEL_ORDER[:3]]
    kv = [r for r in rows if r["solver"] == "kvaerno5" and r.get("steps")]
    if not kv:
        return ""
    ratios = []
    for r in kv:
        explicit = [q for q in rows if q["scene"] == r["scene"] and q["model"] == r["model"]
                    and q["solver"] in ("tsit5", "dopri5", "dopri8") and q["error_m"] > 0]
        times = [interp_time(sorted((q["error_m"], q["run_s"]) for q in explicit
                                    if q["solver"] == s), r["error_m"])
                 for s in {q["solver"] for q in explicit}]
        times = [t for t in times if t]
        if times:
            ratios.append(r["run_s"] / min(times))
    date = str(d.get("machine", {}).get("date", ""))[:10]
    text = (f"In the work-precision run ({date or 'undated'}), Kvaerno5 on L0-L2 rejected "
            f"{_percent_range([r['rejected'] / r['steps'] for r in kv])} of its steps")
    if ratios:
        text += (f" and took {min(ratios):.0f} to {max(ratios):.0f} times the fastest explicit "
                 f"solver's time at the error it reached")
    text += "."
    if date and date < STAGE_SOLVE_DATE:
        text += (f" Those rows predate the current stage solve and controller "
                 f"({STAGE_SOLVE_DATE}, below); rerun `python benchmarks/run.py --parts "
                 f"work-precision` to update them.")
    imp = _load("implicit_l2.json")
    if imp is not None:
        k5 = [r for r in imp["rows"] if r.get("ok") and r["solver"] == "kvaerno5"]
        if k5:
            text += (f" With the current stage solve (`implicit_l2.json`, L2 servo-circle, t = "
                     f"{', '.join(f'{t:g}' for t in sorted({r['t_mm'] for r in k5}))} mm, rtol "
                     f"{min(r['rtol'] for r in k5):g} to {max(r['rtol'] for r in k5):g}) it "
                     f"rejects {_percent_range([r['rejected_fraction'] for r in k5])}.")
    return text


@_from_json("identify_known_truth.json")
def known_truth(d) -> str:
    rows = [[r["case"], ", ".join(r["unknowns"]), " / ".join(f"{v:.4g}" for v in r["truth"]),
             r["actuation"], " / ".join(f"{b:.2g}" for b in r["bias_in_std"]),
             " / ".join(f"{v:.2f}" for v in r["mean_abs_error_in_std"]),
             " / ".join(f"{100 * c:.1f} %" for c in r["coverage_95"]), r["seeds"],
             _ms(r["warm_fit_s_median"])] for r in d["rows"]]
    dd = d["data"]
    return ("**Known truth on data ppr_jax did not make** (`benchmarks/identify_known_truth.py`:"
            f" the independent scipy L2, truth {dd['truth']} (and the fitted unknowns' truth"
            f" in each row), commands from {dd['commands_from']},"
            f" {dd['t_end_s']:g} s at {dd['rate_hz']:g} Hz, noise {dd['noise']}; bias of the "
            "noise-free fit and mean |error| in standard deviations (0.80 expected), coverage of "
            "the linearised 95 % intervals over the noise seeds):\n\n"
            + _table(["case", "unknowns", "truth", "driven by", "bias (std)",
                      "mean abs error (std)",
                      "coverage 95 %", "seeds", "warm fit"], rows))


@_from_json("start_sensitivity.json")
def start_sensitivity(d) -> str:
    """How much the start moves each metric and its t-derivative (benchmarks/start_sensitivity.py)
    and the library's sensitivities against the independent scipy L2's central differences."""
    parts = []
    for name, sc in d["scenes"].items():
        ref, lib = sc["reference"], sc["library"]
        rows = []
        for m in sc["metrics"]:
            v2, d2 = ref["two-pass"]["values"][m], ref["two-pass"]["derivatives"][m]

            def rel(a, b):
                """The change from b to a: in percent, or as a factor where it is one."""
                if not b:
                    return "n/a"
                return f"{100 * (a / b - 1):+.2g} %" if abs(a / b - 1) < 1 else f"x {a / b:.2g}"

            lv, ld = lib["two-pass"]["values"][m], lib["two-pass"]["derivatives"][m]
            rows.append([f"`{m}`", f"{v2:.6g}", rel(ref["one-pass"]["values"][m], v2),
                         rel(ref["static"]["values"][m], v2), f"{d2:.6g}",
                         rel(ref["one-pass"]["derivatives"][m], d2),
                         rel(ref["static"]["derivatives"][m], d2),
                         rel(lib["one-pass"]["derivatives"][m], ld),
                         f"{abs(lv / v2 - 1):.1e}", f"{abs(ld / d2 - 1):.1e}"])
        parts.append(
            f"**{name}** ({sc['t_end_s']:g} s, {sc['n_out']} samples, t = "
            f"{1e3 * sc['t_m']:g} mm; central differences at {sc['rel_step']:g} t; the starts' "
            "columns: the change from the two-pass value):\n\n"
            + _table(["metric m", "m (two-pass)", "one-pass", "static", "dm/dt (two-pass)",
                      "one-pass", "static", "dm/dt, library one-pass", "library m vs reference",
                      "library dm/dt vs reference"], rows))
        steps = sc["step_study"]
        head = ["step / t"] + [f"`{m}`" for m in sc["metrics"]]
        srows = [[f"{r['rel_step']:g}"] + [f"{r['derivatives'][m]:.7g}" for m in sc["metrics"]]
                 for r in steps]
        srows.append(["library (forward mode)"]
                     + [f"{lib['two-pass']['derivatives'][m]:.7g}" for m in sc["metrics"]])
        parts.append(f"Step-size study, {name}: the reference's central differences dm/dt "
                     "(metric units per m) against the relative step, and the library's "
                     "derivative:\n\n" + _table(head, srows))
    return "\n\n".join(parts) + "\n\n" + _machine(d)


def _threshold_table(d) -> str:
    a, b = list(d["settings"])

    def ratio(r, stat):
        # the key the script writes; files written before it compared any two settings
        return r.get(f"second / first ({stat})", r.get(f"derivatives / import ({stat})"))

    rows = [[r["quantity"].replace(" (s)", ""), _ms(r[a]["min"]), _ms(r[b]["min"]),
             f"{ratio(r, 'min'):.2f}", f"{ratio(r, 'median'):.2f}"] for r in d["rows"]]
    return (_table(["warm, minimum of the processes' minima", a, b, "ratio of minima",
                    "ratio of medians"], rows)
            + f"\n\n{d['repeats']} processes a setting, interleaved. " + _machine(d))


@_from_json("loop_threshold.json")
def loop_threshold(d) -> str:
    """XLA's small-loop threshold, the import's against `configure_cpu(derivatives=True)`'s
    (benchmarks/loop_threshold.py): per quantity the minimum over the processes of each setting,
    and the ratios of the minima and of the medians."""
    return _threshold_table(d)


@_from_json("loop_threshold_default.json")
def loop_threshold_default(d) -> str:
    """The import's small-loop threshold, 256 KiB before and 1 MiB now
    (benchmarks/loop_threshold.py --bytes): as `loop_threshold`."""
    return _threshold_table(d)


@_from_json("path_cost.json")
def path_cost(d) -> str:
    """Cost per integrator step of a path read from a file against the circle
    (benchmarks/path_cost.py)."""
    rows = []
    for r in d["rows"]:
        per = r["per_step_s"]
        after = r.get("per_step_after_input_vs_paper")
        rows.append([r["scene"], r["drive"], r["model"], _ms(r["run_s"]),
                     _ms(r["input_s"]) if "input_s" in r else "",
                     str(r["accepted_steps"]) if r["accepted_steps"] else "no ODE",
                     f"{1e6 * per:.0f} us" if per else "",
                     f"{r['per_step_vs_paper']:.2f}" if r.get("per_step_vs_paper") else "",
                     f"{after:.2f}" if after else "",
                     f"{r['run_vs_paper']:.2f}"])
    return (_table(["scene", "drive", "model", "run", "of which input", "steps", "per step",
                    "per step / paper's", "after the input / paper's", "run / paper's"], rows)
            + f"\n\n{d['t_end_s']:g} s, {d['n_out']} outputs, the file sampled at "
            f"{d['rate_hz']:g} Hz; the fastest of {d['repeats']} interleaved rounds after "
            "compiling. *Of which input*: the scene's input (its table along the path, built "
            "once per run) compiled and timed alone; *after the input*: (run - input) / steps, "
            "what each step costs.\n\n" + _machine(d))


@_from_json("identify_own.json")
def identify_own(d) -> str:
    """Identification of one's own experiment: the command line cold and warm, the API, and
    the hopeless starts refused (benchmarks/identify_own.py)."""
    cli, api = d.get("cli", {}), d["api (one process, no persistent cache)"]
    rows = []
    for key, what in (("cold", "`ppr-jax identify`, fresh process, empty compilation cache"),
                      ("second_process", "`ppr-jax identify`, a second process")):
        if key in cli:
            r = cli[key]
            rows.append([what, f"{r['wall_s']:.1f} s",
                         f"gamma = {r['estimate']:.4f} +- {r['std']:.4f}" if "estimate" in r
                         else f"exit {r['exit']}"])
    rows.append(["`pj.identify`, first fit (compiles)", f"{api['first']['wall_s']:.1f} s",
                 f"gamma = {api['first']['estimate']:.4f} +- {api['first']['std']:.4f}"])
    rows.append(["`pj.identify`, a second fit", f"{api['second']['wall_s']:.2f} s",
                 f"{api['second']['iterations']} iterations"])
    for what, r in cli.get("hopeless", {}).items():
        rows.append([f"hopeless start: {what}", f"{r['wall_s']:.1f} s",
                     f"refused, exit {r['exit']}"])
    loads = [r["load_before"][0] for r in (*[cli[k] for k in ("cold", "second_process")
                                              if k in cli], api["first"], api["second"])]
    e = d["experiment"]
    return (_table(["run", "wall", "result"], rows)
            + f"\n\n{e['t_end_s']:g} s at {e['rate_hz']:g} Hz on a path: {e['path']}; data of "
            f"the {e['data']}, true gamma {e['truth_gamma']:g}, start at the {e['start_gamma']}; "
            f"2 CPU cores, JAX {d['jax']}, load average {min(loads):.1f}-{max(loads):.1f} "
            "before the runs.")


@_from_json("compensate.json")
def compensate(d) -> str:
    """Compensation's cost and effect: a figure eight, cold and warm, against a forward run
    (benchmarks/compensate.py)."""
    rows = []
    for r in d["rows"]:
        b, a = r["error_before"], r["error_after"]
        rows.append([f"{r['model']}, {r['drive']}", f"{b['position_max'] * 1e3:.3g} mm",
                     f"{a['position_max'] * 1e3:.2g} mm",
                     f"{b['phi_max'] * 1e3:.3g} / {a['phi_max'] * 1e3:.2g} mrad",
                     _ms(r["inversion_warm_s"]), _ms(r["forward_run_s"]),
                     f"{r['inversion_over_forward_run']:.1f}", f"{r['cold_s']:.0f} s"])
    r0 = d["rows"][0]
    opt = [f"{r['model']}, {r['drive']}: first call {r['optimise']['first_s']:.0f} s, warm "
           f"{r['optimise']['warm_s']:.1f} s ({r['optimise']['iterations']} iterations, cost "
           f"{r['optimise']['cost_start_m2']:.2g} -> {r['optimise']['cost_m2']:.2g} m^2"
           + (f"; one Jacobian {r['optimise']['jacobian_s']['differences']:.1f} s by differences"
              f", {r['optimise']['jacobian_s']['forward']:.0f} s by forward mode, "
              f"{r['optimise']['jacobian_rel_diff']:.1g} apart"
              if "jacobian_s" in r["optimise"] else "") + ")"
           for r in d["rows"] if r.get("optimise")]
    tail = (" `method=\"optimise\"` (12 knots, at most 4 iterations, from the inversion's "
            "commands, no replays): " + "; ".join(opt) + ".") if opt else ""
    return (_table(["model, drive", "miss, nominal commands", "compensated", "phi: nominal / "
                    "compensated", "inversion (warm)", "one forward run", "inversion / run",
                    "first call, whole (cold)"], rows)
            + f"\n\n{r0['t_end_s']:g} s of a figure eight (2 rad/s, the orientation moving too) "
            f"at {r0['commands']} command times, Table 1's robot with 0.5 mm strips; the "
            "inversion alone, warm, against one forward run of the compensated commands; the "
            "first call in a fresh process: the inversion, the nominal and the compensated "
            "runs, compilation included." + tail + " " + _machine(d))


def compensate_headline() -> str:
    """The README's compensation cell, from benchmarks/results/compensate.json (L2, motion then
    torque drive)."""
    d = _load("compensate.json")
    r = {row["drive"]: row for row in d["rows"] if row["model"] == "double1r"}
    m, t = r["motion"], r["torque"]

    def mm(x):
        return f"{x * 1e3:.2g}"

    return (f"miss {mm(m['error_before']['position_max'])} / "
            f"{mm(t['error_before']['position_max'])} mm -> "
            f"{mm(m['error_after']['position_max'])} / {mm(t['error_after']['position_max'])} mm;"
            f" inversion {m['inversion_over_forward_run']:.1f} / "
            f"{t['inversion_over_forward_run']:.1f} forward runs' time (warm), first call "
            f"{m['cold_s']:.0f} / {t['cold_s']:.0f} s")


def simulate_headline() -> str:
    """The README's `ppr-jax simulate` cell, from benchmarks/results/latency.json (the new
    checkout's whole-command walls): first process (cold) / second process (warm), L0-L2 as a
    range and the quasi-static L3 (N = 16)."""
    d = _load("latency.json")
    wall = {r["name"]: r["new"]["wall_s"] for r in d["rows"] if r.get("new")}

    def side(kind):
        v = [wall[f"simulate {m} {kind}"] for m in ("rigid", "reduced", "double1r")]
        return f"{min(v):.1f}-{max(v):.1f} s (L0-L2)"

    return (f"{side('cold')}, {wall['simulate beam cold']:.0f} s (L3) / {side('warm')}, "
            f"{wall['simulate beam warm']:.1f} s (L3)")


def headline() -> dict:
    """The contenders' matched times, which the README's headline table quotes (to check it)."""
    d = _load("cpu", "contenders.json")
    return {r["tool"] + "@" + f"{r['error_m']:g}": r["run_s"] for r in d["matched"]} if d else {}


def tables() -> dict:
    return {
        "work-precision": work_precision("cpu"),
        "work-precision-gpu": work_precision("gpu"),
        "contenders": contenders(),
        "compile": compile_times(),
        "compile-budget": compile_budget(),
        "latency": latency(),
        "batch": batch("cpu"),
        "batch-gpu": batch("gpu"),
        "mjx": mjx_batch(),
        "studies": studies(),
        "engine-profile": engine_profile(),
        "engine-profile-batch": engine_profile_batch(),
        "engine-ab": engine_ab(),
        "l3": l3(),
        "l3-scene": l3_scene(),
        "implicit": implicit(),
        "kvaerno-l0-l2": kvaerno_l0_l2(),
        "known-truth": known_truth(),
        "start-sensitivity": start_sensitivity(),
        "path-cost": path_cost(),
        "loop-threshold": loop_threshold(),
        "loop-threshold-default": loop_threshold_default(),
        "identify-own": identify_own(),
        "compensate": compensate(),
    }


def main():
    for name, text in tables().items():
        print(f"## {name}\n\n{text}\n")


if __name__ == "__main__":
    main()
