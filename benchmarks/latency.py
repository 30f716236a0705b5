"""What a user waits for, in fresh processes: start-up, the command line, a cold and a warm
`ppr-jax simulate`, and identification cold against warm; one checkout, or two side by side.

    python benchmarks/latency.py [--quick]                              # this checkout
    python benchmarks/latency.py --base ../ppr_jax-main --new . [--quick]  # A/B

Every row is a fresh process of the same Python (`--python`, default this one) with
`PYTHONPATH=<checkout>`, and each process that imports the library checks that `ppr_jax` came
from that checkout. Rows (wall time of the process, minimum of repeats; base and new
interleaved, so that a drift of the machine's load falls on both):

- `python -c pass`, `import jax`, `import ppr_jax` (and the import's own time, measured inside
  the process), `ppr-jax --help` (the console script's entry point, `ppr_jax_cli.main`), and
  `import matplotlib (Figure, Agg)`, what `simulate`'s figures import;
- per model (`rigid`, `reduced`, `double1r`, `beam` at `--elements 16`): `ppr-jax simulate
  --model M --out DIR` (scene `paper-circle`) with a fresh `PPR_JAX_CACHE_DIR` (cold), then
  the same command in a second process on that cache (warm); the command's own log line
  "done in X s (compile Y s, run Z ms, ...)" gives its compile and run;
- identification (`--parts identify`): `--identify fits` (default), as
  `benchmarks/identify_time.py`: (t, K_theta) by L2 from a synthetic servo-circle experiment,
  the first fit (with compilation) against a second fit in the same process; `--identify
  processes`: `ppr-jax identify` of t from `ppr-jax synth` data in a process with a fresh
  cache, then in a second process on that cache.

The JSON holds each row for base and new, and the ratios the latency goals set, each with
`met`: cold compile new / base per model (<= 1/3), second process / cold process wall per
model (<= 0.1), import ppr_jax / import jax (<= 1.3), `--help` minus `python -c pass`
(<= 0.5 s), identification cold / warm (<= 2). A goal is judged on the new
checkout; the base's value is beside it. Each goal not met names what bounds it (`bound`, from
this run's rows and `benchmarks/results/compile_budget.json`) and the remaining lever (`lever`).

Bytecode: the children write and read it under one `PYTHONPYCACHEPREFIX` directory (never in
the checkouts), warmed by one untimed run of each start-up command and a short simulation per
checkout, so that no timed process compiles Python sources (a user's installation has its
bytecode too).

`--quick`: simulations and identification over 1 s (`--t-end 1`), one repeat of each.
Writes `benchmarks/results/latency.json` (`--out`).

`--suite-log LOG COMMIT` only adds the test suite's goal (pytest's wall on a fresh clone against
the base's 1,814 s, <= 1/3) from the log of `.ci/run` on COMMIT to the JSON at `--out`, keeping
its other rows: the suite takes ten minutes and is not timed here.
"""

from __future__ import annotations

import argparse
import datetime
import importlib.metadata
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
OUT = os.path.join(HERE, "results", "latency.json")
BUDGET = os.path.join(HERE, "results", "compile_budget.json")
MODELS = ("rigid", "reduced", "double1r", "beam")
BEAM_ELEMENTS = 16
PARTS = ("startup", "simulate", "identify")
GOALS = {"cold_compile_new_over_base": 1 / 3, "warm_over_cold_wall": 0.1,
         "import_ppr_jax_over_import_jax": 1.3, "help_minus_pass_s": 0.5,
         "identify_cold_over_warm": 2.0, "suite_new_over_base": 1 / 3}
#: the issue's measurement of the base's test suite: `.ci/run` on d914f86 (473 tests), pytest's
#: wall on the 2-core machine
SUITE_BASE = {"commit": "d914f86", "tests": 473, "wall_s": 1814.0}
MARK = "LATENCY_PPR_JAX_FILE="

#: the console script as installed (`ppr-jax = ppr_jax_cli:main`), from the checkout on the path;
#: then the file ppr_jax came from, for the check
CLI = ("import sys, ppr_jax_cli\n"
       "sys.argv[0] = 'ppr-jax'\n"
       "try:\n"
       "    rc = ppr_jax_cli.main()\n"
       "finally:\n"
       "    m = sys.modules.get('ppr_jax')\n"
       f"    print('{MARK}' + (m.__file__ if m else ppr_jax_cli.__file__), file=sys.stderr)\n"
       "sys.exit(rc)\n")


