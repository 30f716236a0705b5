"""Every benchmark script in benchmarks/ still runs end to end, on tiny settings (all `slow`).

The documentation publishes numbers from `benchmarks/results/*.json` (`scripts/gen_perf.py`,
docs/performance.md and the pages that quote a study), so the scripts that make them must keep
running: nothing else runs them, and two of them had not run for weeks, unnoticed, since an
argument check refused their calls. One test per script
(`benchmarks/*.py`, ids the script's stem): the whole `benchmarks/` directory is copied into the
test's temporary directory and the copy of the script runs there in a fresh process, with the
cheapest options it has (`CASES`: a short horizon, one model, one solver, one repeat), and must
exit 0 and write (or rewrite) the JSON it publishes. The scripts write next to themselves
(`Path(__file__).parent / "results"`), so they write into the copy: the published results in the
repository are never touched. A script added to benchmarks/ without an entry in `CASES` fails
its test, so that it gets one.

`plots.py` is the suite's figure module, not a script (`run.py` and `notebooks/benchmarks.ipynb`
import it): its test draws every figure from the copy's published JSON. `mjx_batch.py` needs
MuJoCo MJX (the `bench` extra), which the test environment lacks: it is skipped when
`mujoco.mjx` cannot be imported. `benchmarks/contenders/` is a package of modules, not scripts
(MuJoCo's and scipy's L2, the known-truth data; checked by `tests/test_mujoco.py` and
`tests/test_scipy_l2.py`): it has no script of its own, is copied with the rest and runs inside
`identify_known_truth.py`, `identify_own.py` and `start_sensitivity.py`. `_common.py` (what
several scripts share) is not a script either: it runs inside the scripts that import it.

No number is checked (tiny settings measure nothing): only that each script runs and writes
its file. The scripts inherit the suite's environment (its fast XLA compile flags and persistent
compilation cache). On the 2-core CPU a script takes 2 to 50 s, mostly XLA compilation, and
`l3_validation.py --quick` (the smallest run it has: about twenty programs) 1 to 2 minutes; the
file took 10 minutes on an empty cache and 7 on the cache that run left
(`python -m pytest -m slow -n 0 tests/test_benchmarks_run.py`).
"""

import importlib
import json
import os
import pathlib
import shutil
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"
SCRIPTS = sorted(p.stem for p in BENCHMARKS.glob("*.py") if not p.stem.startswith("_"))

#: per script: its tiny arguments, and the files (under the copy's `results/`) it must write
CASES = {
    "compensate": (["--models", "rigid", "--drives", "torque", "--t-end", "0.2", "--repeats",
                    "1", "--optimise"], ["compensate.json"]),
    "beam_convergence": (["--max-n", "4"], ["beam_convergence.json"]),
    "derivative_latency": (["--new", str(ROOT), "--quick", "--rows", "modes"],
                           ["derivative_latency.json"]),
    "beam_stiffness": (["--n", "2", "--t-end", "0.005", "--rtols", "1e-4", "--solvers", "tsit5"],
                       ["beam_stiffness.json"]),
    "compile_budget": (["--models", "rigid", "--scenes", "servo-circle", "--repeats", "1"],
                       ["compile_budget.json"]),
    "design": (["--repeats", "1", "--optimizers", "slsqp", "--no-tier2"], ["design.json"]),
    "design_latency": (["--new", str(ROOT), "--closed-form", "--repeats", "1"],
                       ["design_latency.json"]),
    "engine_ab": (["--checkout", str(ROOT), "--new", str(ROOT), "--quick", "--parts", "run"],
                  ["engine_ab.json"]),
    "identify_known_truth": (["--seeds", "2", "--t-end", "0.3", "--cases", "gamma-auto"],
                             ["identify_known_truth.json"]),
    "identify_l3": (["--elements", "2", "--t-end", "0.2"], ["identify_l3.json"]),
    "identify_own": (["--t-end", "0.5"], ["identify_own.json"]),
    "identify_profile": (["--t-end", "0.3"], ["identify_profile.json"]),
    "identify_strip": (["--t-end", "0.5"], ["identify_strip.json"]),
    "identify_time": (["--t-end", "0.3"], ["identify_time.json"]),
    "implicit_l2": (["--thickness", "2", "--t-end", "0.05", "--solvers", "tsit5", "--rtols",
                     "1e-4", "--repeats", "1"], ["implicit_l2.json"]),
    "kernel_counts": (["--repeats", "1"], ["kernel_counts.json"]),
    "l3_full_vs_quasi_static": (["--t-end", "0.01", "--elements", "2"],
                                ["l3_full_vs_quasi_static.json"]),
    "l3_implicit": (["--elements", "2", "--t-end", "0.001", "--n-out", "3", "--losses", "0",
                     "--solvers", "tsit5", "--rtols", "1e-5", "--ref-solver", "tsit5",
                     "--ref-rtol", "1e-7", "--no-quasi-static"], ["l3_implicit.json"]),
    "l3_validation": (["--quick"], ["l3_validation_quick.json"]),
    "l3_whole_scene": (["--elements", "2", "--solvers", "ros34pw2"], ["l3_whole_scene.json"]),
    "latency": (["--new", str(ROOT), "--parts", "startup", "simulate", "--models", "rigid",
                 "--quick", "--repeats", "1"], ["latency.json"]),
    "mjx_batch": (["--sizes", "1", "--dt", "1e-3", "--t-end", "0.05", "--rtols", "1e-6",
                   "--repeats", "1"], ["cpu/mjx_batch.json"]),
    "path_cost": (["--repeats", "1", "--models", "rigid"], ["path_cost.json"]),
    "run": (["--quick", "--parts", "batch", "--models", "reduced", "--sizes", "1", "--repeats",
             "1"], ["cpu/batch.json"]),
    "sensitivity_cost": (["--t-end", "0.1", "--n-out", "3", "--rtol", "1e-4", "--repeats", "1",
                          "--skip-jacfwd", "--only-grad"], ["sensitivity_cost.json"]),
    "start_sensitivity": (["--quick"], ["start_sensitivity.json"]),
    "loop_threshold": (["--quick", "--repeats", "1"], ["loop_threshold.json"]),
    "sweep_sharding": (["--members", "2", "--chunk", "2", "--t-end", "0.1", "--model", "rigid",
                        "--repeats", "1"], ["sweep_sharding.json"]),
}
#: scripts that need what the test environment may lack: {script: (module, why)}
NEEDS = {"mjx_batch": ("mujoco.mjx", "needs MuJoCo MJX (`pip install '.[bench]'`, "
                                     "mujoco-mjx), not installed here")}


