"""The fused equations of motion of L0-L2 (`ppr_jax/_models/fused.py`) against the generic
projection (`_dynamics._eom_terms`, vmapped JVPs of the kinematics), which stays the reference:
the terms M, h, Q, Jth and the accelerations at random states, and their forward (JVP) and
reverse (VJP) derivatives with respect to the state and to the robot's parameters.

Two robots: the defaults (centre-line joints) and one with every term of the fused formulas
switched on (the strip geometry's fixed link offsets, spring damping, actuator friction, rotor
inertia). One compiled program per model, robot and formulation evaluates a batch of states."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ppr_jax as pj
import ppr_jax._scenes._batch as scenes_batch
from ppr_jax._dynamics import (
    EOM,
    _eom_terms,
    accelerations,
    eom_terms,
    for_batch,
    has_fused_terms,
)
from ppr_jax._geometry import home_pose
from ppr_jax._scenes import map_members
from tests.helpers import (
    EOM_MODELS as MODELS,
    EOM_PARAMS as PARAMS,
    EOM_ROBOTS as ROBOTS,
    eom_states as _states,
    relative_close as _close,
)


def _fused(model, robot, z, zd):
    kin, M, h, Q, Jth, JX = model.fused_eom(robot, z, zd)
    return EOM(M=M, h=h, Q_passive=Q, Jth=Jth, JX=JX, kin=kin)


def _generic(model, robot, z, zd):
    return _eom_terms(model, robot, z, zd, implicit=True)


def _program(model, eom_fn):
    """One compiled program: at a batch of states, the terms, z'' and its JVP along a random
    direction of (z, z', parameters) and its VJP (state and parameters)."""

    def terms(values, params, z, zd, tau):
        robot = pj.Robot(params.replace(**dict(zip(PARAMS, values))))
        eom = eom_fn(model, robot, z, zd)
        zdd = accelerations(eom, tau, jnp.array([0.3, -0.2, 0.05]))
        return zdd, (eom.M, eom.h, eom.Q_passive, eom.Jth, eom.JX)

    def one(values, params, z, zd, tau, dv, dz, dzd, ct):
        f = lambda v, a, b: terms(v, params, a, b, tau)[0]  # noqa: E731
        zdd, rest = terms(values, params, z, zd, tau)
        _, tangent = jax.jvp(f, (values, z, zd), (dv, dz, dzd))
        _, pull = jax.vjp(f, values, z, zd)
        return zdd, rest, tangent, pull(ct)

    return jax.jit(jax.vmap(one, in_axes=(None, None, 0, 0, 0, 0, 0, 0, 0)))


def _pairs():
    # The default tier keeps L2 on the all-terms robot: it shares the double-1R bodies, offsets
    # and springs with L1 and the damping and friction with L0, and every model's fused terms
    # meet an independent formulation there too (test_paper_eom: the Lagrangian by autodiff and
    # the paper's closed form). The other pairs run in the second tier.
    for m in MODELS:
        for r in ROBOTS:
            slow = not (m == "double1r" and r != "default")
            yield pytest.param((m, r), id=f"{m}-{r}",
                               marks=[pytest.mark.slow] if slow else [])


@pytest.fixture(scope="module", params=list(_pairs()))
def pair(request):
    name, robot_name = request.param
    model, params = pj.get_model(name), ROBOTS[robot_name]
    values, args = _states(model, params, seed=MODELS.index(name) * 10 + len(robot_name))
    fused = _program(model, _fused)(values, params, *args)
    generic = _program(model, _generic)(values, params, *args)
    return name, fused, generic


def test_terms_and_accelerations(pair):
    name, fused, generic = pair
    for what, a, b in zip(("M", "h", "Q_passive", "Jth", "JX"), fused[1], generic[1]):
        _close(a, b, f"{name} {what}")
    _close(fused[0], generic[0], f"{name} z''")
    # the comparison is not vacuous: the states move and the terms are not zero
    assert np.abs(np.asarray(generic[1][1])).max() > 0
    assert np.abs(np.asarray(generic[0])).max() > 0


def test_forward_mode(pair):
    name, fused, generic = pair
    _close(fused[2], generic[2], f"{name} JVP of z''")


def test_reverse_mode(pair):
    name, fused, generic = pair
    for what, a, b in zip(("parameters", "z", "z'"), fused[3], generic[3]):
        # per parameter: their derivatives differ by orders of magnitude (E against t)
        a, b = np.asarray(a), np.asarray(b)
        if what == "parameters":
            for k, p in enumerate(PARAMS):
                _close(a[:, k], b[:, k], f"{name} VJP of z'' w.r.t. {p}")
        else:
            _close(a, b, f"{name} VJP of z'' w.r.t. {what}")


def test_the_simulator_uses_the_fused_terms():
    """`eom_terms` (every right-hand side, statics, modes) takes the fused path for L0-L2 and the
    generic one for L3 (which has no `chain_spec`)."""
    robot = pj.Robot(ROBOTS["default"])
    for name in MODELS:
        model = pj.get_model(name)
        z = model.coords_from_pose(robot, home_pose(robot))
        assert model.fused_eom(robot, z, jnp.zeros_like(z)) is not None
    assert pj.get_model("beam").fused_eom(robot, None, None) is None
    # a vmapped batch's program takes the generic terms (faster under vmap; test_batch.py
    # compares its members with single runs, which take the fused ones), decided before tracing
    for name in MODELS:
        model = pj.get_model(name)
        assert has_fused_terms(model) and not has_fused_terms(for_batch(model))
        assert for_batch(model) != model and type(for_batch(model)) is type(model)
    beam = pj.get_model("beam")
    # a model without fused terms keeps its terms; every batch member integrates with diffrax
    # (`AbstractModel.batch_member`, `_lean.py`)
    assert for_batch(beam).fused == beam.fused and for_batch(beam).batch_member
    assert not beam.batch_member
    # the one batch mapper hands every member the batch's model, wherever it sits in the shared
    # arguments (a scene's batch passes the model, a sweep its `Evaluation`'s context): on a
    # CPU, members of fused models run one after another with the models unchanged; with L3
    # among them, or where members are vmapped (here: no loop platform), every model as a
    # vmapped batch takes it
    def seen_by(shared, loop_platforms=("cpu",)):
        seen = []

        def member(one, shared):
            seen.extend(shared)
            return one

        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(scenes_batch, "LOOP_PLATFORMS", loop_platforms)
            map_members(member)(jnp.zeros(2), shared)
        return [s["m"] if isinstance(s, dict) else s for s in seen]

    fused = [pj.get_model("double1r"), {"m": pj.get_model("rigid")}]
    assert jax.default_backend() == "cpu"
    assert [has_fused_terms(m) for m in seen_by(fused)] == [True, True]
    assert [m.batch_member for m in seen_by(fused)] == [False, False]
    assert [has_fused_terms(m) for m in seen_by(fused, ())] == [False, False]
    with_l3 = seen_by([pj.get_model("double1r"), {"m": beam}])
    assert not has_fused_terms(with_l3[0]) and all(m.batch_member for m in with_l3)


#: what a batch's members differ in: their state, or one parameter
BATCHINGS = ("state", *PARAMS)


def _batched_terms(eom_fn, model, params, batching):
    """The terms of two members that differ in `batching`, as a function of the parameters'
    values and the states, vmapped inside whatever differentiates it (a derivative of a batched
    program: identification's Jacobian over its experiments, a sweep's sensitivities)."""

    @jax.jit
    def member(values, z, zd):
        # the terms used inside the same program, as a right-hand side uses them
        eom = eom_fn(model, pj.Robot(params.replace(**dict(zip(PARAMS, values)))), z, zd)
        zdd = accelerations(eom, eom.Jth[:, 0], eom.JX[0])
        return eqx.tree_at(lambda e: e.h, eom, eom.h + zdd)

    def terms(values, z, zd):
        values = tuple(values[i] for i in range(len(PARAMS)))  # one input a parameter
        if batching == "state":
            return jax.vmap(member, in_axes=(None, 0, 0))(values, z[:2], zd[:2])
        # only this parameter is batched: a custom derivative's batching is decided per input
        k = PARAMS.index(batching)
        members = (*values[:k], values[k] * jnp.array([1.0, 1.01]), *values[k + 1:])
        axes = tuple(0 if i == k else None for i in range(len(PARAMS)))
        return jax.vmap(member, in_axes=(axes, None, None))(members, z[0], zd[0])

    return terms


def _jvp_of(f):
    return lambda values, z, zd, dv, dz, dzd: jax.jvp(f, (values, z, zd), (dv, dz, dzd))[1]


def _grad_of(f):
    def loss(values, z, zd):
        eom = f(values, z, zd)
        return sum(jnp.sum(jnp.sin(x)) for x in (eom.M, eom.h, eom.Q_passive, eom.Jth, eom.JX))

    return jax.grad(loss, argnums=(0, 1, 2))


def _used(model, robot, z, zd):
    return eom_terms(model, robot, z, zd)


# L0 and L1 in the second tier: L2's terms hold every kind of term of theirs (the pairs above
# compare all three models' values)
@pytest.mark.parametrize("name", [
    pytest.param(m, marks=[pytest.mark.slow]) for m in MODELS])  # second tier: the batch's
    # generic terms meet single runs in the default tier (test_batch)
def test_derivatives_of_batched_terms(name):
    """The simulator's terms (`eom_terms`: the fused primal, M, h and Q differentiated through the
    generic projection) under `vmap` inside a derivative, the members differing in their state or
    in one parameter (one batched input each). JAX fixes a custom derivative's batching from its
    primal, and a rule whose output is batched where the primal's is not fails to trace (L2's Jth
    is constant in the fused terms and a function of the state in the generic ones). Every
    batching is traced in forward mode, the batch of states in reverse mode too; L2's batch of
    states is evaluated against the generic projection."""
    model, params = pj.get_model(name), ROBOTS["default"]
    values, (z, zd, _, dv, dz, dzd, _) = _states(model, params, seed=7)
    args = (values, z, zd, dv[0], dz, dzd)
    for batching in BATCHINGS:
        f = _batched_terms(_used, model, params, batching)
        jax.eval_shape(_jvp_of(f), *args)
        if batching == "state":  # reverse mode transposes the same rule (its tracing is costly)
            jax.eval_shape(_grad_of(f), *args[:3])
    if name != "double1r":
        return  # L2's terms, whose Jth the two formulations compute differently, are evaluated
    used, generic = (jax.jit(_jvp_of(_batched_terms(fn, model, params, "state")))(*args)
                     for fn in (_used, _generic))
    for what in ("M", "h", "Q_passive", "Jth", "JX"):
        _close(getattr(used, what), getattr(generic, what), f"{name} d{what}")
