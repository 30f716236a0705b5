"""L2 `double1r`: the double-1R PRB model without the quasi-static assumption (MODEL.md section 5).

Both pivots of every compliant joint are free and the pseudo-link keeps its inertia: 12 joint
coordinates with 6 loop closures, 6 DOF. We integrate in the independent coordinates
z = (x, y, phi, th_11, th_21, th_31): given the pose and the actuated angles, each chain closes in
closed form (the two-link (r2, r3) problem from B_i to E_i, elbow branch sigma), so the loop
closures hold to rounding at every step instead of drifting, and the actuated angles are
coordinates, which makes motion-driven actuation a plain partition of z.
"""

from __future__ import annotations

import jax.numpy as jnp

from ._kinematics import chain_closure_double1r, deflections, ik_reduced
from ._model import AbstractModel, Kin, chain_bodies_double1r, masses_double1r


class Double1R(AbstractModel):
    name = "double1r"
    level = 2
    n_dof = 6
    actuated_index = (3, 4, 5)

    def kinematics(self, params, dv, z):
        X, th_a = z[:3], z[3:]
        th, margin = chain_closure_double1r(params, dv, X, th_a)
        p, ang = chain_bodies_double1r(params, dv, th, X)
        return Kin(
            X=X, th=th, body_p=p, body_ang=ang,
            defl=deflections(params, dv, th).reshape(-1), th_a=th_a, margin=margin,
        )

    def masses(self, params, dv):
        return masses_double1r(params, dv)

    def stiffness(self, params, dv):
        return dv.K

    def coords_from_pose(self, params, dv, X):
        th, _ = ik_reduced(params, dv, X)
        return jnp.concatenate([X, th[:, 0]])
