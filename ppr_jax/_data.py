"""Measured trajectories (MODEL.md section 7): tracker CSV files, their units and their validation.

A tracker file is a CSV table, one row per sample, with the columns

    time, x, y, phi                 required: sample time and platform pose (x, y, phi)
    th_1, th_2, th_3                optional: actuated angles (all three or none)
    tau_1, tau_2, tau_3             optional: actuator torques (all three or none)

Units are SI (s, m, rad, N m) unless declared, in this order of precedence:
- in the column name, ``x[mm]``, ``phi[deg]``, ``time[ms]``;
- in a header comment line, ``# units: time=s, length=mm, angle=deg, torque=N m``;
- by the caller (``load_csv(..., length_unit="mm")``, CLI ``--length-unit mm``).
A declared unit that contradicts the caller's raises, rather than picking one silently.
Lines starting with ``#`` are comments; blank lines are skipped. ``t`` is accepted for ``time``.

Encodings: UTF-8 (with or without a byte-order mark), UTF-16 and UTF-32 with a byte-order mark
(what Windows tools write as "Unicode"); comment lines may also hold Latin-1 (cp1252) bytes, such
as a degree sign. Anything else (a binary file, UTF-16 without a byte-order mark, non-UTF-8
bytes outside comments) is refused. Files larger than `MAX_FILE_BYTES` (512 MiB) are refused
before reading, lines longer than `MAX_LINE_CHARS` when met; memory stays bounded by a line.

Everything the loader rejects raises `DataError` (a `PPRError`, hence a `ValueError`) naming the
file, the column or the (1-based, as an editor shows them) line numbers.
"""

from __future__ import annotations

import csv
import math
import os
import re
from typing import NamedTuple, Optional, Sequence

import equinox as eqx
import numpy as np

from ._custom_types import Array
from ._errors import DataError
from ._files import write_file
from ._labels import label_field

#: unit name -> factor to SI, per kind of quantity
UNITS = {
    "time": {"s": 1.0, "ms": 1e-3},
    "length": {"m": 1.0, "mm": 1e-3},
    "angle": {"rad": 1.0, "mrad": 1e-3, "deg": math.pi / 180.0},
    "torque": {"nm": 1.0, "n m": 1.0, "n*m": 1.0, "n.m": 1.0, "nmm": 1e-3, "n mm": 1e-3},
}
#: column -> kind of quantity
COLUMNS = {
    "time": "time", "x": "length", "y": "length", "phi": "angle",
    "th_1": "angle", "th_2": "angle", "th_3": "angle",
    "tau_1": "torque", "tau_2": "torque", "tau_3": "torque",
}
REQUIRED = ("time", "x", "y", "phi")
ALIASES = {"t": "time"}
#: reference size of the workspace (m): the base side of Table 1. A pose whose distance from the
#: base origin is 30 times larger or smaller than this is in the wrong units.
WORKSPACE_SCALE = 0.9
#: fewest samples an experiment may have
MIN_SAMPLES = 5
#: a time step longer than GAP_FACTOR times the median step of a file is a gap (samples lost by
#: the recorder): a spline (or a fit's simulation) would bridge it with motion no one measured
GAP_FACTOR = 10.0
#: the longest median sample step (s) of a tracker file: a tracker records at 1 Hz or faster, and
#: a file sampled more slowly is in milliseconds read as seconds (100 Hz reads as 0.1 Hz)
MAX_MEDIAN_STEP = 1.0
#: largest tracker file read (bytes): 512 MiB, some 5 million rows of ten columns
MAX_FILE_BYTES = 512 * 2**20
#: longest line read (characters): a row of ten numbers is under 300
MAX_LINE_CHARS = 100_000
#: byte-order marks and the encodings they announce, longest first
_BOMS = ((b"\xff\xfe\x00\x00", "utf-32"), (b"\x00\x00\xfe\xff", "utf-32"),
         (b"\xef\xbb\xbf", "utf-8-sig"), (b"\xff\xfe", "utf-16"), (b"\xfe\xff", "utf-16"))


