"""Exported scene programs (`ppr_jax._programs`): a stored program gives the results of the
usual compile, for any parameter values, its key is the same in a fresh process and changes with
everything the trace depends on, and a damaged or unstorable program falls back to the usual
compile."""

import os
import pathlib
import subprocess
import sys

import diffrax
import jax
import numpy as np
import pytest

import ppr_jax as pj
from ppr_jax import _programs
from ppr_jax._programs import DEPENDENCIES, MAGIC, NotExportable, program_key
from ppr_jax._scenes import SceneOptions, prepare

ROOT = pathlib.Path(__file__).resolve().parents[1]
#: a short scene: the program is the full scene's, its run is short
KW = dict(model="rigid", t_end=0.1, n_out=11)


def _call(scene="paper-circle", params=None, model="rigid", **over):
    kw = dict(t_end=0.1, n_out=11)
    kw.update(over)
    return prepare(scene, params, model, SceneOptions(**kw))


def _programs_in(d):
    """The stored programs of a store directory (beside them: their executables)."""
    return sorted(pathlib.Path(d).glob("*.jaxexport"))


def _executables_in(d):
    return sorted(pathlib.Path(d).glob("*.jaxexec"))


def _same(a, b):
    la = jax.tree_util.tree_leaves(a.result)
    lb = jax.tree_util.tree_leaves(b.result)
    assert len(la) == len(lb)
    for x, y in zip(la, lb):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-13, atol=1e-15)


@pytest.fixture(scope="module")
def direct():
    """The usual compile, the reference."""
    return {t: pj.run_scene("paper-circle", pj.scene_params("paper-circle", t=t), **KW)
            for t in (0.3e-3, 0.35e-3)}


def test_stored_program_equals_the_usual_compile(tmp_path, direct):
    d = str(tmp_path / "programs")
    first = pj.run_scene("paper-circle", **KW, program_dir=d)
    assert first.timing["program"] == "exported"
    assert len(_programs_in(d)) == 1
    _same(first, direct[0.3e-3])
    # Another thickness is another input, not another program: loaded, and its own results.
    second = pj.run_scene("paper-circle", pj.scene_params("paper-circle", t=0.35e-3), **KW,
                          program_dir=d)
    assert second.timing["program"] == "loaded"
    assert len(_programs_in(d)) == 1
    _same(second, direct[0.35e-3])
    assert second.metrics["radial_error_max_m"] != first.metrics["radial_error_max_m"]

    # A damaged file is exported afresh over, not trusted.
    (path,) = _programs_in(d)
    path.write_bytes(b"not a program")
    with pytest.warns(_programs.RepairWarning, match="no ppr_jax program header"):
        third = pj.run_scene("paper-circle", **KW, program_dir=d)
    assert third.timing["program"] == "exported"
    _same(third, direct[0.3e-3])


def _flip(path: pathlib.Path, start: float = 1 / 3, n: int = 64) -> None:
    """Invert n bytes from `start` (a fraction of the size) on: a same-size damage."""
    b = bytearray(path.read_bytes())
    i = int(len(b) * start)
    b[i:i + n] = bytes(x ^ 0xFF for x in b[i:i + n])
    path.write_bytes(bytes(b))


def _repaired(d, direct, path):
    """One run over a damaged store: one RepairWarning naming the file, exported afresh, the
    usual results, and a sound file left behind (the next run loads it without a word)."""
    with pytest.warns(_programs.RepairWarning, match=str(path.name)) as rec:
        r = pj.run_scene("paper-circle", **KW, program_dir=d)
    assert len([w for w in rec if issubclass(w.category, _programs.RepairWarning)]) == 1
    assert r.timing["program"] == "exported"
    _same(r, direct[0.3e-3])
    assert path.read_bytes().startswith(MAGIC)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", _programs.RepairWarning)
        again = pj.run_scene("paper-circle", **KW, program_dir=d)
    assert again.timing["program"] == "loaded"
    _same(again, direct[0.3e-3])


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_a_damaged_program_is_named_deleted_and_exported_afresh(tmp_path, direct):
    d = str(tmp_path / "programs")
    pj.run_scene("paper-circle", **KW, program_dir=d)
    (path,) = _programs_in(d)
    good = path.read_bytes()
    # The reproducer: 64 bytes flipped a third of the way in (same size). Before the
    # checksum, deserialisation accepted it and the compile failed on every later run.
    _flip(path)
    _repaired(d, direct, path)
    # A file whose checksum was rewritten to match its damaged program: caught where it fails
    # to deserialise or to compile.
    payload = bytearray(good[len(MAGIC) + 65:])
    i = len(payload) // 3
    payload[i:i + 64] = bytes(x ^ 0xFF for x in payload[i:i + 64])
    path.write_bytes(_programs._pack(bytes(payload)))
    _repaired(d, direct, path)
    # A program stored without the header (an older layout under the same name).
    path.write_bytes(good[len(MAGIC) + 65:])
    _repaired(d, direct, path)


