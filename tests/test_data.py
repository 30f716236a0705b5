"""Tracker CSV files: units, several experiments, and one test per kind of malformed file
(each must raise `DataError` naming what is wrong). No simulation: fast."""

import math

import numpy as np
import pytest

import ppr_jax as pj
from ppr_jax._data import DataError


def _write(tmp_path, text, name="f.csv"):
    p = tmp_path / name
    p.write_text(text)
    return str(p)


def _good_rows(n=8, scale=1.0, phi_scale=1.0):
    t = np.arange(n) * 0.01
    x = (0.55 + 0.001 * np.arange(n)) * scale
    y = 0.2598 * scale * np.ones(n)
    phi = -0.01 * np.arange(n) * phi_scale
    return t, x, y, phi


def _table(header, cols):
    lines = [header] + [",".join(f"{v:.17g}" for v in row) for row in np.column_stack(cols)]
    return "\n".join(lines) + "\n"


def _refused(tmp_path, header, cols, match, **kwargs):
    """`load_csv` of the table `header`, `cols` (written to tmp_path) refuses it: a `DataError`
    matching `match`."""
    with pytest.raises(DataError, match=match):
        pj.load_csv(_write(tmp_path, _table(header, cols)), **kwargs)


def test_si_file_reads_back_exactly(tmp_path):
    t, x, y, phi = _good_rows()
    e = pj.load_csv(_write(tmp_path, _table("time,x,y,phi", [t, x, y, phi])))
    np.testing.assert_allclose(e.ts, t, rtol=0, atol=1e-15)
    np.testing.assert_allclose(e.X, np.column_stack([x, y, phi]), rtol=1e-12)
    assert e.th is None and e.tau is None and e.name == "f"


def test_units_from_columns_header_and_options_agree(tmp_path):
    t, x, y, phi = _good_rows()
    ref = np.column_stack([x, y, phi])
    # column units: ms, mm, deg
    cols = [t * 1e3, x * 1e3, y * 1e3, np.degrees(phi)]
    e1 = pj.load_csv(_write(tmp_path, _table("time[ms],x[mm],y[mm],phi[deg]", cols), "a.csv"))
    # header comment
    txt = "# units: time=ms, length=mm, angle=deg\n" + _table("t,x,y,phi", cols)
    e2 = pj.load_csv(_write(tmp_path, txt, "b.csv"))
    # options
    e3 = pj.load_csv(_write(tmp_path, _table("time,x,y,phi", cols), "c.csv"), time_unit="ms",
                     length_unit="mm", angle_unit="deg")
    for e in (e1, e2, e3):
        np.testing.assert_allclose(e.ts, t, atol=1e-15)
        np.testing.assert_allclose(e.X, ref, rtol=1e-12, atol=1e-15)


def test_optional_angles_and_torques(tmp_path):
    t, x, y, phi = _good_rows()
    th = np.column_stack([np.full_like(t, v) for v in (0.1, 0.2, 0.3)])
    tau = th * 10
    e = pj.load_csv(_write(tmp_path, _table("time,x,y,phi,th_1,th_2,th_3,tau_1,tau_2,tau_3",
                                            [t, x, y, phi, *th.T, *tau.T])))
    np.testing.assert_allclose(e.th, th)
    np.testing.assert_allclose(e.tau, tau)


def test_write_then_load_round_trip(tmp_path):
    t, x, y, phi = _good_rows()
    e = pj.experiment(t, np.column_stack([x, y, phi]), th=np.ones((len(t), 3)) * 0.5)
    path = str(tmp_path / "w.csv")
    pj.write_csv(path, e, length_unit="mm", angle_unit="deg", comments=["synthetic"])
    back = pj.load_csv(path)
    np.testing.assert_allclose(back.X, e.X, rtol=1e-9)
    np.testing.assert_allclose(back.th, e.th, rtol=1e-9)


