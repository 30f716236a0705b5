"""Forward dynamics' derivatives through the balance (`_dynamics.torque_driven_accelerations`:
M dz'' = d(Q - M a - h) at a = z'' held, the tangent of the fused balance) against the
derivatives of the generic projection's M, h and Q (`fused=False`), which is the reference: at
random states, in forward (JVP) and reverse (VJP) mode, with respect to the state, the robot's
parameters and a state-feedback drive's gains (a drive nobody here chose: torques that depend on
time, the actuated angles and their rates). One compiled program per model and formulation."""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ppr_jax as pj
from ppr_jax._dynamics import _has_fused_balance, for_batch, torque_driven_accelerations
from tests.helpers import (
    EOM_MODELS as MODELS,
    EOM_PARAMS as PARAMS,
    EOM_ROBOTS as ROBOTS,
    eom_states as _states,
    relative_close as _close,
)


class FeedbackDrive(eqx.Module):
    """tau = tau0 + sin(w t) a + Kp (th_ref - th_a) - Kd th_a' (N m): every field a tangent."""

    tau0: jax.Array
    a: jax.Array
    w: jax.Array
    Kp: jax.Array
    Kd: jax.Array
    th_ref: jax.Array

    def torque_at(self, t, th_a, thd_a):
        return (self.tau0 + jnp.sin(self.w * t) * self.a + self.Kp * (self.th_ref - th_a)
                - self.Kd * thd_a)


def _drive(th_ref):
    return FeedbackDrive(tau0=jnp.array([0.2, -0.1, 0.05]), a=jnp.array([0.1, 0.3, -0.2]),
                         w=jnp.asarray(3.0), Kp=jnp.array([2.0, 1.5, 1.0]),
                         Kd=jnp.array([0.05, 0.08, 0.02]), th_ref=th_ref)


def _program(model):
    wrench = jnp.array([0.3, -0.2, 0.05])

    def f(values, drive, z, zd, params):
        robot = pj.Robot(params.replace(**dict(zip(PARAMS, values))))
        return torque_driven_accelerations(model, robot, drive, wrench, 0.37, z, zd)

    def one(values, drive, params, z, zd, dv, dz, dzd, ct):
        g = lambda v, d, a, b: f(v, d, a, b, params)  # noqa: E731
        out = g(values, drive, z, zd)
        ddrive = jax.tree.map(lambda x: 0.1 * x, drive)
        _, tangent = jax.jvp(g, (values, drive, z, zd), (dv, ddrive, dz, dzd))
        _, pull = jax.vjp(g, values, drive, z, zd)
        return out, tangent, pull((ct, ct[:3]))

    return jax.jit(jax.vmap(one, in_axes=(None, None, None, 0, 0, 0, 0, 0, 0)))


def _cases():
    # In the default tier: L2 on the all-terms robot (its chains' own coordinates, every term of
    # the balance); L0 (the platform's coordinates only), L1 (L0's balance code, L2's bodies)
    # and L2 on the default robot run in the second tier.
    for m in MODELS:
        for r in ROBOTS:
            fast = m == "double1r" and r != "default"
            yield pytest.param((m, r), id=f"{m}-{r}",
                               marks=[] if fast else [pytest.mark.slow])


@pytest.fixture(scope="module", params=list(_cases()))
def pair(request):
    name, robot_name = request.param
    model, params = pj.get_model(name), ROBOTS[robot_name]
    values, (z, zd, _, dv, dz, dzd, ct) = _states(model, params, seed=3 + MODELS.index(name))
    drive = _drive(jnp.array([0.1, -0.2, 0.3]))
    args = (values, drive, params, z, zd, dv, dz, dzd, ct)
    generic = dataclasses.replace(model, fused=False)
    assert _has_fused_balance(model) and not _has_fused_balance(generic)
    return name, _program(model)(*args), _program(generic)(*args)


def test_values(pair):
    name, used, ref = pair
    _close(used[0][0], ref[0][0], f"{name} z''")
    _close(used[0][1], ref[0][1], f"{name} tau")
    assert np.abs(np.asarray(ref[0][0])).max() > 0


def test_forward_mode(pair):
    name, used, ref = pair
    _close(used[1][0], ref[1][0], f"{name} JVP of z''")
    _close(used[1][1], ref[1][1], f"{name} JVP of tau")
    assert np.abs(np.asarray(ref[1][0])).max() > 0


def test_reverse_mode(pair):
    name, used, ref = pair
    (dv, ddrive, dz, dzd), (rv, rdrive, rz, rzd) = used[2], ref[2]
    for k, p in enumerate(PARAMS):
        _close(dv[:, k], rv[:, k], f"{name} VJP w.r.t. {p}")
    for field in ("tau0", "a", "w", "Kp", "Kd", "th_ref"):
        _close(getattr(ddrive, field), getattr(rdrive, field), f"{name} VJP w.r.t. drive {field}")
    _close(dz, rz, f"{name} VJP w.r.t. z")
    _close(dzd, rzd, f"{name} VJP w.r.t. z'")