@pytest.fixture
def fresh_compiles(monkeypatch):
    """Programs compiled under a persistent-cache key of their own (a nonce in JAX's
    `custom_hook`), so that this test's compilations miss the shared test cache: an
    executable is stored only from a fresh compilation. Calling the fixture's value draws a
    new nonce."""
    import uuid

    from jax._src import cache_key

    def renew():
        nonce = uuid.uuid4().hex
        monkeypatch.setattr(cache_key, "custom_hook", lambda: nonce)

    renew()
    return renew


def test_a_stored_executable_is_loaded_and_a_damaged_one_repaired(tmp_path, direct,
                                                                  fresh_compiles,
                                                                  monkeypatch):
    """Beside the program its executable: a later run loads it, not the program (the usual
    results, another thickness too); a program exported afresh drops the executables of the one
    it replaces; a damaged executable is named and deleted, and the program compiled."""
    import warnings

    d = str(tmp_path / "programs")
    pj.run_scene("paper-circle", **KW, program_dir=d)
    (xpath,) = _executables_in(d)
    (path,) = _programs_in(d)
    assert xpath.name.startswith(path.name[:-len(".jaxexport")])
    assert xpath.read_bytes().startswith(_programs.EXEC_MAGIC)

    def no_program(*a, **k):
        raise AssertionError("the program was read, not its executable")

    with monkeypatch.context() as m, warnings.catch_warnings():
        m.setattr(_programs, "_load", no_program)
        warnings.simplefilter("error", _programs.RepairWarning)
        r = pj.run_scene("paper-circle", pj.scene_params("paper-circle", t=0.35e-3), **KW,
                         program_dir=d)
    assert r.timing["program"] == "loaded"
    _same(r, direct[0.35e-3])

    # the program exported afresh (here: a damaged program, compiled under a new key): its old
    # executable goes, the new program's is stored
    fresh_compiles()
    path.write_bytes(b"not a program")
    with pytest.warns(_programs.RepairWarning, match="no ppr_jax program header"):
        r = pj.run_scene("paper-circle", **KW, program_dir=d)
    assert r.timing["program"] == "exported"
    (new,) = _executables_in(d)
    assert new != xpath
    _same(r, direct[0.3e-3])

    # a flipped byte: the checksum catches it; the program is loaded and compiled (no
    # executable stored from a persistent-cache hit: `test_no_executable_from_...`)
    _flip(new)
    with pytest.warns(_programs.RepairWarning, match=f"executable {new}") as rec:
        r = pj.run_scene("paper-circle", **KW, program_dir=d)
    assert len([w for w in rec if issubclass(w.category, _programs.RepairWarning)]) == 1
    assert r.timing["program"] == "loaded"
    _same(r, direct[0.3e-3])
    if not jax.config.jax_compilation_cache_dir:
        assert _executables_in(d) == [new]
        assert new.read_bytes().startswith(_programs.EXEC_MAGIC)


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_a_read_only_store_with_a_damaged_executable(tmp_path, direct, fresh_compiles,
                                                     monkeypatch):
    """A store that cannot be written (read-only) holding a damaged executable: every run says
    so once, without claiming a deletion that did not happen, keeps the file, and runs the
    stored program (no trace, no full compile) to the usual results. Read-only is simulated
    (the tests may run as root, whom the permission bits do not stop): deleting and writing in
    the store fail with EACCES."""
    import errno
    import warnings

    d = str(tmp_path / "programs")
    pj.run_scene("paper-circle", **KW, program_dir=d)  # a fresh compile: executable stored
    (xpath,) = _executables_in(d)
    _flip(xpath)
    damaged = xpath.read_bytes()

    remove = os.remove

    def refuse(path, *a, **k):
        if not str(path).startswith(d):  # JAX's own files: as usual
            return remove(path, *a, **k)
        raise PermissionError(errno.EACCES, "Permission denied", str(path))

    def not_traced(*a, **k):
        raise AssertionError("the program was traced again: the store was not used")

    monkeypatch.setattr(os, "remove", refuse)
    monkeypatch.setattr(_programs, "_write", refuse)
    monkeypatch.setattr(_programs, "_export", not_traced)
    for _ in range(2):
        with warnings.catch_warnings(record=True) as rec:
            warnings.simplefilter("always")
            r = pj.run_scene("paper-circle", **KW, program_dir=d)
        said = [str(w.message) for w in rec if issubclass(w.category, _programs.RepairWarning)]
        assert len(said) == 1, said
        assert str(xpath) in said[0] and "read-only" in said[0], said
        assert "deleted and" not in said[0], said
        assert r.timing["program"] == "loaded"
        _same(r, direct[0.3e-3])
        assert xpath.read_bytes() == damaged