class Experiment(eqx.Module):
    """One measured experiment, in SI units.

    ts (n,) sample times (s), strictly increasing; X (n, 3) platform pose x, y (m), phi (rad);
    th (n, 3) actuated angles (rad) or None; tau (n, 3) actuator torques (N m) or None.
    `name` (static) labels the experiment in reports; `dropped_lines` (static) the file lines
    dropped as NaN rows (``drop_nan=True``)."""

    ts: Array
    X: Array
    th: Optional[Array] = None
    tau: Optional[Array] = None
    name: str = label_field(default="experiment")
    dropped_lines: tuple = eqx.field(static=True, default=())

    @property
    def n(self) -> int:
        return int(np.shape(self.ts)[0])


def _where(source, lines):
    shown = ", ".join(str(v) for v in lines[:10]) + (", ..." if len(lines) > 10 else "")
    return f"{source}: line{'s' if len(lines) > 1 else ''} {shown}"


def experiment(ts, X, th=None, tau=None, *, name: str = "experiment",
               min_samples: int = MIN_SAMPLES, lines: Optional[Sequence[int]] = None,
               check_units: bool = True, max_gap: Optional[float] = None) -> Experiment:
    """Validate arrays in SI units and build an `Experiment` (see `load_csv` for the checks).

    **Arguments:**

    - `ts`: (n,) sample times (s).
    - `X`: (n, 3) platform poses (m, m, rad).
    - `th`, `tau`: (n, 3) actuated angles (rad) and actuator torques (N m), or None (default).
    - `name`: the experiment's name, used in messages (default "experiment").
    - `min_samples`: the fewest samples accepted (default 5).
    - `lines`: the row labels used in messages (file lines); None (default): 1-based sample
      index.
    - `check_units`: refuse data that looks like wrong units (default True; as `load_csv`).
    - `max_gap`: refuse a time step longer than this many median steps (`check_gaps`;
      `load_csv` passes `GAP_FACTOR`); None (the default for arrays): uneven sampling is
      accepted.

    **Returns:**

    An `Experiment` holding the arrays as float64.

    **Raises:**

    `DataError` naming the rows for wrong shapes, NaN or infinite values, too few samples,
    duplicated or decreasing times, a gap, or (with `check_units`) wrong-looking units.
    """
    ts = np.asarray(ts, dtype=np.float64)
    X = np.asarray(X, dtype=np.float64)
    n = ts.shape[0] if ts.ndim == 1 else -1
    if ts.ndim != 1:
        raise DataError(f"{name}: time must be a vector (n,), got shape {ts.shape}")
    if X.shape != (n, 3):
        raise DataError(f"{name}: pose must have shape (n, 3) = ({n}, 3) (x, y, phi), "
                        f"got {X.shape}")
    lines = np.arange(1, n + 1) if lines is None else np.asarray(lines)
    extra = {}
    for key, v in (("th", th), ("tau", tau)):
        if v is not None:
            v = np.asarray(v, dtype=np.float64)
            if v.shape != (n, 3):
                raise DataError(f"{name}: {key} must have shape ({n}, 3), got {v.shape}")
        extra[key] = v
    allv = np.column_stack([ts, X] + [v for v in extra.values() if v is not None])
    bad = ~np.all(np.isfinite(allv), axis=1)
    if bad.any():
        raise DataError(f"{_where(name, lines[bad].tolist())}: NaN or infinite values "
                        f"({int(bad.sum())} rows); remove those rows from the arrays (the file "
                        f"readers drop them with drop_nan=True, CLI --drop-nan)")
    if n < min_samples:
        raise DataError(f"{name}: too few samples: {n} (at least {min_samples} needed)")
    dt = np.diff(ts)
    dup = np.flatnonzero(dt == 0)
    if dup.size:
        raise DataError(f"{_where(name, lines[dup + 1].tolist())}: duplicated time "
                        f"(same as the line before); times must be strictly increasing")
    back = np.flatnonzero(dt < 0)
    if back.size:
        raise DataError(f"{_where(name, lines[back + 1].tolist())}: time decreases; times must "
                        f"be strictly increasing (sort the file, or split it into experiments)")
    if max_gap is not None:
        check_gaps(name, ts, lines, "line", max_gap)
    if check_units:
        check_time_units(name, ts)
        check_pose_units(name, X)
    return Experiment(ts=ts, X=X, th=extra["th"], tau=extra["tau"], name=name)


