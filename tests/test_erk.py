"""The explicit solvers with their stages as straight-line code (`_erk.py`) against diffrax's own
Tsit5, Dopri5 and Dopri8 on a small forced, damped double pendulum: the same steps, the same
trajectory to rounding, the same derivatives in every adjoint, and no loop inside a step."""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ppr_jax._erk import FusedDopri5, FusedDopri8, FusedTsit5

Y0 = jnp.array([1.0, -0.5, 0.2, 0.1])
TS = jnp.linspace(0.0, 3.0, 13)


def _vf(t, y, p):
    x, v = y[:2], y[2:]
    return jnp.concatenate([v, -p * jnp.sin(x) * (1 + 0.3 * jnp.cos(3 * t)) - 0.1 * v])


def _solve(solver, p=1.1, adjoint=diffrax.RecursiveCheckpointAdjoint(), rtol=1e-8):
    return diffrax.diffeqsolve(
        diffrax.ODETerm(_vf), solver, 0.0, 3.0, None, Y0, args=p, saveat=diffrax.SaveAt(ts=TS),
        stepsize_controller=diffrax.PIDController(rtol=rtol, atol=1e-10), max_steps=4096,
        adjoint=adjoint,
    )


@pytest.mark.parametrize("ours, theirs", [(FusedTsit5, diffrax.Tsit5),
                                          (FusedDopri5, diffrax.Dopri5),
                                          (FusedDopri8, diffrax.Dopri8)])
def test_same_steps_and_trajectory_as_diffrax(ours, theirs):
    a, b = _solve(ours()), _solve(theirs())
    assert int(a.stats["num_steps"]) == int(b.stats["num_steps"])
    assert int(a.stats["num_rejected_steps"]) == int(b.stats["num_rejected_steps"])
    np.testing.assert_allclose(a.ys, b.ys, rtol=0, atol=1e-11)


def test_pytree_state():
    def vf(t, y, args):
        d = _vf(t, jnp.concatenate(y), 1.1)
        return d[:2], d[2:]

    sols = [diffrax.diffeqsolve(diffrax.ODETerm(vf), s, 0.0, 3.0, None, (Y0[:2], Y0[2:]),
                                saveat=diffrax.SaveAt(ts=TS),
                                stepsize_controller=diffrax.PIDController(rtol=1e-8, atol=1e-10))
            for s in (FusedTsit5(), diffrax.Tsit5())]
    for a, b in zip(sols[0].ys, sols[1].ys):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)


def test_derivatives_in_every_adjoint():
    """d/dp of a smooth scalar of the saved trajectory: reverse mode (recursive checkpoints and
    backsolve) and forward mode against diffrax's Tsit5 in reverse mode and central finite
    differences (at a tolerance where they resolve it)."""

    def loss(p, solver, adjoint):
        return jnp.sum(_solve(solver, p, adjoint, rtol=1e-12).ys ** 2)

    ref = jax.grad(loss)(1.1, diffrax.Tsit5(), diffrax.RecursiveCheckpointAdjoint())
    h = 1e-5
    rc = diffrax.RecursiveCheckpointAdjoint()
    fd = (loss(1.1 + h, diffrax.Tsit5(), rc) - loss(1.1 - h, diffrax.Tsit5(), rc)) / (2 * h)
    np.testing.assert_allclose(ref, fd, rtol=1e-7)
    s = FusedTsit5()
    rev = jax.grad(loss)(1.1, s, diffrax.RecursiveCheckpointAdjoint())
    back = jax.grad(loss)(1.1, s, diffrax.BacksolveAdjoint(solver=FusedTsit5()))
    fwd = jax.jvp(lambda p: loss(p, s, diffrax.ForwardMode()), (1.1,), (1.0,))[1]
    np.testing.assert_allclose(rev, ref, rtol=1e-10)
    np.testing.assert_allclose(fwd, ref, rtol=1e-10)
    # backsolve integrates the adjoint equation: its own error, not rounding
    np.testing.assert_allclose(back, ref, rtol=1e-6)


def _primitives(jaxpr, acc):
    for e in jaxpr.eqns:
        acc.add(e.primitive.name)
        for v in e.params.values():
            for x in v if isinstance(v, (list, tuple)) else [v]:
                inner = getattr(x, "jaxpr", x)
                inner = getattr(inner, "jaxpr", inner)
                if hasattr(inner, "eqns"):
                    _primitives(inner, acc)
    return acc


def test_a_step_is_straight_line_code():
    """No loop inside a step (diffrax's Runge-Kutta step runs its stages as a while loop)."""
    terms = diffrax.ODETerm(_vf)

    def prims(solver):
        state = solver.init(terms, 0.0, 0.1, Y0, 1.1)
        jaxpr = jax.make_jaxpr(lambda y: solver.step(terms, 0.0, 0.1, y, 1.1, state, False))(Y0)
        return _primitives(jaxpr.jaxpr, set())

    assert "while" in prims(diffrax.Tsit5())
    for s in (FusedTsit5(), FusedDopri5(), FusedDopri8()):
        assert "while" not in prims(s)