def test_a_program_that_cannot_be_stored_is_traced_once(tmp_path, direct, monkeypatch):
    """A store that cannot be written (read-only, full): the program exported for it runs all
    the same, unstored; the scene is traced once, not exported and then compiled again."""
    import errno

    traces = []
    export = _programs._export

    def counted(*a, **k):
        traces.append(1)
        return export(*a, **k)

    def full(path, data):
        raise OSError(errno.ENOSPC, "No space left on device", path)

    monkeypatch.setattr(_programs, "_export", counted)
    monkeypatch.setattr(_programs, "_write", full)
    r = pj.run_scene("paper-circle", **KW, program_dir=str(tmp_path / "programs"))
    assert r.timing["program"] == "exported" and len(traces) == 1
    assert _programs_in(tmp_path / "programs") == []
    _same(r, direct[0.3e-3])


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_no_executable_from_a_persistent_cache_hit(tmp_path, direct, fresh_compiles):
    """An executable read from JAX's persistent cache serialises incompletely (it then fails
    when run): a program whose compilation was a cache hit stores none, and later runs load the
    program and give the usual results."""
    if not jax.config.jax_compilation_cache_dir:
        pytest.skip("no persistent compilation cache in this run")
    d = str(tmp_path / "programs")
    pj.run_scene("paper-circle", **KW, program_dir=d)  # compiled: cached, executable stored
    assert len(_executables_in(d)) == 1
    d2 = str(tmp_path / "programs2")  # the same program again: a persistent-cache hit
    assert pj.run_scene("paper-circle", **KW, program_dir=d2).timing["program"] == "exported"
    assert _executables_in(d2) == []
    again = pj.run_scene("paper-circle", pj.scene_params("paper-circle", t=0.35e-3), **KW,
                         program_dir=d2)
    assert again.timing["program"] == "loaded"
    assert _executables_in(d2) == []
    _same(again, direct[0.35e-3])


def test_key_holds_the_versions_of_ppr_jax_and_its_numerical_dependencies(monkeypatch):
    assert set(DEPENDENCIES) == {"ppr_jax", "jax", "jaxlib", "diffrax", "equinox", "optimistix",
                                 "lineax"}
    versions = _programs.dependency_versions()
    for name in DEPENDENCIES:
        assert f"{name}=" in versions
    base = program_key(_call().args, "x")
    for name in DEPENDENCIES:
        bumped = versions.replace(f"{name}=", f"{name}=9")
        monkeypatch.setattr(_programs, "dependency_versions", lambda b=bumped: b)
        assert program_key(_call().args, "x") != base, name
    monkeypatch.undo()


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_key_is_the_same_in_a_fresh_process():
    script = ("from ppr_jax._scenes import SceneOptions, prepare; "
              "from ppr_jax._programs import program_key; "
              "c = prepare('paper-circle', None, 'rigid', SceneOptions(t_end=0.1, n_out=11)); "
              "print(program_key(c.args, 'x'))")
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True,
                         text=True, timeout=300, check=True).stdout.split()[-1]
    assert out == program_key(_call().args, "x")


