"""docs/extending.md's recipes, followed literally: a copy of the package gets a new scene, a new
metric, a new model and a new solver exactly where the page says (new files in `_models/` and
`_scenes/`, one line in each registry, the names in `_names.py`, one entry of the metric
catalogue),
and a script in a fresh process then uses each where the page says it follows: `run_scene`,
sweeps, sensitivities and the command line's choices. The results are checked against
independent computations: the new model and solver against the built-in L1 and Tsit5 runs of
the same scene (which tests/test_scene_interface.py and test_dynamics.py check against closed
forms and the paper's equations), the new metric against the same number from the result's
signals in NumPy, the new scene against its closed-form path.

Cheap settings: L1 (`reduced`) under L0's torques, L0 and L1 on the new scene, 0.3 s horizons.
The default suite checks the registries, the command line's choices and the new metric without
compiling (one fresh process, about 10 s); the runs through `run_scene`, sweeps, sensitivities and
the command line compile several programs each (a minute or more per recipe on 2 cores) and
are slow tests."""

import inspect
import os
import pathlib
import re
import shutil
import subprocess
import sys
import textwrap

import pytest

from tests.helpers import SmoothLine

ROOT = pathlib.Path(__file__).resolve().parents[1]
PAGE = (ROOT / "docs" / "extending.md").read_text()


def _edit(path: pathlib.Path, anchor: str, new: str, after: bool = True) -> None:
    """Insert `new` after (or before) the one occurrence of `anchor` in the file."""
    text = path.read_text()
    assert text.count(anchor) == 1, (path, anchor)
    path.write_text(text.replace(anchor, anchor + new if after else new + anchor))


def _model_file(pkg: pathlib.Path) -> str:
    """The new model's file: L1's (`reduced.py`) under another class name, model name and
    default rtol (a model's defaults are its class variables, the page says): a final subclass
    of `AbstractDouble1R`, as the page's recipe has it."""
    text = (pkg / "_models" / "reduced.py").read_text()
    for old, new in (("class Reduced(AbstractDouble1R)", "class TightReduced(AbstractDouble1R)"),
                     ('name = "reduced"', 'name = "tight-reduced"'),
                     ("default_rtol = RTOL", "default_rtol = 1e-10")):
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    return text


#: the new scene: a straight line with a quintic time law, torque-driven by L1's inverse
#: dynamics, as a file of its own with a final subclass of `AbstractScene`; the line is
#: tests/helpers.py's `SmoothLine` (its source)
SCENE_FILE = '''
"""A scene on a straight line: added as docs/extending.md says."""

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp

from .._models import AbstractModel, Reduced
from ._base import AbstractScene, torque_input


''' + inspect.getsource(SmoothLine) + '''

class LineScene(AbstractScene):
    """Torques of L1's inverse dynamics along the line."""

    name: ClassVar[str] = "line"
    thickness: ClassVar[float] = 0.3e-3
    reference: ClassVar[dict] = {}
    drive: ClassVar[str] = "torque"

    @property
    def input_model(self) -> AbstractModel:
        return Reduced()

    def trajectory(self):
        return SmoothLine()

    def commands(self, model, robot, traj, ts, panels):
        return torque_input(self.input_model, robot, traj, ts, panels)

    def follows_its_input(self, model):
        return "its own inverse-dynamics torques" if model.name == "reduced" else ""
'''

#: the new metric: one entry of the catalogue, as the page writes it
METRIC_ENTRY = (PAGE.split('```python\n  "x_error_max_m"', 1)[1].split("```", 1)[0]
                .replace("\n  ", "\n"))
METRIC_ENTRY = '    "x_error_max_m"' + METRIC_ENTRY.replace("\n", "\n    ").rstrip(" ")