def check_gaps(source: str, ts, rows, label: str = "line", max_gap: float = GAP_FACTOR) -> None:
    """Raise `DataError` at the first time step longer than `max_gap` times the median step of
    times ts (n,) (strictly increasing; n > 2): samples lost by the recorder. The message names
    the sample (`rows`: its labels, file lines), its time, the gap and how many there are. The
    one gap check of the path loaders and the tracker files."""
    ts = np.asarray(ts, dtype=np.float64)
    rows = np.asarray(rows)
    if ts.shape[0] <= 2:
        return
    dt = np.diff(ts)
    med = float(np.median(dt))
    gap = np.flatnonzero(dt > max_gap * med)
    if gap.size:
        i = int(gap[0]) + 1
        raise DataError(
            f"{source}: {label} {int(rows[i])} (t = {float(ts[i]):.6g} s): gap of "
            f"{float(dt[i - 1]):.6g} s after {label} {int(rows[i - 1])} (t = "
            f"{float(ts[i - 1]):.6g} s), more than {max_gap:g} times the median time step "
            f"{med:.6g} s ({gap.size} gap{'s' if gap.size > 1 else ''}): samples are missing; "
            f"split the file there, or pass max_gap=None if the sampling is meant to be uneven")


def check_time_units(name, ts) -> None:
    """Raise `DataError` when the times ts (n,) (s) of a tracker file are in the wrong unit: a
    median sample step above `MAX_MEDIAN_STEP` (1 s), slower than any tracker records, as
    milliseconds read as seconds give. `name` labels the message."""
    if np.shape(ts)[0] < 2:
        return
    med = float(np.median(np.diff(np.asarray(ts, dtype=np.float64))))
    if med > MAX_MEDIAN_STEP:
        raise DataError(
            f"{name}: the median time step is {med:.4g} s ({1 / med:.3g} Hz), slower than a "
            f"tracker records (a step of at most {MAX_MEDIAN_STEP:g} s): probably milliseconds "
            f"read as seconds; declare the unit (column 'time[ms]', header '# units: "
            f"time=ms', or time_unit='ms' / --time-unit ms)")


def check_pose_units(name, X):
    """Raise `DataError` when poses X (n, 3) (m, m, rad) are in the wrong units: the median
    platform position 30 times farther from (or nearer to) the base origin than the workspace
    (`WORKSPACE_SCALE`), or |phi| above pi/2. `name` labels the message."""
    # Why a scale test: a tracker exporting mm into a file read as m (or the reverse) gives poses
    # 1000 times off, and a fit would then "succeed" on nonsense.
    d = float(np.median(np.hypot(X[:, 0], X[:, 1])))
    if d > 30 * WORKSPACE_SCALE:
        raise DataError(
            f"{name}: the platform position is {d:.4g} m from the base origin, about "
            f"{d / WORKSPACE_SCALE:.0f} times the workspace (base side {WORKSPACE_SCALE} m): "
            f"probably millimetres read as metres; declare the unit (column 'x[mm]', header "
            f"'# units: length=mm', or length_unit='mm' / --length-unit mm)")
    if d < WORKSPACE_SCALE / 30:
        raise DataError(
            f"{name}: the platform position is only {d:.4g} m from the base origin, about "
            f"1/{WORKSPACE_SCALE / max(d, 1e-300):.0f} of the workspace (base side "
            f"{WORKSPACE_SCALE} m): probably wrong units (metres read as millimetres?); declare "
            f"the unit of the file")
    phimax = float(np.max(np.abs(X[:, 2])))
    if phimax > math.pi / 2:
        raise DataError(
            f"{name}: platform rotation |phi| reaches {phimax:.4g} rad, beyond what the robot "
            f"can turn (pi/2): {_angle_guess(phimax)} read as radians; declare the unit "
            f"(column 'phi[deg]' or 'phi[mrad]', header '# units: angle=deg', or "
            f"angle_unit='deg' / --angle-unit deg)")