def test_key_follows_what_the_trace_depends_on():
    base = program_key(_call().args, "x")
    # numbers are inputs: same program
    assert program_key(_call(rtol=1e-6, t_end=0.2).args, "x") == base
    assert program_key(_call(params=pj.scene_params("paper-circle", t=0.4e-3)).args, "x") == base
    # shapes, structure and static choices are not
    assert program_key(_call(n_out=12).args, "x") != base
    assert program_key(_call(solver="dopri5").args, "x") != base
    assert program_key(_call(model="reduced").args, "x") != base
    assert program_key(_call(params=pj.scene_params("paper-circle", l3=0.1)).args, "x") != base
    assert (program_key(_call(model=pj.Beam(8)).args, "x")
            != program_key(_call(model=pj.Beam(10)).args, "x"))
    assert program_key(_call().args, "y") != base


def test_key_leaves_out_labels_and_defaults(tmp_path):
    """Equal programs key alike: a field given its default value (`Beam(4, strip_loss=0.0)` is
    `Beam(4)`), and a path read from another file of the same shape (its name is a label,
    `label_field`; its knots are inputs). What changes the program still changes the key: a
    damped beam, the spline's boundary condition, the number of knots."""
    assert (program_key(_call(model=pj.Beam(4, strip_loss=0.0)).args, "x")
            == program_key(_call(model=pj.Beam(4)).args, "x"))
    assert (program_key(_call(model=pj.Beam(4, strip_loss=1e-4)).args, "x")
            != program_key(_call(model=pj.Beam(4)).args, "x"))

    def key(name, n=21, bc="natural", amp=0.05):
        ts = np.linspace(0.0, 1.0, n)
        X = np.column_stack([0.45 + amp * np.sin(2 * np.pi * ts), 0.26 + 0 * ts, 0 * ts])
        path = tmp_path / name
        np.savetxt(path, np.column_stack([ts, X]), delimiter=",", header="time,x,y,phi",
                   comments="", fmt="%.17g")
        scene = pj.PathScene(pj.load_path(str(path), bc=bc), drive="torque", name=name)
        return program_key(_call(scene).args, "x")

    base = key("run1.csv")
    assert key("run2.csv", amp=0.07) == base
    assert key("run3.csv", bc="clamped") != base
    assert key("run4.csv", n=22) != base


def test_a_closure_in_the_static_arguments_is_not_stored():
    norm = lambda x: jax.numpy.max(jax.numpy.abs(x))  # noqa: E731
    c = _call(controller=diffrax.PIDController(rtol=1e-8, atol=1e-10, norm=norm))
    with pytest.raises(NotExportable):
        program_key(c.args, "x")


