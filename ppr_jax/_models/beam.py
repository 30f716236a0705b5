"""L3 `beam`: each compliant strip as a discretized geometrically exact beam (MODEL.md section 5).

A planar, inextensible Euler-Bernoulli strip of the actual radius r, length L = r theta_c and
EI = E w t^3/12, clamped to the inner sides of the links, as a Hencky bar chain of N rigid
segments (chords of the unloaded arc cells, so the rest shape is exact for every N; O(1/N^2) to
the elastica): interior springs EI/ds, clamp half-springs 2 EI/ds. Coordinates
z = (x, y, phi, th_a1..3, interior relative angles), n = 3 + 3N, independent: each chain closes
in closed form (a two-link problem), so the loops close to rounding and the generic equations of
motion, statics and modes apply unchanged. The derivation, geometry and body layout:
docs/beam_model.md.

`Kin.th` (3, N + 2) = (th_a, theta_1 .. theta_N, th3) per chain; `Kin.deflection` (3 (N + 1),) the
spring deflections chain-major (clamp half-spring, N - 1 interior springs, clamp half-spring),
with `Beam.stiffness` the matching vector. Also here: `solve_strip`, the same discrete strip as an
end-loaded cantilever, the counterpart of `ppr_jax.elastica.solve_cantilever`.
"""

from __future__ import annotations

from functools import partial

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx

from .._custom_types import Array, Float
from .._errors import PPRError
from .._geometry import base_points, e, ik_reduced, platform_points, two_link, wrap
from .._linalg import SmallLU, solve
from .._names import FULL_L3_ATOL, FULL_L3_RTOL
from .._robot import Robot
from .base import AbstractModel, Kin, rotor_inertia

# ---------------------------------------------------------------------------------------------
# Strip constants
# ---------------------------------------------------------------------------------------------


class StripConstants(eqx.Module):
    """Discretization constants of one strip with N elements (SI units, radians).

    EI bending stiffness (N m^2); ds = L/N cell arclength (m); h = 2 r sin(ds/(2r)) segment
    (chord) length (m); dtheta = theta_c/N rest turn of an interior spring in magnitude (rad;
    the signed rest turn is sigma dtheta); k_in = EI/ds, k_end = 2 EI/ds (N m/rad);
    m_seg = rho_m w t ds (kg) and I_seg = m_seg ds^2/12 (kg m^2) per segment."""

    EI: Array
    ds: Array
    h: Array
    dtheta: Array
    k_in: Array
    k_end: Array
    m_seg: Array
    I_seg: Array


def strip_constants(robot: Robot, n_elements: int) -> StripConstants:
    """`StripConstants` of the robot's strips discretized into `n_elements` segments."""
    p = robot
    N = n_elements
    EI = p.E * p.w * p.t**3 / 12
    L = p.r * p.theta_c
    ds = L / N
    h = 2 * p.r * jnp.sin(ds / (2 * p.r))
    m = p.rho_m * p.w * p.t * ds
    return StripConstants(
        EI=EI, ds=ds, h=h, dtheta=p.theta_c / N, k_in=EI / ds, k_end=2 * EI / ds, m_seg=m,
        I_seg=m * ds**2 / 12,
    )


def _elbow(robot: Robot):
    # Branch of the unloaded shape: the chord of the arc turns sigma theta_c/2 from th_a, the
    # offset vector g turns sigma (theta_c - atan(b_r/(2 l3))): their difference has the sign of
    # sigma (theta_c/2 - atan(b_r/(2 l3))).
    s = robot.sigma
    return jnp.where(robot.theta_c / 2 >= jnp.arctan2(robot.b_r / 2, robot.l3), s, -s)


# ---------------------------------------------------------------------------------------------
# The model
# ---------------------------------------------------------------------------------------------


