"""The scene programs hold no host callbacks, so JAX's persistent compilation cache stores them and
a second `ppr-jax` run skips their compilation (the console script sets equinox's runtime-error
mode to NaN; every result is checked from the returned status codes)."""

import os
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]

SCRIPT = """
import ppr_jax as pj, ppr_jax_cli  # noqa: F401 (the console script's module imports)
pj.enable_compilation_cache({path!r}, min_compile_time_s=0.0)
r = pj.paper_circle(model="rigid", t_end=0.1, n_out=11)
assert bool(r.ok)
"""


def test_scene_program_is_stored_in_the_persistent_cache(tmp_path):
    cache = tmp_path / "cache"
    env = dict(os.environ, EQX_ON_ERROR="nan", PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, "-c", SCRIPT.format(path=str(cache))], env=env,
                          capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    names = [p.name for p in cache.iterdir()]
    assert any(n.startswith("jit__paper_circle_core-") for n in names), names