LAPACK = """
import json, sys
import jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)
from ppr_jax import _programs

def fn(a, b):
    return jnp.linalg.solve(a, b)

a = jnp.array([[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]])
b = jnp.array([1.0, 2.0, 3.0])
run, how = _programs.load_or_export(fn, (a, b), b, sys.argv[1], "lapack")
print(json.dumps({"how": how, "x": np.asarray(run(a, b)).tolist()}))
"""


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_an_executable_with_lapack_calls_loads_in_a_fresh_process(tmp_path):
    """A program with LAPACK custom calls (jnp.linalg.solve): its executable, loaded in a
    process that has lowered nothing (so jaxlib has not initialised LAPACK; without
    `_prepare_targets` the run crashes), solves as numpy does."""
    import json

    d = tmp_path / "programs"
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(("JAX_COMPILATION_CACHE", "JAX_PERSISTENT_CACHE"))}
    env.update(PYTHONPATH=str(ROOT), JAX_PLATFORMS="cpu")

    def run():
        p = subprocess.run([sys.executable, "-c", LAPACK, str(d)], env=env, capture_output=True,
                           text=True, timeout=300)
        assert p.returncode == 0, p.stderr[-3000:]
        return json.loads(p.stdout.strip().splitlines()[-1])

    first = run()
    assert first["how"] == "exported"
    (xpath,) = _executables_in(d)
    head = _programs._unpack(xpath.read_bytes(), _programs.EXEC_MAGIC).split(b"\n", 1)[0]
    assert any(t.startswith("lapack_") for t in json.loads(head)["targets"])
    second = run()
    assert second["how"] == "loaded"
    a = np.array([[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]])
    np.testing.assert_allclose(second["x"], np.linalg.solve(a, [1.0, 2.0, 3.0]), rtol=1e-14)


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_identification_program_is_stored_and_loaded(tmp_path, monkeypatch):
    """`identify(program_dir=...)` (the command line passes its store): the fit's
    residual-and-Jacobian program is exported once; a later fit of the same structure and
    shapes, other data included, loads it without tracing (export is made to fail here), and
    every fit equals the usual compile's to rounding. The two experiments have other names
    (their files', a label): one program. L0 torque-driven, 0.3 s."""
    truth = pj.scene_params("paper-circle")
    kw = dict(model="rigid", scene="paper-circle", noise=(5e-6, 5e-5),
              fit_options=pj.FitOptions(starts=1),
              initial={"t": 0.8 * float(truth.t)})
    exps = [pj.synthesize("paper-circle", "rigid", truth, noise_pos=5e-6, noise_phi=5e-5,
                          rate=100, t_end=0.3, seed=s, name=f"run{s}") for s in (0, 1)]
    d = str(tmp_path / "programs")
    # each phase as a fresh process would run it: nothing compiled kept from the one before
    monkeypatch.setattr(_programs, "_CACHED", {})
    usual = [pj.identify(e, ("t",), **kw) for e in exps]
    monkeypatch.setattr(_programs, "_CACHED", {})
    stored = pj.identify(exps[0], ("t",), program_dir=d, **kw)
    files = list(pathlib.Path(d).glob("identify-rigid-*.jaxexport"))
    assert len(files) == 1, sorted(os.listdir(d))

    def no_export(*a, **k):
        raise AssertionError("traced and exported again instead of loading the stored program")

    monkeypatch.setattr(_programs, "_CACHED", {})
    monkeypatch.setattr(_programs, "_export", no_export)
    loaded = [pj.identify(e, ("t",), program_dir=d, **kw) for e in exps]
    assert list(pathlib.Path(d).glob("identify-rigid-*.jaxexport")) == files
    for a, b in zip([stored, *loaded], [usual[0], *usual]):
        np.testing.assert_allclose(a.estimate, b.estimate, rtol=1e-12)
        np.testing.assert_allclose(a.std, b.std, rtol=1e-9)
        assert a.history["iterations"] == b.history["iterations"]
    assert abs(usual[1].estimate[0] - usual[0].estimate[0]) > 1e-3 * usual[0].std[0]


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_sensitivity_programs_are_stored_and_loaded(tmp_path, monkeypatch):
    """`sensitivity(program_dir=...)` (the command line passes its store): the Jacobian's
    program (which gives the metrics' values too) is exported once, and the metrics' own
    program only when `evaluate` is first called; a later call of the same setting, at another
    nominal robot, loads them without tracing (export made to fail), and every result equals
    the usual compile's."""
    kw = dict(model="rigid", parameters=("t", "gamma"), metrics=("radial_error_max_m",),
              t_end=0.1, n_out=11)
    p0 = pj.scene_params("paper-circle")
    p1 = p0.replace(t=0.35e-3)
    d = str(tmp_path / "programs")
    monkeypatch.setattr(_programs, "_CACHED", {})
    usual = [pj.sensitivity("paper-circle", p, **kw) for p in (p0, p1)]
    monkeypatch.setattr(_programs, "_CACHED", {})
    stored = pj.sensitivity("paper-circle", p0, program_dir=d, **kw)
    files = sorted(pathlib.Path(d).glob("sensitivity-*.jaxexport"))
    assert len(files) == 1, sorted(os.listdir(d))  # the forward Jacobian, values its primal
    x0 = [stored.param_values[n] for n in stored.parameters]
    assert stored.evaluate(x0) == pytest.approx(list(stored.values.values()), rel=1e-13)
    files = sorted(pathlib.Path(d).glob("sensitivity-*.jaxexport"))
    assert len(files) == 2, sorted(os.listdir(d))  # and now the values' own program

    def no_export(*a, **k):
        raise AssertionError("traced and exported again instead of loading the stored program")

    monkeypatch.setattr(_programs, "_CACHED", {})
    monkeypatch.setattr(_programs, "_export", no_export)
    loaded = [pj.sensitivity("paper-circle", p, program_dir=d, **kw) for p in (p0, p1)]
    assert loaded[0].evaluate(x0) == pytest.approx(list(stored.values.values()), rel=1e-13)
    assert sorted(pathlib.Path(d).glob("sensitivity-*.jaxexport")) == files
    for a, b in zip([stored, *loaded], [usual[0], *usual]):
        np.testing.assert_allclose(a.jacobian, b.jacobian, rtol=1e-12)
        assert a.values == pytest.approx(b.values, rel=1e-13)
    assert abs(usual[1].jacobian[0, 0] / usual[0].jacobian[0, 0] - 1) > 1e-3


