import jax
import pytest

jax.config.update("jax_enable_x64", True)
# Strict promotion: an implicit dtype promotion (int with float, float32 with float64) or an
# implicit rank broadcast is an error in the tests, so the package states both where it means them.
jax.config.update("jax_numpy_dtype_promotion", "strict")
jax.config.update("jax_numpy_rank_promotion", "raise")

import ppr_jax as pj  # noqa: E402


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_code():
    """Drop JAX's compiled executables after each test module. Every executable keeps about three
    memory mappings of JIT code; a suite that compiles tens of thousands of them (eager op-by-op
    tests compile every primitive) passes the kernel's limit of 65,530 mappings per process
    (vm.max_map_count), and LLVM then segfaults while compiling. Session fixtures hold results,
    not executables, so nothing shared is lost."""
    yield
    jax.clear_caches()


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
