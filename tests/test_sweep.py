"""Sweeps: batched members equal single runs, failed members are reported and the rest kept,
sharded equals unsharded, the CLI writes its files and resumes.

One short scene (L1 driven by L0's torques, so the radial error is millimetres, not zero) and one
compiled sweep program are shared by the module: the grid mixes equal-links (l3 = l1) and
unequal-links members, unreachable members (a = 3 m: the chains cannot close) and members that
need more solver steps than `MAX_STEPS` (the thickest strip), with a padded last chunk.
"""

import json
import os
import subprocess
import sys
import textwrap

import jax
import numpy as np
import pytest

import ppr_jax as pj
from ppr_jax._cli import main
from ppr_jax._studies import METRICS, design_members
from tests.helpers import env_with_devices

KW = dict(model="reduced", torque_model="rigid", t_end=0.5, n_out=11)
#: the thickest strip needs 38 steps over 0.5 s, the others 16-28
MAX_STEPS = 30
VARY = {"t": [0.25e-3, 0.35e-3, 0.5e-3], "l3": [0.366, 0.40], "a": [0.9, 3.0]}
CHUNK = 4


@pytest.fixture(scope="module")
def program_dir(tmp_path_factory):
    return str(tmp_path_factory.mktemp("programs"))


@pytest.fixture(scope="module")
def swept(program_dir):
    """The module's sweep, through a program store as the command line runs it: its chunk
    programs are exported and compiled from the stored form (checked against single runs
    below); the sweeps without a store compile as usual."""
    return pj.sweep("paper-circle", vary=VARY, chunk_size=CHUNK, max_steps=MAX_STEPS,
                    program_dir=program_dir, **KW)


def _no_export(*a, **k):
    raise AssertionError("traced and exported again instead of loading the stored program")


def _same_rows(rows, ref_rows):
    assert len(rows) == len(ref_rows)
    for r, ref in zip(rows, ref_rows):
        assert set(r) == set(ref)
        for k, v in ref.items():
            assert r[k] == v or (isinstance(v, float) and np.isnan(v) and np.isnan(r[k])), k


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_a_stored_sweep_program_is_loaded_not_traced(swept, program_dir, monkeypatch):
    """The fixture stored one program per group (equal links or not). A later sweep of the
    same setting loads them without tracing (export made to fail): the same rows, bit for bit
    (the same executable); and at other values of the varied parameters (the robot's
    parameters are the program's inputs), rows of those values."""
    import pathlib

    from ppr_jax import _programs

    files = sorted(pathlib.Path(program_dir).glob("sweep-*.jaxexport"))
    assert len(files) == 2, sorted(os.listdir(program_dir))
    monkeypatch.setattr(_programs, "_CACHED", {})
    monkeypatch.setattr(_programs, "_export", _no_export)
    again = pj.sweep("paper-circle", vary=VARY, chunk_size=CHUNK, max_steps=MAX_STEPS,
                     program_dir=program_dir, **KW)
    _same_rows(again.rows, swept.rows)
    other = dict(VARY, t=[0.26e-3, 0.3e-3, 0.34e-3])
    moved = pj.sweep("paper-circle", vary=other, chunk_size=CHUNK, max_steps=MAX_STEPS,
                     program_dir=program_dir, **KW)
    assert [r["t"] for r in moved.rows[::4]] == other["t"]
    ok = [r for r in moved.rows if r["status"] == "ok"]
    assert ok and all(np.isfinite(r["radial_error_max_m"]) for r in ok)
    assert sorted(pathlib.Path(program_dir).glob("sweep-*.jaxexport")) == files


def test_grid_order_and_columns(swept):
    assert len(swept.rows) == 12
    assert swept.varied == ["t", "l3", "a"]
    # the first name varies slowest, the last fastest
    assert [r["a"] for r in swept.rows[:4]] == [0.9, 3.0, 0.9, 3.0]
    assert [r["t"] for r in swept.rows[:4]] == [0.25e-3] * 4
    for r in swept.rows:
        assert set(swept.columns) == set(r)
    arr = swept.to_numpy()
    assert arr.shape == (12,) and arr["member"].tolist() == list(range(12))


