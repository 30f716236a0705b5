"""Command line interface `ppr-jax` (docs/cli.md): the parser of every command and the entry
point.

The parser is built from plain-Python modules only (`_names` for choices and defaults): `--help`
and a mistyped option answer without importing JAX. Each command imports the library in its
`cmd_*` function."""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
import time

from .._names import T_END
from ._common import (
    HelpFormatter,
    _log,
    parent_parsers,
)
from ._compensate import add_compensate
from ._design import add_design
from ._identify import add_identify
from ._modes import _add_modes
from ._prb import _add_prb, _add_prb_table
from ._sensitivity import add_sensitivity
from ._simulate import _add_simulate
from ._sweep import add_sweep
from ._synth import add_synth
from ._torques import _add_torques

#: The commands, in the order `--help` lists them: each entry adds one subparser. A new command
#: is one module in this wing with a function `add(sub, parents, fmt)`, and one line here.
COMMANDS = [
    _add_simulate, _add_torques, _add_modes, _add_prb, _add_prb_table,
    add_sweep, add_sensitivity, add_identify, add_synth, add_design, add_compensate,
]


def build_parser():
    fmt = HelpFormatter
    p = argparse.ArgumentParser(prog="ppr-jax",
                                description="Command line interface of ppr_jax (docs/cli.md).",
                                formatter_class=fmt)
    sub = p.add_subparsers(dest="cmd", required=True)
    parents = parent_parsers()
    for add in COMMANDS:
        add(sub, parents, fmt)
    return p


def _runtime_message(err: Exception) -> str:
    """The library's own message out of an error raised inside compiled code (equinox's runtime
    errors arrive wrapped in JAX's), without the framework's hints."""
    text = str(err)
    for marker in ("EqxRuntimeError: ", "XlaRuntimeError: "):
        if marker in text:
            text = text.split(marker, 1)[1]
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    keep = [ln for ln in lines if not ln.startswith(("-----", "This error", "Note:", "If this"))]
    return keep[0] if keep else (lines[0] if lines else type(err).__name__)


def main(argv=None, *, exit_on_interrupt: bool = False) -> int:
    """Run the command line; every user error is one line on stderr and exit status 2. Ctrl-C
    (SIGINT) is one line too, naming what the command had written (`kept_files`), and exit
    status 130 (128 + SIGINT, the shell's convention).

    **Arguments:**

    - `argv`: the arguments (default: `sys.argv[1:]`).
    - `exit_on_interrupt`: after an interrupt's line, end the process at once with status 130
      (`os._exit`), as the console script does, instead of returning 130 (`_exit_at_once`).

    **Returns:**

    The exit status."""
    state = {"started": time.time(), "args": None}
    caught = threading.Event()
    previous, repeating = _insist_on_sigint(caught)
    unraisable = sys.unraisablehook
    sys.unraisablehook = _quiet_interrupts(unraisable)
    try:
        return _main(argv, state)
    except KeyboardInterrupt:
        caught.set()
        print(f"ppr-jax: interrupted; kept: {kept_files(state['args'], state['started'])}",
              file=sys.stderr)
        if exit_on_interrupt:
            _exit_at_once(130)
        return 130
    finally:
        caught.set()
        # the repeats end before the handler is restored: none lands after it
        for thread in repeating:
            thread.join()
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
        sys.unraisablehook = unraisable


def _quiet_interrupts(hook):
    """`sys.unraisablehook` that passes over a KeyboardInterrupt: one raised where it cannot
    propagate (JAX's garbage-collection callback, a `__del__`, a weakref callback) is printed
    by Python as "Exception ignored in ..." with its traceback, before the command line's one
    line. It is raised again within `INTERRUPT_REPEAT_S` (`_insist_on_sigint`), where it can
    propagate. Anything else goes to `hook`."""
    def unraisable(info):
        if not isinstance(info.exc_value, KeyboardInterrupt):
            hook(info)

    return unraisable