class AbstractBeam(AbstractModel):
    """What the two forms of L3 share: N-element Hencky strips clamped to the links' inner sides
    (module docstring), their springs and the outputs computed from the chain angles
    th (3, N + 2) = (th_a, theta_1 .. theta_N, th3) of `Kin.th`. `Beam` keeps the strips'
    inertia and interior angles as coordinates; `QuasiStaticBeam` (`beam_qs.py`) puts every strip
    in static equilibrium for its clamp poses."""

    n_elements: int = eqx.field(static=True, default=8)

    def __check_init__(self):
        if not (isinstance(self.n_elements, int) and self.n_elements >= 2):
            raise PPRError(f"n_elements must be an integer >= 2, got {self.n_elements!r}")

    def stiffness(self, robot):
        N = self.n_elements
        sc = strip_constants(robot, N)
        one_chain = jnp.concatenate(
            [sc.k_end[None], sc.k_in * jnp.ones(N - 1, dtype=jnp.float64), sc.k_end[None]]
        )
        return jnp.tile(one_chain, 3)

    def strip_start(self, robot: Robot, th_a) -> Float[Array, "3 2"]:
        """P1 (3, 2) (m): where each strip leaves its drive link (at l1 along the link, b_r/2 off
        its centre line on the inner side), for drive angles th_a (3,)."""
        return (base_points(robot) + robot.l1 * e(th_a)
                + robot.sigma * (robot.b_r / 2) * e(th_a + jnp.pi / 2))

    def spring_deflections(self, robot: Robot, th_a, u, th3) -> Float[Array, " m"]:
        """Spring deflections (3 (N + 1),) (rad), chain-major (clamp half-spring, N - 1 interior
        springs, clamp half-spring), from the drive angles th_a (3,), the segment angles
        relative to them u (3, N) and the connecting links' angles th3 (3,)."""
        sd = robot.sigma * strip_constants(robot, self.n_elements).dtheta
        d_first = wrap(u[:, 0] - sd / 2)
        d_mid = jnp.diff(u, axis=1) - sd
        d_last = wrap(th3 - th_a - u[:, -1] - sd / 2)
        return jnp.concatenate([d_first[:, None], d_mid, d_last[:, None]], axis=1).reshape(-1)

    # -- outputs --------------------------------------------------------------------------------

    def chain_points(self, robot, th):
        """(P1, P2, Q2, E) each (3, 2) (m) from the chain angles th (3, N + 2) of `Kin.th`:
        strip start and end, start of the connecting link's centre line, the chain's E_i."""
        sc = strip_constants(robot, self.n_elements)
        sig = robot.sigma
        th_a, thetas, th3 = th[:, 0], th[:, 1:-1], th[:, -1]
        P1 = self.strip_start(robot, th_a)
        P2 = P1 + sc.h * jnp.sum(e(thetas), axis=1)
        Q2 = P2 - sig * (robot.b_r / 2) * e(th3 + jnp.pi / 2)
        return P1, P2, Q2, Q2 + robot.l3 * e(th3)

    def chain_E(self, robot, th):
        """Chain end E_i (3, 2) (m) from the chain angles th (3, N + 2) of `Kin.th`."""
        return self.chain_points(robot, th)[3]

    def loop_residual(self, robot, kin):
        """The chain's E_i minus the platform's E_i (3, 2) (m): zero to rounding."""
        return self.chain_E(robot, kin.th) - platform_points(robot, kin.X)

    def joint_end_rotations(self, robot, kin):
        """Rotations (3, 2) (rad) of the strip's two end tangents relative to its chord P1 -> P2,
        minus their rest values: (chord - th_a) - sigma theta_c/2 and (th3 - chord) -
        sigma theta_c/2. The unloaded chord is parallel to L2's pseudo-link, so these compare
        with L2's pivot deflections (d_i1, d_i2) and sum to the same total th3 - th_a -
        sigma theta_c."""
        th = kin.th
        ch = jnp.sum(e(th[:, 1:-1]), axis=1)
        chord = jnp.arctan2(ch[:, 1], ch[:, 0])
        half = robot.sigma * robot.theta_c / 2
        r1 = wrap(chord - th[:, 0] - half)
        r2 = wrap(th[:, -1] - chord - half)
        return jnp.stack([r1, r2], axis=-1)

    def corners(self, robot, th):
        """Where each chain's drive-link and connecting-link centre lines meet (3, 2) (m), from
        the chain angles th (3, N + 2) of `Kin.th`: the virtual corner C_i of L0 (at
        R1 = l1 + r_i tan(theta_c/2) from A_i) when the strip is at rest."""
        _, _, Q2, _ = self.chain_points(robot, th)
        A = base_points(robot)
        d1, d3 = e(th[:, 0]), e(th[:, -1])
        # A + s d1 = Q2 + u d3  ->  [d1, -d3] (s, u) = Q2 - A
        Mtx = jnp.stack([d1, -d3], axis=-1)  # (3, 2, 2)
        su = jax.vmap(solve)(Mtx, Q2 - A)
        return A + su[:, :1] * d1

    def rest_angles(self, robot, th_a):
        """Chain angles th (3, N + 2) of the unloaded (natural-arc) strips for drive angles
        th_a (3,): every spring at its rest turn."""
        N = self.n_elements
        sc = strip_constants(robot, N)
        sig = robot.sigma
        thetas = th_a[:, None] + sig * sc.dtheta * (jnp.arange(N, dtype=jnp.float64) + 0.5)[None, :]
        th3 = th_a + sig * robot.theta_c
        return jnp.concatenate([th_a[:, None], thetas, th3[:, None]], axis=1)