def _import(module: str) -> str:
    out = (f"import time\nt = time.perf_counter()\nimport {module}\n"
           "print('IMPORT_S', time.perf_counter() - t)\n")
    if module == "ppr_jax":
        out += f"print('{MARK}' + ppr_jax.__file__)\n"
    return out


IDENTIFY = f"""
import json, sys, time
import ppr_jax as pj
print('{MARK}' + pj.__file__)
t_end = float(sys.argv[1])
truth = pj.scene_params("servo-circle")
truth = truth.replace(K_theta=float(pj.derived(truth).K_theta))
exp = pj.synthesize("servo-circle", "double1r", truth, noise_pos=1e-4, noise_phi=1e-3,
                    rate=100.0, t_end=t_end, seed=0)
start = {{"t": 0.9 * float(truth.t), "K_theta": 1.2 * float(truth.K_theta)}}
walls = []
for _ in range(2):
    t0 = time.perf_counter()
    fit = pj.identify(exp, ("t", "K_theta"), model="double1r", scene="servo-circle",
                      initial=start, force=True)
    walls.append(time.perf_counter() - t0)
print("IDENTIFY " + json.dumps({{"first_fit_s": walls[0], "second_fit_s": walls[1],
                                "iterations": fit.history.get("iterations")}}))
"""

DONE = re.compile(r"done in ([\d.]+) s \(compile ([\d.]+) s, run ([\d.]+) ms")


def machine() -> dict:
    """Where and with what the rows were measured (no JAX in this process)."""
    versions = {}
    for name in ("jax", "jaxlib", "diffrax", "equinox", "numpy"):
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = None
    return {
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "machine": platform.processor() or platform.machine(),
        "platform": platform.platform(), "cpus": os.cpu_count(),
        "backend": os.environ.get("JAX_PLATFORMS") or "cpu",
        "python": platform.python_version(), "versions": versions,
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
    }


class Checkout:
    def __init__(self, label: str, path: str, python: str, pycache: str):
        self.label, self.path, self.python = label, os.path.realpath(path), python
        if not os.path.isfile(os.path.join(self.path, "ppr_jax", "__init__.py")):
            raise SystemExit(f"{path}: no ppr_jax package there")
        self.env = {k: v for k, v in os.environ.items()
                    if k not in ("PYTHONPATH", "PYTHONDONTWRITEBYTECODE", "PPR_JAX_CACHE_DIR",
                                 "PPR_JAX_CACHE")
                    and not k.startswith(("JAX_COMPILATION_CACHE", "JAX_PERSISTENT_CACHE"))}
        self.env.update(PYTHONPATH=self.path, PYTHONPYCACHEPREFIX=pycache, MPLBACKEND="Agg")

    def describe(self) -> dict:
        def git(*a):
            p = subprocess.run(["git", "-C", self.path, *a], capture_output=True, text=True)
            return p.stdout.strip() if p.returncode == 0 else None

        return {"path": self.path, "commit": git("rev-parse", "HEAD"),
                "dirty": bool(git("status", "--porcelain", "--untracked-files=no"))}

    def run(self, code: str, args=(), env=None, timeout=1800.0) -> dict:
        """One fresh process `python -c code args`: its wall time and output."""
        e = dict(self.env, **(env or {}))
        t0 = time.perf_counter()
        p = subprocess.run([self.python, "-c", code, *args], capture_output=True, text=True,
                           env=e, cwd=tempfile.gettempdir(), timeout=timeout)
        wall = time.perf_counter() - t0
        text = p.stdout + p.stderr
        if p.returncode != 0:
            tail = " | ".join(text.strip().splitlines()[-3:])
            raise RuntimeError(f"{self.label}: exit {p.returncode}: {tail}")
        seen = re.findall(re.escape(MARK) + r"(.+)", text)
        for f in seen:
            if not os.path.realpath(f.strip()).startswith(self.path + os.sep):
                raise RuntimeError(f"{self.label}: ppr_jax came from {f.strip()}, not from "
                                   f"{self.path}")
        return {"wall_s": wall, "text": text, "checked": bool(seen)}


