"""Scene programs exported once and loaded by later processes, so that a second run neither
traces nor compiles.

JAX's persistent compilation cache skips XLA's compilation in a second process, but its key is
the traced program, so every process still traces the scene first: 1.5-4 s for L0-L2 and more
for L3, most of a second run. `jax.export` stores the traced program itself (StableHLO, with the
input and output shapes), so a later process deserialises it and compiles it, and the persistent
cache answers that compilation. A program is stored under a key of everything the trace
depended on that is not an input array: the static part of the scene's arguments (model, solver,
structural choices such as `equal_links`), the shapes and dtypes of the inputs, the backend, the
versions of ppr_jax and its numerical dependencies (`DEPENDENCIES`: jax, jaxlib, diffrax,
equinox, optimistix, lineax), and a hash of this package's source and data files, so that
editing the library or upgrading a dependency exports afresh instead of loading a stale program.
The numbers (parameters, tolerances, t_end) are inputs: changing them reuses the program.

Each stored file starts with a header holding the sha256 of the serialised program. A file
whose header or checksum does not match, that does not deserialise, or whose program does not
compile is named once in a `RepairWarning`, deleted and exported afresh: a damaged store repairs
itself and never breaks a run.

A program must hold no host callbacks, which `jax.export` cannot store. The scene programs
report failures as status codes; diffrax adds `eqx.error_if` checks of the output times (which
the scenes build themselves, always valid), so the export traces with equinox's runtime errors
in NaN mode, as the console script runs anyway. Anything that cannot be exported (a callback, a
static argument whose identity a key cannot capture, such as a closure) falls back to the usual
compile, so this is a cache, never a change of results.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib.metadata
import os
import pathlib
import re
import tempfile
import types
import warnings
from typing import Callable, Optional

import equinox as eqx
import jax

from ._errors import RepairWarning

#: bump when the stored layout changes
FORMAT = 2
#: the first bytes of a stored program; then the sha256 of the rest (64 hex digits) and a newline
MAGIC = b"ppr_jax program 2\n"
#: the distributions whose versions key the stored programs and the sweeps' settings digests
DEPENDENCIES = ("ppr_jax", "jax", "jaxlib", "diffrax", "equinox", "optimistix", "lineax")
#: the programs' subdirectory of the compilation cache directory (where the command line keeps
#: them)
PROGRAM_SUBDIR = "ppr_jax_programs"
_PACKAGE = pathlib.Path(__file__).resolve().parent


@functools.lru_cache(maxsize=None)
def source_hash() -> str:
    h = hashlib.sha256()
    for p in sorted(_PACKAGE.rglob("*")):
        if p.suffix in (".py", ".json", ".csv") and "__pycache__" not in p.parts:
            h.update(str(p.relative_to(_PACKAGE)).encode())
            h.update(p.read_bytes())
    return h.hexdigest()


@functools.lru_cache(maxsize=None)
def dependency_versions() -> str:
    """"name=version,..." of `DEPENDENCIES` ("?" for one not installed as a distribution)."""
    out = []
    for name in DEPENDENCIES:
        try:
            out.append(f"{name}={importlib.metadata.version(name)}")
        except importlib.metadata.PackageNotFoundError:
            out.append(f"{name}=?")
    return ",".join(out)


class NotExportable(Exception):
    """A scene call whose program this module does not store (the caller compiles it as usual)."""


def _static_functions(static) -> list[str]:
    """The functions among the static arguments, by module and name. A function defined inside
    another (a closure, a lambda) may capture values its name does not show, so two different
    programs could share a key: such a call is not stored."""
    names = []
    for leaf in jax.tree_util.tree_leaves(static):
        if isinstance(leaf, types.FunctionType):
            if "<" in leaf.__qualname__:
                raise NotExportable(f"static function {leaf.__qualname__} is not keyable")
            names.append(f"{leaf.__module__}.{leaf.__qualname__}")
    return names


def program_key(args: tuple, label: str) -> str:
    """The key of a scene call's program (module docstring): a hex digest."""
    dyn, static = eqx.partition(args, eqx.is_array)
    functions = _static_functions(static)
    leaves = jax.tree_util.tree_leaves(dyn)
    text = "\n".join([
        f"format {FORMAT}", label, dependency_versions(), jax.default_backend(), source_hash(),
        str(jax.tree_util.tree_structure(dyn)),
        eqx.tree_pformat(static, short_arrays=True), str(functions),
        str([(tuple(x.shape), str(x.dtype)) for x in leaves]),
    ])
    # Object addresses in reprs differ between processes and say nothing about the program.
    text = re.sub(r" at 0x[0-9a-fA-F]+", "", text)
    return hashlib.sha256(text.encode()).hexdigest()[:32]


@contextlib.contextmanager
def _errors_as_nan():
    """Trace with equinox's runtime errors in NaN mode (no host callback; module docstring)."""
    try:
        from equinox import _errors
    except ImportError:  # pragma: no cover - equinox moved it: export may then fail, and fall back
        yield
        return
    old = _errors.EQX_ON_ERROR
    _errors.EQX_ON_ERROR = "nan"
    try:
        yield
    finally:
        _errors.EQX_ON_ERROR = old


