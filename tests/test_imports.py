"""`import ppr_jax` stays light: the offline PRB fit, the elastica and scipy's optimizers are lazy.

Runs in a fresh interpreter (a subprocess), since this test session has imported everything.
"""

import os
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]

HEAVY = ("scipy.optimize", "scipy.interpolate", "ppr_jax._prb_fit", "ppr_jax.elastica")

CODE = f"""
import sys

import ppr_jax

HEAVY = {HEAVY!r}
loaded = [m for m in HEAVY if m in sys.modules]
assert not loaded, f"import ppr_jax loaded {{loaded}}"

# The robot's default PRB parameters come from the table alone.
K_theta = float(ppr_jax.derived(ppr_jax.RobotParams()).K_theta)
assert 2.0 < K_theta < 3.5, K_theta
loaded = [m for m in HEAVY if m in sys.modules]
assert not loaded, f"derived() loaded {{loaded}}"
assert {{"fit_prb", "prb_error", "elastica", "prb_parameters", "prb_table"}} <= set(dir(ppr_jax))

# The lazy names are still reachable, and are the objects of their modules.
from ppr_jax import prb_error
assert callable(ppr_jax.fit_prb) and ppr_jax.fit_prb.__module__ == "ppr_jax._prb_fit"
assert prb_error is sys.modules["ppr_jax._prb_fit"].prb_error
assert ppr_jax.elastica is sys.modules["ppr_jax.elastica"]
assert callable(ppr_jax.elastica.solve_cantilever)
import ppr_jax.elastica as el
assert el.solve_cantilever is ppr_jax.elastica.solve_cantilever
try:
    ppr_jax.no_such_name
except AttributeError as err:
    assert "no_such_name" in str(err)
else:
    raise AssertionError("missing attribute did not raise")
print("ok", ppr_jax.__file__)
"""


def test_import_ppr_jax_does_not_load_the_offline_fit():
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env.setdefault("JAX_PLATFORMS", "cpu")
    res = subprocess.run([sys.executable, "-c", CODE], capture_output=True, text=True, env=env,
                         cwd=ROOT, timeout=240)
    assert res.returncode == 0, res.stdout + res.stderr
    assert res.stdout.startswith("ok")
    # The interpreter imported this checkout's package, not another installed copy.
    assert pathlib.Path(res.stdout.split()[1]).resolve() == ROOT / "ppr_jax" / "__init__.py"


def test_light_names_match_the_registries():
    """`_names` (what the parser reads) lists the registries' names in their order."""
    import ppr_jax._names as names
    from ppr_jax._models import MODELS
    from ppr_jax._scenes import SCENE_CLASSES, SCENES
    from ppr_jax._simulate import SOLVERS
    from ppr_jax._studies import SWEEP_SCENES

    assert names.MODEL_NAMES == tuple(MODELS)
    assert names.KINEMATIC_MODELS == tuple(n for n, c in MODELS.items()
                                           if c.actuated_index is None)
    assert names.SOLVER_NAMES == tuple(SOLVERS)
    assert names.SCENE_NAMES == tuple(SCENE_CLASSES) == SWEEP_SCENES
    assert SCENES == (*SCENE_CLASSES, "modes")
