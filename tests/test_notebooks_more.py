"""The second half of the notebooks (`test_notebooks.NOTEBOOK_GROUPS`), in a file of its own so
that the suite's workers can run the two halves side by side."""

import pytest
from test_notebooks import NOTEBOOK_GROUPS, run_notebook


@pytest.mark.parametrize("path", NOTEBOOK_GROUPS["more"])
def test_notebook_runs(path, tmp_path):
    run_notebook(path, tmp_path)