def _angle_guess(phimax: float) -> str:
    """What angles reaching `phimax` "radians" probably are: degrees, milliradians, or either
    (a robot that turns its platform by at most pi/2 = 90 deg = 1571 mrad; the scenes' turn by
    a few degrees, tens of milliradians)."""
    deg = phimax <= 90.0
    mrad = phimax <= 1000.0 * math.pi / 2
    if deg and mrad:
        return "probably degrees or milliradians"
    return "probably milliradians" if mrad else "probably degrees" if deg else "an unknown unit"


_HEADER_UNITS = re.compile(r"^\s*#\s*units?\s*:\s*(.*)$", re.IGNORECASE)
_COL = re.compile(r"^\s*([A-Za-z_0-9]+)\s*(?:\[\s*([^\]]*?)\s*\]|\(\s*([^)]*?)\s*\))?\s*$")


def _unit_factor(source, kind, unit, where):
    u = unit.strip().lower()
    if u not in UNITS[kind]:
        allowed = ", ".join(k for k in UNITS[kind] if " " not in k or kind == "torque")
        raise DataError(f"{source}: unknown {kind} unit {unit!r} in {where}; allowed: {allowed}")
    return UNITS[kind][u]


def _lines(path: str, source: str):
    """(line number, text) of the file's lines, decoded (module docstring), with the size and
    line-length limits; raises `DataError` naming the file, the line and the encoding tried."""
    size = os.path.getsize(path)
    if size > MAX_FILE_BYTES:
        raise DataError(f"{source}: {size / 2**20:.0f} MiB, above the limit of "
                        f"{MAX_FILE_BYTES / 2**20:.0f} MiB for a tracker file "
                        f"(ppr_jax._data.MAX_FILE_BYTES); split it into several experiments")
    with open(path, "rb") as f:
        head = f.read(4)
    encoding = next((enc for bom, enc in _BOMS if head.startswith(bom)), "utf-8")
    shown = {"utf-8-sig": "UTF-8", "utf-8": "UTF-8", "utf-16": "UTF-16", "utf-32": "UTF-32"}
    tried = shown[encoding] + (" (byte-order mark)" if encoding != "utf-8" else
                               ", or Latin-1 in comment lines")
    # Without a byte-order mark: UTF-8, its undecodable bytes kept as surrogates to be decoded
    # as Latin-1 in comment lines and refused elsewhere.
    errors = "surrogateescape" if encoding == "utf-8" else "strict"
    lineno = 0
    try:
        with open(path, encoding=encoding, errors=errors, newline="") as f:
            while True:
                line = f.readline(MAX_LINE_CHARS + 1)
                if not line:
                    return
                lineno += 1
                if len(line) > MAX_LINE_CHARS:
                    raise DataError(f"{source}: line {lineno} is longer than {MAX_LINE_CHARS} "
                                    f"characters (ppr_jax._data.MAX_LINE_CHARS): not a tracker "
                                    f"table (a binary file, or one without line breaks?)")
                if "\x00" in line:
                    raise DataError(f"{source}: line {lineno} holds NUL characters: a binary "
                                    f"file or UTF-16 without a byte-order mark, not {tried} "
                                    f"text; save it as UTF-8")
                if errors == "surrogateescape" and any("\udc80" <= ch <= "\udcff" for ch in line):
                    if not line.lstrip().startswith("#"):
                        raise DataError(f"{source}: line {lineno} is not {tried} text (bytes "
                                        f"that UTF-8 cannot decode outside a comment line); "
                                        f"save it as UTF-8")
                    line = line.encode("utf-8", "surrogateescape").decode("cp1252", "replace")
                yield lineno, line
    except UnicodeDecodeError as err:
        raise DataError(f"{source}: after line {lineno}, bytes that {tried} cannot decode "
                        f"({err.reason}); save it as UTF-8") from None


