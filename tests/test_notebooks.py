"""Every notebook in notebooks/ runs top to bottom on small settings (PPR_NOTEBOOK_SMALL=1), each
in its own process (its compiled programs are not this process's).

The notebooks are split over two test files (this one and `test_notebooks_more.py`, by
`NOTEBOOK_GROUPS`): the suite distributes whole files over its workers, and the notebooks
together take about five minutes, too long a tail for one worker."""

import os
import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))
#: notebooks run by `test_notebooks_more.py`; every other one runs here
MORE = ("identification", "which_model")
NOTEBOOK_GROUPS = {
    "here": [p for p in NOTEBOOKS if p.stem not in MORE],
    "more": [p for p in NOTEBOOKS if p.stem in MORE],
}


def run_notebook(path, tmp_path):
    env = dict(os.environ, PPR_NOTEBOOK_SMALL="1", MPLBACKEND="Agg", PPR_REPO=str(ROOT))
    proc = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "run_notebook.py"), str(path)],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900,
    )
    assert proc.returncode == 0, proc.stderr[-4000:]


@pytest.mark.parametrize("path", NOTEBOOK_GROUPS["here"],
                         ids=[p.stem for p in NOTEBOOK_GROUPS["here"]])
def test_notebook_runs(path, tmp_path):
    run_notebook(path, tmp_path)