class Beam(AbstractBeam):
    """L3 `beam`: the compliant strips as N-element Hencky bar chains (module docstring).

    `n_elements` (static) is N, the number of rigid segments per strip; n_dof = 3 + 3N.
    z = (x, y, phi, th_a1, th_a2, th_a3, phi_12..phi_1N, phi_22..phi_2N, phi_32..phi_3N)
    (m, m, rad, rad...). Converges to the elastica as O(1/N^2).

    `strip_loss` (static, seconds, >= 0; default 0: undamped strips, as in the paper) is the
    retardation time tau of a Kelvin-Voigt material loss in the strips: each strip spring i gets
    the viscous damping c_spring + tau k_i (N m s/rad), k_i its entry of `stiffness`, so the
    damping matrix is c_spring J_d^T J_d + tau K and an undamped mode of angular frequency omega
    whose energy sits in the strips gets the damping ratio zeta = tau omega / 2. Stiffness-
    proportional on purpose: it damps the fast strip modes (kHz, what makes the full L3 stiff
    and rings after every jerk of the drive) and leaves the slow modes of the robot nearly
    untouched. For tau = 1e-5 s (N = 8, default robot, actuators locked): the first strip mode
    (2.4 kHz) gets zeta = 0.075, the highest (19.9 kHz; 85 kHz at N = 16) zeta = 0.62, and the
    robot's first mode (9.6 Hz) zeta = 3e-4. Zero is allowed (the default); a negative value
    raises `PPRError`. The loss enters through `damping`, which `_dynamics.py` applies to every
    spring's deflection rate."""

    name = "beam"
    level = 3
    actuated_index = (3, 4, 5)
    #: strips with their own inertia have modes up to 5e5 rad/s at N = 16, where an explicit
    #: solver is bound by stability to microsecond steps: Kvaerno5 with its Jacobian kept across
    #: steps. Over the whole paper-circle at N = 16 and rtol 1e-4 it took 72 s against diffrax's
    #: Kvaerno5's 179 s (the same steps, a Jacobian every step) and Ros34PW2's 314 s (65,066
    #: steps: order 3) on a 2-core CPU (docs/theory/strips.md)
    default_solver = "kvaerno5-kept"
    #: looser than the other levels' (`_names.FULL_L3_RTOL` says why)
    default_rtol = FULL_L3_RTOL
    default_atol = FULL_L3_ATOL

    strip_loss: float = eqx.field(default=0.0, static=True)

    def __check_init__(self):
        v = self.strip_loss
        if (isinstance(v, bool) or not isinstance(v, (int, float)) or not v >= 0
                or v == float("inf")):
            raise PPRError(f"strip_loss (Kelvin-Voigt retardation time of the strips) must be a "
                           f"finite number of seconds in [0, inf), got {v!r}")

    def damping(self, robot):
        """Viscous damping of the springs (N m s/rad), one per entry of `Kin.deflection`:
        c_spring + strip_loss * `stiffness` (Kelvin-Voigt strips; class docstring); the scalar
        c_spring when strip_loss is 0."""
        if self.strip_loss == 0:
            return robot.c_spring
        return robot.c_spring + self.strip_loss * self.stiffness(robot)

    @property
    def n_dof(self) -> int:  # type: ignore[override]
        return 3 + 3 * self.n_elements

    @property
    def fast_index(self) -> tuple:  # type: ignore[override]
        """The interior strip angles (their modes reach 5e5 rad/s at N = 16)."""
        return tuple(range(6, self.n_dof))

    # -- coordinates ----------------------------------------------------------------------------

    def split(self, z):
        """(X (3,), th_a (3,), phi (3, N - 1) interior relative angles) from z."""
        N = self.n_elements
        return z[:3], z[3:6], z[6:].reshape(3, N - 1)

    def _chains(self, robot: Robot, z):
        """Close the three chains. Returns a dict of (3, ...) arrays: th (3, N+2), P1, nodes
        (3, N+1, 2), Q2, E (chain's E_i), margin."""
        sc = strip_constants(robot, self.n_elements)
        sig = robot.sigma
        X, th_a, phi = self.split(z)
        alpha = jnp.concatenate([jnp.zeros((3, 1)), jnp.cumsum(phi, axis=1)], axis=1)  # (3, N)
        c = sc.h * jnp.sum(e(alpha), axis=1)  # chord in the frame of segment 1 (3, 2)
        P1 = self.strip_start(robot, th_a)
        g = jnp.stack([robot.l3, -sig * robot.b_r / 2])
        arg_g = jnp.arctan2(g[1], g[0])
        E = platform_points(robot, X)
        la = jnp.linalg.norm(c, axis=-1)
        ta, tb, margin = two_link(E - P1, la, jnp.linalg.norm(g), _elbow(robot))
        theta1 = ta - jnp.arctan2(c[:, 1], c[:, 0])
        # keep the angles continuous with the unbounded coordinate th_a (atan2 wraps)
        theta1 = th_a + wrap(theta1 - th_a)
        thetas = theta1[:, None] + alpha  # (3, N)
        th3 = tb - arg_g
        th3 = thetas[:, -1] + wrap(th3 - thetas[:, -1])
        steps = sc.h * e(thetas)  # (3, N, 2)
        nodes = jnp.concatenate(
            [P1[:, None, :], P1[:, None, :] + jnp.cumsum(steps, axis=1)], axis=1
        )
        P2 = nodes[:, -1]
        Q2 = P2 - sig * (robot.b_r / 2) * e(th3 + jnp.pi / 2)
        E_chain = Q2 + robot.l3 * e(th3)
        th = jnp.concatenate([th_a[:, None], thetas, th3[:, None]], axis=1)
        return dict(th=th, P1=P1, nodes=nodes, Q2=Q2, E=E_chain, margin=margin, sc=sc)

    def kinematics(self, robot, z):
        N = self.n_elements
        X, th_a, _ = self.split(z)
        ch = self._chains(robot, z)
        th, nodes = ch["th"], ch["nodes"]
        thetas, th3 = th[:, 1:-1], th[:, -1]
        A = base_points(robot)
        p1 = A + (robot.l1 / 2) * e(th_a)
        pseg = (nodes[:, :-1] + nodes[:, 1:]) / 2  # (3, N, 2)
        p3 = ch["Q2"] + (robot.l3 / 2) * e(th3)
        p = jnp.concatenate([p1, pseg.reshape(3 * N, 2), p3, X[None, :2]], axis=0)
        ang = jnp.concatenate([th_a, thetas.reshape(-1), th3, X[2:3]])
        deflection = self.spring_deflections(robot, th_a, thetas - th_a[:, None], th3)
        return Kin(X=X, th=th, body_p=p, body_ang=ang, deflection=deflection, th_a=th_a,
                   margin=ch["margin"])

    def masses(self, robot):
        N = self.n_elements
        sc = strip_constants(robot, N)
        one = jnp.ones(3, dtype=jnp.float64)
        ones = jnp.ones(3 * N, dtype=jnp.float64)
        m = jnp.concatenate([robot.m1 * one, sc.m_seg * ones, robot.m3 * one, robot.m4[None]])
        I = jnp.concatenate(
            [rotor_inertia(robot) * one, sc.I_seg * ones, robot.I3 * one, robot.I4[None]]
        )
        return m, I

    def coords_from_pose(self, robot, X):
        """A smooth guess on the L1 manifold: th_a from L1's inverse kinematics (eq 29) and every
        interior joint at its rest turn plus an equal share of the L1 joint's total deflection
        (th_i3 - th_i1 - sigma theta_c; a pure-moment distribution: an end half-spring, twice as
        stiff, takes half a share, so N shares in all). A Newton starting point for
        `static_equilibrium` / `quasi_static_state`, not an equilibrium of L3."""
        N = self.n_elements
        th, _ = ik_reduced(robot, X)
        # the links' centre-line angles (the chain's first and last vectors are offset from
        # them by delta1, delta3 when `joint_geometry` is `strip`; L3 itself ignores the option)
        th_a = th[:, 0] - robot.sigma * robot.delta1
        th3 = th[:, 2] + robot.sigma * robot.delta3
        D = wrap(th3 - th_a - robot.sigma * robot.theta_c)
        phi = jnp.broadcast_to(((robot.sigma * robot.theta_c + D) / N)[:, None], (3, N - 1))
        return jnp.concatenate([X, th_a, phi.reshape(-1)])

    def strip_nodes(self, robot, z) -> Float[Array, "3 n 2"]:
        """Strip node positions (3, N + 1, 2) (m) (P1 first, P2 last) at coordinates z."""
        return self._chains(robot, z)["nodes"]


