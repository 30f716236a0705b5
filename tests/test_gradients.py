"""Gradients of a simulated L2 metric with respect to t, gamma and K_theta against central finite
differences, in reverse mode (jax.grad) and forward mode (jax.jvp with diffrax.ForwardMode).
L2 (`double1r`), the most detailed model that runs a scene in the default suite; L1's gradients
run in the notebooks and in the identification tests.

One compiled reverse pass gives the gradient for every parameter at once; one compiled forward
pass serves every tangent direction."""

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ppr_jax as pj

TS = jnp.linspace(0.0, 0.6, 7)


@pytest.fixture(scope="module")
def pexp(params, dv):
    """Explicit PRB parameters (the default takes them from the fitted table) so that gamma and
    K_theta are leaves to differentiate."""
    return params.replace(gamma=float(dv.gamma), K_theta=float(dv.K_theta))


@pytest.fixture(scope="module")
def fns(pexp):
    params = pexp
    traj = pj.Circle()
    # Torques computed once for the nominal robot: the data an identification holds fixed.
    tt = jnp.linspace(0, 0.6, 61)
    tau = pj.Interpolated(tt, jax.vmap(pj.InverseDynamicsTorque(pj.Reduced(), params, traj))(tt))
    act = pj.TorqueDriven(tau)
    model = pj.Double1R()
    # the initial state is data, like the torques: the nominal robot's quasi-static state
    z0, zd0 = pj.quasi_static_state(model, params, traj, 0.0, act)

    def metric(p, adjoint=None):
        sol = pj.simulate(model, p, act, z0, zd0, TS, rtol=1e-12, atol=1e-13,
                          adjoint=adjoint)
        c = jnp.asarray(traj.center)[None, :]
        er = jnp.linalg.norm(sol.z[:, :2] - c, axis=-1) - traj.radius
        # a smooth scalar of the whole run: squared radial error (mm^2) plus final angle (mrad)
        return jnp.sum((1e3 * er) ** 2) + 1e3 * sol.z[-1, 2]

    value = eqx.filter_jit(metric)
    rev = eqx.filter_jit(jax.grad(metric))
    fwd = eqx.filter_jit(
        lambda p, tp: jax.jvp(lambda q: metric(q, diffrax.ForwardMode()), (p,), (tp,))[1]
    )
    return value, rev, fwd, metric


@pytest.mark.parametrize("name", ["t", "gamma", "K_theta"])
def test_gradient_reverse_and_forward_vs_finite_differences(pexp, fns, name):
    params = pexp
    value, rev, fwd, _ = fns
    x0 = float(getattr(params, name))
    h = 1e-5 * x0

    def at(v):
        return eqx.tree_at(lambda p: getattr(p, name), params, jnp.asarray(v, dtype=jnp.float64))

    fd = (float(value(at(x0 + h))) - float(value(at(x0 - h)))) / (2 * h)
    g_rev = float(getattr(rev(params), name))
    tangent = jax.tree_util.tree_map(jnp.zeros_like, params)
    tangent = eqx.tree_at(lambda p: getattr(p, name), tangent, jnp.ones((), jnp.float64))
    g_fwd = float(fwd(params, tangent))
    assert abs(fd) * x0 > 1e-3  # the metric really depends on the parameter
    np.testing.assert_allclose(g_rev, fd, rtol=2e-5)
    np.testing.assert_allclose(g_fwd, fd, rtol=2e-5)
    np.testing.assert_allclose(g_fwd, g_rev, rtol=1e-8)


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_reverse_mode_does_not_depend_on_the_checkpoint_schedule(pexp, fns):
    """diffrax's backward pass recomputes steps from its checkpoints; where it decided them
    again, a recomputed error estimate rounding differently from the forward pass's could
    reject a step the forward pass kept, and the gradient followed another step sequence
    (1 % off at this run's rtol 1e-12 under one compilation, right under another). The
    library differentiates on the forward pass's recorded steps, so three checkpoints
    (nearly every step recomputed) give the default schedule's gradient, up to the forward
    pass's own dependence on its program: at rtol 1e-12 the error estimate is close to
    rounding, and the same solve compiled into different programs takes different step
    sequences (750 steps in the default schedule's gradient, 756 with three checkpoints, 766
    undifferentiated; measured at fa32980), whose gradients differ by the integration's error
    (5e-9 relative), not by the 1e-2 of a gradient that follows other steps than its
    solution."""
    _, rev, _, metric = fns
    adjoint = diffrax.RecursiveCheckpointAdjoint(checkpoints=3)
    g3 = eqx.filter_jit(jax.grad(lambda p: metric(p, adjoint)))(pexp)
    g = rev(pexp)
    for name in ("t", "gamma", "K_theta"):
        np.testing.assert_allclose(float(getattr(g3, name)), float(getattr(g, name)),
                                   rtol=1e-7, err_msg=name)
