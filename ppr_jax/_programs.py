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
The numbers (parameters, tolerances, t_end) are inputs: changing them reuses the program. The key
reads the arguments in a canonical form (`canonical`): a field at its default value keys as if
left out, and a label (a path file's or an experiment's name, `_labels.label_field`) not at all,
so a measured path re-read from another file of the same shape loads the same program.

Each stored file starts with a header holding the sha256 of the serialised program. A file
whose header or checksum does not match, that does not deserialise, or whose program does not
compile is named once in a `RepairWarning`, deleted and exported afresh: a damaged store repairs
itself and never breaks a run. A store that cannot be written (read-only, full) is used as far as
it goes: a damaged file that cannot be deleted is named as such in its warning (kept, never
claimed deleted), and the run goes on without it, compiling the stored program where only its
executable is damaged; a program that cannot be stored runs unstored, traced once.

A program must hold no host callbacks, which `jax.export` cannot store. The scene programs
report failures as status codes; diffrax adds `eqx.error_if` checks of the output times (which
the scenes build themselves, always valid), so the export traces with equinox's runtime errors
in NaN mode, as the console script runs anyway. Anything that cannot be exported (a callback, a
static argument whose identity a key cannot capture, such as a closure) falls back to the usual
compile, so this is a cache, never a change of results.

Beside each program the store keeps its compiled form, XLA's executable
(`jax.experimental.serialize_executable`; `<label>-<key>-<program>-<machine>.jaxexec`), so that a
later process skips deserialising and lowering the program and reading JAX's persistent cache:
0.4-0.7 s of `ppr-jax simulate`'s second process for L0 (2 MB), less for L3 at N = 16,
whose 16 MB executable takes 2-3 s to load either way. Its name holds the sha256 of the program
it was compiled from and a digest of the machine (backend, devices, the CPU's model and
features, which the compiled code targets, and `XLA_FLAGS`): a program exported afresh, or
another machine sharing the directory, never loads a stale executable. It is stored only where
every custom call of the program is one this module knows how to prepare (the LAPACK kernels,
which jaxlib initialises when lowering, and which a loaded executable would otherwise call
uninitialised), and only from a fresh compilation: an executable that JAX read from its
persistent cache serialises incompletely on the CPU (jaxlib 0.10: the copy lacks compiled
functions and fails when run, "Function ... not found"), so where the compilation was a
persistent-cache hit no executable is stored and later processes load the program as before. A
damaged executable (header, checksum, deserialisation) is named in a `RepairWarning` and
deleted, and the program is compiled (an executable stored afresh as above).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import glob
import hashlib
import importlib.metadata
import json
import os
import pathlib
import re
import types
import warnings
from typing import Callable, Optional

import equinox as eqx
import jax

from ._errors import RepairWarning
from ._files import write_file
from ._host_split import HostSplit
from ._labels import LABEL

#: bump when the stored layout changes
FORMAT = 2
#: the first bytes of a stored program; then the sha256 of the rest (64 hex digits) and a newline
MAGIC = b"ppr_jax program 2\n"
#: the first bytes of a stored executable; then the sha256 of the rest and a newline, one line of
#: JSON (the program's custom-call targets), and XLA's serialised executable
EXEC_MAGIC = b"ppr_jax executable 1\n"
#: custom-call targets a stored executable may hold: jaxlib's LAPACK kernels, initialised before
#: loading (`_prepare_targets`)
_EXEC_TARGETS = re.compile(r"lapack_\w+")
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


def _function_name(fn) -> str:
    """A function's module and name. A function defined inside another (a closure, a lambda)
    may capture values its name does not show, so two different programs could share a key:
    such a call is not stored."""
    if "<" in fn.__qualname__:
        raise NotExportable(f"static function {fn.__qualname__} is not keyable")
    return f"{fn.__module__}.{fn.__qualname__}"


def _is_default(f: dataclasses.Field, value) -> bool:
    """Whether a field holds its declared default (a Python scalar, string or None, compared by
    value: `Beam(4)` and `Beam(4, strip_loss=0.0)` are one program)."""
    d = f.default
    if d is dataclasses.MISSING or not isinstance(d, (bool, int, float, str, type(None))):
        return False
    return type(value) in (bool, int, float, str, type(None)) and value == d


