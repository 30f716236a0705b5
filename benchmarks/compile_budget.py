"""Where a scene program's compilation goes: tracing, lowering, XLA, per part of the scene.

    python benchmarks/compile_budget.py [--models rigid reduced] [--scenes paper-circle]

For each model (L0 `rigid`, L1 `reduced`, L2 `double1r`, L3 `beam` with quasi-static strips at
N = 16) and scene (`paper-circle`, `servo-circle`), a fresh process (no persistent compilation
cache; equinox's runtime errors in NaN mode, as the `ppr-jax` console script runs) takes the
scene program that `run_scene` compiles (`_scenes/_run.py:prepare(scene, None, model,
SceneOptions())`: one robot, the scene's defaults) and measures

- the whole program: tracing, lowering to StableHLO, XLA compilation (seconds apart), its run
  (minimum of `--repeats` after a warm-up, each ending in `block_until_ready`), the lowered
  program's size (StableHLO lines and characters; its private functions; each one counted once
  per call path, as XLA inlines them: "expanded" lines) and the optimised HLO's size, and how
  many copies of the right-hand side it holds: the call sites of the equations of motion
  (`_dynamics._eom_terms_jit`, an `eqx.filter_jit`, so each use is a `func.call` to a private
  function) and their copies after inlining, the same for the vector field
  (`_simulate._vector_field`), and the `stablehlo.while` / `stablehlo.case` ops;
- the attribution of the whole program's lines, right-hand-side copies and loops to the parts
  of `AbstractScene.run` (`_scenes/_base.py`), from each op's source location (the frame of
  `AbstractScene.run` it was traced under): `input` (`scene.commands`: the input table
  `tabulated` with its node checks and `path_out_of_reach`), `start`
  (`quasi_static_core` and the loop check at the start), `integration` (`simulate_core`, the
  diffrax solve), `kinematics` (motion-driven L0/L1: forward kinematics and inverse dynamics,
  no ODE), `outputs` (`_result`: `_metrics.outputs`, the nominal path, the status), `checks`
  (the precondition flags that freeze a failed run) and `boundary` (the jitted function's own
  argument and result handling);
- each part alone: wrapped in `eqx.filter_jit` with the arguments the scene passes it (the
  previous part's results, run for real), after `jax.clear_caches()` (so it traces afresh),
  its trace, lower and compile seconds and its size. The parts chained reproduce the whole
  program's platform poses (`parts_match_whole_m`).

Writes `benchmarks/results/compile_budget.json` (rows of other models and scenes already there
are kept) and prints a table. A row takes 20 s (L0) to a few minutes (L3) on 2 cores.
"""

from __future__ import annotations

import argparse
import collections
import functools
import json
import linecache
import os
import re
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
OUT = os.path.join(HERE, "results", "compile_budget.json")
MODELS = ("rigid", "reduced", "double1r", "beam")
SCENES = ("paper-circle", "servo-circle")
BEAM_ELEMENTS = 16
#: private functions counted as right-hand-side copies: the equations of motion, and the vector
#: field that calls them in the solver
RHS = {"eom": re.compile(r"_eom_terms_jit(_\d+)?$"),
       "vector_field": re.compile(r"_vector_field(_\d+)?$")}
#: equinox's wrapper frames, skipped when naming the function a part is traced in
WRAPPERS = {"BoundMethod.__call__", "_call", "_JitWrapper.__call__",
            "_filter_jit_cache.<locals>.fun_wrapped", "_JitWrapper.lower"}
PARTS = ("input", "start", "integration", "kinematics", "outputs", "checks", "boundary",
         "other")


# --------------------------------------------------------------------------------------------
# The lowered program's text


def _functions(text: str) -> dict:
    """{name: body lines} of the module's `func.func`s (the body between the header and the
    closing brace at two spaces' indentation)."""
    out, name, body = {}, None, []
    head = re.compile(r"^  func\.func (?:public |private )?@([\w$.-]+)\(")
    for line in text.splitlines():
        m = head.match(line)
        if m:
            name, body = m.group(1), []
            continue
        if name is not None:
            if line.startswith("  }"):
                out[name] = body
                name = None
            else:
                body.append(line)
    return out


_CALL = re.compile(r"\bcall @([\w$.-]+)\(")


