"""`FlatJit` (`ppr_jax/_dispatch.py`) against `eqx.filter_jit`, which it stands in for: arrays
traced and other leaves static, non-array leaves of the result given back, derivatives and
vmap through it, and its ahead-of-time `lower(...).compile()`."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ppr_jax._dispatch import FlatJit


class Box(eqx.Module):
    x: jax.Array
    scale: float  # a Python float: static for filter_jit
    name: str = eqx.field(static=True)


class Out(eqx.Module):
    y: jax.Array
    label: str


def _f(box, n, z):
    return Out(y=box.scale * jnp.sin(box.x) * n + z, label=f"{box.name}-{n}")


def test_values_and_static_leaves_as_filter_jit():
    traces = []

    def f(box, n, z):
        traces.append(1)
        return _f(box, n, z)

    fj = FlatJit(f)
    box = Box(jnp.array([0.1, 0.2]), 2.0, "a")
    calls = [(box, 3, np.float64(0.5)), (Box(jnp.array([0.3, 0.4]), 2.0, "a"), 3, np.float64(0.9)),
             (Box(jnp.array([0.3, 0.4]), 5.0, "b"), 4, 1.5)]
    for i, (b, n, z) in enumerate(calls):
        got, want = fj(b, n, z), eqx.filter_jit(_f)(b, n, z)
        assert got.label == want.label
        np.testing.assert_array_equal(got.y, want.y)
        # the second call changes arrays only: no new trace; the third a static float, an int,
        # a string and a Python float argument (static, as filter_jit holds it): a new trace
        assert len(traces) == [1, 1, 2][i]


def test_derivatives_and_vmap_through_it():
    box = Box(jnp.array([0.1, 0.2]), 2.0, "a")
    z = jnp.array(0.3)
    for g in (jax.grad, jax.jacfwd):
        got = g(lambda x: FlatJit(_f)(Box(x, 2.0, "a"), 3, z).y.sum())(box.x)
        want = g(lambda x: eqx.filter_jit(_f)(Box(x, 2.0, "a"), 3, z).y.sum())(box.x)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-15)
    xs = jnp.linspace(0.0, 1.0, 6).reshape(3, 2)
    got = jax.vmap(lambda x: FlatJit(_f)(Box(x, 2.0, "a"), 3, z).y)(xs)
    np.testing.assert_allclose(got, 2.0 * jnp.sin(xs) * 3 + z, rtol=0, atol=1e-15)


def test_ahead_of_time_compile_is_called_with_the_same_arguments():
    fj = FlatJit(_f)
    box = Box(jnp.array([0.1, 0.2]), 2.0, "a")
    lowered = fj.lower(box, 3, jnp.array(0.5))
    compiled = lowered.compile()
    assert "sine" in compiled.as_text() or "sin" in compiled.as_text()
    # JAX's own stages, as equinox's Lowered.lowered and Compiled.compiled give them
    # (benchmarks/compile_budget.py reads them)
    assert isinstance(lowered.lowered, jax.stages.Lowered)
    assert isinstance(compiled.compiled, jax.stages.Compiled)
    out = compiled(Box(jnp.array([0.7, 0.8]), 2.0, "a"), 3, jnp.array(1.0))
    assert out.label == "a-3"
    np.testing.assert_allclose(out.y, 2.0 * np.sin([0.7, 0.8]) * 3 + 1.0, rtol=0, atol=1e-15)
