"""What both contenders take from the library: the `paper-circle` torques and its L2 initial
state, computed as the scene computes them, once per call on the host."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import ppr_jax as pj

#: Torques are evaluated in chunks of this many times (padded): one compiled shape for every
#: grid a contender asks for, so a sweep over step sizes compiles once.
CHUNK = 8192


@eqx.filter_jit
def _torques_chunk(fn, ts):
    return jax.vmap(fn)(ts)


def scene_torque_fn(params: pj.RobotParams, path=None) -> pj.InverseDynamicsTorque:
    """The scene's torque function tau_a(t) (3,) (N m): L1 inverse dynamics along `path`
    (default eq 55's circle)."""
    return pj.InverseDynamicsTorque(pj.Reduced(), pj.Robot(params),
                                    pj.Circle() if path is None else path)


def scene_torques(params: pj.RobotParams, ts, path=None) -> np.ndarray:
    """The scene's torques (n, 3) (N m) at times ts (n,) (s), exactly (no interpolation), along
    `path` (default eq 55's circle)."""
    fn = scene_torque_fn(params, path)
    ts = np.asarray(ts, dtype=np.float64).ravel()
    out = np.empty((ts.size, 3))
    for k in range(0, ts.size, CHUNK):
        part = ts[k:k + CHUNK]
        pad = np.concatenate([part, np.full(CHUNK - part.size, part[-1])])
        out[k:k + part.size] = np.asarray(_torques_chunk(fn, jnp.asarray(pad)))[: part.size]
    return out


@eqx.filter_jit
def _pose_derivatives(path, t):
    d1 = jax.jacfwd(path)
    return path(t), d1(t), jax.jacfwd(d1)(t)


def pose_derivatives(path):
    """t -> (X, X', X'') (3,) each (numpy) of a pose path t -> X (3,): the path is the scene's
    input, its derivatives by forward-mode differentiation of that input."""
    return lambda t: tuple(np.asarray(a, dtype=float)
                           for a in _pose_derivatives(path, jnp.asarray(t, dtype=jnp.float64)))


def initial_state(params: pj.RobotParams):
    """The library's L2 `paper-circle` initial state (z0, z0') at t = 0, z = (x, y, phi, th_a1,
    th_a2, th_a3): `ppr_jax.quasi_static_state` under the scene's torques, as the scene starts."""
    act = pj.TorqueDriven(scene_torque_fn(params))
    z0, zd0 = pj.quasi_static_state(pj.Double1R(), pj.Robot(params), pj.Circle(), 0.0, act)
    return np.asarray(z0, dtype=float), np.asarray(zd0, dtype=float)