class Program:
    """The call graph of a lowered module and each function's size when inlined."""

    def __init__(self, text: str):
        self.bodies = _functions(text)
        self.calls = {f: collections.Counter(c for ln in b for c in _CALL.findall(ln))
                      for f, b in self.bodies.items()}

    @functools.lru_cache(maxsize=None)
    def expanded(self, f: str) -> collections.Counter:
        """Lines, while/case ops and right-hand-side copies of `f` with every call inlined."""
        body = self.bodies.get(f, [])
        c = collections.Counter(lines=len(body),
                                while_ops=sum("stablehlo.while" in ln for ln in body),
                                case_ops=sum("stablehlo.case" in ln for ln in body))
        for g, k in self.calls.get(f, {}).items():
            for key, pat in RHS.items():
                if pat.match(g):
                    c[key] += k
            for key, v in self.expanded(g).items():
                c[key] += k * v
        return c

    def summary(self, text: str) -> dict:
        full = self.expanded("main")
        rhs = {}
        for key, pat in RHS.items():
            names = sorted(f for f in self.bodies if pat.match(f))
            rhs[key] = {
                "functions": len(names),
                "lines_each": [len(self.bodies[f]) for f in names],
                "call_sites": sum(self.calls[f2][f] for f2 in self.calls for f in names),
                "copies_inlined": full[key],
            }
        top = sorted(self.bodies, key=lambda f: -len(self.bodies[f]))[:8]
        return {
            "stablehlo_lines": len(text.splitlines()), "stablehlo_chars": len(text),
            "functions": len(self.bodies),
            "expanded_lines": full["lines"],
            "while_ops": text.count("stablehlo.while"), "case_ops": text.count("stablehlo.case"),
            "while_ops_inlined": full["while_ops"], "case_ops_inlined": full["case_ops"],
            "rhs": rhs,
            "largest_functions": [{"name": f, "lines": len(self.bodies[f])} for f in top],
        }


def _locations(debug_text: str) -> dict:
    return {m.group(1): m.group(2)
            for m in re.finditer(r"^#(loc\d*) = (loc\(.*\))$", debug_text, re.M)}


def _frames(locs: dict):
    """loc id -> its Python frames, innermost first: (function, file, line)."""

    @functools.lru_cache(maxsize=None)
    def frames(ref: str) -> tuple:
        s = locs.get(ref)
        if s is None:
            return ()
        m = re.fullmatch(r"loc\(callsite\(#(loc\d+) at #(loc\d+)\)\)", s)
        if m:
            return frames(m.group(1)) + frames(m.group(2))
        m = re.fullmatch(r'loc\("((?:[^"\\]|\\.)*)"\(#(loc\d+)\)\)', s)
        if m:
            f = re.match(r'loc\("((?:[^"\\]|\\.)*)":(\d+):', locs.get(m.group(2), ""))
            if f:
                return ((m.group(1), f.group(1), int(f.group(2))),)
            return frames(m.group(2))  # a name-stack location around a call site
        return ()

    return frames


def _part(frames: tuple) -> tuple:
    """(part, detail) of an op from its frames: the line of `AbstractScene.run` it was traced
    under, and the function that line called."""
    names = [f[0] for f in frames]
    if "AbstractScene.run" not in names:
        return "boundary", ""
    i = names.index("AbstractScene.run")
    src = linecache.getline(frames[i][1], frames[i][2])
    below = [n for n in names[:i] if n not in WRAPPERS]
    inner = below[-1] if below else ""
    detail = below[-2] if len(below) > 1 else inner
    if "commands" in src:
        return "input", detail
    if "_result" in src:
        return "outputs", detail
    if any(k in src for k in ("quasi_static_core", "_open_at", "initial_offset")):
        return "start", inner
    if any(k in src for k in ("simulate_core", "max_steps")):
        return "integration", inner
    if any(k in src for k in ("_any(", "params_invalid")):
        return "checks", inner
    if any(k in src for k in ("kinematic_motion", "first_failure", "Solution(", "zero",
                              "codes")):
        return "kinematics", inner
    return "other", src.strip()[:40]


def attribute(program: Program, debug_text: str) -> dict:
    """{part: {lines, expanded lines, rhs copies, loops, detail: {...}}} of the whole program's
    main function: each op by its source location, each call with its callee inlined."""
    locs = _locations(debug_text)
    frames = _frames(locs)
    main = _functions(debug_text)["main"]
    out: dict = {}
    part = ("boundary", "")
    for ln in main:
        m = re.search(r"loc\(#(loc\d+)\)\s*$", ln)
        if m:  # lines without a location (region braces) go with the op before them
            part = _part(frames(m.group(1)))
        c = collections.Counter(lines=1, expanded_lines=1,
                                while_ops=int("stablehlo.while" in ln),
                                case_ops=int("stablehlo.case" in ln))
        for g in _CALL.findall(ln):
            for key, pat in RHS.items():
                if pat.match(g):
                    c[key] += 1
            e = program.expanded(g)
            c["expanded_lines"] += e["lines"]
            for key in ("while_ops", "case_ops", *RHS):
                c[key] += e[key]
        row = out.setdefault(part[0], {"detail": {}})
        for key, v in c.items():
            row[key] = row.get(key, 0) + v
        if part[1]:
            d = row["detail"].setdefault(part[1], {"lines": 0, "expanded_lines": 0, "eom": 0})
            for key in d:
                d[key] += c[key]
    for row in out.values():
        for key in ("lines", "expanded_lines", "while_ops", "case_ops", *RHS):
            row.setdefault(key, 0)
    return {p: out[p] for p in PARTS if p in out}