def _min_row(samples: list) -> dict:
    """The sample with the least wall time, with every wall time beside it."""
    best = dict(min(samples, key=lambda s: s["wall_s"]))
    best["walls_s"] = [s["wall_s"] for s in samples]
    return best


def _interleaved(checkouts, repeats, one) -> dict:
    """{label: min row} of `one(checkout)` run `repeats` times per checkout, alternating."""
    samples = {c.label: [] for c in checkouts}
    for _ in range(repeats):
        for c in checkouts:
            samples[c.label].append(one(c))
    return {label: _min_row(s) for label, s in samples.items()}


def startup_rows(checkouts, repeats) -> list:
    cmds = [("python -c pass", "pass", ()), ("import jax", _import("jax"), ()),
            ("import ppr_jax", _import("ppr_jax"), ()), ("ppr-jax --help", CLI, ("--help",)),
            ("import matplotlib (Figure, Agg)",
             _import("matplotlib.figure, matplotlib.backends.backend_agg"), ())]
    rows = []
    for name, code, args in cmds:
        def one(c, code=code, args=args):
            r = c.run(code, args)
            m = re.search(r"IMPORT_S ([\d.e+-]+)", r["text"])
            out = {"wall_s": r["wall_s"]}
            if m:
                out["import_s"] = float(m.group(1))
            if r["checked"]:
                out["ppr_jax_checked"] = True
            return out

        row = {"name": name, "part": "startup", **_interleaved(checkouts, repeats, one)}
        rows.append(row)
        _print(row)
    return rows


def simulate_rows(checkouts, models, repeats, t_end) -> list:
    rows = []
    for model in models:
        extra = ["--elements", str(BEAM_ELEMENTS)] if model == "beam" else []
        extra += ["--t-end", str(t_end)] if t_end is not None else []
        samples = {c.label: {"cold": [], "warm": []} for c in checkouts}
        for _ in range(repeats):
            for c in checkouts:
                cache = tempfile.mkdtemp(prefix="ppr_jax_latency_cache_")
                try:
                    for kind in ("cold", "warm"):
                        with tempfile.TemporaryDirectory(prefix="ppr_jax_latency_out_") as out:
                            r = c.run(CLI, ["simulate", "--model", model, "--out", out, *extra],
                                      env={"PPR_JAX_CACHE_DIR": cache})
                        m = DONE.search(r["text"])
                        s = {"wall_s": r["wall_s"], "ppr_jax_checked": r["checked"]}
                        if m:
                            s.update(done_in_s=float(m.group(1)), compile_s=float(m.group(2)),
                                     run_ms=float(m.group(3)))
                        samples[c.label][kind].append(s)
                finally:
                    shutil.rmtree(cache, ignore_errors=True)
        for kind in ("cold", "warm"):
            row = {"name": f"simulate {model} {kind}", "part": "simulate", "model": model,
                   "kind": kind, "command": "ppr-jax simulate --model " + " ".join([model, *extra])
                   + " --out DIR",
                   **{label: _min_row(s[kind]) for label, s in samples.items()}}
            rows.append(row)
            _print(row)
    return rows


def identify_rows(checkouts, repeats, t_end) -> list:
    def one(c):
        r = c.run(IDENTIFY, [str(t_end)])
        d = json.loads(r["text"].split("IDENTIFY ", 1)[1].splitlines()[0])
        d["first_over_second"] = d["first_fit_s"] / d["second_fit_s"]
        return dict(d, wall_s=r["wall_s"], ppr_jax_checked=r["checked"])

    row = {"name": "identify (t, K_theta), L2 servo-circle", "part": "identify",
           "mode": "fits", "t_end_s": t_end, **_interleaved(checkouts, repeats, one)}
    _print(row)
    return [row]