def _exit_at_once(status: int) -> None:
    """End the process with `status` without the interpreter's finalisation. An interrupt can
    come while XLA's threads still work (a compilation's, an asynchronous computation's); the
    finalisation (JAX's exit handler destroys the backend, modules and their objects are torn
    down) then races them, and the process died with SIGSEGV after its line (3 of 10 interrupts
    during a compilation where it was found; 1 in about 40 on a loaded 2-core machine). Exit
    handlers (`atexit`) do not run either. Nothing is left to finalise: every file is closed
    by then (written whole, or its temporary removed: `_files.write_file`), and the standard
    streams are flushed here."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError, AttributeError):  # closed, or replaced by None
            pass
    os._exit(status)


#: seconds between the repeats of an interrupt not yet caught (`_insist_on_sigint`)
INTERRUPT_REPEAT_S = 0.2


def _insist_on_sigint(caught: threading.Event):
    """Make Ctrl-C (SIGINT) raise KeyboardInterrupt, and raise it again every
    `INTERRUPT_REPEAT_S` until `main` has caught it (`caught` set). JAX's tracing runs code under
    bare `except:` clauses (`operator.index` probes of every shape); a KeyboardInterrupt raised
    inside one is swallowed, and the command would run to its end with Ctrl-C ignored. A SIGINT
    ignored by whoever started the process (a shell's background job) stays ignored, as Python
    leaves it. Once `caught` is set the handler does nothing: a repeat already on its way, or a
    second Ctrl-C while the command ends, adds no second interrupt. Returns the SIGINT handler
    replaced (None where none is set: ignored, or not the main thread) and the list that holds
    the repeating thread once started, for the caller to join."""
    repeating = []
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        return None, repeating

    main = threading.main_thread().ident

    def repeat():
        # a signal, not `_thread.interrupt_main`: it also wakes a main thread that sleeps
        while not caught.wait(INTERRUPT_REPEAT_S):
            signal.pthread_kill(main, signal.SIGINT)

    def on_sigint(signum, frame):
        if caught.is_set():
            return
        if not repeating:
            repeating.append(threading.Thread(target=repeat, daemon=True))
            repeating[0].start()
        raise KeyboardInterrupt

    try:
        return signal.signal(signal.SIGINT, on_sigint), repeating
    except ValueError:  # signal handlers belong to the main thread
        return None, repeating


#: kept_files names at most this many files, then counts the rest
KEPT_LISTED = 6


def kept_files(args, since: float) -> str:
    """What an interrupted command leaves: the files under its --out (a directory, or a file)
    written since `since` (a time.time()), complete ones only (never a `*.tmp` half-write), or
    "nothing written". A sweep's finished chunks are kept for a rerun to resume from."""
    out = getattr(args, "out", None)
    if not out or not os.path.exists(out):
        return "nothing written"
    if os.path.isfile(out):
        paths = [out]
    else:
        paths = [os.path.join(d, f) for d, _, files in os.walk(out) for f in files]
    new = []
    for p in paths:
        try:
            # 1 s of slack: a coarse file-system clock
            if os.path.getmtime(p) >= since - 1.0 and not p.endswith(".tmp"):
                new.append(p)
        except OSError:  # removed meanwhile
            pass
    if not new:
        return "nothing written"
    new.sort()
    names = [os.path.relpath(p, out) if p != out else p for p in new]
    text = ", ".join(names[:KEPT_LISTED]) + (f" and {len(names) - KEPT_LISTED} more"
                                             if len(names) > KEPT_LISTED else "")
    text = text if os.path.isfile(out) else f"{text} in {out}"
    if getattr(args, "cmd", None) == "sweep" and any("chunk_" in n for n in names):
        text += " (a rerun with the same --out resumes from the finished chunks)"
    return text


def _main(argv, state) -> int:
    args = build_parser().parse_args(argv)
    state["args"] = args
    import jax  # after parsing: --help and a bad option answer without JAX

    from .._errors import PPRError

    # the command as typed, for reports that say how they were made
    args.argv = list(sys.argv[1:] if argv is None else argv)
    args.program_dir = None
    if getattr(args, "t_end", T_END) is None and getattr(args, "path", None) is None:
        args.t_end = T_END  # a --path file's own horizon is read with the file (scene_from_args)
    if os.environ.get("PPR_JAX_CPU_DEFAULTS", "1") != "0":
        from .._devices import configure_cpu, default_flags, set_xla_flags

        try:
            if args.cmd == "sweep":
                configure_cpu()  # one host device per core: a sweep's chunks split over them
            else:
                set_xla_flags(default_flags())  # as `import ppr_jax` sets them
        except PPRError:  # JAX started already (the command called from Python): keep it
            pass
    if os.environ.get("PPR_JAX_CACHE", "1") != "0":
        from .._cache import enable_compilation_cache
        from .._programs import PROGRAM_SUBDIR

        try:
            # Every program is stored, the small ones too (`enable_compilation_cache`), and the
            # exported scene programs beside them: a second run skips tracing and compiling.
            args.program_dir = os.path.join(enable_compilation_cache(min_compile_time_s=0.0),
                                            PROGRAM_SUBDIR)
        except OSError as err:  # a read-only home: run without the cache, say so once
            _log(f"ppr-jax: note: compilation cache disabled ({err})")
    try:
        return args.func(args)
    except (PPRError, ValueError) as err:
        msg = str(err)
    except OSError as err:
        msg = f"{err.filename or ''}: {err.strerror or err}".lstrip(": ")
    except jax.errors.JaxRuntimeError as err:
        msg = _runtime_message(err)
    print(f"ppr-jax: error: {' '.join(msg.split())}", file=sys.stderr)
    return 2
