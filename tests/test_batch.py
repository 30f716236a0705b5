"""vmap over a batch of robots equals a Python loop; batch failures name the failing members."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ppr_jax as pj
from ppr_jax._errors import raise_if
from tests.helpers import raises_in_compiled_code


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_vmapped_scene_equals_python_loop(params, paper_circle_L1):
    ts = [0.3e-3, 0.35e-3, 0.4e-3]
    batch = pj.stack_params([params.replace(t=t) for t in ts])
    # A model mismatch makes the runs differ: simulate L2 would be costly here, so drive L1 with
    # the torques of each robot and compare against single runs of the same compiled scene.
    res = pj.paper_circle(batch, model="reduced", t_end=2.0)
    assert res.X.shape == (3, 755, 3)
    for i, t in enumerate(ts):
        single = pj.paper_circle(params.replace(t=t), model="reduced", t_end=2.0)
        # the same pytree, one member of it
        assert jax.tree_util.tree_structure(single) == jax.tree_util.tree_structure(res)
        np.testing.assert_allclose(res.X[i], single.X, rtol=0, atol=1e-12)
        np.testing.assert_allclose(res.tau[i], single.tau, rtol=1e-12, atol=1e-14)
    # different thicknesses really give different torques
    assert float(jnp.abs(res.tau[0] - res.tau[2]).max()) > 1e-3


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_scene_under_user_vmap_equals_batched_call(params):
    """The public scene entry is traceable: jax.vmap over it gives the batched call's result."""
    ts = jnp.array([0.3e-3, 0.4e-3])
    batch = pj.stack_params([params.replace(t=float(t)) for t in ts])
    ref = pj.paper_circle(batch, model="reduced", t_end=0.5, n_out=6)
    got = jax.vmap(lambda t: pj.paper_circle(params.replace(t=t), model="reduced", t_end=0.5,
                                             n_out=6))(ts)
    np.testing.assert_allclose(got.X, ref.X, rtol=0, atol=1e-12)
    m = pj.scene_metrics(ref)
    assert isinstance(m, list) and len(m) == 2 and m[0]["num_steps"] > 0


def test_batched_inverse_kinematics_names_failing_members(params):
    X = jnp.array([[0.45, 0.26, 0.0], [1.6, 0.2, 0.0], [0.5, 0.3, 0.0], [-0.8, 0.1, 0.0]])
    with pytest.raises(pj.PPRError, match=r"unreachable pose.*2 batch members: \[1, 3\]"):
        pj.inverse_kinematics(params, X)
    ok = pj.inverse_kinematics(params, X[jnp.array([0, 2])])
    assert ok.th.shape == (2, 3, 3)


def test_batched_solver_failures_name_members(params):
    """A real solver failure in a batch: L1 driven by its own torques on eq 55, four strip
    thicknesses, a step limit of 60 that the thin strips (12-15 steps over 0.5 s) stay under
    and the stiff 1.8 and 2 mm strips (about 100 steps: K grows as t^3) run out of. The error
    names members 1 and 3 and why; the other members' results are kept, on the circle of eq 55
    (a robot driven by its own inverse-dynamics torques follows it to the solver tolerance)."""
    ts = [0.3e-3, 2.0e-3, 0.35e-3, 1.8e-3]
    batch = pj.stack_params([params.replace(t=t) for t in ts])
    kw = dict(model="reduced", t_end=0.5, n_out=6, max_steps=60)
    res = pj.paper_circle(batch, throw=False, **kw)
    assert list(res.failures()) == [1, 3]
    codes = [int(res.result._value[i]) for i in range(4)]
    assert codes == [0, int(pj.RESULTS.max_steps_reached._value)] * 2
    wt = 5 / 6 * np.linspace(0.0, 0.5, 6)  # eq 55 at the output times
    X55 = np.column_stack([0.45 + 0.1 * np.cos(wt), 0.15 * np.sqrt(3) + 0.1 * np.sin(wt),
                           -0.05 * np.sin(wt)])
    for i in (0, 2):
        np.testing.assert_allclose(res.X[i], X55, rtol=0, atol=1e-9)
    with pytest.raises(pj.SimulationError,
                       match=r"2 of 4 batch members\): member 1: The maximum number of solver "
                             r"steps.*; member 3: The maximum number of solver steps") as info:
        pj.paper_circle(batch, **kw)
    kept = info.value.result
    for i in (0, 2):
        np.testing.assert_array_equal(kept.X[i], res.X[i])


