"""L1 `reduced`: the paper's workspace model (eq 54, MODEL.md section 5).

The double-1R chains under the quasi-static assumption d_i1 = d_i2 (eq 29), so the platform pose
X determines every joint angle (inverse kinematics, closed form when r1 = r3). Coordinates z = X
(3 DOF). The equations of motion M_e X'' + C_e X' + dU/dX = S^T tau_a are those of eq 54
(M_e = J^T M J, C_e = J^T (M J' + C J)) with the spring term written as the gradient of U
(MODEL.md: eqs 50-51 are a roundabout way of writing it).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .._geometry import ik_reduced_trig, loop_residual
from .base import ATOL, RTOL
from .double1r import AbstractDouble1R


class Reduced(AbstractDouble1R):
    """L1 `reduced`, the paper's workspace model (module docstring): z = X = (x, y, phi)
    (m, m, rad), 3 DOF; every joint angle from the inverse kinematics under eq 29."""

    name = "reduced"
    fast_index = ()
    default_solver = "tsit5"
    default_rtol = RTOL
    default_atol = ATOL
    level = 1
    n_dof = 3
    actuated_index = None

    # The dependent coordinates u (3, 2) are each chain's (th_i1, th_i3); eq 29 puts th_i2 at
    # (th_i1 + th_i3)/2 + c (c = 0 on the centre lines), and the loop closes.

    def _angles(self, robot, u):
        c2 = robot.sigma * (robot.delta3 - robot.delta1) / 2
        return jnp.stack([u[:, 0], (u[:, 0] + u[:, 1]) / 2 + c2, u[:, 1]], axis=-1)

    def dependent(self, robot, z):
        u, margin, _ = self.dependent_trig(robot, z)
        return u, margin

    def dependent_trig(self, robot, z):
        th, margin, trig = ik_reduced_trig(robot, z)
        return th[:, ::2], margin, trig

    def closure_residual(self, robot, z, u):
        return loop_residual(robot, self._angles(robot, u), z)

    def kin_at(self, robot, z, u, margin, trig=None):
        return self.kin_from_angles(robot, z, self._angles(robot, u), margin, trig)

    def chain_spec(self, robot, z, u, trig=None):
        # th_i2 = (th_i1 + th_i3)/2 + c: the chain angles depend on z through u alone
        Gu = np.array([[1.0, 0.0], [0.5, 0.5], [0.0, 1.0]])
        return self.double1r_spec(robot, self._angles(robot, u), np.zeros((3, 3, 3)), Gu,
                                  trig=trig)

    def coords_from_pose(self, robot, X):
        return X