# ---------------------------------------------------------------------------------------------
# The discrete strip as a cantilever (check against the elastica)
# ---------------------------------------------------------------------------------------------


class StripSolution(eqx.Module):
    """Equilibrium of the discrete cantilever strip, in the clamp tangent frame of
    `ppr_jax.elastica.solve_cantilever`. s (N+1,) nominal arclength of the nodes (m); x, y (N+1,)
    node positions (m); theta (N,) segment angles (rad); tip (3,) (x, y, tip tangent angle)
    (m, m, rad); result the optimistix result code of the last Newton solve."""

    s: Array
    x: Array
    y: Array
    theta: Array
    tip: Array
    result: optx.RESULTS


@partial(jax.jit, static_argnames=("n_elements", "n_continuation"))
def solve_strip(
    length, EI, kappa0, force, moment, *, n_elements: int, n_continuation: int = 4
) -> StripSolution:
    """Static equilibrium of the N-element strip clamped at s = 0 under an end load.

    Same conventions as `ppr_jax.elastica.solve_cantilever`: clamp at the origin with tangent +x,
    rest curvature kappa0/length towards +y (kappa0 = length/R, nondimensional), dead end force
    `force` (2,) (N) and end moment `moment` (N m, counterclockwise). The discretization is the
    one of `Beam`: clamp half-spring 2 EI/ds, N - 1 interior springs EI/ds, segments of chord
    length h = ds sinc(kappa0/(2N)); the tip tangent is a zero-length stub behind an end
    half-spring 2 EI/ds (the robot's clamp to the connecting link), which gives the tip angle
    theta_N + (kappa0/L + moment/EI) ds/2. Unknowns (theta_1..theta_N, tip angle): Newton on
    the gradient of the potential energy, with `n_continuation` load steps from the unloaded
    arc. Differentiable (implicit function theorem)."""
    N = n_elements
    length, EI, kappa0, moment = (jnp.asarray(v, jnp.float64) for v in (length, EI, kappa0, moment))
    force = jnp.asarray(force, jnp.float64)
    ds = length / N
    dth = kappa0 / N
    h = ds * jnp.sinc(dth / (2 * jnp.pi))  # 2 (L/kappa0) sin(kappa0/(2N)), also for kappa0 = 0
    k_in, k_end = EI / ds, 2 * EI / ds

    def energy(q, lam):
        theta, tip_angle = q[:N], q[N]
        d0 = theta[0] - dth / 2
        dm = jnp.diff(theta) - dth
        dN = tip_angle - theta[-1] - dth / 2
        U = 0.5 * k_end * (d0**2 + dN**2) + 0.5 * k_in * jnp.sum(dm**2)
        tip = h * jnp.sum(e(theta), axis=0)
        return U - lam * (force @ tip + moment * tip_angle)

    grad = jax.grad(energy)

    def resid(q, lam):
        return grad(q, lam) / k_in  # nondimensional (rad)

    def step(q, lam):
        newton = optx.Newton(rtol=1e-13, atol=1e-13, linear_solver=SmallLU())
        sol = optx.root_find(resid, newton, q, args=lam, max_steps=50, throw=False)
        return sol.value, sol.result == optx.RESULTS.successful

    # the unloaded arc
    q0 = jnp.concatenate([dth * (jnp.arange(N, dtype=jnp.float64) + 0.5), kappa0[None]])
    lams = jnp.arange(1, n_continuation + 1, dtype=jnp.float64) / n_continuation
    q, converged = jax.lax.scan(step, q0, lams)
    result = optx.RESULTS.where(
        jnp.all(converged), optx.RESULTS.successful, optx.RESULTS.nonlinear_divergence
    )
    theta, tip_angle = q[:N], q[N]
    steps = h * e(theta)
    nodes = jnp.concatenate([jnp.zeros((1, 2)), jnp.cumsum(steps, axis=0)], axis=0)
    return StripSolution(
        s=jnp.linspace(0.0, 1.0, N + 1) * length, x=nodes[:, 0], y=nodes[:, 1], theta=theta,
        tip=jnp.stack([nodes[-1, 0], nodes[-1, 1], tip_angle]), result=result,
    )
