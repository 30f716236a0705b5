"""Where a run's kernels and time go: XLA kernels launched by the scenes and by reverse mode.

Two measurements, one script.

**The engine profile** (`--all-models`, writes `benchmarks/results/engine_profile.json`): for
L0 `rigid`, L1 `reduced`, L2 `double1r` and the quasi-static L3 `beam` (N = 8) on
`paper-circle` (the scene's defaults: L1 torques, 7.54 s, 755 output times, the model's default
solver and tolerances; L3 over a shorter horizon, `--l3-t-end`, 51 output times), the scene
program that `pj.paper_circle` compiles (`_scenes/_run.py: prepare`, `scene_program`), compiled
ahead of time and then

- timed: the run (minimum of `--repeats` after a warm-up, each ending in `block_until_ready`),
  and the dispatch alone (a compiled function of the same arguments that computes nothing);
- its kernel events counted in JAX's profiler trace of one run (every event that names an HLO
  instruction, less the loops and conditionals that contain others), each with its duration;
  the traced run's time outside kernels (launches, loop control) is spread evenly over its
  kernels, the cost of launching one;
- each event attributed to a part by the Python call stack that XLA keeps for its HLO
  instruction (`stack_frame_id` in the compiled module's text: the frames JAX recorded while
  tracing, no annotation in the library needed, so a checkout of another commit is measured the
  same way). An instruction without a stack (a copy or dot that XLA made) takes the stack of
  the nearest instruction that uses it, else of one it uses. The parts (`PARTS`): fixed, once
  a run: the dispatch, the input table (`input_table`: the table and the path's checks), the
  quasi-static start (`start`), the solver's start (`solver_start`: initial step size, first
  stage), the per-output quantities at the output times (`outputs`: kinematics, residual,
  energies, torques) and the final status (`status_fixed`); in every step of the solver's
  loop: the right-hand side (`rhs_eom`: the equations of motion; `rhs_mass_solve`: the solve
  with the mass matrix; `rhs_loop_closure`: the closed loop's kinematics; `rhs_spring_solve`:
  L1's quasi-static spring solve, L3's strips), the input table's lookup (`input_lookup`), the
  Runge-Kutta stage arithmetic (`rk_stages`), the error estimate and step-size controller
  (`error_controller`), saving at output times (`saving`: interpolation and the store) and the
  loop's status checks and bookkeeping (`loop_status`, with the freeze of a failed member).
  A part's time is its share of the profiled run's time (its kernels' durations and their
  launches) applied to the unprofiled run less the dispatch. The shares are biased: the
  profiler lengthens each kernel it records, the step's short kernels several times over
  (L1: 34 ms of recorded kernel time in a 5.2 ms run) and the long kernels that run once
  hardly at all, so the parts outside the loop come out several times too small;
- hence the two largest of those parts also compiled and timed alone (`alone`: the scene's
  input, `scene.commands`, and the per-output quantities on the run's solution,
  `_metrics.outputs`);
- the same program over `--short-t-end` (0.01 s, the same output count and input table: one
  compiled program, the horizon is an argument): the difference of the two runs over the
  difference of their steps is the cost of a step (`us_per_step`, `kernels_per_step`), free of
  any attribution (the two runs timed in turn, so that both see the same load; on a busy
  machine the time can still come out wrong, even negative: the kernels are exact);
- one right-hand side alone (the scene's vector field at its initial state): its compiled XLA
  operations, its time per call inside a `lax.scan` of 2,000 calls, and its arithmetic as
  element operations (each elementwise operation once per output element) in the traced
  program and in the compiled one: XLA's fusion recomputes a value in every fusion that uses
  it, so the second can exceed the first (`jaxpr_element_ops`, `hlo_element_ops`).

`--checkout DIR` measures DIR's library (another commit: `before`) and this tree's (`after`),
each in a fresh process with `PYTHONPATH` set to its tree, one after the other on the same
machine, and writes both, their ratios and the speed goals met or not (`GOALS`: the run at most
1/5 of before's for L0-L2 and 1/2 for L3, kernel events a step at most 1/10). Kernel counts are
the robust figure; times on a shared machine are noisy (read differences below 10-20 % as
noise). Most of the script's time is compilation: an estimated 1-2 minutes a tree on a quiet
2-core CPU (XLA compiles L0-L2 in 3-8 s and L3 in about 15 s there), 20 minutes a tree on a
2-core machine shared with several others.

**A batch's profile** (`--all-models --batch B`, writes
`benchmarks/results/engine_profile_batch.json`): the same parts for the program of a batch of B
robots (`profile_batch`). A batch launches as many kernels as one run, each over every member,
so its time is arithmetic, and where XLA's fusion computes a value again in every kernel or
every entry that reads it, that recomputation is paid per member: the profile names the kernels
that take the most time.

**Reverse mode's cost** (without `--all-models`, writes `benchmarks/results/kernel_counts.json`):
the L1 `paper-circle` sensitivity (`benchmarks/sensitivity_cost.py`: 7.54 s, rtol 1e-8, L1 under
the rigid model's torques, the scalar `radial_error_min_m` of all 19 parameters) is made of
kernels of a few dozen numbers each, so its time is set by how many kernels XLA's CPU runtime
launches, not by arithmetic. Counted two ways:

- whole programs: the kernel events of one call of the compiled forward run and of its `grad`,
  from JAX's profiler trace (as above);
- one right-hand side (the scene's vector field at one state, torques from the scene's table): its
  compiled XLA operations (fusions, dots, copies) in the forward evaluation, a JVP (one tangent of
  the state) and a VJP (cotangents of the state and the robot), with the number of those fusions
  whose root is a zero-padding op (`pad`: the transpose of a slice), and its time per call inside
  a `lax.scan` of 2,000 calls (minimum of repeats).

Run:

    python benchmarks/kernel_counts.py --all-models --checkout /work/base   # before and after
    python benchmarks/kernel_counts.py --all-models                          # this tree only
    python benchmarks/kernel_counts.py --all-models --batch 256 --models reduced double1r \
        --checkout /work/base --repeats 5                                    # a batch's
    python benchmarks/kernel_counts.py [--model reduced] [--repeats 25]      # reverse mode
"""