def identify_process_rows(checkouts, repeats, t_end) -> list:
    """`ppr-jax identify` of t from synthetic servo-circle data (`ppr-jax synth`, untimed) in a
    process with a fresh cache (cold), then again on that cache (warm)."""
    samples = {c.label: {"cold": [], "warm": []} for c in checkouts}
    for _ in range(repeats):
        for c in checkouts:
            with tempfile.TemporaryDirectory(prefix="ppr_jax_latency_id_") as d:
                data = os.path.join(d, "data.csv")
                c.run(CLI, ["synth", "--t-end", str(t_end), "--out", data],
                      env={"PPR_JAX_CACHE_DIR": os.path.join(d, "synth_cache")})
                for kind in ("cold", "warm"):
                    r = c.run(CLI, ["identify", "--data", data, "--unknown", "t", "--initial",
                                    "t=0.00045", "--out", os.path.join(d, kind)],
                              env={"PPR_JAX_CACHE_DIR": os.path.join(d, "cache")})
                    m = re.search(r"done in ([\d.]+) s", r["text"])
                    samples[c.label][kind].append(
                        {"wall_s": r["wall_s"], "ppr_jax_checked": r["checked"],
                         "done_in_s": float(m.group(1)) if m else None})
    rows = []
    for kind in ("cold", "warm"):
        row = {"name": f"identify t {kind} (processes)", "part": "identify", "mode": "processes",
               "kind": kind, "t_end_s": t_end,
               "command": "ppr-jax identify --data DATA --unknown t --initial t=0.00045",
               **{label: _min_row(s[kind]) for label, s in samples.items()}}
        rows.append(row)
        _print(row)
    return rows


def _print(row):
    sides = [k for k in ("base", "new") if k in row]
    cells = []
    for k in sides:
        r = row[k]
        c = f"{k} {r['wall_s']:.2f} s"
        if "import_s" in r:
            c += f" (import {r['import_s']:.2f} s)"
        if "compile_s" in r:
            c += f" (compile {r['compile_s']:.1f} s, run {r['run_ms']:.1f} ms)"
        if "first_fit_s" in r:
            c += f" (first fit {r['first_fit_s']:.1f} s, second {r['second_fit_s']:.1f} s)"
        cells.append(c)
    print(f"{row['name']:32s} " + " | ".join(cells), flush=True)


def goals(rows, labels) -> list:
    by = {r["name"]: r for r in rows}
    out = []

    def add(goal, value, extra=None, base_value=None):
        limit = GOALS[goal]
        d = {"goal": goal, "limit": limit, "value": value,
             "met": None if value is None else bool(value <= limit)}
        if base_value is not None:
            d["base_value"] = base_value
        d.update(extra or {})
        out.append(d)

    def val(name, side, key):
        r = by.get(name, {}).get(side)
        return None if r is None else r.get(key)

    def ratio(a, b):
        return None if a is None or b is None or b == 0 else a / b

    have_base = "base" in labels
    for model in MODELS:
        cold = f"simulate {model} cold"
        if cold not in by:
            continue
        if have_base:
            add("cold_compile_new_over_base",
                ratio(val(cold, "new", "compile_s"), val(cold, "base", "compile_s")),
                {"model": model})
        warm = f"simulate {model} warm"
        add("warm_over_cold_wall",
            ratio(val(warm, "new", "wall_s"), val(cold, "new", "wall_s")), {"model": model},
            ratio(val(warm, "base", "wall_s"), val(cold, "base", "wall_s")))
    if "import jax" in by:
        add("import_ppr_jax_over_import_jax",
            ratio(val("import ppr_jax", "new", "import_s"), val("import jax", "new", "import_s")),
            {"measured": "each import's own time inside its process"},
            ratio(val("import ppr_jax", "base", "import_s"),
                  val("import jax", "base", "import_s")))

        def diff(side):
            a, b = val("ppr-jax --help", side, "wall_s"), val("python -c pass", side, "wall_s")
            return None if a is None or b is None else a - b

        add("help_minus_pass_s", diff("new"), {"measured": "process wall times"},
            diff("base"))
    idn = [r for r in rows if r["part"] == "identify" and r["mode"] == "fits"]
    if idn:
        add("identify_cold_over_warm", idn[0]["new"]["first_over_second"],
            {"mode": "fits", "measured": "first fit (with compilation) / second fit, one process"},
            idn[0].get("base", {}).get("first_over_second"))
    cold, warm = "identify t cold (processes)", "identify t warm (processes)"
    if cold in by:
        add("identify_cold_over_warm",
            ratio(val(cold, "new", "wall_s"), val(warm, "new", "wall_s")),
            {"mode": "processes",
             "measured": "wall of a process with a fresh cache / a second process on it"},
            ratio(val(cold, "base", "wall_s"), val(warm, "base", "wall_s")))
    return out


