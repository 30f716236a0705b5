"""The scene programs hold no host callbacks, so JAX's persistent compilation cache stores them and
a second `ppr-jax` run skips their compilation (the console script sets equinox's runtime-error
mode to NaN; every result is checked from the returned status codes)."""

import os
import pathlib
import subprocess
import sys
import zlib

import pytest

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
    assert any(n.startswith("jit_scene_program-") for n in names), names


SMALL = """
import warnings, jax, jax.numpy as jnp, ppr_jax as pj
warnings.simplefilter("always")
pj.enable_compilation_cache({path!r}, min_compile_time_s=0.0)
x = jnp.linspace(0.0, 1.0, 64).reshape(8, 8)
print(float(jax.jit(lambda a: jnp.sum(jnp.sin(a) @ a.T))(x)))
"""


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_a_damaged_persistent_cache_entry_is_deleted_and_stored_afresh(tmp_path):
    """JAX alone warns about a damaged entry and recompiles on every run, never replacing it:
    the entry is named once, deleted and stored again, and the next run is silent."""
    cache = tmp_path / "cache"
    env = dict(os.environ, PYTHONPATH=str(ROOT), JAX_PLATFORMS="cpu")

    def run():
        p = subprocess.run([sys.executable, "-c", SMALL.format(path=str(cache))], env=env,
                           capture_output=True, text=True, timeout=300, cwd=tmp_path)
        assert p.returncode == 0, p.stderr[-3000:]
        return p

    first = run()
    (entry,) = [p for p in cache.iterdir()
                if p.name.startswith("jit__lambda") and p.name.endswith("-cache")]
    b = bytearray(entry.read_bytes())
    i = len(b) // 3
    b[i:i + 64] = bytes(x ^ 0xFF for x in b[i:i + 64])
    entry.write_bytes(bytes(b))
    second = run()
    assert second.stdout == first.stdout
    assert "RepairWarning" in second.stderr and entry.name in second.stderr, second.stderr
    assert second.stderr.count(entry.name) == 1
    zlib.decompress(entry.read_bytes())  # stored afresh, sound (raises if still damaged)
    third = run()
    assert third.stdout == first.stdout
    assert "RepairWarning" not in third.stderr and "Error reading" not in third.stderr