class Table(NamedTuple):
    """The columns of a CSV table in SI units (`read_columns`): `columns` maps each column's
    canonical name (`COLUMNS`) to its (n,) values, `lines` holds the (1-based) file line of each
    row, `dropped` the lines dropped as NaN rows, `source` the file's base name."""

    source: str
    columns: dict
    lines: np.ndarray
    dropped: tuple


def read_columns(path: str, *, required: Sequence[str] = REQUIRED,
                 time_unit: Optional[str] = None, length_unit: Optional[str] = None,
                 angle_unit: Optional[str] = None, torque_unit: Optional[str] = None,
                 drop_nan: bool = False) -> Table:
    """Read a CSV table (format and units: module docstring) into its columns in SI units, the
    reader behind `load_csv` and the path and command-log loaders (`_paths.py`).

    `required` names the columns that must be present; any other known column (`COLUMNS`) may
    be. Raises `DataError` for a missing file, unknown, duplicated or missing columns, bad
    units, unreadable numbers and (unless `drop_nan`) NaN, empty or infinite cells, naming the
    file and the lines. The rows are neither counted nor ordered here: the callers check that."""
    if not isinstance(path, (str, os.PathLike)):
        raise DataError(f"a data file is a path (str or os.PathLike), got {type(path).__name__} "
                        f"{path!r}")
    path = os.fspath(path)
    source = os.path.basename(path)
    if not os.path.isfile(path):
        raise DataError(f"{path}: no such file")
    options = {"time": time_unit, "length": length_unit, "angle": angle_unit,
               "torque": torque_unit}
    for kind, u in options.items():
        if u is not None:
            _unit_factor(source, kind, u, "the options")
    header_units: dict[str, str] = {}
    rows: list[tuple[int, list[str]]] = []
    header: Optional[list[str]] = None
    header_line = 0
    for lineno, line in _lines(path, source):
        s = line.strip()
        if not s:
            continue
        if s.startswith("#"):
            m = _HEADER_UNITS.match(s)
            if m:
                for item in m.group(1).split(","):
                    if not item.strip():
                        continue
                    if "=" not in item:
                        raise DataError(f"{source}: line {lineno}: units header expects "
                                        f"kind=unit items (kinds: {', '.join(UNITS)}), got "
                                        f"{item.strip()!r}")
                    k, u = (v.strip() for v in item.split("=", 1))
                    k = k.lower()
                    if k not in UNITS:
                        raise DataError(f"{source}: line {lineno}: unknown kind {k!r} in the "
                                        f"units header; allowed: {', '.join(UNITS)}")
                    _unit_factor(source, k, u, f"line {lineno}")
                    header_units[k] = u
            continue
        try:
            cells = next(csv.reader([line]))
        except csv.Error as err:
            raise DataError(f"{source}: line {lineno}: cannot read it as CSV ({err})") from None
        if header is None:
            header, header_line = cells, lineno
        else:
            rows.append((lineno, cells))
    if header is None:
        raise DataError(f"{source}: no header row (expected columns {', '.join(required)})")
    cols: list[str] = []
    col_units: list[Optional[str]] = []
    for raw in header:
        m = _COL.match(raw)
        if not m:
            raise DataError(f"{source}: line {header_line}: cannot read column name {raw!r} "
                            f"(expected NAME or NAME[unit])")
        c = ALIASES.get(m.group(1).lower(), m.group(1).lower())
        if c not in COLUMNS:
            raise DataError(f"{source}: unknown column {raw.strip()!r}; allowed names: "
                            f"{', '.join(COLUMNS)} (units as NAME[unit]; 't' is read as 'time')")
        if c in cols:
            raise DataError(f"{source}: column {c!r} appears twice")
        cols.append(c)
        col_units.append(m.group(2) or m.group(3))
    missing = [c for c in required if c not in cols]
    if missing:
        groups = {"x, y, phi": ("x", "y", "phi"), "th_1..th_3": ("th_1", "th_2", "th_3"),
                  "tau_1..tau_3": ("tau_1", "tau_2", "tau_3")}
        optional = ", ".join(k for k, g in groups.items() if not set(g) & set(required))
        raise DataError(f"{source}: missing column(s) {', '.join(missing)}; required: "
                        f"{', '.join(required)}; optional: {optional}; found: "
                        f"{', '.join(header)}")
    for group in (("th_1", "th_2", "th_3"), ("tau_1", "tau_2", "tau_3")):
        have = [c for c in group if c in cols]
        if have and len(have) != 3:
            raise DataError(f"{source}: columns {', '.join(group)} come as a set of three; "
                            f"found only {', '.join(have)}")
    factors = []
    for c, cu in zip(cols, col_units):
        kind = COLUMNS[c]
        declared = cu if cu else header_units.get(kind)
        opt = options[kind]
        if declared and opt and (_unit_factor(source, kind, declared, f"column {c!r}")
                                 != _unit_factor(source, kind, opt, "the options")):
            raise DataError(f"{source}: column {c!r} is declared in {declared!r} by the file "
                            f"but {opt!r} was given as an option; remove one")
        unit = declared or opt
        factors.append(1.0 if unit is None else _unit_factor(source, kind, unit, f"column {c!r}"))
    data = np.full((len(rows), len(cols)), np.nan)
    lines = np.array([ln for ln, _ in rows], dtype=int)
    for i, (ln, cells) in enumerate(rows):
        if len(cells) != len(cols):
            raise DataError(f"{source}: line {ln}: {len(cells)} cells, the header has {len(cols)}")
        for j, cell in enumerate(cells):
            s = cell.strip()
            if s == "" or s.lower() in ("nan", "na", "null", "none"):
                continue  # missing value: a NaN row, reported below
            try:
                data[i, j] = float(s)
            except ValueError:
                raise DataError(f"{source}: line {ln}, column {cols[j]!r}: cannot read "
                                f"{s!r} as a number") from None
    data = data * np.asarray(factors)
    bad = ~np.all(np.isfinite(data), axis=1)
    dropped: tuple = ()
    if bad.any():
        if not drop_nan:
            raise DataError(f"{_where(source, lines[bad].tolist())}: NaN, empty or infinite values "
                            f"({int(bad.sum())} rows); drop them with drop_nan=True "
                            f"(CLI --drop-nan)")
        dropped = tuple(int(v) for v in lines[bad])
        data, lines = data[~bad], lines[~bad]
    return Table(source=source, columns={c: data[:, j] for j, c in enumerate(cols)},
                 lines=lines, dropped=dropped)