#: the remaining levers of the goals not met (`bounds`)
LEVERS = {
    "suite_new_over_base": (
        "taken: XLA's cheapest code generation for tests (LLVM -O0 and the loop emitters), "
        "the xla_defaults tests in a subprocess, module and session fixtures sharing compiled "
        "runs, long files handed out first, the suite's cache keeping programs over 1 s only. "
        "Measured and not taken: keeping JAX's in-memory caches across test files (no gain: "
        "116.8 s against 120.1 s on four heavy files in one process), the persistent cache for "
        "every program (91 s against 86 s), the notebooks in the test process instead of a "
        "subprocess each (a process's imports take 0.9 s: 5 s of the suite's 1,260 "
        "worker-seconds); a third worker (a .ci/run, install included, used 185 % of the two "
        "cores: 1,302 CPU-s in 700 s, so the two workers keep both busy). Read in equinox's "
        "source and not taken: the implicit solvers' right-hand side under noinline (diffrax's "
        "2022 lever) lowers to a host callback, a separately compiled function called from "
        "Python at every evaluation, which jax.export cannot store and which costs a host "
        "round trip per right-hand side. Taken since: a sensitivity is one program (the "
        "Jacobian's primal gives the values; a separate values program was 2 s of tracing "
        "and 2 s of XLA time); the suite's cache threshold restored after each test (a "
        "command run in a test had set it to 0 for the rest of its worker: 1,207 cache entries "
        "against 227 on two files); test_implicit's full L3 loads the command line's stored "
        "program or stores it for it (test_cli's test 29.6 -> 6.5 s); the quasi-static start's "
        "smaller derivative. Interleaved fresh-clone runs on one evening: 135cbef 700.6 s, "
        "this code 640.5 s and 620.2 s around it (584.6 s an hour earlier; 1,154 "
        "worker-seconds against 1,257-1,399). "
        "The next landing added the stored programs' tests of design, synth, torques and "
        "modes (each compiles its programs twice, usual and exported: 653 -> 658 tests), "
        "623.8 s on a fresh clone, and 602.2 s for the landing's code (its step-aside test "
        "on a small program instead of the 7 s jacfwd of modes); 640.6 s with the start's "
        "stencil check and its test (660 tests). "
        "Remaining: fewer distinct programs, tests sharing one setting's compiled run (shapes, "
        "solver and options), and smaller programs (the implicit solvers' full L3, 17-26 s of "
        "XLA time per solver in test_implicit, its quasi-static start compiled into each)"),
    "cold_compile_new_over_base": (
        "taken: XLA's CPU loop emitters (--xla_cpu_use_fusion_emitters=false, "
        "ppr_jax/_devices.py), 40-55 % less XLA time at the same run time; a smaller program "
        "(fused equations of motion, the lean loop of steps, small solves without gathers or "
        "scatters, derived quantities in numpy, the strips' equilibrium with no unrolled step: "
        "L3 at N = 16 18.0 -> 9.5 s of XLA time). Measured and not taken: LLVM at -O0 "
        "(--xla_backend_optimization_level=0) cuts XLA's time by a further 35-40 % but runs L2 "
        "1.65x and L3 2.7x slower (the test suite uses it); the scene's parts as programs of "
        "their own, each compiled on a thread while the next is traced: L0 first call 2.69 -> "
        "2.39-2.43 s, L2 none (5.27-5.32 against 5.15-5.28 s), since XLA already keeps about "
        "1.5 of the 2 cores busy; the quasi-static start's balance as the fused balance (XLA "
        "-0.2 s, tracing +0.2 s). Remaining: tracing and lowering (1.0 s of L0's, 2.0 s of "
        "L2's), spread over the input table, the start, the solve and the outputs"),
    "warm_over_cold_wall": (
        "the warm process loads the program's executable (no trace, lowering or compilation). "
        "Taken since: `--no-figures` (no plotting library: a warm L0 process 2.4-2.6 -> "
        "1.6-1.7 s), the results printed before the figures are drawn, and ml_dtypes 0.7.0 "
        "excluded (import jax 1.0 -> 0.45 s). What is left is the interpreter and its imports "
        "(jax, equinox, diffrax, which the scene's static arguments need; matplotlib for the "
        "figures), drawing the figures, and for L3 loading its executable (1.0 s at N = 16): a "
        "scene module that does not import diffrax when an executable is loaded"),
    "identify_cold_over_warm": (
        "taken: `ppr-jax identify` keeps the fit's residual-and-Jacobian program in the program "
        "store as the scenes' are (`identify(program_dir=...)`), so a second process loads its "
        "executable instead of tracing it (L2: an 8 s trace, most of the second process's wait "
        "before). Within one process the second fit reuses the compiled program, so the ratio "
        "of first to second fit is compilation against iterations: the first fit's XLA "
        "compilation of the simulation's forward-mode Jacobian (L2 servo circle: about 8 s "
        "with the loop emitters) is the bound. Taken since: the quasi-static start is "
        "differentiated as a root of its balance, not through its Newton iteration (XLA 5.4 -> "
        "4.8 s, lowering 1.0 -> 0.5 s of L2's fit program). Measured and not taken: the start's "
        "two passes with carries that hold the parameters' tangent from the first (JAX's "
        "fixpoint over a scan's carry tangents then ends in one trace): 0.3 s less tracing, "
        "0.2 s more XLA time. Remaining: tracing the forward-mode Jacobian of the solve "
        "itself (6 s for L2, of which the start's is 1.4 s at most) and the input table shared "
        "with the scenes"),
}


