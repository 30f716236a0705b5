"""The paper's closed-form equations of motion (eqs 13-15, 30-35, 41, 47, 54), written out as
printed (with the (3,1) entry of M_i corrected to beta13 c_i13, MODEL.md section 5).

`ppr_jax` derives its equations of motion generically (`_dynamics.py`); this module is an
independent second formulation kept as a reference (the tests compare the two) and for users who
want the paper's matrices themselves.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.scipy.linalg import block_diag

from ._geometry import BETA, deflections, ik_reduced
from ._params import RobotParams
from ._prb import derived
from ._robot import Robot


def paper_constants(params: RobotParams) -> dict:
    """alpha1..3, beta12, beta13, beta23 of eqs 30-35 (kg m^2), with r_ac = l1/2, r_bc = r2/2,
    r_dc = s + l3/2 and the reflected rotor inertia added to I1."""
    dv = derived(params)
    r_ac, r_bc, r_dc = params.l1 / 2, dv.r2 / 2, dv.s + params.l3 / 2
    I1 = dv.I1 + params.J_rotor
    return {
        "alpha1": I1 + dv.m1 * r_ac**2 + dv.m2 * dv.r1**2 + dv.m3 * dv.r1**2,
        "alpha2": dv.I2 + dv.m2 * r_bc**2 + dv.m3 * dv.r2**2,
        "alpha3": dv.I3 + dv.m3 * r_dc**2,
        "beta12": dv.m2 * dv.r1 * r_bc + dv.m3 * dv.r1 * dv.r2,
        "beta13": dv.m3 * dv.r1 * r_dc,
        "beta23": dv.m3 * dv.r2 * r_dc,
    }


def paper_joint_matrices(params: RobotParams, th, thdot):
    """M (12, 12) and C (12, 12) of eq 41 for joint angles th (3, 3) and rates thdot (3, 3)."""
    dv = derived(params)
    k = paper_constants(params)
    blocks_M, blocks_C = [], []
    for i in range(3):
        t1, t2, t3 = th[i]
        d1, d2, d3 = thdot[i]
        c12, c13, c23 = jnp.cos(t1 - t2), jnp.cos(t1 - t3), jnp.cos(t2 - t3)
        s12, s13, s23 = jnp.sin(t1 - t2), jnp.sin(t1 - t3), jnp.sin(t2 - t3)
        b12, b13, b23 = k["beta12"], k["beta13"], k["beta23"]
        blocks_M.append(jnp.array([
            [k["alpha1"], b12 * c12, b13 * c13],
            [b12 * c12, k["alpha2"], b23 * c23],
            [b13 * c13, b23 * c23, k["alpha3"]],
        ]))
        blocks_C.append(jnp.array([
            [0.0, b12 * s12 * d2, b13 * s13 * d3],
            [-b12 * s12 * d1, 0.0, b23 * s23 * d3],
            [-b13 * s13 * d1, -b23 * s23 * d2, 0.0],
        ]))
    blocks_M.append(jnp.diag(jnp.stack([dv.m4, dv.m4, dv.I4])))
    blocks_C.append(jnp.zeros((3, 3)))
    return block_diag(*blocks_M), block_diag(*blocks_C)


def paper_jacobian(params: RobotParams, X):
    """J = [P^-1 Q; I3] (eq 47) of the L1 model at pose X: P_i, Q_i of eq 13 with the row of the
    quasi-static constraint th_i1 - 2 th_i2 + th_i3 = 0 (eq 29) appended, so that P_i is square."""
    dv = derived(params)
    th, _ = ik_reduced(Robot(params), X)
    P, Q = [], []
    for i in range(3):
        t = th[i]
        r = jnp.stack([dv.r1, dv.r2, dv.r3])
        P.append(jnp.stack([-r * jnp.sin(t), r * jnp.cos(t), jnp.array([1.0, -2.0, 1.0])]))
        a = BETA[i] + X[2]
        Q.append(jnp.array([
            [1.0, 0.0, -dv.rho_E * jnp.sin(a)],
            [0.0, 1.0, dv.rho_E * jnp.cos(a)],
            [0.0, 0.0, 0.0],
        ]))
    J_th = jnp.linalg.solve(block_diag(*P), jnp.concatenate(Q, axis=0))
    return jnp.concatenate([J_th, jnp.eye(3)], axis=0), th


def paper_workspace_eom(params: RobotParams, X, Xdot):
    """(M_e, C_e X', spring force) of eq 54 from the paper's matrices: M_e = J^T M J,
    C_e X' = J^T (M J' X' + C J X'), spring = J^T K_blocks (q - q0) = dU/dX."""
    dv = derived(params)
    J, th = paper_jacobian(params, X)
    Jdot_Xdot = jax.jvp(lambda X: paper_jacobian(params, X)[0] @ Xdot, (X,), (Xdot,))[1]
    qdot = J @ Xdot
    M, C = paper_joint_matrices(params, th, qdot[:9].reshape(3, 3))
    Me = J.T @ M @ J
    CeXd = J.T @ (M @ Jdot_Xdot + C @ qdot)
    d = deflections(Robot(params), th)
    # K_i (q - q0) of eq 41 written with the deflections: (-d_i1, d_i1 - d_i2, d_i2) K.
    Kq = jnp.concatenate(
        [jnp.stack([-d[i, 0], d[i, 0] - d[i, 1], d[i, 1]]) for i in range(3)] + [jnp.zeros(3)]
    )
    return Me, CeXd, J.T @ (dv.K * Kq)