def load_csv(path: str, *, time_unit: Optional[str] = None, length_unit: Optional[str] = None,
             angle_unit: Optional[str] = None, torque_unit: Optional[str] = None,
             drop_nan: bool = False, min_samples: int = MIN_SAMPLES,
             name: Optional[str] = None, check_units: bool = True,
             max_gap: Optional[float] = GAP_FACTOR) -> Experiment:
    """Read a tracker CSV file (format: module docstring) into an `Experiment` in SI units.

    Units: column ``name[unit]`` > header ``# units: kind=unit, ...`` > the `*_unit` options > SI.

    **Arguments:**

    - `path`: the CSV file.
    - `time_unit`, `length_unit`, `angle_unit`, `torque_unit`: the units of columns that
      declare none (`UNITS`: s, ms; m, mm; rad, mrad, deg; Nm, Nmm); None (default): SI. An
      option that contradicts a declared unit raises `DataError`.
    - `drop_nan`: NaN (or empty) cells make their rows fail with their line numbers, unless
      `drop_nan` (then they are dropped and listed in `Experiment.dropped_lines`); default
      False.
    - `min_samples`: the fewest rows accepted (default 5).
    - `name`: the experiment's name; None (default): the file's name without extension.
    - `check_units`: refuse poses about 1000 times off the workspace, |phi| > pi/2 or a median
      time step above 1 s (wrong units: mm, degrees or ms read as SI); False skips these.
    - `max_gap`: refuse a gap, a time step longer than `max_gap` times the median step
      (default `GAP_FACTOR` 10, as the path loaders refuse); None accepts uneven sampling.

    **Returns:**

    An `Experiment` in SI units.

    **Raises:**

    `DataError` for: a missing file, missing or unknown columns (the message lists the allowed
    names), unreadable numbers, fewer than `min_samples` rows, duplicated or decreasing times,
    a gap, a unit option contradicting a declared unit, NaN cells without `drop_nan`, or (with
    `check_units`) wrong-looking units.
    """
    table = read_columns(path, time_unit=time_unit, length_unit=length_unit,
                         angle_unit=angle_unit, torque_unit=torque_unit, drop_nan=drop_nan)
    source, col, lines = table.source, table.columns, table.lines
    name = name or os.path.splitext(source)[0]

    def triple(prefix):
        if f"{prefix}_1" not in col:
            return None
        return np.column_stack([col[f"{prefix}_{k}"] for k in (1, 2, 3)])

    exp = experiment(col["time"], np.column_stack([col["x"], col["y"], col["phi"]]),
                     triple("th"), triple("tau"), name=source, min_samples=min_samples,
                     lines=lines, check_units=check_units, max_gap=max_gap)
    return Experiment(ts=exp.ts, X=exp.X, th=exp.th, tau=exp.tau, name=name,
                      dropped_lines=table.dropped)


