"""L3 `beam` with quasi-static strips: the default form of L3 in scenes.

Why
---
The strips of L3 weigh 0.35 % of a drive link (8e-4 kg against 0.23 kg at t = 0.3 mm) and their
own bending modes start near 1 kHz and reach ~(N/pi)^2 times that in the N-element chain (20 kHz
at N = 8): with them, an explicit solver needs steps of ~1e-6 s. The robot's modes are ~10 Hz. So
each strip takes its static equilibrium shape for its two clamp poses at every instant
(`strip.py`), and only the rigid bodies keep coordinates.

Degrees of freedom
------------------
The strip is a nonlinear three-DOF spring between the drive link and the connecting link (the
relative position and angle of its two clamps), where the double-1R joint of L1/L2 allows two.
The connecting links are massive, so their angles stay coordinates: z = (x, y, phi, th_a1,
th_a2, th_a3, th3_1, th3_2, th3_3) (m, m, rad, rad x 6), n = 9, independent. The drive link and
th_a give the start clamp (pose of P1), the platform and th3 the end clamp (pose of P2): rigid
geometry, so the chains close to rounding for any z, and a strip that cannot reach (or a Newton
solve that fails) shows as a loop-closure residual, which the scenes report.

The strip's potential U(z) = sum (k/2) d(u*(z), z)^2 is the generic spring energy of
`_dynamics.py` with the deflections d of the solved shape u*(z); its gradient is the clamp wrench
(the constraint force lam and the clamp moments), and the implicit derivatives of u* give the
stiffness matrix used by modes and implicit solvers. Statics are those of `Beam` exactly (the
same potential; `tests/test_beam_qs.py`). The strips' viscous damping c_spring acts on the rates
of their spring deflections as in `Beam`.

Strip inertia
-------------
Lumped: half of each strip's mass as a point mass at each of its clamps (P1 on the drive link,
P2 on the connecting link), no rotary inertia. The strip's kinetic energy in its slaved shape
differs from that by terms of order m_strip / m_link ~ 0.4 % of the links' kinetic energy times
the strip's share of the motion, below the model's other errors; keeping it exactly would need
the second derivatives of the implicit shape in every right-hand side evaluation.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from .._custom_types import Array, Float
from .._geometry import base_points, e, ik_reduced, platform_points, wrap
from .._robot import Robot
from .base import ATOL, RTOL, Kin, rotor_inertia
from .beam import AbstractBeam, strip_constants
from .strip import apply_K, shape_sensitivity, strip_equilibrium

#: above this nondimensional residual of the strip's equilibrium equations the shape is not used:
#: the chain's margin goes to -1 and its loop-closure residual shows the failure
STRIP_TOL = 1e-10


class QuasiStaticBeam(AbstractBeam):
    """L3 `beam` with quasi-static strips (module docstring). `n_elements` (static) is N, the
    segments per strip; z = (x, y, phi, th_a (3,), th3 (3,)), n_dof = 9 for every N. `Kin` is
    L3's: `Kin.th` (3, N + 2) = (th_a, theta_1 .. theta_N, th3), `Kin.deflection` the 3 (N + 1)
    spring deflections, so every output of `Beam` applies."""

    name = "beam"
    fast_index = ()
    default_solver = "dopri8"
    default_rtol = RTOL
    default_atol = ATOL
    level = 3
    n_dof = 9
    actuated_index = (3, 4, 5)

    def clamps(self, robot: Robot, z):
        """(P1 (3, 2), P2 (3, 2)) the strips' start and end points (m) at coordinates z."""
        X, th_a, th3 = z[:3], z[3:6], z[6:9]
        sig = robot.sigma
        P1 = self.strip_start(robot, th_a)
        Q2 = platform_points(robot, X) - robot.l3 * e(th3)
        P2 = Q2 + sig * (robot.b_r / 2) * e(th3 + jnp.pi / 2)
        return P1, P2

    def strips(self, robot: Robot, z):
        """Equilibrium of the three strips at z: (u (3, N) segment angles from th_a (rad),
        lam (3, 2) clamp force over k_in (1/m), err (3,) solver residuals)."""
        N = self.n_elements
        sc = strip_constants(robot, N)
        th_a, th3 = z[3:6], z[6:9]
        d = self._strip_gap(robot, z)
        rest = robot.sigma * robot.theta_c
        beta = rest + wrap(th3 - th_a - rest)

        def one(d, beta):
            return strip_equilibrium(N, sc.h, robot.sigma * sc.dtheta, d, beta)

        return jax.vmap(one)(d, beta)

    def kinematics(self, robot, z):
        N = self.n_elements
        sc = strip_constants(robot, N)
        X, th_a, th3 = z[:3], z[3:6], z[6:9]
        u, _, err = self.strips(robot, z)
        thetas = th_a[:, None] + u
        P1, P2 = self.clamps(robot, z)
        p, ang, _, _ = self.bodies(robot, z)
        deflection = self.spring_deflections(robot, th_a, u, th3)
        th = jnp.concatenate([th_a[:, None], thetas, th3[:, None]], axis=1)
        reach = 1 - jnp.linalg.norm(P2 - P1, axis=-1) / (N * sc.h)
        margin = jnp.where(err <= STRIP_TOL, reach, -1.0)
        return Kin(X=X, th=th, body_p=p, body_ang=ang, deflection=deflection, th_a=th_a,
                   margin=margin)

    def spring_force(self, robot, z, zdot, kin):
        """Strip forces without the Jacobian of the strip shape. Elastic part: by the envelope
        theorem the gradient of U(z) = U(u*(z), z) is the partial gradient, at the solved shape
        u* and force lam*, of the Lagrangian U(u, z) - lam . c(u, z) (the clamp wrenches), so only
        closed-form derivatives in z are taken; u* and lam* still depend on z, so derivatives of
        this force (stiffness, sensitivities) see the implicit shape. Damping: c_spring on every
        spring's deflection rate, -c J_d^T J_d z' (`_strip_damping`)."""
        N = self.n_elements
        sc = strip_constants(robot, N)
        th_a = z[3:6]
        u = kin.th[:, 1:-1] - th_a[:, None]  # (3, N) the solved shapes
        rest = robot.sigma * robot.theta_c
        beta = rest + wrap(kin.th[:, -1] - th_a - rest)
        # the force through each strip from its shape: least squares of the KKT rows (exact at
        # the solution), mu = (C C^T)^-1 C (K u - b)
        # (products as broadcast sums: small dots are library calls on a CPU, `strip.py`)
        g = apply_K(u) - jnp.zeros_like(u).at[:, -1].set(2 * beta)
        C = jnp.stack([-jnp.sin(u), jnp.cos(u)], axis=1)  # (3, 2, N)
        CCt = jnp.sum(C[:, :, None] * C[:, None], axis=-1)
        Cg = jnp.sum(C * g[:, None], axis=-1)
        det = CCt[:, 0, 0] * CCt[:, 1, 1] - CCt[:, 0, 1] * CCt[:, 1, 0]
        mu = jnp.stack([CCt[:, 1, 1] * Cg[:, 0] - CCt[:, 0, 1] * Cg[:, 1],
                        CCt[:, 0, 0] * Cg[:, 1] - CCt[:, 1, 0] * Cg[:, 0]], axis=-1) / det[:, None]

        def lagrangian(zz):
            d = self.spring_deflections(robot, zz[3:6], u, zz[6:9])
            U = 0.5 * jnp.sum(self.stiffness(robot) * d**2)
            return U - sc.k_in * jnp.sum(mu * (-self._strip_gap(robot, zz) / sc.h))

        Q = -jax.grad(lagrangian)(z)

        return Q + _strip_damping(self, robot, z, zdot, u, mu)

    def _strip_gap(self, robot, z):
        """d (3, 2): the end clamp's position P2 - P1 in the start clamp's frame (m)."""
        th_a = z[3:6]
        P1, P2 = self.clamps(robot, z)
        D = P2 - P1
        c, s = jnp.cos(th_a), jnp.sin(th_a)
        return jnp.stack([c * D[:, 0] + s * D[:, 1], -s * D[:, 0] + c * D[:, 1]], axis=-1)

    def bodies(self, robot, z):
        """Bodies without the strip solve (they are the rigid links and the clamp points)."""
        X, th_a, th3 = z[:3], z[3:6], z[6:9]
        P1, P2 = self.clamps(robot, z)
        p1 = base_points(robot) + (robot.l1 / 2) * e(th_a)
        p3 = platform_points(robot, X) - (robot.l3 / 2) * e(th3)
        p = jnp.concatenate([p1, p3, X[None, :2], P1, P2], axis=0)
        return p, jnp.concatenate([th_a, th3, X[2:3], th_a, th3]), th_a, X

    def masses(self, robot):
        sc = strip_constants(robot, self.n_elements)
        one = jnp.ones(3, dtype=jnp.float64)
        half = sc.m_seg * self.n_elements / 2 * one
        m = jnp.concatenate([robot.m1 * one, robot.m3 * one, robot.m4[None], half, half])
        I = jnp.concatenate(
            [rotor_inertia(robot) * one, robot.I3 * one, robot.I4[None], 0 * one, 0 * one]
        )
        return m, I

    def coords_from_pose(self, robot, X):
        """The pose, and the drive and connecting links' centre-line angles of L1's inverse
        kinematics (eq 29): a Newton starting point, not an equilibrium of L3."""
        th, _ = ik_reduced(robot, X)
        th_a = th[:, 0] - robot.sigma * robot.delta1
        th3 = th[:, 2] + robot.sigma * robot.delta3
        return jnp.concatenate([X, th_a, th3])

    def strip_nodes(self, robot, z) -> Float[Array, "3 n 2"]:
        """Strip node positions (3, N + 1, 2) (m) (P1 first, P2 last) at coordinates z."""
        sc = strip_constants(robot, self.n_elements)
        u, _, _ = self.strips(robot, z)
        P1, _ = self.clamps(robot, z)
        steps = sc.h * e(z[3:6, None] + u)
        return jnp.concatenate([P1[:, None], P1[:, None] + jnp.cumsum(steps, axis=1)], axis=1)


