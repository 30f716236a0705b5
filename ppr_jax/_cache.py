"""JAX's persistent compilation cache, so that a second run on the same machine does not compile
again. The cache does not store programs with host callbacks: the scene programs report failures
as status codes, but diffrax checks its output times with `eqx.error_if`, a callback unless
equinox's runtime errors are in NaN mode (`EQX_ON_ERROR=nan`, as the console script sets). The
exported scene programs (`_programs.py`, `run_scene(program_dir=...)`) are traced in NaN mode
whatever the session's mode, so their compiled form is always stored.

A damaged cache entry (a flipped or truncated byte; JAX compresses each entry with zlib or zstd,
whose checksums catch it, and deserialises it) is repaired: `enable_compilation_cache` wraps
JAX's cache read (`jax._src.compilation_cache.get_executable_and_time`, the one place that reads
an entry) so that an entry that fails to read is named once in a `RepairWarning`, deleted, and
compiled and stored afresh. Left to itself JAX warns and recompiles on every run, but never
overwrites the damaged entry. Where that function is missing (another JAX), entries are not
repaired: JAX's own warning names the program, and deleting the cache directory repairs it."""

from __future__ import annotations

import os
import warnings
from typing import Optional

import jax

from ._errors import RepairWarning


def default_cache_dir() -> str:
    """`$PPR_JAX_CACHE_DIR`, else `$XDG_CACHE_HOME/ppr_jax/jax` (default `~/.cache/ppr_jax/jax`)."""
    if os.environ.get("PPR_JAX_CACHE_DIR"):
        return os.environ["PPR_JAX_CACHE_DIR"]
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "ppr_jax", "jax")


def enable_compilation_cache(path: Optional[str] = None, min_compile_time_s: float = 0.5) -> str:
    """Store compiled programs under `path` (default `default_cache_dir()`) and reuse them in
    later processes: programs that took at least `min_compile_time_s` to compile are kept. The
    command line enables it unless `PPR_JAX_CACHE=0`, with `min_compile_time_s=0`: besides its
    scene programs a command runs a few small ones (the derived quantities, the scene's inputs),
    each 10-300 ms to compile and below the default threshold, so a second process would compile
    them all again; read back from the cache they take milliseconds. Returns the directory. Call
    it before the first compilation; safe to call again."""
    path = default_cache_dir() if path is None else path
    os.makedirs(path, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", path)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", float(min_compile_time_s))
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    _repair_damaged_entries()
    return path


def _entry_paths(cache_key: str) -> list[str]:
    """The files of a persistent-cache entry in a local cache directory (JAX's `LRUCache`
    layout: `<key>-cache` and, with eviction, `<key>-atime`)."""
    directory = jax.config.jax_compilation_cache_dir
    if not directory or "://" in str(directory):
        return []
    return [os.path.join(str(directory), f"{cache_key}{suffix}") for suffix in ("-cache", "-atime")]


def _repair_damaged_entries() -> bool:
    """Wrap JAX's cache read so that a damaged entry is deleted, named once and recompiled
    (module docstring). Returns whether the wrapper is in place."""
    try:
        from jax._src import compilation_cache as cc
    except ImportError:  # pragma: no cover - JAX moved its cache
        return False
    read = getattr(cc, "get_executable_and_time", None)
    if read is None:  # pragma: no cover
        return False
    if getattr(read, "_ppr_jax_repairs", False):
        return True
    verification = getattr(cc, "CacheVerificationError", ())

    def get_executable_and_time(cache_key, *args, **kwargs):
        try:
            return read(cache_key, *args, **kwargs)
        except Exception as err:
            if isinstance(err, verification) or jax.config.jax_raise_persistent_cache_errors:
                raise
            removed = []
            for p in _entry_paths(cache_key):
                try:
                    os.remove(p)
                    removed.append(p)
                except FileNotFoundError:
                    pass
                except OSError:  # read-only: JAX's own warning and recompile, as before
                    raise err from None
            if not removed:
                raise
            text = str(err).strip().splitlines()
            warnings.warn(f"compilation cache entry {removed[0]} is damaged ({type(err).__name__}"
                          f"{': ' + text[0] if text else ''}): deleted and compiled afresh",
                          RepairWarning, stacklevel=2)
            return None, None  # a cache miss: JAX compiles and stores the entry anew

    get_executable_and_time._ppr_jax_repairs = True
    cc.get_executable_and_time = get_executable_and_time
    return True