# --------------------------------------------------------------------------------------------
# The child process: one (model, scene)


def _stages(fn, args) -> tuple:
    """(lowered, compiled, seconds): trace, lower and compile an `eqx.filter_jit` function
    ahead of time, each stage timed (through equinox's jit wrapper where its internals are
    as expected; otherwise `fn.lower`, trace and lower together)."""
    try:
        from equinox import _jit
        from equinox._compile_utils import Compiled

        info = (fn._signature, fn._dynamic_fun, fn._static_fun, fn.donate_first,
                fn.donate_rest)
        t0 = time.perf_counter()
        dd, dn, st = _jit._preprocess(info, args, {}, return_static=True)
        traced = fn._cached.trace(dd, dn, st)
        t1 = time.perf_counter()
        lowered = traced.lower()
        t2 = time.perf_counter()
        compiled = lowered.compile()
        t3 = time.perf_counter()
        wrapped = Compiled(compiled, info, _jit._preprocess, _jit._postprocess)
        secs = {"trace_s": t1 - t0, "lower_s": t2 - t1, "trace_lower_s": t2 - t0,
                "compile_s": t3 - t2}
    except (AttributeError, ImportError, TypeError):
        t0 = time.perf_counter()
        low = fn.lower(*args)
        t1 = time.perf_counter()
        wrapped = low.compile()
        t2 = time.perf_counter()
        lowered, compiled = low.lowered, wrapped.compiled
        secs = {"trace_s": None, "lower_s": None, "trace_lower_s": t1 - t0, "compile_s": t2 - t1}
    return lowered, compiled, wrapped, secs


def _sizes(lowered, compiled) -> tuple:
    text = lowered.as_text()
    program = Program(text)
    out = program.summary(text)
    hlo = compiled.as_text() or ""
    out["optimised_hlo"] = {"lines": len(hlo.splitlines()), "chars": len(hlo),
                            "while_ops": len(re.findall(r"\bwhile\(", hlo)),
                            "conditional_ops": len(re.findall(r"\bconditional\(", hlo))}
    return out, program


def _measure(fn, args, label: str) -> tuple:
    lowered, compiled, wrapped, secs = _stages(fn, args)
    sizes, program = _sizes(lowered, compiled)
    row = dict(secs, **sizes)
    print(f"  {label}: trace+lower {secs['trace_lower_s']:.2f} s, compile "
          f"{secs['compile_s']:.2f} s, {sizes['stablehlo_lines']} lines", file=sys.stderr,
          flush=True)
    return row, wrapped, lowered, program


