"""`import ppr_jax` stays light: the offline PRB fit, the elastica and scipy's optimizers are lazy.

Runs in a fresh interpreter (a subprocess), since this test session has imported everything.
"""

import os
import pathlib
import subprocess
import sys

import pytest

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


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
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


def _run(code: str, timeout: float = 240) -> str:
    """Run `code` in a fresh interpreter on this checkout; returns its stdout."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env.setdefault("JAX_PLATFORMS", "cpu")
    env.pop("JAX_ENABLE_X64", None)  # the package enables float64 itself
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                         cwd=ROOT, timeout=timeout)
    assert res.returncode == 0, res.stdout + res.stderr
    return res.stdout


#: what `import ppr_jax` must not load: the numerical stack comes with the first name used
NOT_ON_IMPORT = ("matplotlib", "scipy", "optimistix", "diffrax", "lineax", "equinox")


def test_import_ppr_jax_loads_no_numerical_module():
    out = _run(f"""
import sys

import ppr_jax

loaded = sorted({{m.split(".")[0] for m in sys.modules}} & set({NOT_ON_IMPORT!r}))
assert not loaded, f"import ppr_jax loaded {{loaded}}"
# every public name is still there, and loads its module on first use
assert set(ppr_jax.__all__) <= set(dir(ppr_jax))
assert ppr_jax.RobotParams.__module__ == "ppr_jax._params"
from ppr_jax import simulate, sweep  # noqa: F401

# a simulation or a study loads figures only when it draws one
assert "matplotlib" not in sys.modules
# float64 holds although JAX came after the package
import jax.numpy as jnp
assert jnp.zeros(1).dtype == jnp.float64, jnp.zeros(1).dtype
print("ok")
""")
    assert out.strip() == "ok"


def test_import_ppr_jax_after_jax_enables_float64():
    out = _run("""
import jax
import jax.numpy as jnp

assert jnp.zeros(1).dtype == jnp.float32
import ppr_jax  # noqa: F401

assert jax.config.jax_enable_x64 and jnp.zeros(1).dtype == jnp.float64
print("ok")
""")
    assert out.strip() == "ok"


def test_cli_parser_and_help_import_no_jax():
    """`ppr-jax --help` (and every command's) answers from plain-Python modules: building the
    parser imports neither JAX nor numpy."""
    out = _run("""
import contextlib
import io
import sys

import ppr_jax._cli
import ppr_jax_cli

parser = ppr_jax._cli.build_parser()
for argv in (["--help"], ["simulate", "--help"], ["identify", "--help"]):
    sys.argv = ["ppr-jax", *argv]
    with contextlib.redirect_stdout(io.StringIO()) as text:
        try:
            ppr_jax_cli.main()
        except SystemExit as err:
            assert err.code == 0, err.code
    assert "usage: ppr-jax" in text.getvalue()
heavy = sorted({m.split(".")[0] for m in sys.modules} & {"jax", "jaxlib", "numpy"})
assert not heavy, f"the parser imported {heavy}"
print("ok")
""")
    assert out.strip() == "ok"


def test_light_names_match_the_registries():
    """`_names` (what the parser reads) lists the registries' names in their order."""
    import ppr_jax._names as names
    from ppr_jax._models import MODELS
    from ppr_jax._scenes import SCENES
    from ppr_jax._simulate import SOLVERS

    assert names.MODEL_NAMES == tuple(MODELS)
    assert names.KINEMATIC_MODELS == tuple(n for n, c in MODELS.items()
                                           if c.actuated_index is None)
    assert names.SOLVER_NAMES == tuple(SOLVERS)
    assert names.SCENE_NAMES == tuple(SCENES)[:len(names.SCENE_NAMES)]
    assert names.SIMULATE_CHOICES == (*names.SCENE_NAMES, "modes")


def test_lazy_exports_match_the_static_imports():
    """The names `__getattr__` loads are the ones the `TYPE_CHECKING` block imports (what static
    tools read), from the same modules."""
    import ast

    import ppr_jax

    tree = ast.parse((ROOT / "ppr_jax" / "__init__.py").read_text())
    block = next(n for n in tree.body if isinstance(n, ast.If)
                 and getattr(n.test, "id", None) == "_TYPE_CHECKING")
    static = {}
    for node in block.body:
        if isinstance(node, ast.ImportFrom):
            for alias in node.names:
                static[alias.asname or alias.name] = "." + (node.module or alias.name)
    assert static == ppr_jax._LAZY