def test_cached_program_steps_aside_under_a_transformation(tmp_path, monkeypatch):
    """Called with traced arguments (`jax.grad`, `jax.jit` of a caller, as `modes` inside a
    user's derivative), `cached_program` returns the function itself, which composes with the
    transformation: the derivative is exact and nothing is stored."""
    import equinox as eqx
    import jax.numpy as jnp

    @eqx.filter_jit
    def fn(a, x):
        return jnp.sum(a * jnp.sin(x))

    monkeypatch.setattr(_programs, "_CACHED", {})
    a, x = jnp.asarray([1.0, 2.0]), jnp.asarray([0.3, 0.7])
    d = str(tmp_path / "programs")

    def f(x):
        return _programs.cached_program(fn, (a, x), 0, d, "t")(a, x)

    np.testing.assert_allclose(np.asarray(jax.grad(f)(x)), np.asarray(a * jnp.cos(x)),
                               rtol=1e-15)
    np.testing.assert_allclose(float(jax.jit(f)(x)), float(f(x)), rtol=1e-15)
    assert len(_programs._CACHED) == 1 and len(_programs_in(d)) == 1  # the plain call's only


def test_cached_program_is_keyed_by_static_values(monkeypatch):
    """`cached_program` reuses a compilation only for the same static values, not merely the
    same structure and shapes: a Python float among the static leaves (as a controller's
    coefficients are) is part of the program."""
    import equinox as eqx
    import jax.numpy as jnp

    class Scaled(eqx.Module):
        k: float  # a static leaf: traced into the program as a constant

    @eqx.filter_jit
    def fn(m, x):
        return m.k * x

    monkeypatch.setattr(_programs, "_CACHED", {})
    x = jnp.ones(3)
    for k in (2.0, 3.0, 2.0):
        run = _programs.cached_program(fn, (Scaled(k), x), 0, None, "t")
        np.testing.assert_array_equal(np.asarray(run(Scaled(k), x)), k * np.ones(3))
    assert len(_programs._CACHED) == 2