from __future__ import annotations

import argparse
import collections
import glob
import json
import math
import os
import platform
import re
import subprocess
import sys
import tempfile
import time

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
OUT = os.path.join(HERE, "results")
#: HLO ops whose profiler events contain other kernels rather than being one
CONTAINER_OPS = ("while", "conditional", "call")
MODELS = ("rigid", "reduced", "double1r", "beam")
#: parts of a run, in the order the docs show them: (name, fixed once a run or per step, what)
PARTS = (
    ("dispatch", "fixed", "the compiled call's dispatch (arguments in, results out)"),
    ("input_table", "fixed", "the input table and the path's checks"),
    ("start", "fixed", "the quasi-static start and its loop check"),
    ("solver_start", "fixed", "the solver's start: initial step size, first stage"),
    ("outputs", "fixed", "per-output quantities at the output times (kinematics, residual, "
                         "energies, torques)"),
    ("status_fixed", "fixed", "the run's status codes"),
    ("other_fixed", "fixed", "the rest outside the solver's loop"),
    ("rhs_eom", "step", "right-hand side: equations of motion"),
    ("rhs_mass_solve", "step", "right-hand side: the solve with the mass matrix"),
    ("rhs_loop_closure", "step", "right-hand side: the closed loop's kinematics"),
    ("rhs_spring_solve", "step", "right-hand side: L1's quasi-static spring solve, L3's strips"),
    ("input_lookup", "step", "the input table's lookup"),
    ("rk_stages", "step", "Runge-Kutta stage arithmetic"),
    ("error_controller", "step", "error estimate and step-size controller"),
    ("saving", "step", "saving at output times (interpolation, store)"),
    ("loop_status", "step", "the loop's status checks and bookkeeping"),
)
STEP_PARTS = tuple(p for p, kind, _ in PARTS if kind == "step")
#: function names (substrings of the qualified name) anywhere in a right-hand side's call stack
#: -> its part, the first that matches
RHS_KEYS = (
    (("torque_at", "angles_at", "Chebyshev", "Interpolated", "PiecewiseCubic"), "input_lookup"),
    (("ik_reduced", ".strips", ".clamps", "_strip", "strip_"), "rhs_spring_solve"),
    (("solve_spd", "_cholesky", "lu_solve", "lu_factor"), "rhs_mass_solve"),
    (("dependent", "kin_at", "closure_residual", "kinematics", "solve_blocks",
      "AbstractClosedLoop.motion", "kin_from_angles", "chain_closure"), "rhs_loop_closure"),
)


# --------------------------------------------------------------------------------------------
# The profiler trace and the compiled module's call stacks


def _trace_events(compiled, args) -> list:
    """[(hlo_op, start_ns, duration_ns, thread)] of one call of `compiled(*args)` in JAX's
    profiler trace: every event that names an HLO instruction (loops and conditionals
    included: `kernels` leaves them out)."""
    from jax.profiler import ProfileData

    for _ in range(3):
        jax.block_until_ready(compiled(*args))
    try:
        opts = jax.profiler.ProfileOptions()
        opts.python_tracer_level = 0  # no Python events: they only slow the traced run
        kw = {"profiler_options": opts}
    except AttributeError:
        kw = {}
    with tempfile.TemporaryDirectory() as d:
        with jax.profiler.trace(d, **kw):
            jax.block_until_ready(compiled(*args))
        data = ProfileData.from_file(glob.glob(f"{d}/**/*.xplane.pb", recursive=True)[0])
    out = []
    for plane in data.planes:
        for line in plane.lines:
            for ev in line.events:
                stats = dict(ev.stats)
                if "hlo_op" in stats:
                    out.append((stats["hlo_op"], ev.start_ns, ev.duration_ns, line.name))
    return out


def _is_kernel(name: str, index: dict) -> bool:
    op = index[name][0] if name in index else re.sub(r"[.\d]+(\.clone)?$", "", name)
    return op not in CONTAINER_OPS


def _kernel_events(compiled, x) -> int:
    """Kernel events of one call of `compiled(x)` (loops and conditionals left out)."""
    index = hlo_index(compiled.as_text())
    return sum(_is_kernel(e[0], index) for e in _trace_events(compiled, (x,)))


def _table_of(text: str, name: str) -> dict:
    i = text.find("\n" + name + "\n")
    out = {}
    if i < 0:
        return out
    for line in text[i + len(name) + 2:].splitlines():
        if not line.strip():
            break
        k, v = line.split(" ", 1)
        out[int(k)] = v
    return out


_INSTR = re.compile(r"^\s+(?:ROOT )?%([^\s=]+) = (.*)$")
_OPCODE = re.compile(r"[\]\}\)] ([a-z][\w-]*)\(")