@pytest.fixture
def bench_copy(tmp_path):
    """A copy of benchmarks/ (results included) in tmp_path: the scripts write into it."""
    shutil.copytree(BENCHMARKS, tmp_path / "benchmarks",
                    ignore=shutil.ignore_patterns("__pycache__"))
    return tmp_path / "benchmarks"


def _snapshot(results: pathlib.Path) -> dict:
    return {str(p.relative_to(results)): (p.stat().st_mtime_ns, p.read_bytes())
            for p in results.rglob("*") if p.is_file()}


def _run(cmd, cwd, pythonpath=()):
    """Runs `cmd` in `cwd` in the suite's environment, with `pythonpath` ahead of its path."""
    env = dict(os.environ, MPLBACKEND="Agg", PPR_JAX_CACHE="0", PYTHONDONTWRITEBYTECODE="1")
    if pythonpath:
        env["PYTHONPATH"] = os.pathsep.join(
            [*map(str, pythonpath), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env.pop("PYTEST_XDIST_WORKER", None)
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, (
        f"{' '.join(map(str, cmd))} exited {proc.returncode}:\n{proc.stderr[-4000:]}")
    return proc


def _written(before: dict, after: dict, names) -> list:
    """The names among `names` whose file is new or changed (mtime or bytes)."""
    return [n for n in names if n in after and after[n] != before.get(n)]


@pytest.mark.slow
@pytest.mark.parametrize("script", SCRIPTS)
def test_benchmark_runs(script, bench_copy):
    if script in NEEDS:
        module, why = NEEDS[script]
        try:
            importlib.import_module(module)
        except ImportError:
            pytest.skip(f"benchmarks/{script}.py {why}")
    results = bench_copy / "results"
    before = _snapshot(results)
    if script == "plots":
        _plots(bench_copy, before)
        return
    assert script in CASES, (
        f"benchmarks/{script}.py has no tiny arguments in tests/test_benchmarks_run.py's CASES")
    args, outputs = CASES[script]
    _run([sys.executable, str(bench_copy / f"{script}.py"), *args], cwd=bench_copy.parent)
    after = _snapshot(results)
    written = _written(before, after, outputs)
    assert written == list(outputs), (
        f"benchmarks/{script}.py did not write {sorted(set(outputs) - set(written))} under "
        f"results/ (new or changed: {sorted(n for n in after if after[n] != before.get(n))})")
    for name in outputs:
        json.loads((results / name).read_text())  # a whole JSON document, not a cut-off one


_PLOTS = """
import json, pathlib, sys
from benchmarks import plots
out = pathlib.Path(sys.argv[1]) / "benchmarks" / "results" / "cpu"
for part, draw in (("work_precision", plots.work_precision), ("contenders", plots.contenders),
                   ("batch", plots.batch)):
    draw(json.loads((out / (part + ".json")).read_text()), str(out))
"""


def _plots(bench_copy, before):
    """plots.py: every figure of the suite redrawn from the copy's published CPU JSON."""
    # the copy's benchmarks/ as the package `benchmarks`, through the path, not the script
    _run([sys.executable, "-c", _PLOTS, str(bench_copy.parent)], cwd=bench_copy.parent,
         pythonpath=[bench_copy.parent])
    pngs = ["cpu/work_precision_paper-circle.png", "cpu/work_precision_servo-circle.png",
            "cpu/contenders.png", "cpu/batch_scaling.png"]
    written = _written(before, _snapshot(bench_copy / "results"), pngs)
    assert written == pngs, f"plots did not redraw {sorted(set(pngs) - set(written))}"