def canonical(obj) -> str:
    """A canonical text of a call's arguments for `program_key`: arrays as their dtype and
    shape (their values are the program's inputs), modules and dataclasses as their class and
    fields, less the fields that hold their default (`_is_default`) and the labels
    (`label_field`); functions by module and name; other values by `repr`. Two argument
    trees of equal canonical text trace to the same program."""
    if eqx.is_array(obj):
        return f"{obj.dtype}{list(obj.shape)}"
    if isinstance(obj, (bool, int, float, str, type(None))):
        return repr(obj)
    if isinstance(obj, types.FunctionType):
        return _function_name(obj)
    if isinstance(obj, types.MethodType):
        return f"{canonical(obj.__self__)}.{obj.__func__.__name__}"
    if isinstance(obj, (tuple, list)):
        return f"{type(obj).__name__}[{', '.join(canonical(x) for x in obj)}]"
    if isinstance(obj, dict):
        return "{" + ", ".join(f"{k!r}: {canonical(obj[k])}" for k in sorted(obj)) + "}"
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        parts = []
        for f in dataclasses.fields(obj):
            if f.metadata.get(LABEL) or not hasattr(obj, f.name):
                continue
            v = getattr(obj, f.name)
            if not _is_default(f, v):
                parts.append(f"{f.name}={canonical(v)}")
        return f"{type(obj).__module__}.{type(obj).__qualname__}({', '.join(parts)})"
    children, treedef = jax.tree_util.tree_flatten(obj, is_leaf=lambda x: x is not obj)
    if children and not (len(children) == 1 and children[0] is obj):
        # another pytree node (jax's own containers): its structure and its children
        return f"{treedef}({', '.join(canonical(c) for c in children)})"
    return repr(obj)