def test_several_files_are_several_experiments(tmp_path):
    t, x, y, phi = _good_rows()
    a = _write(tmp_path, _table("time,x,y,phi", [t, x, y, phi]), "run.csv")
    d = tmp_path / "other"
    d.mkdir()
    b = _write(d, _table("time,x,y,phi", [t, x, y, phi]), "run.csv")
    exps = pj.load_experiments([a, b])
    assert len(exps) == 2 and exps[0].name != exps[1].name


def test_shipped_example_file_loads():
    """The shipped example (servo-circle, L2, t = 0.5 mm, 100 Hz, noise 0.1 mm on x, y and
    1 mrad on phi, th_i noise-free, per its header) against independent references: numpy's
    own parse of the file (mm to m), the nominal circle of eq 55, the noise its header states,
    and the L1 inverse kinematics of eq 55 in MODEL.md section 4's closed form."""
    from ppr_jax._data import example_path

    e = pj.load_csv(example_path())
    raw = np.loadtxt(example_path(), delimiter=",", comments="#", skiprows=4)
    assert e.n == len(raw) == 101 and e.th is not None and e.tau is not None
    np.testing.assert_array_equal(e.ts, raw[:, 0])
    np.testing.assert_allclose(e.ts, np.arange(101) * 0.01, rtol=0, atol=1e-15)
    np.testing.assert_allclose(e.X, np.column_stack([raw[:, 1:3] / 1e3, raw[:, 3]]), rtol=1e-15)
    np.testing.assert_array_equal(e.th, raw[:, 4:7])
    np.testing.assert_array_equal(e.tau, raw[:, 7:10])
    wt = 5 / 6 * raw[:, 0]
    X55 = np.column_stack([0.45 + 0.1 * np.cos(wt), 0.15 * np.sqrt(3) + 0.1 * np.sin(wt),
                           -0.05 * np.sin(wt)])
    # L2 under L1's angles stays near the circle: measured 0.60 mm (noise and model mismatch)
    # in x, y and 5.7 mrad in phi (its mean offset, 2.1 mrad, is L2's softer rotation)
    dev = np.asarray(e.X) - X55
    assert np.abs(dev[:, :2]).max() < 1e-3 and np.abs(dev[:, 2]).max() < 1e-2
    # the noise: a second difference of white noise has 6 times its variance (the motion's own
    # second difference, 7e-6 m and 3e-6 rad per sample, is far below it); measured 0.095 mm,
    # 0.089 mm, 1.08 mrad against the header's 0.1 mm, 0.1 mm, 1 mrad (99 samples: about 10 %
    # sampling error)
    sigma = np.diff(np.asarray(e.X), 2, axis=0).std(axis=0) / np.sqrt(6)
    np.testing.assert_allclose(sigma, [1e-4, 1e-4, 1e-3], rtol=0.25)
    # th_i noise-free: the commanded angles, L1's inverse kinematics of eq 55 (t = 0.5 mm does
    # not change r1, r2): (2 r1 cos v + r2) e(u) = E_i - A_i, th_i1 = u - v with v < 0 (sigma = -1)
    dv = pj.derived(pj.scene_params("servo-circle"))
    r1, r2, rho_E, a = float(dv.r1), float(dv.r2), float(dv.rho_E), 0.9
    A = np.array([[0.0, 0.0], [a, 0.0], [a / 2, np.sqrt(3) * a / 2]])
    for i, beta in enumerate([7 * np.pi / 6, -np.pi / 6, np.pi / 2]):
        E = X55[:, :2] + rho_E * np.column_stack([np.cos(beta + X55[:, 2]),
                                                  np.sin(beta + X55[:, 2])])
        d = E - A[i]
        u = np.arctan2(d[:, 1], d[:, 0])
        v = -np.arccos((np.hypot(d[:, 0], d[:, 1]) - r2) / (2 * r1))
        th = e.th[:, i] - (u - v)
        # measured 5e-10 rad: the file's 10 significant digits
        np.testing.assert_allclose((th + np.pi) % (2 * np.pi) - np.pi, 0, atol=5e-9)