def load_experiments(paths: Sequence[str], **kw) -> list[Experiment]:
    """Several files as several experiments (options as `load_csv`, shared by all files)."""
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    if not paths:
        raise DataError("no data file given")
    exps = [load_csv(p, **kw) for p in paths]
    names = [e.name for e in exps]
    if len(set(names)) != len(names):  # name them apart in reports
        exps = [Experiment(ts=e.ts, X=e.X, th=e.th, tau=e.tau, name=f"{e.name}#{i + 1}",
                           dropped_lines=e.dropped_lines) for i, e in enumerate(exps)]
    return exps


def write_csv(path: str, exp: Experiment, *, length_unit: str = "mm", angle_unit: str = "rad",
              comments: Sequence[str] = ()) -> None:
    """Write an `Experiment` as a tracker file (units in the header comment and column names).

    **Arguments:**

    - `path`: the file to write (its directory is created).
    - `exp`: the `Experiment` (SI units); its angles and torques are written where not None.
    - `length_unit`: unit of x and y in the file, "m" or "mm" (default "mm").
    - `angle_unit`: unit of phi and the angles in the file, "rad", "mrad" or "deg" (default
      "rad"). Torques are written in N m.
    - `comments`: lines written first as `# ` comments (default none).

    **Returns:**

    None.
    """
    fl = UNITS["length"][length_unit]
    fa = UNITS["angle"][angle_unit]
    cols = ["time[s]", f"x[{length_unit}]", f"y[{length_unit}]", f"phi[{angle_unit}]"]
    blocks = [np.asarray(exp.ts)[:, None], np.asarray(exp.X)[:, :2] / fl,
              np.asarray(exp.X)[:, 2:] / fa]
    if exp.th is not None:
        cols += [f"th_{k}[{angle_unit}]" for k in (1, 2, 3)]
        blocks.append(np.asarray(exp.th) / fa)
    if exp.tau is not None:
        cols += [f"tau_{k}[Nm]" for k in (1, 2, 3)]
        blocks.append(np.asarray(exp.tau))
    data = np.column_stack(blocks)
    d = os.path.dirname(os.path.abspath(path))
    os.makedirs(d, exist_ok=True)
    with write_file(path, "w", newline="") as f:
        for c in comments:
            f.write(f"# {c}\n")
        f.write(f"# units: time=s, length={length_unit}, angle={angle_unit}, torque=Nm\n")
        w = csv.writer(f)
        w.writerow(cols)
        for row in data:
            w.writerow([f"{v:.10g}" for v in row])


def example_path() -> str:
    """Path of the example tracker file shipped with the package (ppr_jax/data/)."""
    return os.path.join(os.path.dirname(__file__), "data", "servo_circle_example.csv")
