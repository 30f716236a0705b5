"""L0 `rigid`: the paper's "simplified model" (MODEL.md section 5).

A rigid 3-RRR: one pin per compliant joint at the virtual corner C_i where the links' centre lines
meet, links R1 = l1 + r_i tan(theta_c/2), R3 = l3 + r_i tan(theta_c/2), a torsion spring
K0 = E I / L with rest turn sigma theta_c, strip mass neglected. Coordinates z = X (3 DOF).
The physical links keep their own mass properties: the drive link's COM is l1/2 from A_i and the
connecting link's l3/2 from E_i.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .._geometry import (
    base_points,
    deflection_rigid,
    e,
    ik_rigid,
    loop_residual_rigid,
    platform_points,
)
from .base import ATOL, RTOL, AbstractClosedLoop, Kin, rotor_inertia
from .fused import Body, ChainSpec, Link


class Rigid(AbstractClosedLoop):
    """L0 `rigid`, the paper's "simplified model" (module docstring): z = X = (x, y, phi)
    (m, m, rad), 3 DOF; one pin per compliant joint at the virtual corner."""

    name = "rigid"
    fast_index = ()
    default_solver = "tsit5"
    default_rtol = RTOL
    default_atol = ATOL
    level = 0
    n_dof = 3
    actuated_index = None

    # The dependent coordinates u (3, 2) are each chain's (th_i1, th_i3).

    # `dependent_trig` stays the default (no sines handed on): L0's two-link closure could hand
    # its angles' sines on as L1's closed form does, but its right-hand side then measured
    # slower, 410 -> 540 ns on the 2-core CPU (L1: 600 -> 410 ns); the fused terms evaluate its
    # seven sines once instead.

    def dependent(self, robot, z):
        return ik_rigid(robot, z)

    def closure_residual(self, robot, z, u):
        return loop_residual_rigid(robot, u, z)

    def kin_at(self, robot, z, u, margin, trig=None):
        X, th = z, u
        A = base_points(robot)
        E = platform_points(robot, X)
        p1 = A + (robot.l1 / 2) * e(th[:, 0])
        p3 = E - (robot.l3 / 2) * e(th[:, 1])
        p = jnp.concatenate([p1, p3, X[None, :2]], axis=0)
        ang = jnp.concatenate([th[:, 0], th[:, 1], X[2:3]])
        return Kin(
            X=X, th=th, body_p=p, body_ang=ang, deflection=deflection_rigid(robot, th),
            th_a=th[:, 0], margin=margin,
        )

    def chain_spec(self, robot, z, u, trig=None):
        # p3 = E_i - (l3/2) e(th_i3) written along the chain, E_i = A_i + R1 e(th_i1) + R3 e(th_i3)
        return ChainSpec(
            alpha=[u[:, 0], u[:, 1]], Gz=np.zeros((2, 3, 3)), Gu=np.eye(2),
            closure=(Link(0, robot.R1), Link(1, robot.R3)),
            bodies=(
                Body((Link(0, robot.l1 / 2),), 0, robot.m1, rotor_inertia(robot)),
                Body((Link(0, robot.R1), Link(1, robot.R3 - robot.l3 / 2)), 1, robot.m3,
                     robot.I3),
            ),
            springs=(np.array([-1.0, 1.0]),),
            actuated=0,
        )

    def masses(self, robot):
        one = jnp.ones(3, dtype=jnp.float64)
        m = jnp.concatenate([robot.m1 * one, robot.m3 * one, robot.m4[None]])
        I = jnp.concatenate([rotor_inertia(robot) * one, robot.I3 * one, robot.I4[None]])
        return m, I

    def stiffness(self, robot):
        return robot.K0

    def coords_from_pose(self, robot, X):
        return X

    def loop_residual(self, robot, kin):
        return loop_residual_rigid(robot, kin.th, kin.X)

    def joint_end_rotations(self, robot, kin):
        # One pin: each end of the joint carries half of the pin's rotation.
        return jnp.stack([kin.deflection / 2, kin.deflection / 2], axis=-1)