def program_key(args: tuple, label: str) -> str:
    """The key of a scene call's program (module docstring): a hex digest of the label, the
    versions, the backend, the source's hash and the arguments' `canonical` text."""
    text = "\n".join([
        f"format {FORMAT}", label, dependency_versions(), jax.default_backend(), source_hash(),
        canonical(args),
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


@contextlib.contextmanager
def export_tracing():
    """The state an exported program is traced in (`_export`). A trace made for the same
    program before exporting it (its output shapes, `jax.eval_shape`) shares its inner traces
    with the export when made in this state too."""
    with jax.default_matmul_precision("highest"), _errors_as_nan():
        yield


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
    with export_tracing():
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


def _pack(payload: bytes, magic: bytes = MAGIC) -> bytes:
    return magic + hashlib.sha256(payload).hexdigest().encode() + b"\n" + bytes(payload)


def _unpack(data: bytes, magic: bytes = MAGIC) -> bytes:
    """The serialised program (or executable, `magic=EXEC_MAGIC`) of a stored file, after its
    header and checksum are checked."""
    n = len(magic)
    if data[:n] != magic or data[n + 64:n + 65] != b"\n":
        raise _Damaged(f"no ppr_jax {'program' if magic == MAGIC else 'executable'} header")
    payload = data[n + 65:]
    if hashlib.sha256(payload).hexdigest().encode() != data[n:n + 64]:
        raise _Damaged("checksum mismatch")
    return payload


@functools.lru_cache(maxsize=None)
def machine_digest() -> str:
    """A digest of what a compiled executable depends on beyond the program: the backend, its
    devices and their count, the CPU (model and instruction-set features, from /proc/cpuinfo
    where there is one), which XLA's CPU code targets, and `XLA_FLAGS`."""
    import platform

    cpu = platform.processor() or platform.machine()
    with contextlib.suppress(OSError):
        with open("/proc/cpuinfo") as f:
            lines = [ln for ln in f.read().splitlines()
                     if ln.startswith(("model name", "flags", "Features", "CPU part"))]
        cpu += "\n".join(sorted(set(lines)))
    d = jax.devices()[0]
    # XLA's flags (the environment's) shape the compiled code as the persistent cache's key
    # says; the device count, the executable's placement
    text = "\n".join([jax.default_backend(), d.platform, d.device_kind,
                      str(getattr(d.client, "platform_version", "")), cpu,
                      os.environ.get("XLA_FLAGS", ""), str(jax.device_count())])
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _custom_call_targets(exported) -> list[str]:
    text = exported.mlir_module()
    return sorted(set(re.findall(r"custom_call @([\w.$-]+)", text))
                  | set(re.findall(r'call_target_name = "([^"]+)"', text)))


def _prepare_targets(targets) -> None:
    """Initialise what the custom calls `targets` need before an executable that holds them runs
    (jaxlib does it when lowering a program, which a loaded executable skips)."""
    if any(_EXEC_TARGETS.fullmatch(t) for t in targets):
        from jaxlib import lapack

        lapack._lapack.initialize()


#: persistent-cache hits seen in this process (`_compile`)
_HITS = [0]


def _count_hits(event: str, **_) -> None:
    if event == "/jax/compilation_cache/cache_hits":
        _HITS[0] += 1


@functools.lru_cache(maxsize=None)
def _listen() -> None:
    jax.monitoring.register_event_listener(_count_hits)


def _compile(exported, leaves):
    """(compiled, fresh): `exported` compiled for `leaves`, and whether XLA compiled it (no
    persistent-cache hit meanwhile, in any thread: then an executable may be stored)."""
    _listen()
    before = _HITS[0]
    compiled = _caller(exported).lower(*leaves).compile()
    return compiled, _HITS[0] == before


def _caller(exported):
    """`jax.jit(exported.call)`; for a program split over n devices (a sweep's chunk under
    `shard_map`), on the first n local devices, its inputs and outputs replicated there (the
    program splits the batch itself). Raises `NotExportable` where there are fewer devices."""
    n = exported.nr_devices
    if n <= 1:
        return jax.jit(exported.call)
    devices = jax.local_devices()[:n]
    if len(devices) < n:
        raise NotExportable(f"the program runs on {n} devices; this process has "
                            f"{len(devices)}")
    from jax.sharding import Mesh, NamedSharding, PartitionSpec

    everywhere = NamedSharding(Mesh(devices, ("d",)), PartitionSpec())
    return jax.jit(exported.call, in_shardings=everywhere, out_shardings=everywhere)


def _trees(n_in: int, n_out: int):
    """The argument and result structures of `jax.jit(exported.call)` on flat leaves."""
    tu = jax.tree_util
    return tu.tree_structure((tuple(range(n_in)), {})), tu.tree_structure(list(range(n_out)))


def _exec_path(path: str, payload: bytes) -> str:
    program = hashlib.sha256(payload).hexdigest()[:16]
    return f"{path[:-len('.jaxexport')]}-{program}-{machine_digest()}.jaxexec"


def _load_executable(xpath: str, n_in: int, n_out: int):
    """The stored executable at `xpath`, loaded; raises `_Damaged` naming what failed."""
    from jax.experimental import serialize_executable

    with open(xpath, "rb") as f:
        payload = _unpack(f.read(), EXEC_MAGIC)
    head, sep, body = payload.partition(b"\n")
    try:
        targets = json.loads(head)["targets"]
    except (ValueError, KeyError, TypeError) as err:
        raise _Damaged("no list of custom calls") from err
    if not sep or not all(_EXEC_TARGETS.fullmatch(t) for t in targets):
        raise _Damaged("custom calls this module does not prepare")
    _prepare_targets(targets)
    try:
        return serialize_executable.deserialize_and_load(body, *_trees(n_in, n_out))
    except Exception as err:
        raise _Damaged(f"does not deserialise ({_first_line(err)})") from err


def _store_executable(xpath: str, compiled, exported, n_in: int, n_out: int) -> None:
    """Store `compiled` (of `exported`) at `xpath` where its custom calls allow (module
    docstring); silently nothing where JAX cannot serialise it."""
    from jax.experimental import serialize_executable

    targets = _custom_call_targets(exported)
    if not all(_EXEC_TARGETS.fullmatch(t) for t in targets):
        return
    try:
        body, in_tree, out_tree = serialize_executable.serialize(compiled)
    except Exception:  # this backend or program cannot be serialised: the program suffices
        return
    if (in_tree, out_tree) != _trees(n_in, n_out):
        return
    payload = json.dumps({"targets": targets}).encode() + b"\n" + bytes(body)
    _write(xpath, _pack(payload, EXEC_MAGIC))


def _write(path: str, data: bytes) -> None:
    """Atomic: a concurrent process sees the whole file or none (`write_file`)."""
    with write_file(path, "wb") as f:
        f.write(data)


def _first_line(err: BaseException) -> str:
    text = str(err).strip().splitlines()
    return f"{type(err).__name__}: {text[0] if text else ''}".rstrip(": ")


def _read(path: str) -> bytes:
    """The checked serialised program at `path`; raises `_Damaged` naming what failed."""
    with open(path, "rb") as f:
        return _unpack(f.read())


def _load(payload: bytes, n_in: int, n_out: int, leaves):
    """The stored program `payload`, deserialised and compiled for `leaves`: (compiled, fresh,
    exported) as `_compile`; raises `_Damaged` naming what failed."""
    try:
        exported = jax.export.deserialize(bytearray(payload))
    except Exception as err:
        raise _Damaged(f"does not deserialise ({_first_line(err)})") from err
    if len(exported.in_avals) != n_in or len(exported.out_avals) != n_out:
        raise _Damaged("its inputs or outputs do not match this call")
    try:
        return (*_compile(exported, leaves), exported)
    except Exception as err:
        raise _Damaged(f"does not compile ({_first_line(err)})") from err


def _repaired(path: str, what: str, err: Exception, how: str, instead: str) -> bool:
    """Delete the damaged `path` and name it in one `RepairWarning` saying what happened:
    deleted and `how` afresh, or, where it cannot be deleted (a read-only store), kept and
    `instead` (the run goes on without it). Returns whether it is gone."""
    try:
        os.remove(path)
    except FileNotFoundError:  # a concurrent process removed it
        pass
    except OSError as rm:
        warnings.warn(f"stored {what} {path} is damaged ({err}) and cannot be deleted (the "
                      f"store is read-only: {rm.strerror or type(rm).__name__}): {instead}; "
                      f"delete it to repair the store", RepairWarning, stacklevel=4)
        return False
    warnings.warn(f"stored {what} {path} is damaged ({err}): deleted and {how} afresh",
                  RepairWarning, stacklevel=4)
    return True


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
    n_in, n_out = len(leaves), out_def.num_leaves
    compiled, how = None, "loaded"
    if os.path.exists(path):
        try:
            payload = _read(path)
            xpath = _exec_path(path, payload)
            if os.path.exists(xpath):
                try:
                    compiled = _load_executable(xpath, n_in, n_out)
                except _Damaged as err:
                    _repaired(xpath, "executable", err, "compiled",
                              "compiled from its stored program")
            if compiled is None:
                compiled, fresh, exported = _load(payload, n_in, n_out, leaves)
                if fresh:
                    with contextlib.suppress(OSError):
                        _store_executable(xpath, compiled, exported, n_in, n_out)
        except _Damaged as err:
            _repaired(path, "program", err, "exported", "traced and compiled anew")
    if compiled is None:
        exported, how = _export(fn, args, out_template), "exported"
        payload = bytes(exported.serialize())
        try:
            os.makedirs(directory, exist_ok=True)
            _write(path, _pack(payload))
        except OSError:
            # a read-only or full store: the program runs all the same, stored or not
            pass
        else:
            # the executables of the program this one replaces
            for old in glob.glob(f"{glob.escape(path[:-len('.jaxexport')])}-*.jaxexec"):
                with contextlib.suppress(OSError):
                    os.remove(old)
        if len(exported.in_avals) != n_in or len(exported.out_avals) != n_out:
            raise NotExportable(f"exported program {path} does not match this call")
        compiled, fresh = _compile(exported, leaves)
        if fresh:
            with contextlib.suppress(OSError):
                _store_executable(_exec_path(path, payload), compiled, exported, n_in, n_out)

    def run(*call_args):
        lv = jax.tree_util.tree_leaves(eqx.filter(call_args, eqx.is_array))
        return jax.tree_util.tree_unflatten(out_def, compiled(*lv))

    return run, how


def compiled_program(fn: Callable, args: tuple, out_template, directory: Optional[str],
                     label: str):
    """`load_or_export` where `directory` is given and the program can be stored, otherwise the
    usual ahead-of-time compile of `fn` (an `eqx.filter_jit` function). Returns (run, how) with
    how "loaded", "exported" or "compiled". A batch split over host threads (`HostSplit`)
    compiles (or stores) one slice's program and runs it on every slice."""
    if isinstance(fn, HostSplit):
        run, how = compiled_program(fn.fn, fn.slices(args)[0], out_template, directory, label)
        return fn.over(run), how
    if directory is not None:
        try:
            return load_or_export(fn, args, out_template, directory, label)
        # OSError: a read-only or full cache directory; ImportError: no flatbuffers, which
        # jax.export's serialisation needs.
        except (NotExportable, OSError, ImportError):
            pass
    return fn.lower(*args).compile(), "compiled"


#: the callables of `cached_program` in this process
_CACHED: dict = {}


def cached_program(fn: Callable, args: tuple, out_template, directory: Optional[str],
                   label: str) -> Callable:
    """`compiled_program(fn, args, ...)` (from the store in `directory` when given), kept for
    later calls in this process by `fn` and the structure and shapes of `args` (the static
    parts compared by equality): a study calling its program once per iteration looks it up
    instead of keying the store again, and a call with and one without a store share one
    compilation (the two programs differ by rounding only). Call the result with arguments of
    the structure of `args` and the same static values. Called with traced arguments (under
    `jax.grad`, `jax.vmap` or `jax.jit` of a caller), it returns `fn` itself."""
    dyn, static = eqx.partition(args, eqx.is_array)
    if any(isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves(dyn)):
        return fn  # called under a transformation (jax.grad of a caller): `fn` composes with it
    # As `eqx.filter_jit` keys its cache: the static leaves' values (a controller's
    # coefficients, a Python float of a path) as well as the structure and the shapes.
    static_leaves, static_def = jax.tree_util.tree_flatten(static)
    key = (fn, static_def, tuple(static_leaves), jax.tree_util.tree_structure(dyn),
           tuple((x.shape, x.dtype) for x in jax.tree_util.tree_leaves(dyn)))
    try:
        run = _CACHED.get(key)
    except TypeError:  # an unhashable static leaf: `fn` itself, which keys its own way
        return fn
    if run is None:
        run, _ = compiled_program(fn, args, out_template, directory, label)
        _CACHED[key] = run
    return run


def clear_cached_programs() -> None:
    """Drop the callables `cached_program` keeps (their executables with them)."""
    _CACHED.clear()
