"""The compliant joint as a double-1R pseudo-rigid-body (PRB) model (MODEL.md section 3, paper 1.1).

All quantities are pure, differentiable functions of `RobotParams`; `derived(params)` gathers them
together with the mass properties of section 1 and L0's rigid-model lengths.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._custom_types import Array
from ._params import RobotParams
from ._prb_table import prb_parameters, prb_parameters_numpy


class Derived(eqx.Module):
    """Derived quantities of MODEL.md sections 1 and 3 (SI units, radians).

    PRB joint: `r_i` ideal radius (eq 1), `l` ideal arc length (eq 2), `l_h = l/2`,
    `kappa0 = theta_c/2` (eq 3), `a_i, b_i` half-joint tip in its tangent frame, `s = (1-gamma) l_h`
    short rigid segment, `Theta_i` PRB angle (eq 4), `Theta_0` angle between the PRB links (eq 5),
    `gamma, rho, K_theta` PRB parameters in use, `I_s = w t^3/12` strip second moment,
    `L = r theta_c` actual strip length (eq 7), `K` spring stiffness of each pivot (eq 6),
    `r2` equivalent pseudo-link (eq 8), `r1, r3` theory link lengths (eqs 10, 11), `psi0` rest turn
    at each pivot (replaces eq 9, see MODEL.md).
    The chain (`params.joint_geometry`): `s, r1, r2, r3` are the short segment and the chain's
    vectors A->B, B->D, D->E of the geometry in use, `delta1, delta3` the fixed angles between the
    drive (connecting) link's centre line and its chain vector (0 on the centre lines). With
    `strip` (MODEL.md section 3a) the PRB joint sits on the actual strip: l_h' = r theta_c/2,
    s' = (1 - gamma) l_h', r2' = r2 r/r_i, r1' = |(l1 + s', b_r/2)|, delta1 = atan2(b_r/2, l1 + s')
    (likewise r3', delta3); kappa0, gamma, rho, K_theta, Theta_i, Theta_0, K and psi0 are
    unchanged (the curvature and the strip are the same).
    L0 (rigid): `R1, R3` link lengths to the virtual corner, `K0 = E I_s / L` pin stiffness.
    Mass properties: `m1, I1` drive link (I about its COM), `m2, I2` strip / pseudo-link,
    `m3, I3` connecting link, `m4, I4` platform, `rho_E = h/sqrt(3)` platform circumradius.
    """

    r_i: Array
    l: Array
    l_h: Array
    kappa0: Array
    a_i: Array
    b_i: Array
    gamma: Array
    rho: Array
    K_theta: Array
    s: Array
    Theta_i: Array
    Theta_0: Array
    I_s: Array
    L: Array
    K: Array
    r2: Array
    r1: Array
    r3: Array
    delta1: Array
    delta3: Array
    psi0: Array
    R1: Array
    R3: Array
    K0: Array
    m1: Array
    I1: Array
    m2: Array
    I2: Array
    m3: Array
    I3: Array
    m4: Array
    I4: Array
    rho_E: Array


def derived(params: RobotParams) -> Derived:
    """All derived quantities of MODEL.md section 3 and the mass properties of section 1."""
    return _derived(params, jnp, prb_parameters)


def _derived(p: RobotParams, xp, prb) -> Derived:
    """`derived` in the array namespace `xp` (`jax.numpy`, or `numpy` for concrete values), with
    `prb` the PRB table's interpolant in the same namespace."""
    r_i = p.r + p.b_r / 2  # eq 1
    l = r_i * p.theta_c  # eq 2
    l_h = l / 2
    kappa0 = l_h / r_i  # eq 3 (the printed "r" is r_i): = theta_c / 2
    a_i = r_i * xp.sin(kappa0)
    b_i = r_i * (1 - xp.cos(kappa0))
    if p.gamma is None or p.K_theta is None:
        gamma_t, _, K_theta_t = prb(kappa0)
    gamma = gamma_t if p.gamma is None else p.gamma
    K_theta = K_theta_t if p.K_theta is None else p.K_theta
    s = (1 - gamma) * l_h
    Theta_i = xp.arctan2(b_i, a_i - s)  # eq 4, with l/2
    rho = xp.sqrt((a_i - s) ** 2 + b_i**2) / l_h if p.rho is None else p.rho
    Theta_0 = 2 * Theta_i + xp.pi - p.theta_c  # eq 5
    I_s = p.w * p.t**3 / 12
    L = p.r * p.theta_c  # eq 7
    K = 2 * p.E * I_s * rho * K_theta / L  # eq 6
    r2 = rho * l_h * xp.sqrt(2 * (1 - xp.cos(Theta_0)))  # eq 8
    r1 = p.l1 + s  # eq 10
    r3 = p.l3 + s  # eq 11
    delta1 = delta3 = xp.zeros_like(r1)
    if p.joint_geometry == "strip":
        # MODEL.md 3a: the same joint scaled to the strip's radius, its pivots offset b_r/2 from
        # the centre lines towards the bend; the bodies keep their centre lines.
        s = (1 - gamma) * p.r * p.theta_c / 2
        r2 = r2 * p.r / r_i
        off = p.b_r / 2
        r1, delta1 = xp.hypot(p.l1 + s, off), xp.arctan2(off, p.l1 + s)
        r3, delta3 = xp.hypot(p.l3 + s, off), xp.arctan2(off, p.l3 + s)
    # The joint is symmetric, so the rest turn at each pivot is half the arc angle whatever gamma
    # and rho are; eq 9 as printed breaks that symmetry (MODEL.md section 3).
    psi0 = p.theta_c / 2
    corner = r_i * xp.tan(p.theta_c / 2)
    R1 = p.l1 + corner
    R3 = p.l3 + corner
    K0 = p.E * I_s / L
    m1 = p.rho_m * p.l1 * p.b_r * p.t_r
    I1 = m1 * (p.l1**2 + p.b_r**2) / 12
    m3 = p.rho_m * p.l3 * p.b_r * p.t_r
    I3 = m3 * (p.l3**2 + p.b_r**2) / 12
    m2 = p.rho_m * p.w * p.t * L
    I2 = m2 * r2**2 / 12
    m4 = p.rho_m * (xp.sqrt(3.0) / 4) * p.h**2 * p.t_p
    I4 = m4 * p.h**2 / 12
    rho_E = p.h / xp.sqrt(3.0)
    return Derived(
        r_i=r_i, l=l, l_h=l_h, kappa0=kappa0, a_i=a_i, b_i=b_i, gamma=gamma, rho=rho,
        K_theta=K_theta, s=s, Theta_i=Theta_i, Theta_0=Theta_0, I_s=I_s, L=L, K=K, r2=r2, r1=r1,
        r3=r3, delta1=delta1, delta3=delta3, psi0=psi0, R1=R1, R3=R3, K0=K0, m1=m1, I1=I1, m2=m2,
        I2=I2, m3=m3, I3=I3, m4=m4, I4=I4, rho_E=rho_E,
    )


def derived_concrete(params: RobotParams) -> Derived:
    """`derived` for concrete parameters, in numpy: its leaves are numpy arrays, which a
    compiled program takes as it takes JAX's. As JAX operations it would be one more compiled
    program (0.2 s of every process's first scene, and again for every new batch size), or,
    op by op, about fifty small computations, each compiled on its first use (about 1 s per
    process). numpy's and XLA's transcendental functions may differ in the last bit: a
    trajectory moves by rounding."""
    p = jax.tree_util.tree_map(np.asarray, params)
    return jax.tree_util.tree_map(np.asarray, _derived(p, np, prb_parameters_numpy))