SCRIPT = '''
import json
import sys
import types

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)
import ppr_jax as pj
from ppr_jax._cli import main
from ppr_jax._names import MODEL_NAMES, SCENE_NAMES, SOLVER_NAMES

out = {}
which = sys.argv[1]
opts = dict(t_end=0.3, n_out=7)
kw = dict(options=pj.SceneOptions(**opts))
if which == "model":
    assert "tight-reduced" in MODEL_NAMES
    new = pj.run_scene("paper-circle", model="tight-reduced", torque_model="rigid", **kw)
    ref = pj.run_scene("paper-circle", model="reduced", torque_model="rigid",
                       options=pj.SceneOptions(rtol=1e-10, atol=1e-10, **opts))
    out["X_diff"] = float(np.abs(np.asarray(new.result.X) - np.asarray(ref.result.X)).max())
    out["moved"] = float(np.abs(np.asarray(ref.result.X)[-1] - np.asarray(ref.result.X)[0]).max())
    out["rtol"] = new.solver["rtol"]
    z, zd = pj.quasi_static_state(pj.get_model("tight-reduced"), pj.RobotParams(), pj.Circle(),
                                  0.0, motion_driven=False)
    out["start_diff"] = float(np.abs(np.asarray(z) - np.asarray(pj.Circle()(0.0))).max())
    out["cli"] = main(["simulate", "--scene", "paper-circle", "--model", "tight-reduced",
                       "--torque-model", "rigid", "--t-end", "0.3", "--n-out", "7",
                       "--out", sys.argv[2]])
elif which == "solver":
    assert "bosh3" in SOLVER_NAMES
    new = pj.run_scene("paper-circle", model="reduced", torque_model="rigid",
                       options=pj.SceneOptions(solver="bosh3", rtol=1e-10, atol=1e-12, **opts))
    ref = pj.run_scene("paper-circle", model="reduced", torque_model="rigid",
                       options=pj.SceneOptions(solver="tsit5", rtol=1e-10, atol=1e-12, **opts))
    out["X_diff"] = float(np.abs(np.asarray(new.result.X) - np.asarray(ref.result.X)).max())
    out["solver"] = new.solver["name"]
    out["cli"] = main(["simulate", "--scene", "paper-circle", "--model", "reduced",
                       "--torque-model", "rigid", "--solver", "bosh3", "--t-end", "0.3",
                       "--n-out", "7", "--out", sys.argv[2]])
elif which == "metric":
    rep = pj.run_scene("paper-circle", model="reduced", torque_model="rigid", **kw)
    X, Xn = np.asarray(rep.result.X), np.asarray(rep.result.X_nominal)
    out["numpy"] = float(np.abs(X[:, 0] - Xn[:, 0]).max())
    sw = pj.sweep("paper-circle", vary={"t": [3e-4]}, model="reduced", torque_model="rigid",
                  **kw)
    out["sweep"] = sw.rows[0]["x_error_max_m"]
    s = pj.sensitivity("paper-circle", model="reduced", torque_model="rigid", parameters=["t"],
                       metrics=["x_error_max_m"], **kw)
    out["sens_value"] = s.values["x_error_max_m"]
    x0 = np.array([s.param_values["t"]])
    h = 1e-5 * x0
    out["sens"] = float(s.jacobian[0, 0])
    out["fd"] = float((s.evaluate(x0 + h)[0] - s.evaluate(x0 - h)[0]) / (2 * h[0]))
elif which == "scene":
    assert "line" in SCENE_NAMES
    rep = pj.run_scene("line", model="reduced", options=pj.SceneOptions(t_end=1.0, n_out=11))
    ts = np.asarray(rep.result.ts)
    u = np.clip(ts, 0.0, 1.0)
    s_ = u**3 * (10 - 15 * u + 6 * u**2)
    line = np.array([0.40, 0.27, 0.0]) + s_[:, None] * np.array([0.09, -0.03, 0.03])
    out["X_diff"] = float(np.abs(np.asarray(rep.result.X) - line).max())
    sw = pj.sweep("line", vary={"t": [3e-4, 4e-4]}, model="rigid",
                  options=pj.SceneOptions(t_end=0.3, n_out=4))
    out["sweep_status"] = [r["status"] for r in sw.rows]
    s = pj.sensitivity("line", model="rigid", parameters=["t"],
                       metrics=["position_error_max_m"], t_end=0.3, n_out=4)
    out["sens_finite"] = bool(np.all(np.isfinite(s.jacobian)) and s.jacobian[0, 0] != 0)
    out["cli"] = main(["simulate", "--scene", "line", "--model", "reduced", "--t-end", "0.3",
                       "--n-out", "4", "--out", sys.argv[2]])
elif which == "registries":
    # no compilation: every registry, name list and the command line's choices
    from ppr_jax._cli._main import build_parser
    from ppr_jax._models import MODELS
    from ppr_jax._scenes import SCENES
    from ppr_jax._simulate import SOLVERS

    out["models"] = list(MODELS) == list(MODEL_NAMES)
    out["solvers"] = list(SOLVERS) == list(SOLVER_NAMES)
    out["scenes"] = list(SCENES) == list(SCENE_NAMES)
    out["rtol"] = pj.get_model("tight-reduced").default_rtol
    from ppr_jax._scenes import get_scene
    from ppr_jax._simulate import get_solver

    out["solver"] = type(get_solver("bosh3")).__name__
    out["scene"] = get_scene("line").name
    args = build_parser().parse_args(["simulate", "--scene", "line", "--model",
                                      "tight-reduced", "--solver", "bosh3"])
    out["cli"] = [args.scene, args.model, args.solver]
    from ppr_jax._studies import CATALOGUE, allowed_metrics
    out["allowed"] = all("x_error_max_m" in allowed_metrics(pj.Circle(), study)
                         for study in ("sweep", "sensitivity", "design"))

    class Signals:  # a result's signals on the host (metric_table's NumPy path)
        X = np.array([[0.55, 0.26, 0.0], [0.449, 0.36, 0.01], [0.352, 0.259, 0.0]])
        X_nominal = np.array([[0.55, 0.26, 0.0], [0.45, 0.36, 0.0], [0.35, 0.26, 0.0]])
        end_rot = np.zeros((3, 2))
        residual = np.zeros(3)
        kinetic = np.zeros(3)
        potential = np.zeros(3)

    out["metric"] = float(CATALOGUE["x_error_max_m"].value(types.SimpleNamespace(
        result=Signals())))
print("RESULT " + json.dumps(out))
'''


