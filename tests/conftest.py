import os
import pathlib

# One persistent compilation cache for the whole test run, shared by the xdist workers, the
# in-process command-line tests and the subprocesses (notebooks, console script): a program that
# several test files compile (a scene, a model's derived quantities) is compiled once. JAX keys
# an entry on the lowered program, the compile options and its own version, so an entry is only
# ever read back for the identical program. Set before JAX and equinox are imported, so that
# subprocesses inherit it too. `PPR_TEST_CACHE_DIR` moves it; `PPR_TEST_CACHE_DIR=0` turns it off.
ROOT = pathlib.Path(__file__).resolve().parents[1]
_CACHE = os.environ.get("PPR_TEST_CACHE_DIR", str(ROOT / ".pytest_cache" / "jax"))
if _CACHE != "0":
    os.environ["PPR_JAX_CACHE_DIR"] = _CACHE  # the command line's cache: the same directory
    os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", _CACHE)
    # Programs that compiled in under a second are not kept: the suite compiles about 6,700
    # programs, most of them eager single operations, and writing each cost more than reading
    # it back saved (test_kinematics and test_dynamics in one process: 91 s with every program
    # kept, 86 s with those over 1 s, 84 s with no cache; the suite's cache hits saved -4 s in
    # all). The console script keeps all of its own (`enable_compilation_cache`).
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "1")
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")
    # a size limit turns on JAX's file lock around reads and writes (two workers, one directory)
    os.environ.setdefault("JAX_COMPILATION_CACHE_MAX_SIZE", str(16 * 2**30))
    # A program with a host callback (equinox's runtime checks in raise mode) is keyed on the
    # callback's address and never read back: the suite runs in NaN mode, as the console script
    # does, and every result is checked from its status codes. Tests of an error raised inside a
    # compiled program switch to raise mode (`helpers.raises_in_compiled_code`).
    os.environ.setdefault("EQX_ON_ERROR", "nan")


# XLA's cheapest code generation halves the suite's compilation, which is most of its time.
# Measured on the 2-core CPU (one L2 `paper-circle` program, XLA's compile seconds, run time):
# 5.5 s, 51 ms by default; 3.2 s, 52 ms with the older loop emitters (`compile_flags`, which the
# command line uses too); 1.9 s, 85 ms with LLVM's optimisation off as well. Each changes a
# result by rounding only (1.5e-12 m in the poses); no tolerance was loosened for them (the
# issue's allowance: "XLA's optimisation effort lowered for tests only if no tolerance has to be
# loosened"). `PPR_TEST_FAST_COMPILE=0` runs the suite with XLA's defaults. The flags as the
# user gave them are kept for the `xla_defaults` tests, set once by the first process (the
# xdist workers inherit the fast flags with them).
_USER_XLA_FLAGS = os.environ.setdefault("PPR_TEST_USER_XLA_FLAGS", os.environ.get("XLA_FLAGS", ""))
_FAST = os.environ.get("PPR_TEST_FAST_COMPILE", "1") != "0"
if _FAST:
    from ppr_jax._devices import default_flags, set_xla_flags  # noqa: E402

    set_xla_flags(["--xla_backend_optimization_level=0", *default_flags()])

import jax  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)
# Strict promotion: an implicit dtype promotion (int with float, float32 with float64) or an
# implicit rank broadcast is an error in the tests, so the package states both where it means them.
jax.config.update("jax_numpy_dtype_promotion", "strict")
jax.config.update("jax_numpy_rank_promotion", "raise")

import ppr_jax as pj  # noqa: E402

