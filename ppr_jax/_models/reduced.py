"""L1 `reduced`: the paper's workspace model (eq 54, MODEL.md section 5).

The double-1R chains under the quasi-static assumption d_i1 = d_i2 (eq 29), so the platform pose
X determines every joint angle (inverse kinematics, closed form when r1 = r3). Coordinates z = X
(3 DOF). The equations of motion M_e X'' + C_e X' + dU/dX = S^T tau_a are those of eq 54
(M_e = J^T M J, C_e = J^T (M J' + C J)) with the spring term written as the gradient of U
(MODEL.md: eqs 50-51 are a roundabout way of writing it).
"""

from __future__ import annotations

from .._geometry import ik_reduced
from .double1r import AbstractDouble1R


class Reduced(AbstractDouble1R):
    """L1 `reduced`, the paper's workspace model (module docstring): z = X = (x, y, phi)
    (m, m, rad), 3 DOF; every joint angle from the inverse kinematics under eq 29."""

    name = "reduced"
    level = 1
    n_dof = 3
    actuated_index = None

    def kinematics(self, robot, z):
        th, margin = ik_reduced(robot, z)
        return self.kin_from_angles(robot, z, th, margin)

    def coords_from_pose(self, robot, X):
        return X