@pytest.fixture(scope="module")
def package(tmp_path_factory):
    """A copy of `ppr_jax` with the page's four recipes applied."""
    root = tmp_path_factory.mktemp("extended")
    pkg = root / "ppr_jax"
    shutil.copytree(ROOT / "ppr_jax", pkg, ignore=shutil.ignore_patterns("__pycache__"))
    # a model: one file in _models/, imported and given one line in MODELS, its name in
    # MODEL_NAMES
    (pkg / "_models" / "tight_reduced.py").write_text(_model_file(pkg))
    _edit(pkg / "_models" / "__init__.py", "from .rigid import Rigid as Rigid\n",
          "from .tight_reduced import TightReduced\n")
    _edit(pkg / "_models" / "__init__.py", "    QuasiStaticBeam.name: QuasiStaticBeam,\n",
          "    TightReduced.name: TightReduced,\n")
    _edit(pkg / "_names.py", 'MODEL_NAMES = ("rigid", "reduced", "double1r", "beam"',
          ', "tight-reduced"')
    # a solver: one entry in SOLVERS, its name in SOLVER_NAMES
    _edit(pkg / "_simulate.py", '    "ros34pw2": Ros34PW2,\n', '    "bosh3": diffrax.Bosh3,\n')
    _edit(pkg / "_names.py", '"kvaerno5-kept",\n                "ros34pw2"', ', "bosh3"')
    # a metric: one entry of CATALOGUE
    _edit(pkg / "_studies" / "_catalogue.py", '    "end_rotation_diff_max_deg": Metric(\n',
          METRIC_ENTRY, after=False)
    # a scene: one file in _scenes/, imported and given one line in SCENES, its name in
    # SCENE_NAMES
    (pkg / "_scenes" / "_line_scene.py").write_text(SCENE_FILE)
    _edit(pkg / "_scenes" / "_registry.py", "from ._servo_circle import ServoCircle\n",
          "from ._line_scene import LineScene\n")
    _edit(pkg / "_scenes" / "_registry.py", "(PaperCircle, ServoCircle", ", LineScene")
    _edit(pkg / "_names.py", 'SCENE_NAMES = ("paper-circle", "servo-circle"', ', "line"')
    return root


