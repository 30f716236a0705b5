"""L1 `reduced`: the paper's workspace model (eq 54, MODEL.md section 5).

The double-1R chains under the quasi-static assumption d_i1 = d_i2 (eq 29), so the platform pose
X determines every joint angle (inverse kinematics, closed form when r1 = r3). Coordinates z = X
(3 DOF). The equations of motion M_e X'' + C_e X' + dU/dX = S^T tau_a are those of eq 54
(M_e = J^T M J, C_e = J^T (M J' + C J)) with the spring term written as the gradient of U
(MODEL.md: eqs 50-51 are a roundabout way of writing it).
"""

from __future__ import annotations

from ._kinematics import deflections, ik_reduced
from ._model import AbstractModel, Kin, chain_bodies_double1r, masses_double1r


class Reduced(AbstractModel):
    name = "reduced"
    level = 1
    n_dof = 3

    def kinematics(self, params, dv, z):
        X = z
        th, margin = ik_reduced(params, dv, X)
        p, ang = chain_bodies_double1r(params, dv, th, X)
        return Kin(
            X=X, th=th, body_p=p, body_ang=ang,
            defl=deflections(params, dv, th).reshape(-1), th_a=th[:, 0], margin=margin,
        )

    def masses(self, params, dv):
        return masses_double1r(params, dv)

    def stiffness(self, params, dv):
        return dv.K

    def coords_from_pose(self, params, dv, X):
        return X