def child(model_name: str, scene_name: str, repeats: int) -> dict:
    import diffrax
    import equinox as eqx
    import jax
    import jax.numpy as jnp
    import numpy as np

    import ppr_jax as pj
    from ppr_jax._actuation import MotionDriven
    from ppr_jax._errors import RESULTS, first_failure
    from ppr_jax._scenes._base import _open_at, kinematic_motion
    from ppr_jax._scenes._options import SceneOptions
    from ppr_jax._scenes._run import prepare
    from ppr_jax._simulate import Solution, simulate_core
    from ppr_jax._statics import quasi_static_core

    assert not jax.config.jax_compilation_cache_dir, "a persistent compilation cache is set"
    load0 = os.getloadavg()
    model = (pj.get_model(model_name, BEAM_ELEMENTS) if model_name == "beam"
             else pj.get_model(model_name))
    c = prepare(scene_name, None, model, SceneOptions())
    scene, model, robot, options = c.args
    row = {"model": model_name, "scene": scene_name, "solver": c.solver_name,
           "elements": BEAM_ELEMENTS if model_name == "beam" else None,
           "ppr_jax": os.path.dirname(pj.__file__),
           "eqx_on_error": os.environ.get("EQX_ON_ERROR", "raise")}

    whole, compiled, lowered, program = _measure(c.fn, c.args, "whole program")
    out = compiled(*c.args)
    jax.block_until_ready(out)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(compiled(*c.args))
        times.append(time.perf_counter() - t0)
    whole["run_s"] = min(times)
    whole["run_s_all"] = times
    whole["attribution"] = attribute(program, lowered.as_text(debug_info=True))
    row["whole"] = whole
    # The whole program again after clearing JAX's caches, as the parts below are measured:
    # a fresh trace, and an XLA compilation without the process's first-compile costs.
    jax.clear_caches()
    _, _, _, again = _stages(c.fn, c.args)
    whole["again_after_clear_caches"] = again

    def part_input(scene, model, robot, options):
        return scene.commands(model, robot, options.trajectory, options.times(), options.panels)

    def part_start(model, robot, options, act):
        z0, zd0, failed = quasi_static_core(model, robot, options.trajectory,
                                            options.times()[0], act)
        return z0, zd0, failed, _open_at(model, robot, z0)

    def part_integration(model, robot, options, act, z0, zd0, skip):
        return simulate_core(model, robot, act, z0, zd0, options.times(), options.solver,
                             options.controller, None, options.max_steps, jnp.zeros(3), False,
                             diffrax.NoProgressMeter(), options.adjoint, skip)

    def part_kinematics(model, robot, options, act):
        ts = options.times()
        X, Xd, tau, codes, folds = kinematic_motion(model, robot, act.angles,
                                                    options.trajectory(ts[0]), ts)
        zero = jnp.asarray(0)
        return Solution(ts=ts, z=X, zdot=Xd, tau=tau, num_steps=zero, num_accepted=zero,
                        num_rejected=zero,
                        result=first_failure((jnp.any(folds), RESULTS.singular_path),
                                             (jnp.any(codes != 0), RESULTS.kinematics_failed)))

    def part_outputs(scene, model, robot, options, sol, failed, open0, inp):
        return scene._result(model, robot, options.trajectory, sol, failed, open0,
                             inp.out_of_reach, inp.coarse, inp.singular)

    parts = {}

    def measure(name, fn, *args):
        jax.clear_caches()
        parts[name], compiled, _, _ = _measure(eqx.filter_jit(fn), args, name)
        return jax.block_until_ready(compiled(*args))

    inp = measure("input", part_input, scene, model, robot, options)
    act = inp.actuation
    if isinstance(act, MotionDriven) and model.actuated_index is None:
        sol = measure("kinematics", part_kinematics, model, robot, options, act)
        res = measure("outputs", part_outputs, scene, model, robot, options, sol, None, None,
                      inp)
    else:
        z0, zd0, failed, open0 = measure("start", part_start, model, robot, options, act)
        flags = [f for f in (failed, open0, inp.out_of_reach, inp.singular, inp.coarse)
                 if f is not None]
        skip = jnp.asarray(np.any([bool(f) for f in flags]))
        sol = measure("integration", part_integration, model, robot, options, act, z0, zd0,
                      skip)
        res = measure("outputs", part_outputs, scene, model, robot, options, sol, failed, open0,
                      inp)
    row["parts"] = parts
    row["parts_match_whole_m"] = float(np.max(np.abs(np.asarray(res.X) - np.asarray(out.X))))
    row["load_average"] = {"start": load0, "end": os.getloadavg()}
    return row


# --------------------------------------------------------------------------------------------
# The parent: fresh processes, the JSON and the table


def _run_child(model: str, scene: str, args) -> dict:
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(("JAX_COMPILATION_CACHE", "JAX_PERSISTENT_CACHE"))}
    env["EQX_ON_ERROR"] = args.on_error
    env["PYTHONPATH"] = os.pathsep.join([ROOT] + [p for p in [env.get("PYTHONPATH")] if p])
    cmd = [sys.executable, os.path.abspath(__file__), "--child", model, scene,
           "--repeats", str(args.repeats)]
    t0 = time.perf_counter()
    p = subprocess.run(cmd, stdout=subprocess.PIPE, text=True, env=env, timeout=args.timeout)
    if p.returncode != 0:
        raise RuntimeError(f"{model} {scene}: the child failed (exit {p.returncode})")
    row = json.loads(p.stdout.strip().splitlines()[-1])
    row["process_s"] = time.perf_counter() - t0
    return row


def _share(row, part) -> str:
    tot = sum(p["compile_s"] for p in row["parts"].values())
    return f"{100 * row['parts'][part]['compile_s'] / tot:.0f} %" if part in row["parts"] else "-"


