"""The PRB joint on the actual strip (`joint_geometry="strip"`, MODEL.md section 3a) against
geometry computed independently: at rest the chain must lie on the joint's natural arc (the drive
link, the ideal arc of radius r_i turning sigma theta_c, the connecting link), with zero spring
deflection; the L1 constraint d_i1 = d_i2 and loop closure hold for equal and unequal links.
The comparison with the beam model L3 (platform compliance) is in tests/test_beam.py."""

import jax.numpy as jnp
import numpy as np
import pytest

import ppr_jax as pj
from ppr_jax._geometry import base_points, deflections, e, loop_residual


@pytest.mark.parametrize("geometry", ["centerline", "strip"])
@pytest.mark.parametrize("sigma", [-1, 1])
def test_rest_chain_lies_on_the_natural_arc(geometry, sigma):
    p = pj.RobotParams(joint_geometry=geometry, sigma=sigma)
    rob = pj.Robot(p)
    th_a = jnp.array([0.3, 1.2, -2.0])
    t1 = th_a + sigma * rob.delta1
    t2 = t1 + sigma * (rob.psi0 - rob.delta1)
    t3 = t2 + sigma * (rob.psi0 - rob.delta3)
    th = jnp.stack([t1, t2, t3], axis=-1)
    np.testing.assert_allclose(deflections(rob, th), 0.0, atol=1e-15)
    A = base_points(rob)
    E = A + rob.r1 * e(t1) + rob.r2 * e(t2) + rob.r3 * e(t3)
    r_i = p.r + p.b_r / 2
    chord = 2 * r_i * jnp.sin(p.theta_c / 2)
    E_arc = (A + p.l1 * e(th_a) + chord * e(th_a + sigma * p.theta_c / 2)
             + p.l3 * e(th_a + sigma * p.theta_c))
    np.testing.assert_allclose(E, E_arc, atol=1e-15)
    # the connecting link leaves the joint turned by exactly sigma theta_c
    np.testing.assert_allclose(t3 + sigma * rob.delta3, th_a + sigma * p.theta_c, atol=1e-15)


def test_strip_geometry_lengths():
    p = pj.RobotParams(joint_geometry="strip")
    c, s = pj.Robot(p.replace(joint_geometry="centerline")), pj.Robot(p)
    r_i = p.r + p.b_r / 2
    np.testing.assert_allclose(s.r2, c.r2 * p.r / r_i, rtol=1e-15)
    np.testing.assert_allclose(s.s, c.s * p.r / r_i, rtol=1e-15)
    np.testing.assert_allclose(s.r1, np.hypot(p.l1 + s.s, p.b_r / 2), rtol=1e-15)
    for name in ("K", "psi0", "gamma", "rho", "K_theta", "Theta_0"):
        np.testing.assert_allclose(getattr(s, name), getattr(c, name), rtol=1e-15)


@pytest.mark.parametrize("l3", [0.366, 0.30])
def test_l1_constraint_and_closure_on_the_strip(l3):
    p = pj.RobotParams(joint_geometry="strip", l3=l3)
    rob = pj.Robot(p)
    X = jnp.array([0.46, 0.25, 0.02])
    r = pj.inverse_kinematics(p, X)
    assert float(jnp.abs(loop_residual(rob, r.th, X)).max()) < 1e-12
    d = deflections(rob, r.th)
    np.testing.assert_allclose(d[:, 0], d[:, 1], atol=1e-13)  # eq 29 on the strip
    # L2 at the L1 coordinates reproduces the same chain (the actuated angle is the link's)
    m = pj.Double1R()
    k = m.kinematics(rob, m.coords_from_pose(rob, X))
    np.testing.assert_allclose(k.th, r.th, atol=1e-12)
    np.testing.assert_allclose(k.th_a, r.th_a, atol=1e-12)


def test_joint_geometry_is_validated():
    with pytest.raises(pj.PPRError, match="joint_geometry"):
        pj.RobotParams(joint_geometry="arc")
    with pytest.raises(pj.PPRError, match="joint_geometry"):
        pj.stack_params([pj.RobotParams(), pj.RobotParams(joint_geometry="strip")])
