"""L2 `double1r`, and what L1 and L2 share: the double-1R pseudo-rigid-body chains.

`AbstractDouble1R` holds the chain of MODEL.md sections 3-4 that both levels use: for each chain
the drive link (COM at l1/2 from A_i), the pseudo-link r2 (COM at its middle, r_bc = r2/2, mass of
the strip) and the connecting link (COM at l3/2 from E_i, i.e. r_dc = s + l3/2 from D_i), two
springs K per joint, and the loop closure of eq 12.

L2 (`Double1R`) drops the quasi-static assumption: both pivots of every compliant joint are free
and the pseudo-link keeps its inertia: 12 joint coordinates with 6 loop closures, 6 DOF. We
integrate in the independent coordinates z = (x, y, phi, th_11, th_21, th_31): given the pose and
the actuated angles, each chain closes in closed form (the two-link (r2, r3) problem from B_i to
E_i, elbow branch sigma), so the loop closures hold to rounding at every step instead of drifting,
and the actuated angles are coordinates, which makes motion-driven actuation a plain partition of
z.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .._geometry import (
    base_points,
    chain_closure_double1r,
    deflections,
    ik_reduced,
    loop_residual,
    turn,
    unit_vectors,
)
from .._robot import Robot
from .base import ATOL, RTOL, AbstractClosedLoop, Kin, rotor_inertia
from .fused import Body, ChainSpec, Link


class AbstractDouble1R(AbstractClosedLoop):
    """The double-1R chains of L1 and L2 (module docstring): bodies, masses, springs, closure.
    Subclasses say which chain angles are their dependent coordinates u and how u closes the
    loops (`dependent`, `closure_residual`, `kin_at` of `AbstractClosedLoop`)."""

    def chain_bodies(self, robot: Robot, th, X, trig=None):
        """Bodies of the chains and the platform: (p (10, 2), ang (10,)), chain-major by body
        type (3 drive links, 3 pseudo-links, 3 connecting links, platform). The links keep their
        centre lines whatever the joint geometry: their angles are the chain angles less the
        fixed offsets delta1, delta3 (zero on the centre lines). `trig`: the angles'
        `_geometry.ChainTrig`, where the closure computed it."""
        A = base_points(robot)
        sig = robot.sigma
        th1 = th[:, 0] - sig * robot.delta1  # the drive link's centre line (= th_a)
        th3 = th[:, 2] + sig * robot.delta3  # the connecting link's centre line
        # The links' centre lines are the chain angles turned by the robot's fixed offsets:
        # turning the unit vectors saves a sine and cosine per link in every evaluation.
        e1, e2, e3 = unit_vectors(th, trig)
        B = A + robot.r1 * e1
        p1 = A + (robot.l1 / 2) * turn(e1, -sig * robot.delta1)
        p2 = B + (robot.r2 / 2) * e2
        E = B + robot.r2 * e2 + robot.r3 * e3
        p3 = E - (robot.l3 / 2) * turn(e3, sig * robot.delta3)
        p = jnp.concatenate([p1, p2, p3, X[None, :2]], axis=0)
        ang = jnp.concatenate([th1, th[:, 1], th3, X[2:3]])
        return p, ang

    def kin_from_angles(self, robot: Robot, X, th, margin, trig=None) -> Kin:
        """`Kin` from the pose X and the chain angles th (3, 3) (their `ChainTrig` where
        known)."""
        p, ang = self.chain_bodies(robot, th, X, trig)
        return Kin(
            X=X, th=th, body_p=p, body_ang=ang, deflection=deflections(robot, th).reshape(-1),
            th_a=th[:, 0] - robot.sigma * robot.delta1, margin=margin, trig=trig,
        )

    def double1r_spec(self, robot: Robot, th, Gz, Gu, own=(), trig=None) -> ChainSpec:
        """The `ChainSpec` of the double-1R chains with angles th (3, 3) (their `ChainTrig`
        where known) and their derivatives Gz (3, 3, n), Gu (3, 2) (the subclass's choice of
        u), the chains' own coordinates `own`: the bodies of `chain_bodies`."""
        sig = robot.sigma
        return ChainSpec(
            alpha=[th[:, 0], th[:, 1], th[:, 2]], Gz=Gz, Gu=Gu,
            closure=(Link(0, robot.r1), Link(1, robot.r2), Link(2, robot.r3)),
            bodies=(
                Body((Link(0, robot.l1 / 2, -sig * robot.delta1),), 0, robot.m1,
                     rotor_inertia(robot)),
                Body((Link(0, robot.r1), Link(1, robot.r2 / 2)), 1, robot.m2, robot.I2),
                Body((Link(0, robot.r1), Link(1, robot.r2), Link(2, robot.r3),
                      Link(2, -robot.l3 / 2, sig * robot.delta3)), 2, robot.m3, robot.I3),
            ),
            springs=(np.array([-1.0, 1.0, 0.0]), np.array([0.0, -1.0, 1.0])),
            actuated=0, own=own, trig=trig,
        )

    def masses(self, robot):
        one = jnp.ones(3, dtype=jnp.float64)
        m = jnp.concatenate([robot.m1 * one, robot.m2 * one, robot.m3 * one, robot.m4[None]])
        I = jnp.concatenate(
            [rotor_inertia(robot) * one, robot.I2 * one, robot.I3 * one, robot.I4[None]]
        )
        return m, I

    def stiffness(self, robot):
        return robot.K

    def loop_residual(self, robot, kin):
        return loop_residual(robot, kin.th, kin.X, kin.trig)

    def joint_end_rotations(self, robot, kin):
        """The two pivot deflections (d_i1, d_i2) of each chain (rad)."""
        return kin.deflection.reshape(3, 2)