def _damping_force(model: QuasiStaticBeam, robot: Robot, z, zdot, u, mu):
    """-c_spring J_d^T J_d z' at the solved shapes u (3, N) and forces mu (3, 2) (the KKT
    multipliers of `strip.kkt_residual`) at z.

    J_d is the Jacobian of the deflections d(z, u*(z)). The shapes' part, du*/dz, is the implicit
    function theorem's -J^-1 F_p dp/dz at the known solution (J, F_p the KKT residual's Jacobians
    in (u, mu) and in p = (d/h, beta, sd), `strip.shape_sensitivity`), so J_d is an explicit
    formula: no second strip solve and no transposed solve, which took the compilation of L3's
    programs to twice what they cost without damping. Differentiable to any order in (robot, z,
    z'), as the shapes' own implicit derivatives are."""
    N = model.n_elements
    sc = strip_constants(robot, N)
    sd = robot.sigma * sc.dtheta
    rest = robot.sigma * robot.theta_c

    def params_of(zz):
        """(3, 4) each strip's p = (d_x/h, d_y/h, beta, sd) at coordinates zz."""
        d = model._strip_gap(robot, zz)
        beta = rest + wrap(zz[6:9] - zz[3:6] - rest)
        return jnp.concatenate([d / sc.h, beta[:, None], jnp.broadcast_to(sd, (3, 1))], axis=1)

    p0 = params_of(z)
    u_p = shape_sensitivity(jnp.concatenate([u, mu], axis=1), p0)[:, :N]  # (3, N, 4)

    def deflections(zz):
        # the shapes to first order about z: exact value and exact first derivative at zz = z
        u_lin = u + jnp.einsum("cnk,ck->cn", u_p, params_of(zz) - p0)
        return model.spring_deflections(robot, zz[3:6], u_lin, zz[6:9])

    _, lin = jax.linearize(deflections, z)
    (JdT_Jd_zd,) = jax.linear_transpose(lin, z)(lin(zdot))
    return -robot.c_spring * JdT_Jd_zd


@eqx.filter_custom_jvp
def _strip_damping(model, robot, z, zdot, u, mu):
    """`_damping_force`, skipped when c_spring is 0 (the default): it adds a third to the cost
    of a right-hand side. The skip is a `lax.cond` on data, so its derivative is given here by
    hand: the derivative of the full expression, which in c_spring is -J_d^T J_d z' also where
    c_spring is 0 (a sensitivity or a fit of c_spring starting from 0 sees it)."""
    return jax.lax.cond(robot.c_spring == 0, lambda: jnp.zeros_like(z),
                        lambda: _damping_force(model, robot, z, zdot, u, mu))


@_strip_damping.def_jvp
def _strip_damping_jvp(primals, tangents):
    model, robot, z, zdot, u, mu = primals
    _, t_robot, t_z, t_zdot, t_u, t_mu = tangents
    return eqx.filter_jvp(lambda r, z, zd, u, mu: _damping_force(model, r, z, zd, u, mu),
                          (robot, z, zdot, u, mu), (t_robot, t_z, t_zdot, t_u, t_mu))
