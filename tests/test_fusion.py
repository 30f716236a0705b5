"""`materialize` (`ppr_jax/_fusion.py`): values that XLA's CPU compiler computes once.

Its values are its argument's (a negative zero aside), exactly; for derivatives it is the
identity; under `vmap` a batched value, and a value the members share (the primal of a
forward-mode Jacobian), is still computed once; and in a compiled program a sine that several
kernels read is computed once. `tangents_once` changes no value or derivative.
On the models: one unbatched right-hand side of L0-L2 (the fused equations of motion)
computes no more sines and cosines than it traces, and its accelerations equal the generic
projection's (the batched comparison in `test_fused_eom.py` runs under `vmap`)."""

import re

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ppr_jax as pj
from ppr_jax._dynamics import _eom_terms, accelerations, eom_terms
from ppr_jax._fusion import materialize, tangents_once
from ppr_jax._geometry import home_pose

TRIG = ("sine", "cosine")


def _trig_elements(text: str) -> int:
    """Sine and cosine elements computed by a compiled module (every instruction, in fusions
    too): what the program's kernels evaluate."""
    n = 0
    for shape, op in re.findall(r"= f64\[([\d,]*)\]\S* (\w+)\(", text):
        if op in TRIG:
            n += int(np.prod([int(d) for d in shape.split(",") if d]))
    return n


def _traced_trig(jaxpr) -> int:
    n = 0
    for eqn in jaxpr.eqns:
        for v in eqn.params.values():
            if isinstance(v, jax.extend.core.ClosedJaxpr):
                n += _traced_trig(v.jaxpr)
            elif isinstance(v, jax.extend.core.Jaxpr):
                n += _traced_trig(v)
        if eqn.primitive.name in ("sin", "cos"):
            n += int(np.prod(eqn.outvars[0].aval.shape))
    return n


def _three_readers(x, y, once):
    s = jnp.sin(x)
    s = materialize(s) if once else s
    return s * y[0] + s[::-1], jnp.concatenate([s, s * y[1]]).sum(), jnp.outer(s, y[:3]).sum(0)


def test_values_are_exact():
    x = jnp.array([-0.0, 1e-300, -2.5, 3.0e300, jnp.inf, -jnp.inf, 0.1])
    out = np.asarray(jax.jit(materialize)(x))
    ref = np.asarray(x)
    assert np.array_equal(out, ref + 0.0)  # -0.0 comes back as +0.0, nothing else moves
    assert np.isnan(np.asarray(jax.jit(materialize)(jnp.array([jnp.nan])))).all()


def test_a_value_many_kernels_read_is_computed_once():
    x, y = jnp.linspace(0.1, 0.7, 3), jnp.arange(4.0)
    once = jax.jit(lambda a, b: _three_readers(a, b, True)).lower(x, y).compile().as_text()
    assert _trig_elements(once) == 3, once
    for a, b in zip(_three_readers(x, y, True), _three_readers(x, y, False)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_computed_once_under_vmap_and_the_identity_for_derivatives():
    x = jnp.linspace(-1.0, 1.0, 6).reshape(2, 3)
    y = jnp.arange(4.0)
    batched = jax.jit(jax.vmap(lambda a: _three_readers(a, y, True)))
    assert _trig_elements(batched.lower(x).compile().as_text()) == 6  # 3 per member, once
    # the same values (the sums' rounding aside: XLA fuses the two programs differently)
    for a, b in zip(batched(x), jax.vmap(lambda a: _three_readers(a, y, False))(x)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-15, atol=1e-16)

    def f(a, once):
        return sum(jnp.sum(o ** 2) for o in _three_readers(a, y, once))

    for g in (jax.grad, jax.jacfwd):
        np.testing.assert_allclose(g(lambda a: f(a, True))(x[0]), g(lambda a: f(a, False))(x[0]),
                                   rtol=1e-14)
    # second order, both modes, as the right-hand sides' derivatives take it
    h1 = jax.jacfwd(jax.grad(lambda a: f(a, True)))(x[0])
    h2 = jax.jacrev(jax.jacfwd(lambda a: f(a, False)))(x[0])
    np.testing.assert_allclose(h1, h2, rtol=1e-12, atol=1e-14)


def test_a_value_shared_by_a_batch_is_computed_once():
    """vmapped over a direction, as `jax.jacfwd` maps a JVP over its tangents: the primal is
    not batched and keeps its one kernel."""
    x, y = jnp.linspace(0.1, 0.7, 3), jnp.arange(4.0)
    def f(a, once):  # squared, so that the tangents read the values
        return [o ** 2 for o in _three_readers(a, y, once)]

    jac = jax.jit(jax.jacfwd(lambda a: f(a, True)))
    assert "reduce-window" in jac.lower(x).compile().as_text()
    for a, b in zip(jac(x), jax.jacfwd(lambda a: f(a, False))(x)):
        np.testing.assert_allclose(a, b, rtol=1e-14)


def _tangent_readers(x, once):
    xs = [jnp.sin(x) * x[0], jnp.cos(x[:2]) ** 2]
    xs = tangents_once(xs) if once else xs
    return xs[0] * xs[1][0] + xs[0][::-1], jnp.outer(xs[1], xs[0]).sum(0)


def test_tangents_once_changes_no_value_or_derivative():
    x = jnp.array([0.3, -1.2, 2.0])
    for a, b in zip(_tangent_readers(x, True), _tangent_readers(x, False)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))

    def f(a, once):
        return sum(jnp.sum(jnp.sin(o)) for o in _tangent_readers(a, once))

    for g in (jax.grad, jax.jacfwd):
        np.testing.assert_allclose(g(lambda a: f(a, True))(x), g(lambda a: f(a, False))(x),
                                   rtol=1e-14)
    # the tangents computed by one kernel of their own (a running sum), in both modes
    for g in (jax.grad, jax.jacfwd):
        text = jax.jit(g(lambda a: f(a, True))).lower(x).compile().as_text()
        assert "reduce-window" in text