def hlo_index(text: str) -> dict:
    """{instruction: (opcode, call stack)} of a compiled module's text (`compiled.as_text()`):
    the stack innermost frame first, each frame (file, function, line), from the module's
    stack-frame tables; an instruction without one gets the stack of its fused computation's
    instructions, else of the nearest instruction of its computation that uses it, else of one
    it uses."""
    files = {k: v.strip('"') for k, v in _table_of(text, "FileNames").items()}
    funcs = {k: v.strip('"') for k, v in _table_of(text, "FunctionNames").items()}
    locs = {}
    for k, v in _table_of(text, "FileLocations").items():
        d = dict(re.findall(r"(\w+)=(\d+)", v))
        locs[k] = (files.get(int(d.get("file_name_id", 0)), "?"),
                   funcs.get(int(d.get("function_name_id", 0)), "?"), int(d.get("line", 0)))
    frames = {}
    for k, v in _table_of(text, "StackFrames").items():
        d = dict(re.findall(r"(\w+)=(\d+)", v))
        # the printed parent is one more than its frame's number (0: none)
        frames[k] = (int(d["file_location_id"]), int(d["parent_frame_id"]) - 1)
    stacks: dict = {}

    def stack(fid):
        if fid not in stacks:
            out, f, seen = [], fid, set()
            while f in frames and f not in seen:
                seen.add(f)
                loc, f = frames[f]
                if loc in locs:
                    out.append(locs[loc])
            stacks[fid] = tuple(out)
        return stacks[fid]

    comps: dict = {}  # computation -> [instruction]
    info: dict = {}  # instruction -> [opcode, stack, operands, computation, called]
    comp = None
    for line in text.splitlines():
        if line and not line[0].isspace() and line.rstrip().endswith("{"):
            comp = line.split()[1 if line.startswith("ENTRY") else 0].lstrip("%")
            comps[comp] = []
            continue
        m = _INSTR.match(line)
        if not m or comp is None:
            continue
        name, rest = m.groups()
        op = _OPCODE.search(rest)
        sf = re.search(r"stack_frame_id=(\d+)", rest)
        called = re.findall(r"calls=%([\w.\-]+)", rest)
        body = rest.split(", metadata=")[0]
        operands = [o for o in re.findall(r"%([\w.\-]+)", body) if o not in called]
        info[name] = [op.group(1) if op else "?", stack(int(sf.group(1))) if sf else (),
                      operands, comp, called]
        comps[comp].append(name)
    users: dict = collections.defaultdict(list)
    for name, (_, _, operands, comp, _) in info.items():
        for o in operands:
            if o in info and info[o][3] == comp:
                users[o].append(name)

    def inherit(name):
        op, st, operands, comp, called = info[name]
        if st:
            return st
        for c in called:  # a fusion: its instructions' stacks
            for n in reversed(comps.get(c, [])):
                if info[n][1]:
                    return info[n][1]
        for nbrs in (users, None):  # breadth first: users, then operands
            seen, front = {name}, [name]
            for _ in range(6):
                nxt = []
                for n in front:
                    for m_ in (users[n] if nbrs is users else info[n][2]):
                        if m_ in info and m_ not in seen:
                            seen.add(m_)
                            if info[m_][1]:
                                return info[m_][1]
                            nxt.append(m_)
                front = nxt
        return ()

    return {name: (v[0], inherit(name)) for name, v in info.items()}


def _rk_error_line() -> int:
    """The line of diffrax's Runge-Kutta step from which it computes the error estimate (0: not
    found, then the estimate counts as stage arithmetic)."""
    try:
        import inspect

        from diffrax._solver import runge_kutta

        lines, first = inspect.getsourcelines(runge_kutta.AbstractRungeKutta.step)
        for i, ln in enumerate(lines):
            if re.match(r"\s*y_error = ", ln):
                return first + i
    except Exception:  # noqa: BLE001 - a diffrax without it: no split
        pass
    return 0


def classify(stack: tuple, rk_error_line: int = 0) -> str:
    """The part of a run (`PARTS`) an HLO instruction with call stack `stack` (innermost first,
    frames (file, function, line)) belongs to."""
    funcs = [f for _, f, _ in stack]

    def has(*keys):
        return any(k in f for f in funcs for k in keys)

    in_loop = any("diffrax" in p and "_integrate" in p and f.startswith("loop.<locals>.body_fun")
                  for p, f, _ in stack)
    # the project's own loop (`ppr_jax/_lean.py`): its step, stages, controller and saving
    lean = any(p.endswith("_lean.py") and f.startswith("lean_solve.<locals>.step")
               for p, f, _ in stack)
    if lean and not has("_vector_field"):
        if has("save", "more", "_interpolant", "_rescale"):
            return "saving"
        if has("_adapt"):
            return "error_controller"
        if has("stage", "_weighted"):
            return "rk_stages"
        return "loop_status"
    if in_loop or lean:
        if has("_vector_field", "ODETerm.vf"):
            for p, f, _ in stack:  # the freeze of a failed member, in the vector field itself
                if "ppr_jax" in p:
                    if f.startswith("_vector_field.<locals>"):
                        return "loop_status"
                    break
            for keys, part in RHS_KEYS:  # in this order: a solve inside the strips is theirs
                if has(*keys):
                    return part
            return "rhs_eom"
        if has("save_ts", "Interpolation", "interpolat", "save"):
            return "saving"
        if has("adapt_step_size", "_clip_to_end", "Controller", "StepSize"):
            return "error_controller"
        for p, f, ln in stack:
            if "runge_kutta" in p and f == "AbstractRungeKutta.step":
                return ("error_controller" if rk_error_line and ln >= rk_error_line
                        else "rk_stages")
        if has("AbstractRungeKutta", "Tsit5", "Dopri", "step"):
            return "rk_stages"
        return "loop_status"
    if has("diffeqsolve", "lean_solve"):
        return "solver_start"
    if has("quasi_static", "_open_at"):
        return "start"
    if has("commands", "torque_input", "motion_input", "tabulated", "scene_input",
           "path_singular", "path_out_of_reach", "path_margins"):
        return "input_table"
    if has("first_failure", "params_invalid", "_any", "check_result"):
        return "status_fixed"
    if has("_outputs", "outputs", "_result"):
        return "outputs"
    return "other_fixed"


