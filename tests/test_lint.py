"""The code is lint-clean under the ruff configuration of pyproject.toml (`[tool.ruff]`): imports
sorted, lines within 100 columns, no unused names. Skipped where ruff is not installed
(pip install '.[test]')."""

import importlib.util
import os
import shutil
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PATHS = ["ppr_jax", "tests", "benchmarks", "scripts"]


def _ruff():
    if importlib.util.find_spec("ruff") is not None:
        return [sys.executable, "-m", "ruff"]
    exe = shutil.which("ruff")
    if exe is None:
        pytest.skip("ruff is not installed: pip install '.[test]'")
    return [exe]


def test_ruff_check():
    proc = subprocess.run(
        [*_ruff(), "check", "--no-cache", *PATHS],
        cwd=ROOT, capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stdout[-10000:] + proc.stderr[-5000:]
