"""A batch split over host threads (`_host_split.HostSplit`) equals the batch run whole, member by
member, failures included."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ppr_jax as pj
from ppr_jax._host_split import HostSplit


def _double(x, shared, y):
    return {"x": 2 * x["a"] + shared, "n": x["b"].sum(axis=-1), "y": y[: x["a"].shape[0]]}


def test_slices_run_apart_and_join_in_the_members_order():
    """Seven members in three slices (strided, the last padded with a repeat of member 6): the
    joined result is the whole batch's, the repeat dropped; an array of another argument whose
    leading axis happens to have the batch's length, and an array of length 1 (a shared one),
    go to every slice whole; under `jax.jit` (traced arguments) the whole batch runs as one
    program; `lower(...).compile()` gives a callable of the whole batch's arguments."""
    fn = jax.jit(_double)
    x = {"a": jnp.arange(7.0), "b": jnp.arange(14.0).reshape(7, 2), "c": jnp.ones(1)}
    shared, y = jnp.float64(0.5), jnp.arange(7.0) * 10
    split = HostSplit(fn, parts=3, batch=7, argnum=0)
    assert split.size == 3
    parts = split.slices((x, shared, y))
    assert [p[0]["a"].tolist() for p in parts] == [[0, 3, 6], [1, 4, 6], [2, 5, 6]]
    assert all(p[0]["c"].shape == (1,) and p[2].shape == (7,) for p in parts)
    want = {"x": 2 * x["a"] + shared, "n": x["b"].sum(axis=-1)}
    for got in (split(x, shared, y), split.lower(x, shared, y).compile()(x, shared, y),
                jax.jit(split)(x, shared, y)):
        np.testing.assert_array_equal(got["x"], want["x"])
        np.testing.assert_array_equal(got["n"], want["n"])
    # the traced call is the whole batch's own: y cut by the whole batch's length
    np.testing.assert_array_equal(jax.jit(split)(x, shared, y)["y"], y)
    with pytest.raises(ValueError, match="parts must be in"):
        HostSplit(fn, parts=8, batch=7, argnum=0)


@pytest.fixture(scope="module")
def split_batch(params):
    """(robots, the batch's result split over two threads, the same batch run whole): five L1
    robots (an odd batch: the second slice is padded), member 3 unreachable."""
    from ppr_jax._scenes import _batch
    from ppr_jax._scenes._run import _JIT_BATCH, prepare

    robots = [params.replace(t=t) for t in (0.3e-3, 0.33e-3, 0.36e-3)]
    robots += [params.replace(a=3.0), params.replace(t=0.39e-3)]
    batch = pj.stack_params(robots)
    opts = pj.SceneOptions(t_end=0.4, n_out=9)
    mp = pytest.MonkeyPatch()
    mp.setattr(_batch, "host_cores", lambda: 2)  # as on the 2-core CI machine, on any machine
    try:
        c = prepare("paper-circle", batch, "reduced", opts)
        assert isinstance(c.fn, HostSplit) and c.fn.parts == 2
        split = pj.paper_circle(batch, model="reduced", options=opts, throw=False)
    finally:
        mp.undo()
    whole = jax.block_until_ready(_JIT_BATCH(*c.args))
    return robots, split, whole


def test_a_split_batch_equals_the_whole_batch(split_batch, params):
    """Every array of the result equals the unsplit batch's exactly (the same program body per
    member), the unreachable member fails alone, and a kept member equals its single run."""
    robots, split, whole = split_batch
    flat_s, def_s = jax.tree_util.tree_flatten(split)
    flat_w, def_w = jax.tree_util.tree_flatten(whole)
    assert def_s == def_w
    for a, b in zip(flat_s, flat_w):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert list(split.failures()) == [3]
    single = pj.paper_circle(robots[4], model="reduced", t_end=0.4, n_out=9)
    np.testing.assert_allclose(split.X[4], single.X, rtol=0, atol=1e-12)
    assert int(split.num_steps[4]) == int(single.num_steps)


def test_a_split_batch_names_its_failing_member(params, monkeypatch, tmp_path):
    """Raised through the split (and through `run_scene`'s compiled program, stored and loaded
    as the command line does): the failing member is named by its place in the whole batch."""
    from ppr_jax._scenes import _batch

    monkeypatch.setattr(_batch, "host_cores", lambda: 2)
    robots = [params.replace(t=0.3e-3), params.replace(t=0.33e-3), params.replace(a=3.0)]
    batch = pj.stack_params(robots)
    opts = pj.SceneOptions(t_end=0.2, n_out=5)
    with pytest.raises(pj.SimulationError, match=r"1 of 3 batch members\): member 2"):
        pj.paper_circle(batch, model="reduced", options=opts)
    for _ in range(2):  # exported, then loaded
        with pytest.raises(pj.SimulationError, match=r"member 2"):
            pj.run_scene("paper-circle", batch, model="reduced", options=opts,
                         program_dir=str(tmp_path))


def test_a_cpu_splits_one_slice_a_core_and_a_gpu_not(monkeypatch):
    """On a CPU, one slice a core this process may use, at most one a member; any model (L3's
    vmapped chunks run on about one core too). A GPU takes the whole batch at once."""
    from ppr_jax._scenes import _batch

    class Device:
        def __init__(self, platform):
            self.platform = platform

    monkeypatch.setattr(_batch, "host_cores", lambda: 4)
    cpu = (Device("cpu"),)
    assert _batch.host_parts(64, cpu) == 4
    assert _batch.host_parts(3, cpu) == 3
    assert _batch.host_parts(1, cpu) == 1
    assert _batch.host_parts(64, (Device("gpu"),)) == 1
    monkeypatch.setattr(_batch, "host_cores", lambda: 1)
    assert _batch.host_parts(64, cpu) == 1


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_a_split_l3_batch_equals_single_runs(params, monkeypatch):
    """Quasi-static L3 (N = 4), whose members run vmapped in each slice: three robots in two
    slices (the second padded) equal their single runs."""
    from ppr_jax._scenes import _batch

    monkeypatch.setattr(_batch, "host_cores", lambda: 2)
    robots = [params.replace(t=t) for t in (0.3e-3, 0.34e-3, 0.38e-3)]
    model, opts = pj.QuasiStaticBeam(4), pj.SceneOptions(t_end=0.05, n_out=6)
    res = pj.paper_circle(pj.stack_params(robots), model=model, options=opts)
    for i, robot in enumerate(robots):
        single = pj.paper_circle(robot, model=model, options=opts)
        np.testing.assert_allclose(res.X[i], single.X, rtol=0, atol=1e-10)
        np.testing.assert_allclose(res.z[i], single.z, rtol=0, atol=1e-9)
