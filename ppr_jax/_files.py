"""The files the library and the command line write: each appears whole or not at all.

`write_file` writes to a temporary file beside the target (`.<name>.<random>.tmp`) and renames
it over the target once the whole content is written (`os.replace`, atomic on one file system).
A write that fails (a full disk, a quota, a read-only directory, an error while formatting the
content, Ctrl-C) removes the temporary file and leaves whatever stood at the target before:
never a truncated file under the name a command reports as written. An `OSError` is raised
again naming the target (`err.filename`): the OSError of a full disk names no file, since the
file object it comes from is not the user's path. The command line prints it as its one line
(`<path>: not written (No space left on device)`, exit 2)."""

from __future__ import annotations

import contextlib
import os
import secrets
from typing import Iterator

#: the suffix of the temporary files (the command line's "kept" list of an interrupted run
#: leaves them out)
TMP_SUFFIX = ".tmp"


def not_written(err: OSError, path) -> OSError:
    """`err` as an OSError of the same kind (errno) naming `path` and saying that nothing was
    written there."""
    text = err.strerror or str(err) or type(err).__name__
    return OSError(err.errno, f"not written ({text})", os.fspath(path))


@contextlib.contextmanager
def write_file(path, mode: str = "w", **kwargs) -> Iterator:
    """Open `path` for writing, whole or not at all (module docstring).

    **Arguments:**

    - `path`: the file to write (its directory must exist).
    - `mode`: `"w"` (text) or `"wb"` (bytes).
    - `kwargs`: `open`'s other arguments (`encoding`, `newline`).

    **Returns:**

    A context manager yielding the open file; `path` holds the content once the block ends
    without error. Raises an `OSError` naming `path` where it cannot be written."""
    if mode not in ("w", "wb"):
        raise ValueError(f"write_file writes a file whole: mode 'w' or 'wb', not {mode!r}")
    path = os.fspath(path)
    directory, name = os.path.split(os.path.abspath(path))
    tmp = os.path.join(directory, f".{name}.{secrets.token_hex(4)}{TMP_SUFFIX}")
    try:
        # os.open with 0o666: the permissions the umask gives `open(path, "w")`
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    except OSError as err:
        raise not_written(err, path) from None
    try:
        try:
            f = os.fdopen(fd, mode, **kwargs)
        except BaseException:
            os.close(fd)
            raise
        with f:
            yield f
        os.replace(tmp, path)
    except BaseException as err:
        with contextlib.suppress(OSError):
            os.remove(tmp)
        if isinstance(err, OSError):
            raise not_written(err, path) from err
        raise


def save_figure(fig, path, **kwargs) -> str:
    """`fig.savefig(path, **kwargs)` through `write_file` (the format from the name's
    extension, as matplotlib chooses it). Returns `path`."""
    fmt = kwargs.pop("format", None) or os.path.splitext(os.fspath(path))[1][1:].lower() or None
    with write_file(path, "wb") as f:
        fig.savefig(f, format=fmt, **kwargs)
    return os.fspath(path)