def test_failed_members_reported_and_rest_kept(swept):
    by = {r["member"]: r for r in swept.rows}
    # a = 3 m: every chain out of reach, found before running
    for i in (1, 3, 5, 7, 9, 11):
        assert by[i]["status"] == "failed"
        assert "unreachable" in by[i]["reason"]
        assert by[i]["result_code"] == -1
        assert np.isnan(by[i]["radial_error_max_m"])
    # the thickest equal-links strip needs more steps than allowed: a solver failure, named
    assert by[8]["status"] == "failed"
    assert "maximum number of solver steps" in by[8]["reason"]
    assert np.isnan(by[8]["radial_error_min_m"])
    ok = [r["member"] for r in swept.ok]
    assert ok == [0, 2, 4, 6, 10]
    for i in ok:
        assert by[i]["reason"] == "" and by[i]["result_code"] == 0
        assert all(np.isfinite(by[i][m]) for m in METRICS)
        assert 0 < by[i]["num_steps"] <= MAX_STEPS


def test_sweep_members_equal_single_runs(swept):
    """Each member against its own single run, with the metrics computed by the numpy reduction
    of `scene_metrics` (an independent path from the traced metrics). Equal- and unequal-links
    members share the sweep; each group runs the program of its single runs (closed-form or
    Newton inverse kinematics)."""
    base = pj.scene_params("paper-circle")
    for r in swept.ok:
        p = base.replace(t=r["t"], l3=r["l3"], a=r["a"])
        single = pj.paper_circle(p, max_steps=MAX_STEPS, **KW)
        m = pj.scene_metrics(single)
        for k in ("radial_error_max_m", "radial_error_min_m", "radial_error_mean_m",
                  "phi_error_max_rad", "constraint_residual_max_m"):
            np.testing.assert_allclose(r[k], m[k], rtol=1e-7, atol=1e-12, err_msg=k)
        np.testing.assert_allclose(r["torque_peak_Nm"], np.abs(single.tau).max(), rtol=1e-9)
        assert r["num_steps"] == m["num_steps"]
    # the members really differ
    assert len({round(r["radial_error_min_m"], 9) for r in swept.ok}) == len(swept.ok)