@pytest.mark.parametrize("name", ["rigid", "reduced", "double1r"])
def test_one_right_hand_side_computes_each_sine_once(name):
    model = pj.get_model(name)
    robot = pj.Robot(pj.RobotParams())
    rng = np.random.default_rng(7)
    X = np.asarray(home_pose(robot)) + rng.uniform(-1, 1, 3) * [0.02, 0.02, 0.05]
    z = jnp.asarray(model.coords_from_pose(robot, jnp.asarray(X)))
    zd = jnp.asarray(rng.normal(size=model.n_dof))
    tau = jnp.array([0.3, -0.2, 0.05])
    w = jnp.zeros(3)

    def fused(r, z, zd):
        return accelerations(eom_terms(model, r, z, zd), tau, w)

    def generic(r, z, zd):
        return accelerations(_eom_terms(model, r, z, zd, implicit=True), tau, w)

    jitted = eqx.filter_jit(fused)
    text = jitted.lower(robot, z, zd).compile().compiled.as_text()
    traced = _traced_trig(jax.make_jaxpr(lambda a, b: fused(robot, a, b))(z, zd).jaxpr)
    assert 0 < _trig_elements(text) <= traced, (_trig_elements(text), traced)
    np.testing.assert_allclose(jitted(robot, z, zd), eqx.filter_jit(generic)(robot, z, zd),
                               rtol=1e-11, atol=1e-11)


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_cos_sin_derivatives_read_the_values_once():
    """`cos_sin`'s values and derivatives (first and second order, both modes) are jnp's, and a
    derivative reads the sines computed once instead of evaluating them again."""
    from ppr_jax._fusion import cos_sin

    a, b = jnp.linspace(-2.0, 2.5, 3), jnp.array([0.3, -1.1])

    def f(x, once):
        u, v = x[:3], x[3:]
        if once:
            (cu, cv), (su, sv) = cos_sin(u, v)
        else:
            cu, cv, su, sv = jnp.cos(u), jnp.cos(v), jnp.sin(u), jnp.sin(v)
        return jnp.concatenate([cu * su[::-1], cv ** 2 - sv, su * v[0]])

    x = jnp.concatenate([a, b])
    np.testing.assert_array_equal(np.asarray(f(x, True)), np.asarray(f(x, False)))
    for jac in (jax.jacfwd, jax.jacrev):
        np.testing.assert_allclose(jac(lambda y: f(y, True))(x), jac(lambda y: f(y, False))(x),
                                   rtol=1e-14, atol=1e-15)
    h1 = jax.jacfwd(jax.jacrev(lambda y: f(y, True)))(x)
    h2 = jax.jacrev(jax.jacfwd(lambda y: f(y, False)))(x)
    np.testing.assert_allclose(h1, h2, rtol=1e-13, atol=1e-14)
    # forward mode evaluates each of the 5 angles' sine and cosine once
    text = jax.jit(jax.jacfwd(lambda y: f(y, True))).lower(x).compile().as_text()
    assert _trig_elements(text) == 10, _trig_elements(text)