class Double1R(AbstractDouble1R):
    """L2 `double1r`: the double-1R PRB model without the quasi-static assumption (module
    docstring). z = (x, y, phi, th_11, th_21, th_31) (m, m, rad, rad, rad, rad); 6 DOF."""

    name = "double1r"
    fast_index = ()
    default_solver = "tsit5"
    default_rtol = RTOL
    default_atol = ATOL
    level = 2
    n_dof = 6
    actuated_index = (3, 4, 5)
    chain_coordinates = 3

    # The dependent coordinates u (3, 2) are each chain's (th_i2, th_i3); th_i1 is th_a (+ the
    # strip geometry's fixed offset), a coordinate.

    def _angles(self, robot, z, u):
        t1 = z[3:] + robot.sigma * robot.delta1
        return jnp.concatenate([t1[:, None], u], axis=1)

    # `dependent_trig` stays the default: the two-link closure could hand its angles' sines on
    # (as L1's closed form does), but L2's right-hand side gained little (725 -> 680 ns on the
    # 2-core CPU) and its scene program's first call took 5 % longer to compile.

    def dependent(self, robot, z):
        th, margin = chain_closure_double1r(robot, z[:3], z[3:])
        return th[:, 1:], margin

    def closure_residual(self, robot, z, u):
        return loop_residual(robot, self._angles(robot, z, u), z[:3])

    def kin_at(self, robot, z, u, margin, trig=None):
        return self.kin_from_angles(robot, z[:3], self._angles(robot, z, u), margin, trig)

    def chain_spec(self, robot, z, u, trig=None):
        # th_i1 = th_a,i (+ a fixed offset) is coordinate 3 + i; u = (th_i2, th_i3)
        Gz = np.zeros((3, 3, 6))
        Gz[0, np.arange(3), 3 + np.arange(3)] = 1.0
        Gu = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
        # each chain's actuated angle moves that chain alone
        return self.double1r_spec(robot, self._angles(robot, z, u), Gz, Gu,
                                  own=self.actuated_index, trig=trig)

    def coords_from_pose(self, robot, X):
        th, _ = ik_reduced(robot, X)
        return jnp.concatenate([X, th[:, 0] - robot.sigma * robot.delta1])