def _innermost(stack: tuple) -> str:
    """The innermost frame of the library or diffrax in `stack`: where a kernel comes from."""
    for path, func, _ in stack:
        if "ppr_jax" in path or "diffrax" in path:
            return f"{os.path.basename(path)}:{func}"
    return "?"


def attribute(events: list, index: dict, rk_error_line: int = 0, detail: dict = None) -> dict:
    """{part: [kernel events, profiled ns]} of a trace's events: each kernel's duration, and the
    traced run's time outside kernels (from the first kernel's start to the last one's end:
    launches, loop control) spread evenly over the kernels. `detail`, where given, gets {part:
    Counter(innermost library or diffrax function: kernel events)}."""
    out = {p: [0, 0] for p, _, _ in PARTS if p != "dispatch"}
    kernels = [e for e in events if _is_kernel(e[0], index)]
    cache: dict = {}
    busy = 0
    for name, _, dur, _ in kernels:
        if name not in cache:
            stack = index[name][1] if name in index else ()
            cache[name] = (classify(stack, rk_error_line), _innermost(stack))
        part, where = cache[name]
        if detail is not None:
            detail.setdefault(part, collections.Counter())[where] += 1
        out[part][0] += 1
        out[part][1] += dur
        busy += dur
    if kernels:
        wall = max(e[1] + e[2] for e in kernels) - min(e[1] for e in kernels)
        launch = max(0.0, wall - busy) / len(kernels)
        for row in out.values():
            row[1] += row[0] * launch
    return out


# --------------------------------------------------------------------------------------------
# Timing and compiled operations


def _ops(compiled_text: str) -> dict:
    """Operations of the entry computation that run as kernels, and the pad-rooted fusions."""
    entry = compiled_text[compiled_text.index("ENTRY"):]
    ops = collections.Counter()
    pads = 0
    for line in entry.splitlines()[1:]:
        m = re.match(r"\s*(?:ROOT )?%?\S+ = \S+ (\w[\w-]*)\(", line)
        if m:
            ops[m.group(1)] += 1
        if " fusion(" in line and '/pad"' in line:
            pads += 1
    free = ("parameter", "constant", "bitcast", "get-tuple-element", "tuple")
    return {"kernels": sum(v for k, v in ops.items() if k not in free), "pad_fusions": pads,
            "dots": ops.get("dot", 0)}


#: elementwise arithmetic, as JAX names it and as XLA's HLO does
_JAXPR_ARITH = {"mul", "add", "sub", "neg", "div", "sin", "cos", "atan2", "sqrt", "select_n",
                "lt", "le", "gt", "ge", "eq", "ne", "integer_pow", "max", "min", "abs", "exp",
                "log", "tan", "rsqrt", "pow", "sign", "floor", "round"}
_HLO_ARITH = {"multiply", "add", "subtract", "negate", "divide", "sine", "cosine", "atan2",
              "sqrt", "select", "compare", "maximum", "minimum", "abs", "exponential", "log",
              "tan", "rsqrt", "power", "sign", "floor", "round-nearest-even", "round-nearest-afz",
              "clamp"}


def jaxpr_element_ops(jaxpr) -> int:
    """Elements computed by `jaxpr`'s elementwise arithmetic (each operation counted once per
    output element; nested jaxprs included): the traced program's arithmetic."""
    n = 0
    for e in jaxpr.eqns:
        if e.primitive.name in _JAXPR_ARITH:
            n += int(math.prod(e.outvars[0].aval.shape))
        for p in e.params.values():
            for sub in (p if isinstance(p, (tuple, list)) else (p,)):
                inner = getattr(sub, "jaxpr", sub)
                if hasattr(inner, "eqns"):
                    n += jaxpr_element_ops(inner)
    return n


def hlo_element_ops(compiled_text: str) -> int:
    """Elements computed by the elementwise arithmetic of a compiled module's text (every
    instruction, inside fusions too, counted once per output element)."""
    n = 0
    for m in re.finditer(r"= [a-z]\w*\[([\d,]*)\](?:\{[^}]*\})? ([a-z][\w-]*)\(", compiled_text):
        if m.group(2) in _HLO_ARITH:
            n += math.prod(int(x) for x in m.group(1).split(",") if x)
    return n


def _min_time(fn, args, repeats, budget_s=None):
    """Minimum over `repeats` calls (fewer where `budget_s` seconds are spent first)."""
    jax.block_until_ready(fn(*args))
    best, spent = float("inf"), 0.0
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(fn(*args))
        dt = time.perf_counter() - t
        best, spent = min(best, dt), spent + dt
        if budget_s is not None and spent > budget_s:
            break
    return best


def _min_times(fn, inputs, repeats, budget_s):
    """[minimum time of `fn(x)`] for each x of `inputs`, called in turn `repeats` times (fewer
    where `budget_s` seconds are spent first)."""
    for x in inputs:
        jax.block_until_ready(fn(x))
    best, spent = [float("inf")] * len(inputs), 0.0
    for _ in range(repeats):
        for i, x in enumerate(inputs):
            t = time.perf_counter()
            jax.block_until_ready(fn(x))
            dt = time.perf_counter() - t
            best[i], spent = min(best[i], dt), spent + dt
        if spent > budget_s:
            break
    return best


def _scanned(fn, pick, times):
    """`fn(r, y, t)` called at each of `times` inside one `lax.scan`, with a carry that depends
    on each call's result so that none is hoisted out of the loop."""
    def run(r, y):
        def body(c, t):
            res = fn(r, (y[0] + c * 1e-9, y[1]), t)
            return c + pick(res) * 1e-12, None

        return jax.lax.scan(body, 0.0, times)[0]

    return eqx.filter_jit(run)


# --------------------------------------------------------------------------------------------
# The engine profile of one tree (this process's `ppr_jax`)