def _path_scene(d, amp):
    """A torque-driven scene on a file's path: an ellipse of half-axes (amp, amp/2) m sampled at
    21 knots, written as d/path.csv (the same name in every directory: a re-measured path)."""
    ts = np.linspace(0.0, 1.0, 21)
    w = 2 * np.pi * ts
    X = np.column_stack([0.45 + amp * np.sin(w), 0.26 + 0.5 * amp * (1 - np.cos(w)),
                         0.02 * np.sin(w)])
    os.makedirs(d, exist_ok=True)
    path = os.path.join(d, "path.csv")
    np.savetxt(path, np.column_stack([ts, X]), delimiter=",", header="time,x,y,phi",
               comments="", fmt="%.17g")
    return pj.PathScene(pj.load_path(path, bc="natural"), drive="torque", name="file")


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_design_programs_are_stored_and_loaded(tmp_path, monkeypatch):
    """`design(program_dir=...)` (the command line passes its store): the metrics with their
    Jacobian, the batch and the metrics' sizes are stored once; a design on another path of
    the same shape (its spline's knots are the programs' inputs, not constants) loads them
    without tracing anything (the metrics' function made to fail), and each design equals the
    usual compile's. Lightest links with a reach margin of 0.3 along the path: the margin binds,
    so the optimum moves with the path."""
    from ppr_jax._studies._design import _problem

    kw = dict(options=pj.SceneOptions(t_end=1.0, n_out=11), starts=1, candidates=8, grid=16,
              l3_elements=None)
    spec = ({"l1": (0.25, 0.45), "l3": (0.25, 0.45)}, {"minimize": "moving_mass_kg"},
            [pj.Constraint("path_reach_margin", lower=0.3)])
    scenes = [_path_scene(str(tmp_path / f"p{a}"), a) for a in (0.05, 0.12)]
    d = str(tmp_path / "programs")

    def fresh():  # each phase as a fresh process would run it
        monkeypatch.setattr(_programs, "_CACHED", {})
        monkeypatch.setattr(_problem, "_SIZES", {})

    fresh()
    usual = [pj.design(*spec, scene=s, **kw) for s in scenes]
    fresh()
    stored = pj.design(*spec, scene=scenes[0], program_dir=d, **kw)
    names = sorted(os.listdir(d))
    exported = [n.rsplit("-", 1)[0] for n in names if n.endswith(".jaxexport")]
    assert exported == ["design-file-batch", "design-file-fwd"], names
    assert len([n for n in names if n.startswith("design-sizes-")]) == 1, names

    def no_trace(*a, **k):
        raise AssertionError("traced the metrics again instead of loading the stored programs")

    fresh()
    monkeypatch.setattr(_programs, "_export", no_trace)
    monkeypatch.setattr(_problem, "_raw_blocks", no_trace)
    loaded = [pj.design(*spec, scene=s, program_dir=d, **kw) for s in scenes]
    assert sorted(os.listdir(d)) == names
    for a, b in zip([stored, *loaded], [usual[0], *usual]):
        assert a.verification["ok"], a.summary()
        for n in ("l1", "l3"):
            np.testing.assert_allclose(a.x[n], b.x[n], rtol=1e-10, err_msg=n)
        assert a.objective["value"] == pytest.approx(b.objective["value"], rel=1e-12)
        (reach,) = [c for c in a.constraints if c["metric"] == "path_reach_margin"]
        assert reach["active"], a.summary()
    assert abs(loaded[1].x["l1"] / loaded[0].x["l1"] - 1) > 0.1


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_modes_torques_and_synth_programs_are_stored_and_loaded(tmp_path, monkeypatch):
    """`ppr-jax modes`, `torques` and `synth` store their programs too (`program_dir`): a
    second call at other parameter values loads them without tracing (export made to fail),
    and every result equals the usual compile's."""
    from ppr_jax._scenes import nominal_torques

    model = pj.get_model("double1r")
    p0 = pj.RobotParams()
    p1 = p0.replace(t=0.35e-3)
    d = str(tmp_path / "programs")

    def calls(params, program_dir):
        m = pj.modes(model, params, program_dir=program_dir)
        ts, tau = nominal_torques(params, t_end=0.1, n_out=11, program_dir=program_dir)
        exp = pj.synthesize("paper-circle", "rigid", params, rate=100.0, t_end=0.1,
                            program_dir=program_dir)
        return np.asarray(m.freq_hz), tau, exp.X, exp.th

    monkeypatch.setattr(_programs, "_CACHED", {})
    usual = [calls(p, None) for p in (p0, p1)]
    monkeypatch.setattr(_programs, "_CACHED", {})
    stored = calls(p0, d)
    labels = sorted({n.rsplit("-", 1)[0] for n in os.listdir(d) if n.endswith(".jaxexport")})
    assert labels == ["modes-double1r-locked", "paper-circle-rigid", "synth-angles-rigid",
                      "torques-reduced"], labels

    def no_export(*a, **k):
        raise AssertionError("traced and exported again instead of loading the stored program")

    monkeypatch.setattr(_programs, "_CACHED", {})
    monkeypatch.setattr(_programs, "_export", no_export)
    loaded = [calls(p, d) for p in (p0, p1)]
    for a, b in zip([stored, *loaded], [usual[0], *usual]):
        for x, y in zip(a, b):
            np.testing.assert_allclose(x, y, rtol=1e-12, atol=1e-15)
    assert abs(usual[1][0][0] / usual[0][0][0] - 1) > 1e-3
