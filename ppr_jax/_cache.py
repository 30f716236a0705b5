"""JAX's persistent compilation cache, so that a second run on the same machine does not compile
again. The cache does not store programs with host callbacks: the scene programs report failures
as status codes, but diffrax checks its output times with `eqx.error_if`, a callback unless
equinox's runtime errors are in NaN mode (`EQX_ON_ERROR=nan`, as the console script sets). The
exported scene programs (`_programs.py`, `run_scene(program_dir=...)`) are traced in NaN mode
whatever the session's mode, so their compiled form is always stored."""

from __future__ import annotations

import os
from typing import Optional

import jax


def default_cache_dir() -> str:
    """`$PPR_JAX_CACHE_DIR`, else `$XDG_CACHE_HOME/ppr_jax/jax` (default `~/.cache/ppr_jax/jax`)."""
    if os.environ.get("PPR_JAX_CACHE_DIR"):
        return os.environ["PPR_JAX_CACHE_DIR"]
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "ppr_jax", "jax")


def enable_compilation_cache(path: Optional[str] = None, min_compile_time_s: float = 0.5) -> str:
    """Store compiled programs under `path` (default `default_cache_dir()`) and reuse them in
    later processes: programs that took at least `min_compile_time_s` to compile are kept. The
    command line enables it unless `PPR_JAX_CACHE=0`. Returns the directory. Call it before the
    first compilation; safe to call again."""
    path = default_cache_dir() if path is None else path
    os.makedirs(path, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", path)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", float(min_compile_time_s))
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return path