def test_central_differences():
    """L2's JVP along a parameter direction against central differences of the primal (a check
    that does not rest on either formulation's derivatives)."""
    model, params = pj.get_model("double1r"), ROBOTS["all-terms"]
    values, (z, zd, *_) = _states(model, params, seed=11)
    drive = _drive(jnp.array([0.1, -0.2, 0.3]))

    @jax.jit
    def f(v):
        robot = pj.Robot(params.replace(**dict(zip(PARAMS, v))))
        return torque_driven_accelerations(model, robot, drive, jnp.zeros(3), 0.2, z[0], zd[0])[0]

    d = jnp.asarray(np.random.default_rng(5).normal(size=len(PARAMS))) * values * 1e-5
    fd = (f(values + d) - f(values - d)) / 2.0
    _, jvp = jax.jvp(f, (values,), (d,))
    err = np.abs(np.asarray(jvp - fd)).max() / np.abs(np.asarray(fd)).max()
    assert err < 1e-6, err


@pytest.mark.parametrize("batched", [  # one in the default tier: the others share its code
    "state", pytest.param("t", marks=pytest.mark.slow),
    pytest.param("drive", marks=pytest.mark.slow)])
def test_batched_inside_a_derivative(batched):
    """vmap inside a derivative (a sweep's sensitivities, identification's experiments): the
    rule's tangents are batched as its primal (JAX requires it). Traced in forward and reverse
    mode for each batched input; the batch's forward-mode values against the generic path."""
    model, params = pj.get_model("double1r"), ROBOTS["default"]
    values, (z, zd, _, dv, *_) = _states(model, params, seed=2)
    drive = _drive(jnp.array([0.1, -0.2, 0.3]))

    def member(m, v, d, zz, zzd):
        robot = pj.Robot(params.replace(**dict(zip(PARAMS, v))))
        return torque_driven_accelerations(m, robot, d, jnp.zeros(3), 0.1, zz, zzd)[0]

    def batch(m):
        def f(v):
            if batched == "state":
                return jax.vmap(lambda a, b: member(m, v, drive, a, b))(z[:2], zd[:2])
            if batched == "drive":
                ds = jax.tree.map(lambda x: jnp.stack([x, 1.1 * x]), drive)
                return jax.vmap(lambda d: member(m, v, d, z[0], zd[0]))(ds)
            return jax.vmap(lambda s: member(m, v * s, drive, z[0], zd[0]))(
                jnp.array([1.0, 1.01]))
        return f

    f, g = batch(model), batch(dataclasses.replace(model, fused=False))
    jax.eval_shape(jax.grad(lambda v: jnp.sum(jnp.sin(f(v)))), values)
    used = jax.jit(lambda v, d: jax.jvp(f, (v,), (d,))[1])(values, dv[0])
    ref = jax.jit(lambda v, d: jax.jvp(g, (v,), (d,))[1])(values, dv[0])
    _close(used, ref, f"batched {batched}")


def test_batch_members_take_the_generic_terms():
    for name in MODELS:
        assert not _has_fused_balance(for_batch(pj.get_model(name)))
    assert not _has_fused_balance(pj.get_model("beam"))


def test_jvp_with_residuals_once_equals_jax_jvp():
    """`_jvp_residuals_once` (the balance's tangent with its primal residuals computed once)
    against `jax.jvp` of the same function: a static integer argument, an argument without a
    tangent (None), and tangents mapped by `vmap` as a forward-mode Jacobian maps them."""
    from ppr_jax._dynamics import _jvp_residuals_once

    def fn(x, k, w):
        s = jnp.sin(x) * jnp.cos(x[::-1]) + w
        a = s * x[0] + jnp.sin(s) * x[1]
        b = jnp.cumsum(a) * s[0] ** k
        return a * b, jnp.sum(b * jnp.sin(a))

    x, w = jnp.linspace(0.1, 1.2, 6), jnp.linspace(-1.0, 1.0, 6)
    directions = jnp.asarray(np.random.default_rng(3).normal(size=(4, 6)))

    def ours(t):
        return _jvp_residuals_once(fn, (x, 3, w), (t, None, None))

    def reference(t):
        return jax.jvp(lambda x: fn(x, 3, w), (x,), (t,))[1]

    got, want = jax.jit(jax.vmap(ours))(directions), jax.vmap(reference)(directions)
    for g, r in zip(got, want):
        np.testing.assert_allclose(g, r, rtol=1e-14, atol=1e-14)
    # a tangent for w as well
    g = _jvp_residuals_once(fn, (x, 3, w), (directions[0], None, directions[1]))
    r = jax.jvp(lambda x, w: fn(x, 3, w), (x, w), (directions[0], directions[1]))[1]
    for a, b in zip(g, r):
        np.testing.assert_allclose(a, b, rtol=1e-14, atol=1e-14)