# ---------------------------------------------------------------------------------------------
# Malformed files: one test per kind
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("header, match", [
    ("time,x,y", r"missing column\(s\) phi.*required: time, x, y, phi"),
    ("time,x,y,theta", r"unknown column 'theta'.*allowed names: time, x, y, phi"),
    ("time,x,y,phi,th_1", "th_1, th_2, th_3 come as a set"),
    ("time,x[inch],y,phi", r"unknown length unit 'inch'.*allowed: m, mm"),
], ids=["missing column", "misnamed column", "incomplete angle set", "unknown unit"])
def test_bad_header_names_the_column(tmp_path, header, match):
    """A column missing, misnamed, incomplete or in an unknown unit: the error names it and
    what is allowed (the columns as many as the header names: time, x, y, phi, then th_1)."""
    t, x, y, phi = _good_rows()
    _refused(tmp_path, header, [t, x, y, phi, t][:header.count(",") + 1], match)


def test_unit_option_contradicting_file(tmp_path):
    t, x, y, phi = _good_rows()
    _refused(tmp_path, "time,x[mm],y[mm],phi", [t, x * 1e3, y * 1e3, phi],
             "declared in 'mm' by the file but 'm' was given", length_unit="m")


def test_duplicated_time(tmp_path):
    t, x, y, phi = _good_rows()
    t[4] = t[3]
    # header is line 1, sample k (0-based) is line k + 2: the duplicate is line 6
    _refused(tmp_path, "time,x,y,phi", [t, x, y, phi], r"line 6: duplicated time")


def test_decreasing_time(tmp_path):
    t, x, y, phi = _good_rows()
    t[5] = t[2]
    _refused(tmp_path, "time,x,y,phi", [t, x, y, phi], r"line 7: time decreases")


def test_nan_rows_reported_with_lines_and_dropped_only_if_asked(tmp_path):
    t, x, y, phi = _good_rows(10)
    text = _table("time,x,y,phi", [t, x, y, phi]).splitlines()
    text[3] = f"{t[2]:.10g},nan,{y[2]:.10g},{phi[2]:.10g}"  # line 4
    text[7] = f"{t[6]:.10g},{x[6]:.10g},,{phi[6]:.10g}"  # line 8, an empty cell
    path = _write(tmp_path, "\n".join(text) + "\n")
    with pytest.raises(DataError, match=r"lines 4, 8: NaN.*drop_nan=True"):
        pj.load_csv(path)
    e = pj.load_csv(path, drop_nan=True)
    assert e.n == 8 and e.dropped_lines == (4, 8)
    assert not np.any(np.isin(e.ts, [t[2], t[6]]))


def test_unreadable_number(tmp_path):
    t, x, y, phi = _good_rows()
    text = _table("time,x,y,phi", [t, x, y, phi]).splitlines()
    text[2] = text[2].replace(text[2].split(",")[1], "0.5O")
    with pytest.raises(DataError, match=r"line 3, column 'x': cannot read '0.5O'"):
        pj.load_csv(_write(tmp_path, "\n".join(text) + "\n"))


def test_millimetres_read_as_metres(tmp_path):
    t, x, y, phi = _good_rows(scale=1e3)
    _refused(tmp_path, "time,x,y,phi", [t, x, y, phi], "probably millimetres read as metres")


def test_pose_1000_times_too_small(tmp_path):
    t, x, y, phi = _good_rows(scale=1e-3)
    _refused(tmp_path, "time,x,y,phi", [t, x, y, phi], "probably wrong units")


def test_degrees_read_as_radians(tmp_path):
    t, x, y, phi = _good_rows(phi_scale=180 / math.pi * 5)  # up to 20 deg, read as rad
    # 20 could be degrees or milliradians: both named
    _refused(tmp_path, "time,x,y,phi", [t, x, y, phi],
             "probably degrees or milliradians read as radians")


def test_milliradians_read_as_radians(tmp_path):
    # up to 350 mrad: beyond 90, so not degrees (it was called "probably degrees")
    t, x, y, phi = _good_rows(phi_scale=1000 * 5)
    assert 90 < np.max(np.abs(phi)) < 1000 * math.pi / 2
    _refused(tmp_path, "time,x,y,phi", [t, x, y, phi], "probably milliradians read as radians")