def test_raise_if_traced_uses_equinox_runtime_error():
    import jax

    f = jax.jit(lambda x: raise_if(x, x < 0, "x must be >= 0"))
    assert float(f(1.0)) == 1.0
    with raises_in_compiled_code("x must be >= 0"):
        jax.block_until_ready(f(-1.0))


@pytest.mark.parametrize("loop", [pytest.param(False, marks=pytest.mark.slow), True],
                         ids=["vmapped-chunks", "one-after-another"])
def test_chunked_batch_equals_single_runs(params, monkeypatch, loop):
    """Vmapped (forced here by leaving no loop platform), a batch larger than `MEMBER_CHUNK`
    runs as a loop over chunks of vmapped members (here chunks of 2, 2 and a remainder of 1);
    on a CPU, by default, L1's members run one after another (`loops_members`). Either way
    every member equals its own single run, with its own steps, and an unreachable member
    fails alone."""
    import ppr_jax._scenes._batch as scenes

    monkeypatch.setattr(scenes, "MEMBER_CHUNK", 2)
    monkeypatch.setattr(scenes, "LOOP_PLATFORMS", ("cpu",) if loop else ())
    monkeypatch.setattr(scenes, "host_cores", lambda: 1)  # the whole batch in one program
    ts = [0.3e-3, 0.32e-3, 0.34e-3, 0.36e-3] + ([0.38e-3] if loop else [])
    robots = [params.replace(t=t) for t in ts] + [params.replace(a=3.0)]
    # a fresh batch size (5 vmapped, 6 one after another), so the patched mapping is traced
    # rather than taken from a cache
    res = pj.paper_circle(pj.stack_params(robots), model="reduced", t_end=0.4, n_out=9,
                          throw=False)
    assert list(res.failures()) == [len(ts)]
    for i, t in enumerate(ts):
        single = pj.paper_circle(params.replace(t=t), model="reduced", t_end=0.4, n_out=9)
        np.testing.assert_allclose(res.X[i], single.X, rtol=0, atol=1e-12)
        np.testing.assert_allclose(res.tau[i], single.tau, rtol=1e-12, atol=1e-14)
        assert int(res.num_steps[i]) == int(single.num_steps)


def test_arrays_all_members_share_run_unbatched(params):
    """A batch's robot keeps one copy of each array its members share (`compress_shared`),
    which `map_members` hands to every member unbatched: exactly the arrays that are equal in
    the members' own robots are cut to one. The members differ in a mass (strip thickness)
    and, for one, in a length, so the geometry is shared by some arrays only. That every
    member of such a batch still equals its single run (a member that took another's array
    would not) is what `test_vmapped_scene_equals_python_loop` and
    `test_chunked_batch_equals_single_runs` check, and the sweep's tests for its chunks."""
    from ppr_jax._robot import Robot
    from ppr_jax._scenes._run import prepare

    members = [params.replace(t=0.3e-3), params.replace(t=0.36e-3),
               params.replace(t=0.33e-3, l3=float(params.l3) * 1.01)]
    c = prepare("paper-circle", pj.stack_params(members), "reduced", pj.SceneOptions())
    singles = [jax.tree_util.tree_leaves(Robot(p)) for p in members]
    leaves = jax.tree_util.tree_leaves(c.args[2])
    n_shared = 0
    for k, leaf in enumerate(leaves):
        equal = all(np.array_equal(np.asarray(s[k]), np.asarray(singles[0][k])) for s in singles)
        assert leaf.shape[0] == (1 if equal else 3), k
        n_shared += equal
    assert 0 < n_shared < len(leaves)
    # identical members: one array keeps the batch's length
    c = prepare("paper-circle", pj.stack_params([members[0]] * 2), "reduced", pj.SceneOptions())
    assert max(x.shape[0] for x in jax.tree_util.tree_leaves(c.args[2])) == 2