if _CACHE != "0":
    from ppr_jax._cache import enable_compilation_cache  # noqa: E402

    enable_compilation_cache(_CACHE, min_compile_time_s=float(
        os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"]))

# Tracing a program makes millions of short-lived Python objects, and each of the collector's
# full passes walks every object the worker holds (the libraries' modules, JAX's caches, the
# fixtures' results). Freezing what is imported and collecting less often: one process, no
# compilation cache, one run a side, test_dynamics 105 -> 93 s, identification's fits 76 -> 66 s,
# test_fused_eom 130 -> 127 s. `PPR_TEST_GC=0` keeps Python's defaults.
if os.environ.get("PPR_TEST_GC", "1") != "0":
    import gc  # noqa: E402

    gc.collect()
    gc.freeze()
    gc.set_threshold(100_000, 50, 100)


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_code():
    """Drop JAX's compiled executables after each test module. Every executable keeps about three
    memory mappings of JIT code; a suite that compiles tens of thousands of them (eager op-by-op
    tests compile every primitive) passes the kernel's limit of 65,530 mappings per process
    (vm.max_map_count), and LLVM then segfaults while compiling. Session fixtures hold results,
    not executables, so nothing shared is lost. Keeping them for a worker's next files until it
    held 20,000 mappings (the scenes at their defaults, which many files run, traced and
    compiled once a worker) did not show a gain: one run a side, 898 against 972 s for the
    default tier, on a 2-core machine whose speed moved by as much between runs of one tree."""
    yield
    jax.clear_caches()
    from ppr_jax._programs import clear_cached_programs

    clear_cached_programs()


@pytest.fixture(autouse=True)
def _keep_the_suites_cache_threshold():
    """The command line called in a test (`main([...])`) sets JAX's persistent-cache threshold
    to 0 for its process (`enable_compilation_cache`: a command keeps all of its programs); in
    a test worker that would last for every later test file, each writing its thousands of
    small programs. The suite's threshold is restored after each test."""
    before = jax.config.jax_persistent_cache_min_compile_time_secs
    yield
    if jax.config.jax_persistent_cache_min_compile_time_secs != before:
        jax.config.update("jax_persistent_cache_min_compile_time_secs", before)


@pytest.fixture(scope="session")
def params():
    """Table 1 defaults, t = 0.3 mm."""
    return pj.RobotParams()


@pytest.fixture(scope="session")
def dv(params):
    return pj.derived(params)


@pytest.fixture(scope="session")
def robot(params):
    """The default robot, built once."""
    return pj.Robot(params)


@pytest.fixture(scope="session")
def paper_circle_L1():
    """The L1 paper-circle scene, as a timed report with metrics (compiled once per session)."""
    return pj.run_scene("paper-circle", model="reduced")



if os.environ.get("PPR_TEST_COMPILE_STATS"):
    # Where the suite's time goes: one JSON line per test (its file, wall seconds, XLA
    # compilation seconds and count, and the shared cache's hits and the compile seconds they
    # saved), appended as the run goes, one file per worker in the given directory.
    import json
    import time

    from jax import monitoring

    _NOW = {}

    def _on_duration(event, duration, **_):
        if event.endswith("backend_compile_duration"):
            _NOW["compile_s"] = _NOW.get("compile_s", 0.0) + duration
            _NOW["compiles"] = _NOW.get("compiles", 0) + 1
        elif event.endswith("compile_time_saved_sec"):
            _NOW["saved_s"] = _NOW.get("saved_s", 0.0) + duration
            _NOW["hits"] = _NOW.get("hits", 0) + 1

    monitoring.register_event_duration_secs_listener(_on_duration)

    @pytest.fixture(autouse=True)
    def _compile_stats(request):
        out = pathlib.Path(os.environ["PPR_TEST_COMPILE_STATS"])
        out.mkdir(parents=True, exist_ok=True)
        t = time.perf_counter()
        yield
        row = dict(_NOW, test=request.node.nodeid, wall_s=time.perf_counter() - t,
                   end=time.time())
        _NOW.clear()
        worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
        with open(out / f"{worker}.jsonl", "a") as f:
            f.write(json.dumps(row) + "\n")


# Tests marked `xla_defaults` check a result that rounding moves: a fold of the kinematics met
# at one sample or the next, a diverged solve's residual, a start solved on a short table that
# agrees with a long table's to 5e-9 under XLA's default code (3.8e-9) but not under the suite's
# (5.8e-9). They keep their tolerances and run, each module's marked tests in one subprocess,
# under the settings the library's users get (XLA's defaults and the flags `import ppr_jax`
# adds), with the suite's cache.
_XLA_DEFAULTS_RESULTS = {}


def pytest_configure(config):
    config.addinivalue_line(
        "markers", "xla_defaults: run under XLA's default CPU settings (in a subprocess when "
        "the suite compiles with its fast settings)")


def _run_under_xla_defaults(items):
    """Run `items` (one module's) in a fresh pytest process with XLA's default settings; returns
    {name: (outcome, text)} from its JUnit report."""
    import subprocess
    import sys
    import tempfile
    import xml.etree.ElementTree as ET

    with tempfile.TemporaryDirectory() as tmp:
        report = os.path.join(tmp, "report.xml")
        env = dict(os.environ, PPR_TEST_FAST_COMPILE="0", XLA_FLAGS=_USER_XLA_FLAGS)
        for name in ("PYTEST_XDIST_WORKER", "PPR_TEST_USER_XLA_FLAGS"):
            env.pop(name, None)
        proc = subprocess.run(
            [sys.executable, "-m", "pytest", "-q", "-n", "0", "-m", "", "-p", "no:cacheprovider",
             f"--junitxml={report}", *[i.nodeid for i in items]],
            cwd=ROOT, env=env, capture_output=True, text=True, timeout=1800)
        out = {}
        if os.path.exists(report):
            for case in ET.parse(report).getroot().iter("testcase"):
                bad = [c for c in case if c.tag in ("failure", "error", "skipped")]
                outcome = bad[0].tag if bad else "passed"
                text = (bad[0].get("message", "") + "\n" + (bad[0].text or "")) if bad else ""
                out[case.get("name")] = (outcome, text)
        return out, proc.stdout[-4000:] + proc.stderr[-4000:]


#: each test file's seconds on one worker of the 2-core machine (`scripts/test_durations.py`
#: writes it from a `PPR_TEST_COMPILE_STATS` run); a file not listed counts as the median
DURATIONS = ROOT / "tests" / "durations.json"


def _longest_files_first(items):
    """Order the items by their file's duration, longest first (within a file as collected).
    The suite hands whole files to its two workers in collection order (`--dist loadfile
    --no-loadscope-reorder`): longest first, the last files handed out are short and the
    workers finish together. xdist's own order, most tests first, handed out the notebooks
    (four tests, 90 s) near the end and left one worker idle for a minute."""
    import json
    import statistics

    cost = json.loads(DURATIONS.read_text()) if DURATIONS.exists() else {}
    default = statistics.median(cost.values()) if cost else 0.0
    items.sort(key=lambda i: -cost.get(i.nodeid.split("::")[0], default))


def pytest_collection_modifyitems(config, items):
    _longest_files_first(items)
    if not _FAST:  # XLA's defaults already: the marked tests run here as they are
        return
    marked = [i for i in items if i.get_closest_marker("xla_defaults") is not None]
    for item in marked:
        module = [i for i in marked if i.module is item.module]

        def runtest(item=item, module=module):
            key = item.module.__name__
            if key not in _XLA_DEFAULTS_RESULTS:
                _XLA_DEFAULTS_RESULTS[key] = _run_under_xla_defaults(module)
            results, log = _XLA_DEFAULTS_RESULTS[key]
            outcome, text = results.get(item.name, ("missing", log))
            if outcome == "skipped":
                pytest.skip(text)
            if outcome != "passed":
                pytest.fail(f"under XLA's default settings ({outcome}):\n{text}", pytrace=False)

        item.runtest = runtest
        item.setup = lambda: None  # its fixtures are the subprocess's