def _scene_call(model_name, t_end, n_out):
    """(compiled run, its dynamic arguments, the prepared call) of `pj.paper_circle`'s program."""
    from ppr_jax._scenes._options import SceneOptions
    from ppr_jax._scenes._run import prepare, scene_program

    c = prepare("paper-circle", None, model_name, SceneOptions(t_end=t_end, n_out=n_out))
    dyn, static = eqx.partition(c.args, eqx.is_array)
    fn = jax.jit(lambda d: scene_program(*eqx.combine(d, static)))
    return fn, dyn, c


def _with_t_end(dyn, t_end):
    """The dynamic arguments with the horizon replaced (an array: no recompilation)."""
    return eqx.tree_at(lambda a: a[3].t_end, dyn, jnp.asarray(t_end, dtype=jnp.float64))


def _rhs_alone(c, repeats) -> dict:
    """One right-hand side of the scene's model at its quasi-static initial state: its compiled
    XLA operations and its time per call in a scan of 2,000 calls."""
    from ppr_jax._simulate import _vector_field, split_coordinates
    from ppr_jax._statics import quasi_static_core

    scene, model, robot, opts = c.args
    ts = opts.times()
    act = scene.commands(model, robot, opts.trajectory, ts, opts.panels).actuation
    z0, zd0, _ = quasi_static_core(model, robot, opts.trajectory, ts[0], act)
    f = jnp.array(split_coordinates(model, act)[0])
    y0, w = (z0[f], zd0[f]), jnp.zeros(3)

    def vf(r, y, t):
        return _vector_field(model, r, act, w, None, t, y)

    lowered = eqx.filter_jit(vf).lower(robot, y0, 0.01)
    text = lowered.compile().compiled.as_text()
    row = _ops(text)
    # the arithmetic: element operations as traced and as compiled (XLA's fusion recomputes a
    # value in every fusion that uses it, so the compiled count can exceed the traced one)
    row["traced_element_ops"] = jaxpr_element_ops(
        jax.make_jaxpr(lambda r, y: vf(r, y, 0.01))(robot, y0).jaxpr)
    row["compiled_element_ops"] = hlo_element_ops(text)
    n_calls = 2000
    times = jnp.linspace(0.0, float(ts[-1]), n_calls)
    run = _scanned(vf, lambda d: d[1][0], times)
    row["us_per_call"] = _min_time(run, (robot, y0), max(3, repeats // 5), 5.0) / n_calls * 1e6
    return row


def _fixed_alone(c, res, repeats) -> dict:
    """The two largest parts outside the solver's loop, each compiled and timed by itself
    (minimum of repeats, seconds): the scene's input (`input`: `scene.commands`, the input
    table and the path's checks) and the per-output quantities on the run's own solution
    (`outputs`: `_metrics.outputs`, kinematics, loop residual and energies at every output
    time). The profiler's shares cannot give them: it lengthens every kernel it records, the
    step's short kernels several times over and the outputs' long ones hardly at all, so their
    shares of a profiled run understate what runs once (L1: 0.12 ms attributed to the outputs,
    about 1 ms measured alone). Inside the run the input's path checks may overlap the solve
    (XLA runs independent operations concurrently), so these are costs, not a partition."""
    from ppr_jax._metrics import outputs

    scene, model, robot, opts = c.args
    ts = opts.times()
    out = {}
    try:
        fn = jax.jit(lambda r, t: scene.commands(model, r, opts.trajectory, t, opts.panels))
        out["input_s"] = _min_time(fn.lower(robot, ts).compile(), (robot, ts), repeats, 3.0)
    except Exception as exc:  # noqa: BLE001 - another tree's internals: say so, go on
        out["input_error"] = f"{type(exc).__name__}: {exc}"[:300]
    try:
        z, zd = jnp.asarray(res.z), jnp.asarray(res.zdot)
        fn = jax.jit(lambda r, a, b: outputs(model, r, a, b))
        out["outputs_s"] = _min_time(fn.lower(robot, z, zd).compile(), (robot, z, zd),
                                     repeats, 3.0)
    except Exception as exc:  # noqa: BLE001
        out["outputs_error"] = f"{type(exc).__name__}: {exc}"[:300]
    return out


def profile_model(model_name, t_end, n_out, short_t_end, repeats) -> dict:
    """The engine profile of one model on `paper-circle` (module docstring)."""
    t0 = time.perf_counter()
    fn, dyn, c = _scene_call(model_name, t_end, n_out)
    compiled = fn.lower(dyn).compile()
    row = {"model": model_name, "scene": "paper-circle", "t_end_s": t_end, "n_out": n_out,
           "solver": c.solver_name, "rtol": float(c.args[3].rtol),
           "atol": float(c.args[3].atol), "compile_s": time.perf_counter() - t0}
    res = compiled(dyn)
    row.update(steps=int(res.num_steps), accepted=int(res.num_accepted),
               rejected=int(res.num_rejected), result=int(jnp.asarray(res.result._value)))
    # the scene and its short horizon (below) timed in turn, so that both see the same load
    short = _with_t_end(dyn, short_t_end)
    row["run_s"], s_run = _min_times(compiled, (dyn, short), repeats, 6.0)
    nothing = jax.jit(lambda d: jnp.zeros(()), keep_unused=True).lower(dyn).compile()
    row["dispatch_s"] = _min_time(nothing, (dyn,), repeats, 1.0)

    text = compiled.as_text()
    index = hlo_index(text)
    events = _trace_events(compiled, (dyn,))
    detail: dict = {}
    parts = attribute(events, index, _rk_error_line(), detail)
    n_kernels = sum(v[0] for v in parts.values())
    traced_ns = sum(v[1] for v in parts.values()) or 1
    row["kernel_events"] = n_kernels
    row["unattributed_kernels"] = sum(1 for e in events if _is_kernel(e[0], index)
                                      and not (index.get(e[0]) or (None, ()))[1])

    # the same program over a short horizon: the difference is what the extra steps cost
    s_steps = int(compiled(short).num_steps)
    s_kernels = sum(_is_kernel(e[0], index) for e in _trace_events(compiled, (short,)))
    row["short"] = {"t_end_s": short_t_end, "steps": s_steps, "run_s": s_run,
                    "kernel_events": s_kernels}
    d_steps = row["steps"] - s_steps
    if d_steps > 0:
        row["us_per_step"] = (row["run_s"] - s_run) / d_steps * 1e6
        row["kernels_per_step"] = (n_kernels - s_kernels) / d_steps
    steps = max(row["steps"], 1)
    work = max(row["run_s"] - row["dispatch_s"], 0.0)
    fixed, step = {"dispatch": {"kernels": 0, "us": row["dispatch_s"] * 1e6}}, {}
    for name, kind, _ in PARTS:
        if name == "dispatch":
            continue
        k, ns = parts[name]
        share = ns / traced_ns
        if kind == "fixed":
            fixed[name] = {"kernels": k, "us": share * work * 1e6, "share": share}
        else:
            step[name] = {"kernels_per_step": k / steps, "us_per_step": share * work * 1e6 / steps,
                          "share": share}
    row["fixed"], row["step"] = fixed, step
    # where each part's kernels come from: its most frequent innermost functions
    row["detail"] = {p: c.most_common(8) for p, c in detail.items()}
    row["attributed_kernels_per_step"] = sum(v["kernels_per_step"] for v in step.values())
    row["attributed_us_per_step"] = sum(v["us_per_step"] for v in step.values())
    row["alone"] = _fixed_alone(c, res, repeats)
    try:
        row["rhs"] = _rhs_alone(c, repeats)
    except Exception as exc:  # noqa: BLE001 - another tree's internals: say so, go on
        row["rhs"] = {"error": f"{type(exc).__name__}: {exc}"[:300]}
    row["wall_s"] = time.perf_counter() - t0
    return row


#: the members of a profiled batch: strip thickness spread evenly over this range (m), as the
#: batch benchmark's (`benchmarks/run.py --parts batch`)
BATCH_T_RANGE = (0.28e-3, 0.40e-3)


def profile_batch(model_name, batch, repeats, rtol=None) -> dict:
    """Where a batch's time goes: `pj.paper_circle`'s program (the scene's defaults, or `rtol`)
    for `batch` robots whose strip thickness is spread over `BATCH_T_RANGE`, mapped as the
    library maps a batch on one device (`_scenes._batch.map_members`: chunks of vmapped
    members, each model as a batch takes it) and timed (minimum of `repeats`); its kernel
    events attributed to the parts as a single run's are (`attribute`), each part's time its
    share of the profiled run applied to the unprofiled one. A batch's kernels are as many as
    one run's, each over a chunk of members: here the arithmetic, not the launches, sets the
    time, so `top` lists the kernels that take most of it, with their part and innermost
    function."""
    import numpy as np

    from ppr_jax import scene_params
    from ppr_jax._robot import as_robot
    from ppr_jax._scenes._batch import map_members
    from ppr_jax._scenes._options import SceneOptions
    from ppr_jax._scenes._run import prepare, scene_program

    t0 = time.perf_counter()
    # `rtol`: the batch benchmark's settings (atol rtol / 100) instead of the scene's defaults
    opts_in = (SceneOptions() if rtol is None else
               SceneOptions(rtol=rtol, atol=rtol * 1e-2, max_steps=400_000))
    c = prepare("paper-circle", None, model_name, opts_in)
    scene, model, _, opts = c.args
    base = scene_params("paper-circle")
    robots = [as_robot(base.replace(t=float(t))) for t in np.linspace(*BATCH_T_RANGE, batch)]
    robots = jax.tree_util.tree_map(lambda *a: jnp.stack(a) if eqx.is_array(a[0]) else a[0],
                                    *robots)
    try:  # as the library's batches do: what the members share, once (`compress_shared`)
        from ppr_jax._scenes._batch import compress_shared
        robots = compress_shared(robots)
    except ImportError:  # a checkout from before it
        pass
    dyn, static = eqx.partition((robots, scene, model, opts), eqx.is_array)
    mapped = map_members(lambda one, s, m, o: scene_program(s, m, one, o))

    def program(d):
        return mapped(*eqx.combine(d, static))

    compiled = jax.jit(program).lower(dyn).compile()
    row = {"model": model_name, "scene": "paper-circle", "batch": batch, "rtol": rtol,
           "t_range_m": list(BATCH_T_RANGE), "n_out": int(opts.times().shape[0]),
           "compile_s": time.perf_counter() - t0}
    res = compiled(dyn)
    row["steps_max"] = int(jnp.max(res.num_steps))
    row["run_s"] = _min_time(compiled, (dyn,), repeats, 20.0)
    row["trajectories_per_s"] = batch / row["run_s"]
    text = compiled.as_text()
    index = hlo_index(text)
    events = _trace_events(compiled, (dyn,))
    rk_line = _rk_error_line()
    parts = attribute(events, index, rk_line)
    row["kernel_events"] = sum(v[0] for v in parts.values())
    traced_ns = sum(v[1] for v in parts.values()) or 1
    row["parts"] = {p: {"kernels": k, "share": ns / traced_ns, "s": ns / traced_ns * row["run_s"]}
                    for p, (k, ns) in parts.items() if k}
    busy, count = collections.Counter(), collections.Counter()
    for name, _, dur, _ in events:
        if _is_kernel(name, index):
            busy[name] += dur
            count[name] += 1
    row["top"] = []
    for name, ns in busy.most_common(10):
        stack = index[name][1] if name in index else ()
        row["top"].append({"kernel": name, "part": classify(stack, rk_line),
                           "where": _innermost(stack), "events": count[name],
                           "share": ns / traced_ns})
    row["wall_s"] = time.perf_counter() - t0
    return row


def _tree_info(path) -> dict:
    def git(*a):
        try:
            return subprocess.run(["git", "-C", path, *a], capture_output=True, text=True,
                                  timeout=30).stdout.strip()
        except (OSError, subprocess.SubprocessError):
            return ""

    return {"path": path, "commit": git("rev-parse", "HEAD"),
            "dirty": bool(git("status", "--porcelain", "--untracked-files=no"))}


def profile_tree(models, repeats, short_t_end, l3_t_end, batch=None, batch_rtol=None) -> dict:
    """The engine profile of every model of `models` with this process's `ppr_jax` (with
    `batch`, of a batch of that many robots: `profile_batch`)."""
    import ppr_jax

    tree = os.path.dirname(os.path.dirname(os.path.abspath(ppr_jax.__file__)))
    out = {**_tree_info(tree), "ppr_jax": os.path.abspath(ppr_jax.__file__), "models": {}}
    for m in models:
        t_end, n_out = (7.54, 755) if m != "beam" else (l3_t_end, int(round(l3_t_end * 100)) + 1)
        try:
            row = (profile_batch(m, batch, repeats, batch_rtol) if batch else
                   profile_model(m, t_end, n_out, short_t_end, repeats))
        except Exception as exc:  # noqa: BLE001 - one model failing leaves the others
            row = {"model": m, "error": f"{type(exc).__name__}: {exc}"[:500]}
        if m == "beam" and not batch:
            row["note"] = (f"quasi-static L3 (N = 8) over {t_end:g} s with {n_out} output times "
                           "(the whole 7.54 s scene takes seconds a run)")
        out["models"][m] = row
        print(json.dumps({k: v for k, v in row.items() if not isinstance(v, dict)}), flush=True)
    return out


def _subprocess_profile(tree, args) -> dict:
    """`profile_tree` of `tree`'s library in a fresh process (`PYTHONPATH` = tree)."""
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "side.json")
        cmd = [sys.executable, os.path.abspath(__file__), "--side", path, "--repeats",
               str(args.repeats), "--short-t-end", str(args.short_t_end), "--l3-t-end",
               str(args.l3_t_end), "--models", *args.models] + (
                   ["--batch", str(args.batch)] if args.batch else []) + (
                   ["--batch-rtol", str(args.batch_rtol)] if args.batch_rtol else [])
        env = dict(os.environ, PYTHONPATH=os.path.abspath(tree))
        try:  # the tree's own XLA settings, not the ones this process's import added
            from ppr_jax._devices import environment_without_defaults

            env = environment_without_defaults(env)
        except ImportError:  # a library without them
            pass
        print(f"-- {tree}", flush=True)
        proc = subprocess.run(cmd, env=env, cwd=d)
        if proc.returncode != 0:
            raise SystemExit(f"the profile of {tree} failed (exit {proc.returncode})")
        with open(path) as f:
            return json.load(f)


def _ratios(before: dict, after: dict) -> dict:
    """after / before per model: the run, kernel events, and per step kernels and time."""
    out = {}
    for m, a in after["models"].items():
        b = before["models"].get(m)
        if not b or "error" in a or "error" in b:
            continue
        r = {}
        for key in ("run_s", "kernel_events", "kernels_per_step", "us_per_step", "steps",
                    "trajectories_per_s"):
            # 0 after is a value (a loop compiled as one kernel: no kernel a step), not missing
            if a.get(key) is not None and b.get(key):
                r[key] = a[key] / b[key]
        out[m] = r
    return out


#: the speed goals this profile measures, after against before: (goal, ratio's key, models, limit)
GOALS = (
    ("paper-circle run at most 1/5 of before's", "run_s", ("rigid", "reduced", "double1r"), 0.2),
    ("paper-circle run at most 1/2 of before's", "run_s", ("beam",), 0.5),
    ("kernel events a step at most 1/10 of before's", "kernels_per_step", MODELS, 0.1),
)


def goals(ratios: dict) -> list:
    """[{goal, model, ratio, limit, met}] of `GOALS` from `_ratios` (met None: not measured)."""
    rows = []
    for goal, key, models, limit in GOALS:
        for m in models:
            v = ratios.get(m, {}).get(key)
            rows.append({"goal": goal, "model": m, "ratio": v, "limit": limit,
                         "met": None if v is None else bool(v <= limit)})
    return rows


def _machine() -> dict:
    import datetime

    return {"cpu": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
            "jax": jax.__version__, "diffrax": diffrax.__version__,
            "backend": jax.default_backend(), "xla_flags": os.environ.get("XLA_FLAGS", ""),
            "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
            "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}


def engine_profile(args) -> None:
    t0 = time.perf_counter()
    what = (f"where the time of a batch of {args.batch} paper-circle runs goes, per model "
            "(profile_batch in benchmarks/kernel_counts.py)" if args.batch else
            "where a paper-circle run's kernels and time go, per model (module docstring of "
            "benchmarks/kernel_counts.py)")
    out = {"what": what,
           "command": "python benchmarks/kernel_counts.py " + " ".join(sys.argv[1:]),
           "parts": {p: {"kind": k, "what": w} for p, k, w in PARTS}, "machine": _machine()}
    if args.checkout:
        out["before"] = _subprocess_profile(args.checkout, args)
        out["after"] = _subprocess_profile(ROOT, args)
        out["ratios"] = _ratios(out["before"], out["after"])
        if not args.batch:  # the goals are a single run's
            out["goals"] = goals(out["ratios"])
    else:
        out["after"] = profile_tree(args.models, args.repeats, args.short_t_end, args.l3_t_end,
                                    args.batch, args.batch_rtol)
    out["runtime_s"] = time.perf_counter() - t0
    default = "engine_profile_batch.json" if args.batch else "engine_profile.json"
    path = os.path.join(OUT, args.out or default)
    with open(path, "w") as fh:
        json.dump(out, fh, indent=1)
    print(f"wrote {path} in {out['runtime_s']:.0f} s")


# --------------------------------------------------------------------------------------------
# Reverse mode's cost (the original measurement)


def reverse_mode(args) -> None:
    from ppr_jax._actuation import InverseDynamicsTorque, TorqueDriven
    from ppr_jax._models import get_model
    from ppr_jax._robot import Robot
    from ppr_jax._scenes import input_panels, scene_params, tabulated as _tabulated_input
    from ppr_jax._simulate import _vector_field
    from ppr_jax._statics import quasi_static_core
    from ppr_jax._studies import explicit_params, metric_function
    from ppr_jax._trajectory import Circle

    out = {"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
           "jax": jax.__version__, "diffrax": diffrax.__version__,
           "backend": jax.default_backend(), "model": args.model, "torque_model": "rigid",
           "xla_flags": os.environ.get("XLA_FLAGS", "")}

    # Whole programs.
    f, x0, _ = metric_function("paper-circle", model=args.model, torque_model="rigid",
                               rtol=1e-8, atol=1e-10,
                               metrics=("radial_error_min_m",))
    progs = {"forward_run": jax.jit(lambda x: f(x)[0]),
             "grad": jax.jit(jax.grad(lambda x: f(x)[0]))}
    out["programs"] = {}
    for name, fn in progs.items():
        c = fn.lower(x0).compile()
        out["programs"][name] = {"kernel_events": _kernel_events(c, x0),
                                 "run_s": _min_time(c, (x0,), args.repeats)}
    fwd = out["programs"]["forward_run"]
    for row in out["programs"].values():
        row["kernels_per_forward"] = row["kernel_events"] / fwd["kernel_events"]
        row["time_per_forward"] = row["run_s"] / fwd["run_s"]
    print(json.dumps(out["programs"], indent=1), flush=True)

    # One right-hand side, at the scene's initial state.
    model, torque_model = get_model(args.model), get_model("rigid")
    robot = Robot(explicit_params(scene_params("paper-circle")))
    traj, t_end = Circle(), 7.54
    ts = jnp.linspace(0.0, t_end, 755)
    torque, *_ = _tabulated_input(InverseDynamicsTorque(torque_model, robot, traj), ts,
                                  input_panels(traj, t_end, 755))
    act = TorqueDriven(torque)
    z0, zd0, _ = quasi_static_core(model, robot, traj, ts[0], act)
    y0, w = (z0, zd0), jnp.zeros(3)

    def vf(r, y, t):
        return _vector_field(model, r, act, w, None, t, y)

    def jvp(r, y, t):
        return jax.jvp(lambda yy: vf(r, yy, t), (y,), (y,))

    def vjp(r, y, t):
        out_, pull = jax.vjp(lambda rr, yy: vf(rr, yy, t), r, y)
        return pull(out_)

    n_calls = 2000
    times = jnp.linspace(0.0, 7.0, n_calls)
    picks = {"forward": (vf, lambda d: d[1][0]), "jvp": (jvp, lambda d: d[1][1][0]),
             "vjp": (vjp, lambda g: g[1][0][0])}
    out["rhs"] = {}
    for name, (fn, pick) in picks.items():
        text = eqx.filter_jit(fn).lower(robot, y0, 1.0).compile().compiled.as_text()
        row = _ops(text)
        row["us_per_call"] = (_min_time(_scanned(fn, pick, times), (robot, y0), args.repeats)
                              / n_calls * 1e6)
        out["rhs"][name] = row
    for row in out["rhs"].values():
        row["kernels_per_forward"] = row["kernels"] / out["rhs"]["forward"]["kernels"]
    print(json.dumps(out["rhs"], indent=1), flush=True)
    path = os.path.join(OUT, args.out or "kernel_counts.json")
    with open(path, "w") as fh:
        json.dump(out, fh, indent=2)
    print(f"wrote {path}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--all-models", action="store_true",
                    help="the engine profile of every model (engine_profile.json)")
    ap.add_argument("--models", nargs="+", default=list(MODELS), choices=MODELS,
                    help="with --all-models: the models profiled")
    ap.add_argument("--checkout", default=None,
                    help="with --all-models: also profile this tree's library ('before'), "
                         "each tree in a fresh process")
    ap.add_argument("--short-t-end", type=float, default=0.01,
                    help="the short horizon (s) whose difference gives a step's cost")
    ap.add_argument("--l3-t-end", type=float, default=0.5, help="L3's horizon (s)")
    ap.add_argument("--model", default="reduced", help="reverse mode's model")
    ap.add_argument("--repeats", type=int, default=25)
    ap.add_argument("--out", default=None, help="file name under benchmarks/results/")
    ap.add_argument("--batch", type=int, default=None,
                    help="with --all-models: profile a batch of this many robots instead of one "
                         "run (engine_profile_batch.json)")
    ap.add_argument("--batch-rtol", type=float, default=None,
                    help="with --batch: this rtol (atol rtol / 100), the batch benchmark's "
                         "settings, instead of the scene's defaults")
    ap.add_argument("--side", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    os.makedirs(OUT, exist_ok=True)
    if args.side:  # one tree's profile, for --checkout
        out = profile_tree(args.models, args.repeats, args.short_t_end, args.l3_t_end,
                           args.batch, args.batch_rtol)
        with open(args.side, "w") as fh:
            json.dump(out, fh)
    elif args.all_models or args.checkout:
        engine_profile(args)
    else:
        reverse_mode(args)


if __name__ == "__main__":
    main()