def test_milliseconds_read_as_seconds(tmp_path):
    """100 Hz stamped in ms, undeclared: a median step of 10 "s" is refused before a fit (it
    once fitted for minutes); declared, the same file reads."""
    t, x, y, phi = _good_rows()
    with pytest.raises(DataError, match=r"f.csv: the median time step is 10 s \(0.1 Hz\).*"
                                        r"probably milliseconds read as seconds"):
        pj.load_csv(_write(tmp_path, _table("time,x,y,phi", [t * 1e3, x, y, phi])))
    e = pj.load_csv(_write(tmp_path, _table("time,x,y,phi", [t * 1e3, x, y, phi]), "g.csv"),
                    time_unit="ms")
    np.testing.assert_allclose(e.ts, t, atol=1e-15)


def test_a_gap_is_refused_as_the_path_loaders_refuse_it(tmp_path):
    """Forty 100 Hz samples missing (0.4 s): refused naming the line after the gap and its time,
    with the path loaders' message; max_gap=None accepts the uneven file."""
    t, x, y, phi = _good_rows(40)
    t[20:] += 0.4
    text = _table("time,x,y,phi", [t, x, y, phi])
    with pytest.raises(DataError, match=r"f.csv: line 22 \(t = 0.6 s\): gap of 0.41 s after line "
                                        r"21 \(t = 0.19 s\), more than 10 times the median"):
        pj.load_csv(_write(tmp_path, text))
    path_file = _write(tmp_path, text, "p.csv")
    with pytest.raises(DataError, match=r"p.csv: line 22 \(t = 0.6 s\): gap of 0.41 s"):
        pj.load_path(path_file)
    assert pj.load_csv(_write(tmp_path, text, "h.csv"), max_gap=None).n == 40


def test_too_few_samples(tmp_path):
    t, x, y, phi = _good_rows(3)
    _refused(tmp_path, "time,x,y,phi", [t, x, y, phi], r"too few samples: 3 \(at least 5")


def test_missing_file_and_empty_file(tmp_path):
    with pytest.raises(DataError, match="no such file"):
        pj.load_csv(str(tmp_path / "nope.csv"))
    with pytest.raises(DataError, match=r"a data file is a path \(str or os.PathLike\), got int"):
        pj.load_csv(123)
    with pytest.raises(DataError, match="no such file"):  # a pathlib path is a path
        pj.load_csv(tmp_path / "nope.csv")
    with pytest.raises(DataError, match="no header row"):
        pj.load_csv(_write(tmp_path, "# only a comment\n"))


def test_ragged_row(tmp_path):
    t, x, y, phi = _good_rows()
    text = _table("time,x,y,phi", [t, x, y, phi]) + "0.5,0.55\n"
    with pytest.raises(DataError, match=r"line 10: 2 cells, the header has 4"):
        pj.load_csv(_write(tmp_path, text))


def test_data_error_is_a_ppr_error():
    assert issubclass(DataError, pj.PPRError) and issubclass(DataError, ValueError)


# Encodings and sizes: decode what can be decoded, refuse the rest with a DataError naming the
# file and the encoding tried.

def _good_text():
    t, x, y, phi = _good_rows()
    return "# units: length=m\n" + _table("time,x,y,phi", [t, x, y, phi])


def test_utf8_byte_order_mark_is_not_part_of_the_first_column(tmp_path):
    p = tmp_path / "bom.csv"
    p.write_bytes(b"\xef\xbb\xbf" + _table("time,x,y,phi", list(_good_rows())).encode())
    e = pj.load_csv(str(p))
    np.testing.assert_allclose(e.ts, _good_rows()[0], rtol=0, atol=1e-15)


