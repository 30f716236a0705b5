import jax
import pytest

jax.config.update("jax_enable_x64", True)

import ppr_jax as pj  # noqa: E402


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
