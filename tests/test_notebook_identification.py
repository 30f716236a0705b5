"""notebooks/identification.ipynb runs top to bottom: its code cells, in order, in a fresh Python
process with the Agg backend (no Jupyter needed). A few minutes, mostly compilation: slow."""

import json
import os
import subprocess
import sys

import pytest

NB = os.path.join(os.path.dirname(__file__), "..", "notebooks", "identification.ipynb")


@pytest.mark.slow
def test_identification_notebook_executes(tmp_path):
    nb = json.load(open(NB))
    src = "\n\n".join(
        "".join(c["source"]) for c in nb["cells"] if c["cell_type"] == "code"
    )
    script = tmp_path / "nb.py"
    script.write_text(src)
    env = dict(os.environ, MPLBACKEND="Agg")
    root = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
    env["PYTHONPATH"] = root + os.pathsep + env.get("PYTHONPATH", "")
    p = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=900)
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    assert "true K_theta inside the 95 % interval: True" in p.stdout
