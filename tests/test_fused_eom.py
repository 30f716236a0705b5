"""The fused equations of motion of L0-L2 (`ppr_jax/_models/fused.py`) against the generic
projection (`_dynamics._eom_terms`, vmapped JVPs of the kinematics), which stays the reference:
the terms M, h, Q, Jth and the accelerations at random states, and their forward (JVP) and
reverse (VJP) derivatives with respect to the state and to the robot's parameters.

Two robots: the defaults (centre-line joints) and one with every term of the fused formulas
switched on (the strip geometry's fixed link offsets, spring damping, actuator friction, rotor
inertia). One compiled program per model, robot and formulation evaluates a batch of states."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ppr_jax as pj
from ppr_jax._dynamics import EOM, _eom_terms, accelerations
from ppr_jax._geometry import home_pose
from ppr_jax._studies import explicit_params

MODELS = ["rigid", "reduced", "double1r"]
N_STATES = 4
#: the parameters whose derivatives are compared (the strip's t, E and gamma, and the radius,
#: density, damping and rotor inertia that enter the fused formulas directly; l1 and l3 stay
#: concrete, so that L1 keeps its closed form)
PARAMS = ("t", "E", "gamma", "r", "rho_m", "c_spring", "c_act", "J_rotor")
TOL = 1e-12


def _robots():
    base = explicit_params(pj.RobotParams())
    full = explicit_params(pj.RobotParams(
        joint_geometry="strip", c_spring=2e-3, c_act=1e-3, J_rotor=1e-4))
    return {"default": base, "all-terms": full}


ROBOTS = _robots()


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


def _states(model, params, seed):
    """Random states near the workspace's centre: poses within a few cm and 0.1 rad of home,
    the internal coordinates off the quasi-static manifold, velocities of order 1."""
    rng = np.random.default_rng(seed)
    robot = pj.Robot(params)
    n = model.n_dof
    Xs = np.asarray(home_pose(robot)) + rng.uniform(-1, 1, (N_STATES, 3)) * [0.03, 0.03, 0.1]
    z = np.stack([np.asarray(model.coords_from_pose(robot, jnp.asarray(X))) for X in Xs])
    z[:, 3:] += rng.uniform(-0.02, 0.02, (N_STATES, n - 3))
    zd = rng.normal(size=(N_STATES, n)) * np.r_[0.2, 0.2, 1.0, [1.0] * (n - 3)]
    tau = rng.normal(size=(N_STATES, 3))
    values = jnp.array([float(getattr(params, p)) for p in PARAMS])
    scale = np.asarray(values) + 1e-3  # relative directions (the damping terms are zero-based)
    dv = rng.normal(size=(N_STATES, len(PARAMS))) * scale
    dz, dzd = rng.normal(size=(N_STATES, n)), rng.normal(size=(N_STATES, n))
    ct = rng.normal(size=(N_STATES, n))
    return values, tuple(jnp.asarray(a) for a in (z, zd, tau, dv, dz, dzd, ct))


def _pairs():
    # The all-terms robot of L0 and L1 is slow-marked to keep the default suite cheap: L2 shares
    # the double-1R bodies, offsets and springs with L1 and the damping and friction with L0.
    for m in MODELS:
        for r in ROBOTS:
            slow = r != "default" and m != "double1r"
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


def _close(a, b, what):
    a, b = np.asarray(a), np.asarray(b)
    scale = max(np.abs(b).max(), 1e-300)
    err = np.abs(a - b).max() / scale
    assert err <= TOL, f"{what}: relative difference {err:.2e}"


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
