"""Every notebook in notebooks/ runs top to bottom on small settings (PPR_NOTEBOOK_SMALL=1), each
in its own process (its compiled programs are not this process's).

The notebooks are split over two test files (this one and `test_notebooks_more.py`, by
`NOTEBOOK_GROUPS`): the suite distributes whole files over its workers, and the notebooks
together take about five minutes, too long a tail for one worker.

The notebooks in `SLOW` (each 55-135 s on the 2-core machine, a sixth of the default suite
together) run with `-m slow`: their studies have tests of their own in the default suite,
and every notebook's code is checked there for the public names it calls
(`test_notebooks_call_only_public_names`)."""

import ast
import json
import os
import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))
#: notebooks run by `test_notebooks_more.py`; every other one runs here
MORE = ("identification", "which_model")
#: notebooks run with `-m slow` (second tier: docs/getting_started.md, "The two tiers"): the
#: studies' notebooks, and quickstart and which_model for their cost; each notebook is a fresh
#: process that compiles its own programs
SLOW = ("compensation", "design", "identification", "quickstart", "sensitivity", "which_model")


def _params(paths):
    return [pytest.param(p, id=p.stem, marks=[pytest.mark.slow] if p.stem in SLOW else [])
            for p in paths]


NOTEBOOK_GROUPS = {
    "here": _params([p for p in NOTEBOOKS if p.stem not in MORE]),
    "more": _params([p for p in NOTEBOOKS if p.stem in MORE]),
}


def run_notebook(path, tmp_path):
    env = dict(os.environ, PPR_NOTEBOOK_SMALL="1", MPLBACKEND="Agg", PPR_REPO=str(ROOT))
    proc = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "run_notebook.py"), str(path)],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900,
    )
    assert proc.returncode == 0, proc.stderr[-4000:]


@pytest.mark.parametrize("path", NOTEBOOK_GROUPS["here"])
def test_notebook_runs(path, tmp_path):
    run_notebook(path, tmp_path)


def test_notebooks_call_only_public_names():
    """Every notebook's code parses, and every `pj.NAME` it reads is in the public API: a
    renamed or removed function fails here, in the default suite, not only in the slow run of
    the notebook."""
    import ppr_jax as pj

    assert {p.stem for p in NOTEBOOKS} >= set(SLOW)
    for path in NOTEBOOKS:
        cells = [c for c in json.loads(path.read_text())["cells"] if c["cell_type"] == "code"]
        for i, cell in enumerate(cells):
            src = "\n".join(ln for ln in "".join(cell["source"]).splitlines()
                            if not ln.lstrip().startswith(("%", "!")))
            tree = ast.parse(src, f"{path.name}[code cell {i}]")
            for node in ast.walk(tree):
                if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                        and node.value.id == "pj"):
                    assert hasattr(pj, node.attr), f"{path.name}, code cell {i}: pj.{node.attr}"