def _budget_row(model: str):
    try:
        with open(BUDGET) as f:
            rows = json.load(f)["rows"]
    except (OSError, ValueError, KeyError):
        return None
    return next((r for r in rows if r["model"] == model and r["scene"] == "paper-circle"), None)


def bounds(rows, goal_rows) -> None:
    """Add `bound` (what bounds the goal, with the measurement) and `lever` to each goal not
    met."""
    by = {r["name"]: r for r in rows}

    def wall(name):
        return by.get(name, {}).get("new", {}).get("wall_s")

    for g in goal_rows:
        if g["met"] is not False:
            continue
        name = g["goal"]
        if name == "cold_compile_new_over_base":
            b = _budget_row(g["model"])
            if b is not None:
                parts = ", ".join(f"{k} {v['compile_s']:.1f} s" for k, v in b["parts"].items())
                g["bound"] = (f"XLA compilation of the scene program, "
                              f"{b['whole']['compile_s']:.1f} s (compile_budget.json, "
                              f"its parts alone: {parts})")
        elif name == "warm_over_cold_wall":
            cold = by[f"simulate {g['model']} cold"]["new"]
            warm = by[f"simulate {g['model']} warm"]["new"]
            imp, mpl, nil = (wall("import jax"), wall("import matplotlib (Figure, Agg)"),
                             wall("python -c pass"))
            known = [x for x in (imp, (mpl - nil) if mpl and nil else None,
                                 warm.get("compile_s"),
                                 (warm.get("run_ms") or 0) / 1e3) if x is not None]
            g["bound"] = (
                f"the warm process {warm['wall_s']:.2f} s against the goal's "
                f"{0.1 * cold['wall_s']:.2f} s: a process importing jax "
                f"{imp if imp is not None else float('nan'):.2f} s, matplotlib's Figure and Agg "
                f"{(mpl - nil) if mpl and nil else float('nan'):.2f} s above a bare "
                f"interpreter, loading the stored program {warm.get('compile_s', float('nan')):.2f}"
                f" s, the run {warm.get('run_ms', float('nan')):.0f} ms; the rest "
                f"{warm['wall_s'] - sum(known):.2f} s (the command's own imports: diffrax, "
                f"the scenes; drawing and writing the figures and the CSV)")
        elif name == "identify_cold_over_warm" and g.get("mode") == "processes":
            c = by["identify t cold (processes)"]["new"]
            w = by["identify t warm (processes)"]["new"]
            g["bound"] = (f"a process with a fresh cache {c['wall_s']:.1f} s (its fit "
                          f"{c.get('done_in_s') or float('nan'):.1f} s) against a second process "
                          f"{w['wall_s']:.1f} s (its fit {w.get('done_in_s') or float('nan'):.1f}"
                          f" s): the first traces and compiles the fit's programs, the second "
                          f"loads them")
            wb = by["identify t warm (processes)"].get("base")
            if wb is not None:
                g["bound"] += (f"; the base's second process took {wb['wall_s']:.1f} s (it "
                               f"traced the fit again), so the ratio rose as the second "
                               f"process got faster")
        elif name == "identify_cold_over_warm" and g.get("mode") == "fits":
            r = next(r for r in rows if r["part"] == "identify" and r["mode"] == "fits")["new"]
            g["bound"] = (f"the first fit {r['first_fit_s']:.1f} s against the second "
                          f"{r['second_fit_s']:.1f} s: the first compiles the simulation, its "
                          f"derivatives and the fit's own programs")
        if name in LEVERS:
            g["lever"] = LEVERS[name]