def test_latin_hypercube_design():
    d = design_members({"t": [0.2e-3, 0.6e-3], "gamma": (0.80, 0.86)}, "lhs", n=16, seed=3)
    again = design_members({"t": [0.2e-3, 0.6e-3], "gamma": (0.80, 0.86)}, "lhs", n=16, seed=3)
    np.testing.assert_array_equal(d["t"], again["t"])
    for name, (lo, hi) in {"t": (0.2e-3, 0.6e-3), "gamma": (0.80, 0.86)}.items():
        u = (d[name] - lo) / (hi - lo)
        # one member in each of the 16 strata
        assert sorted(np.floor(u * 16).astype(int).tolist()) == list(range(16))
    other = design_members({"t": [0.2e-3, 0.6e-3]}, "lhs", n=16, seed=4)
    assert not np.array_equal(other["t"], d["t"])
    with pytest.raises(pj.PPRError, match="cannot vary 'sigma'"):
        design_members({"sigma": [1, -1]})


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_cli_sweep_writes_files_and_resumes(tmp_path, swept, capsys):
    out = tmp_path / "sw"
    argv = ["sweep", "--scene", "paper-circle", "--model", "reduced", "--torque-model", "rigid",
            "--vary", "t=0.25e-3,0.35e-3,0.5e-3", "--vary", "l3=0.366,0.40", "--vary", "a=0.9,3",
            "--chunk", str(CHUNK), "--t-end", "0.5", "--n-out", "11", "--max-steps",
            str(MAX_STEPS), "--out", str(out)]
    assert main(argv) == 0
    for f in ("sweep.csv", "failed.csv", "summary.json", "metrics_vs_t.png", "metrics_vs_l3.png",
              "metrics_vs_a.png"):
        assert (out / f).stat().st_size > 0, f
    text = capsys.readouterr().out
    assert "12 members, 5 ok, 7 failed" in text
    import csv

    with open(out / "sweep.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 12
    for r, ref in zip(rows, swept.rows):
        assert r["status"] == ref["status"]
        if ref["status"] == "ok":
            np.testing.assert_allclose(float(r["radial_error_min_m"]), ref["radial_error_min_m"],
                                       rtol=1e-12)
    with open(out / "failed.csv") as f:
        failed = list(csv.DictReader(f))
    assert [int(r["member"]) for r in failed] == [1, 3, 5, 7, 8, 9, 11]
    # resume: the first chunk is kept as written, the removed second chunk is run again
    chunks = sorted((out / "chunks").glob("chunk_*.json"))
    assert len(chunks) == 2
    t_first = chunks[0].stat().st_mtime_ns
    chunks[0].write_text(chunks[0].read_text())  # same content, a new mtime to compare against
    t_first = chunks[0].stat().st_mtime_ns
    chunks[1].unlink()
    assert main(argv) == 0
    assert chunks[0].stat().st_mtime_ns == t_first
    assert chunks[1].exists()
    with open(out / "sweep.csv") as f:
        assert list(csv.DictReader(f)) == rows
    # another sweep into the same directory is refused, not mixed in
    argv2 = list(argv)
    argv2[argv2.index("--n-out") + 1] = "12"
    assert main(argv2) == 2
    assert "different sweep" in capsys.readouterr().err


@pytest.mark.parametrize("bad, message", [
    (["--vary", "t=1:2"], "cannot read"),
    (["--vary", "sigma=1,-1"], "cannot vary 'sigma'"),
    (["--vary", "t=0.3e-3:0.4e-3:2", "--lhs", "0"], "--lhs needs N >= 1"),
    ([], "at least one --vary"),
])
def test_cli_sweep_user_errors(tmp_path, capsys, bad, message):
    assert main(["sweep", "--out", str(tmp_path / "x"), *bad]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1


def test_cli_sweep_out_is_a_file(tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("")
    assert main(["sweep", "--vary", "t=0.3e-3,0.4e-3", "--out", str(f)]) == 2
    assert "is a file" in capsys.readouterr().err


SHARDED = textwrap.dedent(
    """
    import json, sys
    import jax
    import ppr_jax as pj
    assert len(jax.devices()) == 2, jax.devices()
    kw, vary, chunk, max_steps, store = json.loads(sys.argv[1])
    r = pj.sweep("paper-circle", vary=vary, chunk_size=chunk, max_steps=max_steps,
                 devices=jax.devices(), program_dir=store, **kw)
    # the stored two-device programs, loaded (no trace) and run again
    from ppr_jax import _programs
    _programs._CACHED.clear()
    def no_export(*a, **k):
        raise AssertionError("traced and exported again instead of loading")
    _programs._export = no_export
    again = pj.sweep("paper-circle", vary=vary, chunk_size=chunk, max_steps=max_steps,
                     devices=jax.devices(), program_dir=store, **kw)
    print(json.dumps([r.rows, again.rows]))
    """
)


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_sharded_sweep_equals_unsharded(swept, tmp_path):
    """The same sweep split over two host devices (shard_map, a local vmap on each) in a fresh
    process, through a program store as the command line runs it (its two-device programs
    exported, then loaded and run again without tracing), member by member against the
    unsharded fixture."""
    env = env_with_devices(2)
    proc = subprocess.run(
        [sys.executable, "-c", SHARDED,
         json.dumps([KW, VARY, CHUNK, MAX_STEPS, str(tmp_path / "programs")])],
        capture_output=True, text=True, timeout=600, env=env,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows, again = json.loads(proc.stdout.strip().splitlines()[-1])
    assert len(list((tmp_path / "programs").glob("sweep-*-2dev-*.jaxexport"))) == 2
    _same_rows(again, rows)
    assert len(rows) == len(swept.rows)
    for r, ref in zip(rows, swept.rows):
        assert r["status"] == ref["status"] and r["reason"] == ref["reason"]
        assert r["num_steps"] == ref["num_steps"]
        for m in METRICS:
            if ref["status"] == "ok":
                np.testing.assert_allclose(r[m], ref[m], rtol=1e-10, atol=1e-12, err_msg=m)


@pytest.mark.slow
def test_chunked_members_equal_the_plain_vmap(swept, monkeypatch):
    """With -m slow (70 s on a 2-core CPU): test_batch's `test_chunked_batch_equals_single_runs`
    checks the members' chunks in the default suite, on the scenes' batch that a sweep runs.

    With chunks of members smaller than a sweep chunk (the scenes' `MEMBER_CHUNK`, here 3 of
    a sweep chunk of 4: a loop over a chunk of 3 and a remainder of 1), every member, failures
    included, equals the sweep of the fixture (whose L1 members, on a CPU, run one after
    another)."""
    import ppr_jax._programs as programs
    import ppr_jax._scenes._batch as scenes

    vmapped = []

    def for_batch(model):
        vmapped.append(model)
        return scenes_for_batch(model)

    scenes_for_batch = scenes.for_batch
    monkeypatch.setattr(scenes, "for_batch", for_batch)  # called on the vmapped path alone
    monkeypatch.setattr(scenes, "MEMBER_CHUNK", 3)
    monkeypatch.setattr(scenes, "LOOP_PLATFORMS", ())  # vmapped, though L1 on a CPU loops
    # trace again with the patched mapper: the stored programs and JAX's traces of the
    # fixture's sweep (same shapes) would hand back the fixture's own program
    monkeypatch.setattr(programs, "_CACHED", {})
    jax.clear_caches()
    again = pj.sweep("paper-circle", vary=VARY, chunk_size=CHUNK, max_steps=MAX_STEPS, **KW)
    assert vmapped, "the sweep did not trace the vmapped path: it compared a program with itself"
    assert len(again.rows) == len(swept.rows)
    for r, ref in zip(again.rows, swept.rows):
        assert (r["status"], r["reason"], r["num_steps"]) == (
            ref["status"], ref["reason"], ref["num_steps"])
        if ref["status"] == "ok":
            # rounding differences only: vectorised, on the generic terms
            for m in METRICS:
                np.testing.assert_allclose(r[m], ref[m], rtol=1e-10, atol=1e-12, err_msg=m)


def test_sweep_of_a_model_that_follows_its_input_warns():
    # L1 under its own torques follows the circle to the solver's tolerance: its radial error
    # columns are the integrator's error, and the sweep says so. (A member with an invalid
    # thickness is reported before anything is compiled, so nothing runs here.)
    with pytest.warns(UserWarning, match="solver's error"):
        r = pj.sweep("paper-circle", vary={"t": [-1e-3]}, model="reduced",
                     torque_model="reduced", t_end=0.1, n_out=3)
    assert len(r.failed) == 1 and not r.ok


def test_option_keywords_of_a_sweep_are_deprecated():
    """The options' fields as `sweep`'s keywords still replace the options' for one release, with
    a `DeprecationWarning` naming them; `options=` alone warns nothing; another keyword is a
    TypeError, as Python's own. (The one member is invalid: nothing is compiled.)"""
    import warnings

    invalid = {"t": [-1e-3]}
    with pytest.warns(DeprecationWarning, match=r"sweep\(n_out=\.\.\., t_end=\.\.\.\) is "
                                                 r"deprecated: pass options=SceneOptions"):
        r = pj.sweep("paper-circle", vary=invalid, t_end=0.1, n_out=3,
                     options=pj.SceneOptions(t_end=0.2))
    assert (r.info["t_end"], r.info["n_out"]) == (0.1, 3)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        r = pj.sweep("paper-circle", vary=invalid, options=pj.SceneOptions(t_end=0.1, n_out=3))
    assert (r.info["t_end"], r.info["n_out"]) == (0.1, 3)
    with pytest.raises(TypeError, match="sweep.. got an unexpected keyword argument 't_stop'"):
        pj.sweep("paper-circle", vary=invalid, t_stop=0.1)


def test_resume_recomputes_a_chunk_that_fails_its_checks(tmp_path, swept, monkeypatch):
    """The issue's reproducer: a member's value edited in a finished chunk must not reach the
    result; the chunk is named once and computed afresh. A chunk of another library version (or
    source) is recomputed too; other settings are still refused."""
    from ppr_jax._studies import _sweep

    d = tmp_path / "chunks"
    kw = dict(vary=VARY, chunk_size=CHUNK, max_steps=MAX_STEPS, checkpoint_dir=str(d), **KW)
    first = pj.sweep("paper-circle", **kw)
    chunk = d / "chunk_00000.json"
    text = chunk.read_text()
    data = json.loads(text)
    rows = data["rows"] if isinstance(data, dict) else data
    j = next(j for j, r in enumerate(rows) if r["status"] == "ok")
    rows[j]["radial_error_max_m"] = 999  # the edit of the issue, checksum left as was
    chunk.write_text(json.dumps(data))
    with pytest.warns(pj.RepairWarning, match="chunk_00000.json.*checksum") as rec:
        again = pj.sweep("paper-circle", **kw)
    assert len([w for w in rec if issubclass(w.category, pj.RepairWarning)]) == 1
    assert 999 not in again.column("radial_error_max_m")
    assert again.rows == first.rows or all(
        a == b or (a != a and b != b) for ra, rb in zip(again.rows, first.rows)
        for a, b in zip(ra.values(), rb.values()))
    # the checksum now matches again: the next rerun uses every chunk without a word
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", pj.RepairWarning)
        pj.sweep("paper-circle", **kw)
    # chunks of another ppr_jax (or its source, or a dependency): every one recomputed
    lib = _sweep.library_digest()
    monkeypatch.setattr(_sweep, "library_digest", lambda: dict(lib, versions="ppr_jax=0.0.1"))
    with pytest.warns(pj.RepairWarning, match="another ppr_jax") as rec:
        pj.sweep("paper-circle", **kw)
    assert len([w for w in rec if issubclass(w.category, pj.RepairWarning)]) == 2
    assert json.loads(chunk.read_text())["digest"] != json.loads(text)["digest"]
    with pytest.raises(pj.PPRError, match="different sweep"):
        pj.sweep("paper-circle", **dict(kw, t_end=0.4))


def test_damaged_sweep_settings_are_rewritten_and_chunks_still_checked(tmp_path, monkeypatch):
    """A damaged `chunks/sweep_settings.json` (cut short, not JSON, not an object, no digest)
    blocked every resume (an unnamed JSON error or an AttributeError). It is named in one
    `RepairWarning` and rewritten; the chunks, which carry their own digest, are still used.
    The settings are written atomically: a write that fails midway leaves the old file whole.
    Other settings are still refused. The store alone: nothing is compiled."""
    import warnings

    from ppr_jax._studies import _sweep

    info = {"scene": "paper-circle", "vary": {"t": [3e-4, 4e-4]}}
    d = tmp_path / "chunks"
    rows = [{"member": 0, "status": "ok", "radial_error_max_m": 1.5e-4},
            {"member": 1, "status": "ok", "radial_error_max_m": 2.5e-4}]
    _sweep._ChunkStore(str(d), info).save(0, [0, 1], rows)
    settings = d / "sweep_settings.json"
    good = json.loads(settings.read_text())
    for damaged in (b'{"digest": "ab', b"", b"\xff\xfe", b"[1, 2]", b'{"digest": 3}', b"{}"):
        settings.write_bytes(damaged)
        with pytest.warns(pj.RepairWarning, match="sweep_settings.json are damaged") as rec:
            store = _sweep._ChunkStore(str(d), info)
        assert len([w for w in rec if issubclass(w.category, pj.RepairWarning)]) == 1, damaged
        assert json.loads(settings.read_text()) == good
        with warnings.catch_warnings():
            warnings.simplefilter("error", pj.RepairWarning)
            assert store.load(0, [0, 1]) == rows  # the chunk proves itself
    assert sorted(os.listdir(d)) == ["chunk_00000.json", "sweep_settings.json"]

    def fail_midway(obj, f, **kw):
        f.write('{"digest": ')
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(_sweep.json, "dump", fail_midway)
    with pytest.raises(OSError):
        _sweep._ChunkStore(str(d), info)
    monkeypatch.undo()
    assert json.loads(settings.read_text()) == good  # the old file, whole
    with pytest.raises(pj.PPRError, match="different sweep"):
        _sweep._ChunkStore(str(d), dict(info, scene="servo-circle"))


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_a_member_whose_path_crosses_a_singularity_is_refused_before_running():
    """The sweep's validation is the scenes' check of a path (`_kinematics.path_margins`): on
    servo-circle with a = 0.6 m, l1 = l3 = 0.45 m, the path of the platform side h = 0.15 m
    crosses a type-II singularity of L1 (det S changes sign between two samples, none of them
    singular: tests/test_design.py re-derives the crossing from `inverse_kinematics`' S), and
    that member is refused with the reason, h = 0.1 m kept. Host-side: no scene is run."""
    from ppr_jax._studies import validate_members

    base = pj.scene_params("servo-circle").replace(a=0.6, l1=0.45, l3=0.45)
    plist, reasons = validate_members("servo-circle", base, {"h": [0.1, 0.15]}, t_end=7.54)
    assert reasons[0] == "" and plist[0] is not None
    assert plist[1] is None and reasons[1].startswith(
        "singular configuration along the nominal path"), reasons


@pytest.mark.parametrize("loop", [True, False], ids=["one-after-another", "vmapped"])
def test_a_members_run_takes_the_batch_mappers_terms(monkeypatch, loop):
    """A sweep's members are mapped as a scene's batch is (`map_members`): on a CPU, members of
    L1 run one after another on the fused equations of motion, as single runs do; vmapped (here
    forced by leaving no loop platform), they take the generic ones (`for_batch`: faster under
    vmap; `test_sweep_members_equal_single_runs` compares the members with single runs). The
    run itself is replaced here: only the model it is handed is checked."""
    import ppr_jax._programs as programs
    import ppr_jax._scenes._batch as scenes_batch
    from ppr_jax._dynamics import has_fused_terms
    from ppr_jax._studies._evaluation import Evaluation

    seen = []

    def run(self, robot, options=None):
        seen.append(self.ctx.model)
        return {m: robot.params.t * 0.0 for m in self.metrics}, 0, 0

    monkeypatch.setattr(Evaluation, "run", run)
    monkeypatch.setattr(scenes_batch, "LOOP_PLATFORMS", ("cpu",) if loop else ())
    monkeypatch.setattr(programs, "_CACHED", {})
    # one slice (no host threads), chunks of one and of two members: each traced afresh, with
    # the patched mapping
    monkeypatch.setattr(scenes_batch, "host_cores", lambda: 1)
    ts = [0.3e-3] if loop else [0.3e-3, 0.31e-3]
    res = pj.sweep("paper-circle", vary={"t": ts}, chunk_size=len(ts), **KW)
    assert [r["status"] for r in res.rows] == ["ok"] * len(ts)
    assert seen and all(m.name == "reduced" and has_fused_terms(m) == loop for m in seen)
    assert has_fused_terms(pj.get_model("reduced"))