def table(data: dict) -> str:
    # a FlatJit program's tracing and lowering are timed together (`_measure`): one column
    lines = [f"{'model':9s} {'scene':13s} {'trace+lower':>11s} {'compile':>8s} "
             f"{'run':>9s} {'lines':>7s} {'expanded':>9s} {'eom calls/copies':>16s} "
             f"{'while/case':>10s}"]
    for r in data["rows"]:
        w = r["whole"]
        e = w["rhs"]["eom"]
        lines.append(
            f"{r['model']:9s} {r['scene']:13s} {w['trace_lower_s']:11.2f} "
            f"{w['compile_s']:8.2f} {1e3 * w['run_s']:7.1f}ms {w['stablehlo_lines']:7d} "
            f"{w['expanded_lines']:9d} {e['call_sites']:>8d}/{e['copies_inlined']:<7d} "
            f"{w['while_ops_inlined']:>4d}/{w['case_ops_inlined']:<5d}")
        tot_lines = w["expanded_lines"]
        for name, p in r["parts"].items():
            a = w["attribution"].get(name, {})
            lines.append(
                f"    {name:12s} alone: trace+lower {p['trace_lower_s']:5.2f} s, compile "
                f"{p['compile_s']:6.2f} s ({_share(r, name):>4s} of the parts'), "
                f"{p['stablehlo_lines']:6d} lines; in the whole: "
                f"{100 * a.get('expanded_lines', 0) / tot_lines:3.0f} % of expanded lines, "
                f"{a.get('eom', 0)} eom copies")
        ps = r["parts"].values()
        again = w.get("again_after_clear_caches", {})
        lines.append(
            f"    parts alone, sum: trace+lower {sum(p['trace_lower_s'] for p in ps):.2f} s, "
            f"compile {sum(p['compile_s'] for p in ps):.2f} s; the whole again after "
            f"clear_caches: trace+lower {again.get('trace_lower_s', float('nan')):.2f} s, "
            f"compile {again.get('compile_s', float('nan')):.2f} s")
        rest = {k: v for k, v in w["attribution"].items() if k not in r["parts"]}
        if rest:
            lines.append("    rest of the whole: " + ", ".join(
                f"{k} {100 * v['expanded_lines'] / tot_lines:.0f} % ({v['eom']} eom)"
                for k, v in rest.items()))
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="+", choices=MODELS, default=list(MODELS))
    ap.add_argument("--scenes", nargs="+", choices=SCENES, default=list(SCENES))
    ap.add_argument("--repeats", type=int, default=3, help="timed runs of the whole program")
    ap.add_argument("--on-error", default="nan", choices=["nan", "raise"],
                    help="EQX_ON_ERROR of the child processes (nan: as the console script)")
    ap.add_argument("--timeout", type=float, default=3600, help="seconds per (model, scene)")
    ap.add_argument("--note", default=None, help="a note stored in the JSON (e.g. a busy machine)")
    ap.add_argument("--out", default=OUT)
    ap.add_argument("--child", nargs=2, metavar=("MODEL", "SCENE"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        print(json.dumps(child(*args.child, args.repeats)), flush=True)
        return 0

    sys.path.insert(0, ROOT)
    from benchmarks.run import machine

    data = {"rows": []}
    if os.path.exists(args.out):
        with open(args.out) as f:
            data = json.load(f)
    data.update({
        "machine": machine(False),
        "what": "one fresh process per (model, scene), no persistent cache, EQX_ON_ERROR="
                f"{args.on_error}; the scene program of run_scene at the scene's defaults "
                f"(7.54 s, 755 output times, default solver and tolerances; beam: quasi-static "
                f"strips, N = {BEAM_ELEMENTS}); seconds of tracing, lowering to StableHLO and "
                f"XLA compilation; run: minimum of {args.repeats}; expanded lines and inlined "
                "copies: each private function counted once per call path (as XLA inlines "
                "them); parts alone: each part of AbstractScene.run in its own filter_jit after "
                "jax.clear_caches()",
    })
    if args.note is not None:
        data["note"] = args.note
    for model in args.models:
        for scene in args.scenes:
            print(f"{model} {scene} ...", file=sys.stderr, flush=True)
            row = _run_child(model, scene, args)
            data["rows"] = [r for r in data["rows"]
                            if (r["model"], r["scene"]) != (model, scene)] + [row]
            data["rows"].sort(key=lambda r: (SCENES.index(r["scene"]), MODELS.index(r["model"])))
            os.makedirs(os.path.dirname(args.out), exist_ok=True)
            with open(args.out, "w") as f:
                json.dump(data, f, indent=1)
    print(table(data))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