def _suite_wall(log_path: str):
    """(passed, failed, pytest's wall s) from the last summary line of a pytest log."""
    with open(log_path) as f:
        lines = [ln for ln in f if re.search(r" in [\d.]+s( \(|\s*=)", ln)]
    if not lines:
        raise SystemExit(f"{log_path}: no pytest summary line")
    counts = {k: int(n) for n, k in re.findall(r"(\d+) (passed|failed|error)", lines[-1])}
    wall = float(re.search(r" in ([\d.]+)s", lines[-1])[1])
    return counts.get("passed", 0), counts.get("failed", 0) + counts.get("error", 0), wall


def suite_goal(log_path: str, commit: str, others=()) -> dict:
    """The test suite's goal from a `.ci/run` log of a fresh clone (pytest's last line "N passed
    in X s" and `.ci/run`'s "rc=... wall=..."): pytest's wall against `SUITE_BASE`'s, with what
    bounds it and the remaining lever when it is not met. `others`: logs of other fresh-clone
    runs of the same code: the goal is met only if every run meets it (the machine's speed
    varies by 10-20 % between runs), and `value` is the slowest run's."""
    tests, failed, wall = _suite_wall(log_path)
    spread = sorted([wall] + [_suite_wall(o)[2] for o in others])
    value = spread[-1] / SUITE_BASE["wall_s"]
    g = {"goal": "suite_new_over_base", "limit": GOALS["suite_new_over_base"], "value": value,
         "met": bool(value <= GOALS["suite_new_over_base"]), "base": SUITE_BASE,
         "new": {"commit": commit, "tests": tests, "wall_s": wall,
                 "failed": failed, "walls_of_nearby_runs_s": spread},
         "measured": "pytest's wall of `.ci/run` on a fresh clone, 2 workers, 2-core machine, "
                     "nothing else running (the base's from the issue)"}
    if not g["met"]:
        g["bound"] = (f"{spread[-1]:.0f} s against the goal's {SUITE_BASE['wall_s'] / 3:.0f} s "
                      f"with {tests} tests against the base's {SUITE_BASE['tests']} ("
                      f"{spread[0]:.0f}-{spread[-1]:.0f} s in {len(spread)} runs of this code: "
                      f"the machine's speed varies); the two "
                      f"workers finish within 5-25 s of each other (files handed out longest "
                      f"first), so the bound is the work: XLA compilation about half of it, "
                      f"tracing a third, one distinct program per test setting (no large "
                      f"program is compiled twice)")
        g["lever"] = LEVERS["suite_new_over_base"]
    return g


