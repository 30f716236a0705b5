"""Files written whole or not at all (`ppr_jax._files`): a write that fails (a full disk, a
file-size limit) names the file, leaves no truncated file under its name and no temporary beside
it, and keeps what stood there before; the command line says so in its one line (exit 2)."""

import contextlib
import errno
import os

import pytest

from ppr_jax._cli import main
from ppr_jax._files import save_figure, write_file


def _full_disk_after(f, n):
    """Write n bytes to `f`, then fail as a full disk does: an OSError naming no file."""
    f.write("x" * n)
    f.flush()
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_a_full_disk_names_the_file_and_leaves_none(tmp_path):
    path = tmp_path / "report.html"
    with pytest.raises(OSError) as err:
        with write_file(path) as f:
            _full_disk_after(f, 5000)
    assert err.value.errno == errno.ENOSPC and err.value.filename == str(path)
    assert "No space left on device" in str(err.value) and "not written" in str(err.value)
    assert os.listdir(tmp_path) == []  # neither the file nor a temporary
    # an earlier file of that name stays as it was
    path.write_text("the earlier report\n")
    with pytest.raises(OSError, match="No space left on device"):
        with write_file(path) as f:
            _full_disk_after(f, 5000)
    assert path.read_text() == "the earlier report\n"
    assert os.listdir(tmp_path) == ["report.html"]
    # any other error while writing leaves nothing either, and is raised as it was
    with pytest.raises(KeyError):
        with write_file(tmp_path / "other.csv") as f:
            f.write("t,x\n")
            raise KeyError("x")
    assert os.listdir(tmp_path) == ["report.html"]


def test_a_written_file_is_whole_with_the_usual_permissions(tmp_path):
    path = tmp_path / "rows.csv"
    with write_file(path, "w", newline="") as f:
        f.write("t,x\r\n0,1\r\n")
    assert path.read_bytes() == b"t,x\r\n0,1\r\n"
    with write_file(path, "wb") as f:
        f.write(b"\x00\x01")
    assert path.read_bytes() == b"\x00\x01"
    umask = os.umask(0)
    os.umask(umask)
    assert os.stat(path).st_mode & 0o777 == 0o666 & ~umask
    assert os.listdir(tmp_path) == ["rows.csv"]
    with pytest.raises(ValueError, match="mode"):
        with write_file(path, "a"):
            pass
    # a directory that is not there: named
    with pytest.raises(FileNotFoundError) as err:
        with write_file(tmp_path / "absent" / "x.json"):
            pass
    assert err.value.filename == str(tmp_path / "absent" / "x.json")


@contextlib.contextmanager
def _file_size_limit():
    """A real write failure of the kernel, in this process: files may grow to 4 kB only
    (RLIMIT_FSIZE; Python ignores the SIGXFSZ that comes with it, so a write past the limit
    fails with EFBIG, "File too large", an OSError naming no file as a full disk's does).
    Nothing may compile meanwhile: JAX's persistent cache would write its entries under it."""
    resource = pytest.importorskip("resource")
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    resource.setrlimit(resource.RLIMIT_FSIZE, (4096, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))


def test_the_command_line_names_the_file_it_could_not_write(tmp_path, capsys, monkeypatch):
    """The commands' shared writers under a real write failure: one line naming the file, exit
    2, and no truncated file left under the name. A command that writes its rows with the
    shared CSV writer (the command is replaced: nothing is computed) and `prb-table --figure`
    (run once without the limit first: its small programs compiled before it)."""
    from ppr_jax._cli import _common, _torques

    def writes_rows(args):
        os.makedirs(args.out, exist_ok=True)
        rows = [{"t": k * 1e-3, "tau_1": 0.1234567890123 * k} for k in range(2000)]
        _common._write_rows(os.path.join(args.out, "torques.csv"), rows, ["t", "tau_1"])
        return 0

    monkeypatch.setattr(_torques, "cmd_torques", writes_rows)
    out = tmp_path / "run"
    with _file_size_limit():
        assert main(["torques", "--out", str(out)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err == [f"ppr-jax: error: {out / 'torques.csv'}: not written (File too large)"], err
    assert os.listdir(out) == []

    png = tmp_path / "prb.png"
    assert main(["prb-table", "--figure", str(tmp_path / "first.png")]) == 0
    assert (tmp_path / "first.png").stat().st_size > 4096
    capsys.readouterr()
    with _file_size_limit():
        assert main(["prb-table", "--figure", str(png)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err == [f"ppr-jax: error: {png}: not written (File too large)"], err
    assert not png.exists()


def test_save_figure_writes_the_format_of_its_name(tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(1, 1))
    try:
        assert save_figure(fig, tmp_path / "a.png", dpi=20) == str(tmp_path / "a.png")
        save_figure(fig, tmp_path / "a.svg")
    finally:
        plt.close(fig)
    assert (tmp_path / "a.png").read_bytes().startswith(b"\x89PNG")
    assert b"<svg" in (tmp_path / "a.svg").read_bytes()[:500]