def _export(fn: Callable, args: tuple, out_template):
    dyn, static = eqx.partition(args, eqx.is_array)
    leaves, tdef = jax.tree_util.tree_flatten(dyn)
    out_def = jax.tree_util.tree_structure(out_template)
    seen = {}

    def flat(*lv):
        out = fn(*eqx.combine(jax.tree_util.tree_unflatten(tdef, lv), static))
        seen["def"] = jax.tree_util.tree_structure(out)
        return jax.tree_util.tree_leaves(out)

    # A config state that is part of JAX's trace-cache keys makes this a fresh trace: the inner
    # jitted functions (diffeqsolve among them) may have been traced in this process already with
    # equinox's raising checks, whose cached traces hold host callbacks; and this trace's NaN-mode
    # checks stay out of the usual calls' cache. "highest" changes nothing numerically here: it
    # concerns matrix products of 32-bit inputs, and every array is 64-bit.
    with jax.default_matmul_precision("highest"), _errors_as_nan():
        try:
            exported = jax.export.export(jax.jit(flat))(*leaves)
        except NotImplementedError as err:
            # jax.export's own refusal of what it cannot serialise ("serialization of
            # host_callbacks is not yet implemented"): this call is compiled the usual way.
            raise NotExportable(str(err)) from err
    if seen["def"] != out_def:
        raise NotExportable(f"result structure {seen['def']} is not the template's {out_def}")
    return exported


class _Damaged(Exception):
    """A stored program that failed a check (the message says which)."""


def _pack(payload: bytes) -> bytes:
    return MAGIC + hashlib.sha256(payload).hexdigest().encode() + b"\n" + bytes(payload)


def _unpack(data: bytes) -> bytes:
    """The serialised program of a stored file, after its header and checksum are checked."""
    n = len(MAGIC)
    if data[:n] != MAGIC or data[n + 64:n + 65] != b"\n":
        raise _Damaged("no ppr_jax program header")
    payload = data[n + 65:]
    if hashlib.sha256(payload).hexdigest().encode() != data[n:n + 64]:
        raise _Damaged("checksum mismatch")
    return payload


def _first_line(err: BaseException) -> str:
    text = str(err).strip().splitlines()
    return f"{type(err).__name__}: {text[0] if text else ''}".rstrip(": ")


def _load(path: str, n_in: int, n_out: int, leaves):
    """The stored program at `path`, compiled for `leaves`; raises `_Damaged` naming what
    failed."""
    with open(path, "rb") as f:
        payload = _unpack(f.read())
    try:
        exported = jax.export.deserialize(bytearray(payload))
    except Exception as err:
        raise _Damaged(f"does not deserialise ({_first_line(err)})") from err
    if len(exported.in_avals) != n_in or len(exported.out_avals) != n_out:
        raise _Damaged("its inputs or outputs do not match this call")
    try:
        return jax.jit(exported.call).lower(*leaves).compile()
    except Exception as err:
        raise _Damaged(f"does not compile ({_first_line(err)})") from err


def load_or_export(fn: Callable, args: tuple, out_template, directory: str, label: str):
    """A compiled callable `run(*args)` equivalent to `fn(*args)` (whose result has the tree
    structure of `out_template`), from the program stored in `directory` under `program_key`,
    exported and stored there first if absent. Returns (run, how): how is "loaded" or
    "exported". A stored file that fails a check (module docstring) is deleted and exported
    afresh, with one `RepairWarning` naming it. Raises `NotExportable` where the program cannot
    be stored (the caller compiles `fn` as usual)."""
    key = program_key(args, label)
    path = os.path.join(directory, f"{label}-{key}.jaxexport")
    out_def = jax.tree_util.tree_structure(out_template)
    leaves = jax.tree_util.tree_leaves(eqx.filter(args, eqx.is_array))
    compiled, how = None, "loaded"
    if os.path.exists(path):
        try:
            compiled = _load(path, len(leaves), out_def.num_leaves, leaves)
        except _Damaged as err:
            warnings.warn(f"stored program {path} is damaged ({err}): deleted and exported "
                          f"afresh", RepairWarning, stacklevel=3)
            with contextlib.suppress(FileNotFoundError):  # a concurrent process removed it
                os.remove(path)
    if compiled is None:
        exported, how = _export(fn, args, out_template), "exported"
        os.makedirs(directory, exist_ok=True)
        # Atomic: a concurrent process sees the whole file or none.
        with tempfile.NamedTemporaryFile(dir=directory, delete=False, suffix=".tmp") as f:
            f.write(_pack(exported.serialize()))
        os.replace(f.name, path)
        if len(exported.in_avals) != len(leaves) or len(exported.out_avals) != out_def.num_leaves:
            raise NotExportable(f"exported program {path} does not match this call")
        compiled = jax.jit(exported.call).lower(*leaves).compile()

    def run(*call_args):
        lv = jax.tree_util.tree_leaves(eqx.filter(call_args, eqx.is_array))
        return jax.tree_util.tree_unflatten(out_def, compiled(*lv))

    return run, how


def compiled_program(fn: Callable, args: tuple, out_template, directory: Optional[str],
                     label: str):
    """`load_or_export` where `directory` is given and the program can be stored, otherwise the
    usual ahead-of-time compile of `fn` (an `eqx.filter_jit` function). Returns (run, how) with
    how "loaded", "exported" or "compiled"."""
    if directory is not None:
        try:
            return load_or_export(fn, args, out_template, directory, label)
        # OSError: a read-only or full cache directory; ImportError: no flatbuffers, which
        # jax.export's serialisation needs.
        except (NotExportable, OSError, ImportError):
            pass
    return fn.lower(*args).compile(), "compiled"