def merge_suite_goal(out: str, goal: dict) -> None:
    """Put the suite's `goal` into the JSON at `out` (replacing an earlier one), leaving the
    rows of the run that wrote it as they are."""
    with open(out) as f:
        data = json.load(f)
    data["goals"] = [g for g in data["goals"] if g["goal"] != goal["goal"]] + [goal]
    with open(out, "w") as f:
        json.dump(data, f, indent=1)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--suite-log", nargs=2, metavar=("LOG", "COMMIT"), default=None,
                    help="only add the test suite's goal, from the log of `.ci/run` on a "
                         "fresh clone of COMMIT, to the JSON at --out (no process is timed)")
    ap.add_argument("--suite-also", nargs="*", default=(), metavar="LOG",
                    help="logs of other fresh-clone runs of the same code: the goal is met "
                         "only if every run meets it")
    ap.add_argument("--new", default=".", help="the checkout measured (default: this one)")
    ap.add_argument("--base", default=None, help="a second checkout to compare against")
    ap.add_argument("--python", default=sys.executable,
                    help="the interpreter of every child (one venv for both checkouts)")
    ap.add_argument("--parts", nargs="+", choices=PARTS, default=list(PARTS))
    ap.add_argument("--models", nargs="+", choices=MODELS, default=list(MODELS))
    ap.add_argument("--identify", nargs="+", choices=["fits", "processes"], default=["fits"],
                    help="identification cold against warm: the first and second fit in one "
                         "process (as benchmarks/identify_time.py), and/or `ppr-jax identify` "
                         "in a process with a fresh cache and again on it")
    ap.add_argument("--repeats", type=int, default=3, help="repeats of the start-up rows")
    ap.add_argument("--sim-repeats", type=int, default=None,
                    help="repeats of the simulations and identification (default 1 with "
                         "--quick, else --repeats)")
    ap.add_argument("--quick", action="store_true",
                    help="simulations and identification over 1 s (--t-end 1)")
    ap.add_argument("--note", default=None, help="a note stored in the JSON")
    ap.add_argument("--out", default=OUT)
    args = ap.parse_args(argv)
    if args.suite_log:
        merge_suite_goal(args.out, suite_goal(*args.suite_log, others=args.suite_also))
        print(f"wrote the suite's goal into {args.out}")
        return 0
    sim_repeats = args.sim_repeats or (1 if args.quick else args.repeats)
    t_end = 1.0 if args.quick else None

    pycache = tempfile.mkdtemp(prefix="ppr_jax_latency_pycache_")
    checkouts = ([Checkout("base", args.base, args.python, pycache)] if args.base else [])
    checkouts.append(Checkout("new", args.new, args.python, pycache))
    labels = [c.label for c in checkouts]
    load0 = os.getloadavg()
    t_start = time.perf_counter()
    try:
        # Bytecode for every module the timed processes import (module docstring).
        for c in checkouts:
            for code, a in (("pass", ()), (_import("jax"), ()), (_import("ppr_jax"), ()),
                            (CLI, ("--help",))):
                c.run(code, a)
            if "simulate" in args.parts or "identify" in args.parts:
                with tempfile.TemporaryDirectory() as d:
                    c.run(CLI, ["simulate", "--model", "rigid", "--t-end", "0.05", "--n-out",
                                "3", "--out", os.path.join(d, "out")],
                          env={"PPR_JAX_CACHE_DIR": os.path.join(d, "cache")})
        rows = []
        if "startup" in args.parts:
            rows += startup_rows(checkouts, args.repeats)
        if "simulate" in args.parts:
            rows += simulate_rows(checkouts, args.models, sim_repeats, t_end)
        if "identify" in args.parts:
            t_id = 1.0 if args.quick else 7.54
            if "fits" in args.identify:
                rows += identify_rows(checkouts, sim_repeats, t_id)
            if "processes" in args.identify:
                rows += identify_process_rows(checkouts, sim_repeats, t_id)
    finally:
        shutil.rmtree(pycache, ignore_errors=True)
    data = {
        "machine": machine(),
        "checkouts": {c.label: c.describe() for c in checkouts},
        "python": args.python,
        "quick": args.quick,
        "scene": "paper-circle" + (" over 1 s (--t-end 1)" if args.quick else " (7.54 s)"),
        "repeats": {"startup": args.repeats, "simulate_identify": sim_repeats},
        "what": "wall times of fresh processes (minimum of repeats, base and new interleaved); "
                "compile_s and run_ms from the command's own log line; import_s measured "
                "inside the process; bytecode warm (PYTHONPYCACHEPREFIX)",
        "load_average": {"start": load0, "end": os.getloadavg()},
        "duration_s": time.perf_counter() - t_start,
        "rows": rows,
        "goals": goals(rows, labels),
    }
    bounds(rows, data["goals"])
    if args.note:
        data["note"] = args.note
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(data, f, indent=1)
    print()
    for g in data["goals"]:
        v = "n/a" if g["value"] is None else f"{g['value']:.3g}"
        b = f" (base {g['base_value']:.3g})" if g.get("base_value") is not None else ""
        print(f"{g['goal']:32s} {g.get('model', g.get('mode', '')):9s} {v:>8s}{b} <= "
              f"{g['limit']:.3g}: "
              f"{'met' if g['met'] else 'not met' if g['met'] is not None else '-'}")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