@pytest.mark.parametrize("encoding", ["utf-16", "utf-16-be", "utf-32"])
def test_utf16_and_utf32_with_byte_order_mark(tmp_path, encoding):
    text = "# tracker export, 20 °C\n" + _good_text()
    bom = {"utf-16-be": "\ufeff"}.get(encoding, "")
    p = tmp_path / "wide.csv"
    p.write_bytes((bom + text).encode(encoding))  # utf-16 / utf-32 write their own mark
    e = pj.load_csv(str(p))
    np.testing.assert_allclose(e.X[:, 0], _good_rows()[1], rtol=1e-15)


def test_latin1_degree_sign_in_a_comment(tmp_path):
    """A Latin-1 byte in a comment (a tracker's "21 °C") goes with the comment, and the rest of
    the file reads as written: the units line after it is honoured (lengths in mm, scaled to m)
    and every value equals the table's, not merely the row count."""
    t, x, y, phi = _good_rows(scale=1e3)  # mm
    p = tmp_path / "latin.csv"
    p.write_bytes("# room at 21 \u00b0C\n".encode("latin-1")
                  + ("# units: length=mm\n" + _table("time,x,y,phi", [t, x, y, phi])).encode())
    e = pj.load_csv(str(p))
    t0, x0, y0, phi0 = _good_rows()
    np.testing.assert_allclose(e.ts, t0, rtol=0, atol=1e-15)
    np.testing.assert_allclose(e.X, np.column_stack([x0, y0, phi0]), rtol=1e-15, atol=0)
    assert e.th is None and e.tau is None


def test_random_bytes_are_refused_naming_file_and_encoding(tmp_path):
    p = tmp_path / "noise.csv"
    p.write_bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    with pytest.raises(DataError, match=r"noise\.csv.*(UTF-8|NUL)"):
        pj.load_csv(str(p))


def test_latin1_outside_comments_and_utf16_without_mark_are_refused(tmp_path):
    p = tmp_path / "badhead.csv"
    p.write_bytes(_good_text().replace("phi", "\u00b0phi").encode("latin-1"))
    with pytest.raises(DataError, match=r"badhead\.csv: line 2 is not UTF-8"):
        pj.load_csv(str(p))
    q = tmp_path / "nomark.csv"
    q.write_bytes(_good_text().encode("utf-16-le"))
    with pytest.raises(DataError, match=r"nomark\.csv: line 1 holds NUL"):
        pj.load_csv(str(q))
    r = tmp_path / "brokenwide.csv"
    r.write_bytes(_good_text().encode("utf-16") + b"\x00\xd8\x41")  # a lone surrogate, odd end
    with pytest.raises(DataError, match=r"brokenwide\.csv.*UTF-16"):
        pj.load_csv(str(r))


def test_file_above_the_size_limit_is_refused_before_reading(tmp_path, monkeypatch):
    from ppr_jax import _data

    assert _data.MAX_FILE_BYTES == 512 * 2**20
    p = tmp_path / "big.csv"
    p.write_text(_good_text())
    monkeypatch.setattr(_data, "MAX_FILE_BYTES", p.stat().st_size - 1)
    opened = []
    real_open = open
    monkeypatch.setattr("builtins.open", lambda *a, **k: opened.append(a) or real_open(*a, **k))
    with pytest.raises(DataError, match=r"big\.csv: .*above the limit"):
        pj.load_csv(str(p))
    assert opened == []


def test_line_above_the_length_limit_is_refused(tmp_path):
    from ppr_jax import _data

    p = tmp_path / "oneline.csv"
    p.write_bytes(b"time,x,y,phi\n" + b"1" * (_data.MAX_LINE_CHARS + 10))
    with pytest.raises(DataError, match=r"oneline\.csv: line 2 is longer than"):
        pj.load_csv(str(p))


def test_nan_in_arrays_is_refused_with_advice_that_fits_arrays():
    """`experiment` from arrays has no drop_nan: its refusal of a NaN row says to remove the row
    (the file readers' drop_nan is named as what drops it from a file)."""
    ts = np.linspace(0.0, 1.0, 10)
    X = np.zeros((10, 3))
    X[3, 0] = np.nan
    with pytest.raises(DataError, match=r"line 4: NaN.*remove those rows from the arrays"):
        pj.experiment(ts, X)