def _run(package, which, tmp_path) -> dict:
    import json

    env = dict(os.environ, PYTHONPATH=str(package), JAX_ENABLE_X64="1")
    proc = subprocess.run([sys.executable, "-c", textwrap.dedent(SCRIPT), which,
                           str(tmp_path / "out")], cwd=package, env=env, capture_output=True,
                          text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    line = [x for x in proc.stdout.splitlines() if x.startswith("RESULT ")][-1]
    return json.loads(line[len("RESULT "):])


def test_registries_and_choices(package, tmp_path):
    """The default suite's part, no compilation: after the recipes every registry agrees with
    its name list, the command line offers the new model, solver and scene, and the new metric
    is allowed by every study and computed (|x - x_nominal| max of three samples: 0.002 m)."""
    out = _run(package, "registries", tmp_path)
    assert out["models"] and out["solvers"] and out["scenes"], out
    assert out["rtol"] == 1e-10 and out["solver"] == "Bosh3" and out["scene"] == "line", out
    assert out["cli"] == ["line", "tight-reduced", "bosh3"], out
    assert out["allowed"] and abs(out["metric"] - 0.002) < 1e-15, out


def _defined(name: str, path: pathlib.Path) -> bool:
    """Whether the module at `path` defines `name` at its top level (an assignment, a function
    or a class), read from its source."""
    import ast

    for node in ast.parse(path.read_text()).body:
        if isinstance(node, (ast.FunctionDef, ast.ClassDef)) and node.name == name:
            return True
        targets = (node.targets if isinstance(node, ast.Assign) else
                   [node.target] if isinstance(node, ast.AnnAssign) else [])
        if any(isinstance(t, ast.Name) and t.id == name for t in targets):
            return True
    return False


def test_the_page_says_where_things_are():
    """What the page says of the code holds: every registry, name list or class its table of
    where things go names is defined in the module it names (`MODELS` in
    ppr_jax/_models/__init__.py, ...), every file the recipes above edit is among those
    modules, and the class variables and methods each recipe lists are those of the base class
    it subclasses (no compilation, no copy of the package)."""
    from ppr_jax._actuation import AbstractActuation
    from ppr_jax._models import AbstractModel
    from ppr_jax._scenes import AbstractScene

    table = PAGE.split("## Where things go", 1)[1].split("\n\n", 2)[1]
    pairs = re.findall(r"`(\w+)(?:\([^`]*\))?`(?: / `(\w+)`)? (?:\(|in )"
                       r"`((?:ppr_jax/)?[\w/]+\.py)`", table)
    assert len(pairs) >= 10, pairs  # the table still reads as it did
    named = set()
    for first, second, where in pairs:
        path = ROOT / (where if where.startswith("ppr_jax/") else "ppr_jax/" + where)
        named.add(path.relative_to(ROOT / "ppr_jax").as_posix())
        for name in filter(None, (first, second)):
            assert _defined(name, path), (name, where)
    # the recipes followed in `package` edit exactly such modules
    edited = {"_models/__init__.py", "_names.py", "_simulate.py", "_studies/_catalogue.py",
              "_scenes/_registry.py"}
    assert edited <= named, edited - named
    for head, base in (("**A model level**", AbstractModel), ("**A scene**", AbstractScene),
                       ("**A model's defaults**", AbstractModel),
                       ("**An actuation**", AbstractActuation)):
        bullet = PAGE.split("- " + head, 1)[1].split("\n- ", 1)[0]
        names = [n for m in re.finditer(r"(?:class\s+variables?|methods)\s+((?:`\w+(?:\([^`]*"
                                        r"\))?`(?:,?\s+and\s+|,\s*)?)+)", bullet)
                 for n in re.findall(r"`(\w+)", m.group(1))]
        assert len(names) >= 3, (head, names)
        for n in names:
            assert hasattr(base, n) or n in getattr(base, "__annotations__", {}), (head, n)


@pytest.mark.slow
def test_a_new_model(package, tmp_path):
    out = _run(package, "model", tmp_path)
    assert out["rtol"] == 1e-10  # its own default, where the options name none
    assert out["X_diff"] < 1e-9 and out["moved"] > 1e-3, out
    assert out["start_diff"] < 1e-15  # torque-driven L1 starts on the path
    assert out["cli"] == 0


@pytest.mark.slow
def test_a_new_solver(package, tmp_path):
    out = _run(package, "solver", tmp_path)
    assert out["X_diff"] < 1e-8, out
    assert "bosh3" in out["solver"].lower(), out
    assert out["cli"] == 0


@pytest.mark.slow
def test_a_new_metric(package, tmp_path):
    out = _run(package, "metric", tmp_path)
    assert out["numpy"] > 1e-6, out  # L1 under L0's torques leaves the circle
    assert abs(out["sweep"] - out["numpy"]) <= 1e-9 * out["numpy"], out
    assert abs(out["sens_value"] - out["numpy"]) <= 1e-9 * out["numpy"], out
    assert abs(out["sens"] - out["fd"]) <= 1e-4 * abs(out["fd"]), out


@pytest.mark.slow
def test_a_new_scene(package, tmp_path):
    out = _run(package, "scene", tmp_path)
    assert out["X_diff"] < 1e-7, out  # L1 under its own torques follows the line
    assert out["sweep_status"] == ["ok", "ok"], out
    assert out["sens_finite"] and out["cli"] == 0, out
