"""The documentation site builds without a warning (`mkdocs build --strict`): every page in the
nav, every link between pages, every `::: ppr_jax.NAME` of the API pages and every generated
performance table resolves."""

import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_mkdocs_build_strict(tmp_path):
    for module in ("mkdocs", "material", "mkdocstrings_handlers.python", "mkdocs_jupyter"):
        pytest.importorskip(module, reason=f"{module} is not installed: pip install '.[docs]'")
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    proc = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=600,
    )
    assert proc.returncode == 0, proc.stdout[-5000:] + proc.stderr[-5000:]
    for page in ("index.html", "api/params/index.html", "performance/index.html",
                 "notebooks/quickstart/index.html"):
        assert (tmp_path / "site" / page).exists(), page
