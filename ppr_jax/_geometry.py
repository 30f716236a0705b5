"""Chain geometry of the planar 3-RRR robot (MODEL.md sections 2 and 4, paper 1.2): points, the
two-link closure, the L1 closed form and the spring deflections (the public kinematics built on
the models is `_kinematics.py`).

Conventions: e(alpha) = (cos alpha, sin alpha); chain i (i = 0, 1, 2 in code, 1..3 in the paper)
runs A_i -> B_i -> D_i -> E_i with absolute link angles th_i1, th_i2, th_i3. The elbow orientation
sigma makes the joint turn by sigma*theta_c at rest (sigma = -1: clockwise).

Every solver here is closed form or a fixed number of Newton steps, so it is jit-able with static
shapes and differentiable; the public wrappers check reachability and residuals and raise a clear
error instead of returning NaN.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ._custom_types import Array, Float
from ._fusion import cos_sin, cos_sin_of, materialize
from ._linalg import solve
from ._robot import Robot

# platform joint directions (NumPy: a module-level jnp array would start the JAX backend at
# import, before a user could choose its devices with `ppr_jax.configure_cpu`)
BETA = np.array([7 * np.pi / 6, -np.pi / 6, np.pi / 2])


@jax.custom_jvp
def e(alpha):
    """Unit vector(s) e(alpha) = (cos alpha, sin alpha), shape alpha.shape + (2,).

    Its derivative is written as e(alpha) turned a quarter (a custom JVP) so that every order of
    derivative reuses the same cosine and sine: with JAX's own rules each JVP of sin and cos
    computed its own cos and sin, which XLA's fusions then recomputed once per consumer; a
    right-hand side took several times the transcendental functions it needs (L1
    `paper-circle`, a batch of 1,024: 610 -> 953 trajectories/s; one L2 run 39 -> 30 ms)."""
    return jnp.stack([jnp.cos(alpha), jnp.sin(alpha)], axis=-1)


@e.defjvp
def _e_jvp(primals, tangents):
    (alpha,), (dalpha,) = primals, tangents
    v = e(alpha)
    return v, jnp.stack([-v[..., 1], v[..., 0]], axis=-1) * dalpha[..., None]


def turn(v, alpha):
    """Vector(s) v (..., 2) turned by the angle alpha (broadcast against v's leading axes):
    e(a + alpha) = turn(e(a), alpha) with one sine and cosine of alpha however many v (a
    scalar alpha's computed once however many kernels read them, `cos_sin_of`)."""
    ca = jnp.stack(cos_sin_of(alpha)) if jnp.ndim(alpha) == 0 else e(alpha)
    # explicit broadcasting (the package runs under JAX's strict rank promotion in its tests)
    shape = jnp.broadcast_shapes(ca.shape[:-1], v.shape[:-1]) + (1,)
    c, s = jnp.broadcast_to(ca[..., 0:1], shape), jnp.broadcast_to(ca[..., 1:2], shape)
    vx, vy = jnp.broadcast_to(v[..., :1], shape), jnp.broadcast_to(v[..., 1:], shape)
    return jnp.concatenate([c * vx - s * vy, s * vx + c * vy], -1)


def home_pose(robot: Robot) -> Float[Array, "3"]:
    """Home pose X_h = (a/2, sqrt(3) a/6, 0), the base centroid."""
    a = robot.a
    return jnp.stack([a / 2, jnp.sqrt(3.0) * a / 6, jnp.zeros_like(a)])


def base_points(robot: Robot) -> Float[Array, "3 2"]:
    """Actuated joints A_1, A_2, A_3 (m)."""
    a = robot.a
    z = jnp.zeros_like(a)
    return jnp.stack(
        [jnp.stack([z, z]), jnp.stack([a, z]), jnp.stack([a / 2, jnp.sqrt(3.0) * a / 2])]
    )


def platform_points(robot: Robot, X: Float[Array, "3"]) -> Float[Array, "3 2"]:
    """Platform joints E_i = (x, y) + rho_E e(beta_i + phi) (m)."""
    # e(beta_i + phi) as e(beta_i) turned by phi: one sine and cosine instead of three, and
    # computed once however many kernels read them (`turn`: XLA copied this sine into every
    # kernel of L1's right-hand side that reads a chain vector, five of them)
    return X[None, :2] + robot.rho_E * turn(np.stack([np.cos(BETA), np.sin(BETA)], -1), X[2])


def wrap(x):
    """Angle wrapped to [-pi, pi] (smooth away from +-pi: derivative 1): x less the nearest
    multiple of 2 pi. The same value as atan2(sin x, cos x) to 1e-15 rad, without its three
    transcendental functions, which it ran inside every right-hand side (L2's 13 % faster)."""
    return x - (2 * jnp.pi) * jnp.round(x / (2 * jnp.pi))


def two_link(d, la, lb, elbow):
    """Solve la e(th_a) + lb e(th_b) = d for (th_a, th_b) on the branch sign(th_b - th_a) = elbow.

    Returns (th_a, th_b, margin) where margin = 1 - |cos(th_b - th_a)| is 0 at the reach limit
    (a singular, stretched or folded, configuration) and negative when d is out of reach; the angles
    are then computed from the clipped cosine and must not be used (callers check `margin`).
    The elbow angle's cosine is the clipped c and its sine elbow sqrt(1 - c^2), not evaluated
    (an L0 right-hand side 410 -> 360 ns on the 2-core CPU).
    """
    dd = jnp.sum(d**2, axis=-1)
    c = (dd - la**2 - lb**2) / (2 * la * lb)
    margin = 1 - jnp.abs(c)
    # Clip away from +-1 so that neither the value nor the gradient is NaN at the reach limit;
    # the margin reports the problem.
    cc = jnp.clip(c, -1 + 1e-15, 1 - 1e-15)
    delta = elbow * jnp.arccos(cc)
    sd = elbow * jnp.sqrt((1 - cc) * (1 + cc))  # sin(delta)
    th_a = jnp.arctan2(d[..., 1], d[..., 0]) - jnp.arctan2(lb * sd, la + lb * cc)
    return th_a, th_a + delta, margin


def _chain_vectors(robot: Robot, X):
    return platform_points(robot, X) - base_points(robot)


# ---------------------------------------------------------------------------------------------
# Inverse kinematics
# ---------------------------------------------------------------------------------------------

#: Newton iterations at most for the unequal-links L1 inverse kinematics (quadratic convergence
#: from the closed-form guess needs 3-5; an unreachable pose exhausts them and shows up as a
#: loop-closure residual, which the scenes turn into an error)
N_NEWTON_IK = 30
#: step (rad) below which that Newton iteration has converged
NEWTON_IK_TOL = 1e-15
#: differentiable Newton steps from the converged root: derivatives exact to this order
N_NEWTON_DIFF = 3


class ChainTrig(NamedTuple):
    """The cosines and sines of a chain's angles, where the closure computes them anyway:
    `cos`, `sin` lists of (3,) arrays (one entry per chain), in the order of the chain angles
    th[:, k]. The equations of motion and the outputs read them instead of evaluating the
    angles' sines again (`_models/fused.py`, `AbstractDouble1R.chain_bodies`)."""

    cos: list
    sin: list


#: |turn| (rad) up to which `_rotated` turns by it exactly (to rounding)
_TURN_MAX = 1e-2


def _rotated(c, s, d):
    """(cos(a + d), sin(a + d)) from (c, s) = (cos a, sin a): cos d and sin d as their Taylor
    polynomials to d^4 and d^5, equal to them to rounding (1e-15) for |d| <= `_TURN_MAX`, with
    d clipped there. d is L1's Newton correction: rounding at the closed form's root, 1e-6 rad
    where the closed form's equal links differ by a finite difference's step (a derivative
    checked against central differences); beyond `_TURN_MAX` the chain does not close (out of
    reach), and the clipped turn keeps the sines bounded, the loop residual near the
    stretched chain's gap. No sine is evaluated."""
    d = jnp.clip(d, -_TURN_MAX, _TURN_MAX)
    d2 = d * d
    cd = 1.0 - 0.5 * d2 * (1.0 - d2 / 12.0)
    sd = d * (1.0 - d2 / 6.0 * (1.0 - d2 / 20.0))
    return c * cd - s * sd, s * cd + c * sd


@jax.custom_jvp
def _trig_of(a, cs):
    """cs = (cos a, sin a) of a 1-D array of angles a, given (computed without evaluating
    sines, `ik_reduced_trig`), once however many kernels read it (`_fusion.materialize`). Its
    derivative is that of the cosines and sines of a, read from cs (as `_fusion.cos_sin`'s):
    differentiated through the products that computed cs, a JVP of the output kinematics took
    more than the sines it saved."""
    return materialize(cs)


@_trig_of.defjvp
def _trig_of_jvp(primals, tangents):
    (a, cs), (da, _) = primals, tangents
    out = _trig_of(a, cs)  # through this rule again at higher orders
    k = a.shape[0]
    return out, jnp.concatenate([-out[k:] * da, out[:k] * da])


def ik_reduced(robot: Robot, X: Float[Array, "3"]):
    """L1 inverse kinematics under the quasi-static assumption th_i1 - 2 th_i2 + th_i3 = 0 (eq 29).

    Returns (th (3, 3) chain angles [i, (th_i1, th_i2, th_i3)], margin (3,)); `ik_reduced_trig`
    also returns their cosines and sines.
    """
    th, margin, _ = ik_reduced_trig(robot, X)
    return th, margin


def ik_reduced_trig(robot: Robot, X: Float[Array, "3"]):
    """L1 inverse kinematics (`ik_reduced`) with the chain angles' cosines and sines.

    Returns (th (3, 3) chain angles [i, (th_i1, th_i2, th_i3)], margin (3,), `ChainTrig`).
    The closed form (MODEL.md section 4) with u = (th1 + th3)/2, v = (th3 - th1)/2:
    (2 r cos v + r2) e(u) = E_i - A_i, is exact when r1 = r3; for r1 != r3 it is the initial guess
    of Newton's method on the 2x2 chain closure, iterated to a step below `NEWTON_IK_TOL` (at most
    `N_NEWTON_IK` iterations, without derivatives), then `N_NEWTON_DIFF` differentiable Newton
    steps from the root, which carry exact derivatives up to that order. `robot.equal_links`
    (static) picks the branch.

    With equal links no sine is evaluated for the chain angles: e(u) is the chain vector's
    direction, cos v the closed form's c and sin v = sigma sqrt(1 - c^2), so th1 = u - v,
    th3 = u + v and th2 = u + c2 are sums of angles whose sines and cosines are products of
    those, turned by the implicit correction (`_rotated`: rounding at the root, more where
    traced link lengths differ from the equal ones the branch was chosen for). They are the
    returned angles' sines to rounding (1e-16), and their derivatives, of every order, are taken
    from the angles' (`_trig_of`). Out of reach (margin < 0) the correction is not small and
    they are not the angles' sines; the margin and the loop residual report that pose either
    way. (An L1 right-hand side evaluated 20 sines and 20 cosines and took 600 ns on the
    2-core CPU; now it evaluates the platform angle's and c2's, and takes 410 ns. The inverse
    trigonometric functions remain, for the angles themselves.)
    """
    d = _chain_vectors(robot, X)
    rbar = (robot.r1 + robot.r3) / 2
    dist = jnp.linalg.norm(d, axis=-1)
    c = (dist - robot.r2) / (2 * rbar)
    margin = 1 - jnp.abs(c)
    cc = jnp.clip(c, -1 + 1e-15, 1 - 1e-15)
    v = robot.sigma * jnp.arccos(cc)
    u = jnp.arctan2(d[:, 1], d[:, 0])
    th1, th3 = u - v, u + v

    # d_i1 = d_i2 (eq 29) puts the middle angle at the mean plus a constant, nonzero only for the
    # strip geometry with unequal links: th_i2 = (th_i1 + th_i3)/2 + c2,
    # c2 = sigma (delta3 - delta1)/2
    c2 = robot.sigma * (robot.delta3 - robot.delta1) / 2

    def resid(th13, di):
        t1, t3 = th13
        t2 = (t1 + t3) / 2 + c2
        return robot.r1 * e(t1) + robot.r2 * e(t2) + robot.r3 * e(t3) - di

    def newton(th13, di):
        # Derivative-free (inputs stopped): the derivatives come from `implicit_correction` at
        # the root, so the loop needs no reverse-mode rule and costs nothing under jvp.
        rob, th13, di, c = jax.lax.stop_gradient((robot, th13, di, c2))

        def res(th13):
            t1, t3 = th13
            return rob.r1 * e(t1) + rob.r2 * e((t1 + t3) / 2 + c) + rob.r3 * e(t3) - di

        def body(c):
            th, k, _ = c
            step = solve(jax.jacfwd(res)(th), res(th))
            return th - step, k + 1, jnp.max(jnp.abs(step))

        def cond(c):
            _, k, err = c
            return (k < N_NEWTON_IK) & (err > NEWTON_IK_TOL)

        th13, _, _ = jax.lax.while_loop(cond, body, (th13, 0, jnp.asarray(jnp.inf)))
        return th13

    def implicit_correction(cv, sv, cm, sm):
        # At the closed-form root the Newton update is zero, but its derivative is the
        # implicit-function derivative -J^-1 dr: exact also in l1 or l3 alone. J multiplies
        # r = 0, so it is held constant (its derivatives would multiply zero): the correction
        # costs one residual and a 2 x 2 inverse in closed form, which matters because it runs
        # inside every right-hand side under two nested derivatives. Written out on the three
        # chains' (3,) arrays, so that XLA fuses it (stacks and 2 x 2 products were a dozen
        # kernels of each L1 right-hand side). The residual and J are the chain's turned by -u
        # (r1 e(-v) + r2 e(c2) + r3 e(v) - (|d|, 0), the same function of every parameter and of
        # X, and the same Newton step): they need no sine of u, and the correction waits only
        # for the closed form's cosine, not for the chain vector's direction.
        rx = (robot.r1 + robot.r3) * cv + robot.r2 * cm - dist
        ry = (robot.r3 - robot.r1) * sv + robot.r2 * sm
        hx, hy = -(robot.r2 / 2) * sm, (robot.r2 / 2) * cm
        # columns d/dt1 = (j00, j10) and d/dt3 = (j01, j11)
        j00, j10, j01, j11 = jax.lax.stop_gradient(
            (hx + robot.r1 * sv, hy + robot.r1 * cv, hx - robot.r3 * sv, hy + robot.r3 * cv)
        )
        inv_det = 1.0 / (j00 * j11 - j01 * j10)
        return -(j11 * rx - j01 * ry) * inv_det, -(j00 * ry - j10 * rx) * inv_det

    # A static choice (`Robot.equal_links`), not a `lax.cond` that vmap would turn into a select
    # running Newton for every member.
    if robot.equal_links:
        # e(u) = d / |d|, e(v) = (c, sigma sqrt(1 - c^2)) (docstring)
        cv, sv = cc, robot.sigma * jnp.sqrt((1 - cc) * (1 + cc))
        cm, sm = cos_sin_of(c2)  # c2 a scalar or one per chain
        # computed once, however many kernels read them (`_fusion.materialize`)
        d13 = materialize(jnp.concatenate(implicit_correction(cv, sv, cm, sm)))
        d1, d3 = d13[:3], d13[3:]
        th1, th3 = th1 + d1, th3 + d3
        # the angles less u, (-v + d1, c2 + (d1 + d3)/2, v + d3), then turned by u
        rel = [_rotated(cv, -sv, d1), _rotated(cm, sm, (d1 + d3) / 2), _rotated(cv, sv, d3)]
        cu, su = d[:, 0] / dist, d[:, 1] / dist
        trig = ([cu * c - su * s for c, s in rel], [su * c + cu * s for c, s in rel])
        chain_trig = _chain_trig([th1, (th1 + th3) / 2 + c2, th3], trig)
    else:
        th13 = jnp.stack([th1, th3], axis=-1)
        # Converged without derivatives, then N_NEWTON_DIFF differentiable Newton steps: at the
        # root each step is exact to one more order of derivative (the Newton map's own
        # derivative vanishes there), and the equations of motion need second derivatives in X
        # (convective terms) and a third order for their parameter gradients.
        th13 = jax.vmap(newton)(th13, d)

        def step(th13, di):
            return th13 - solve(jax.jacfwd(resid)(th13, di), resid(th13, di))

        for _ in range(N_NEWTON_DIFF):
            th13 = jax.vmap(step)(th13, d)
        th1, th3 = th13[:, 0], th13[:, 1]
        chain_trig = ChainTrig(*cos_sin(th1, (th1 + th3) / 2 + c2, th3))
    # (th1, th3) -> (th1, mean + c2, th3) as a product with a constant matrix. Stacked
    # elementwise, XLA's CPU fusion computed th1 and th3 (the closed form or the Newton
    # correction, with their sines) again for every entry of th and of each of its tangents: an
    # L1 batch of 256 on `paper-circle` spent 29 % of its run in those stacks (the path's
    # singularity check, the spring solve, the output kinematics) and ran at 0.75 of c4893c8's
    # speed. A batched dot is a kernel of its own, so its operands are computed once. (One
    # unbatched evaluation: XLA turns the small dot back into fused arithmetic, the run's time
    # unchanged. Under XLA's default flags YNNPACK takes the dot, slowly for this shape;
    # `configure_cpu` turns that off.)
    P = jnp.asarray([[1.0, 0.5, 0.0], [0.0, 0.5, 1.0]], dtype=th1.dtype)
    zero = jnp.zeros_like(th1)
    mid = jnp.broadcast_to(c2, th1.shape)  # c2 is a scalar or one per chain
    th = jnp.stack([th1, th3], axis=-1) @ P + jnp.stack([zero, mid, zero], axis=-1)
    return th, margin, chain_trig


def _chain_trig(angles, trig) -> ChainTrig:
    """`ChainTrig` of the chain angles `angles` (a list of (3,) arrays) from their cosines and
    sines `trig` (two such lists), computed without evaluating sines; derivatives through
    `_trig_of`."""
    k = len(angles)
    cs = _trig_of(jnp.concatenate(angles), jnp.concatenate(list(trig[0]) + list(trig[1])))
    return ChainTrig(cos=[cs[3 * j : 3 * j + 3] for j in range(k)],
                     sin=[cs[3 * (k + j) : 3 * (k + j) + 3] for j in range(k)])


def ik_rigid(robot: Robot, X: Float[Array, "3"]):
    """L0 inverse kinematics of the rigid 3-RRR (links R1, R3 meeting at the virtual corner C_i).

    Returns (th (3, 2) [i, (th_i1, th_i3)], margin (3,)).
    """
    d = _chain_vectors(robot, X)
    t1, t3, margin = two_link(d, robot.R1, robot.R3, robot.sigma)
    return jnp.stack([t1, t3], axis=-1), margin


def chain_closure_double1r(robot: Robot, X, th_a):
    """L2: given the platform pose X and the actuated angles th_a (3,), close each chain with the
    two-link (r2, r3) solution on the elbow branch sigma. Returns (th (3, 3) chain angles, margin
    (3,)); the first chain angle is th_a + sigma delta1 (th_a itself on the centre lines)."""
    t1 = th_a + robot.sigma * robot.delta1
    B = base_points(robot) + robot.r1 * e(t1)
    d = platform_points(robot, X) - B
    t2, t3, margin = two_link(d, robot.r2, robot.r3, robot.sigma)
    # th_a is an unbounded coordinate while atan2 wraps: keep the chain's angles continuous with
    # it so that joint angles, plots and deflections never jump by 2 pi.
    t2 = t1 + wrap(t2 - t1)
    t3 = t2 + wrap(t3 - t2)
    return jnp.stack([t1, t2, t3], axis=-1), margin


def loop_residual(robot: Robot, th, X, trig=None) -> Float[Array, "3 2"]:
    """Loop closure (eq 12): A_i + r1 e(th_i1) + r2 e(th_i2) + r3 e(th_i3) - E_i (m), th (3, 3);
    `trig`, where given, the angles' `ChainTrig`."""
    ev = unit_vectors(th, trig)
    chain = base_points(robot) + robot.r1 * ev[0] + robot.r2 * ev[1] + robot.r3 * ev[2]
    return chain - platform_points(robot, X)


def unit_vectors(th, trig=None) -> list:
    """[e(th[:, k]) for each k] (each (3, 2)), from `trig` (a `ChainTrig`) where given."""
    if trig is None:
        return [e(th[:, k]) for k in range(th.shape[-1])]
    return [jnp.stack([c, s], axis=-1) for c, s in zip(trig.cos, trig.sin)]


def loop_residual_rigid(robot: Robot, th, X) -> Float[Array, "3 2"]:
    """L0 loop closure A_i + R1 e(th_i1) + R3 e(th_i3) - E_i (m), th (3, 2)."""
    chain = base_points(robot) + robot.R1 * e(th[:, 0]) + robot.R3 * e(th[:, 1])
    return chain - platform_points(robot, X)


# ---------------------------------------------------------------------------------------------
# Deflections
# ---------------------------------------------------------------------------------------------


def deflections(robot: Robot, th) -> Float[Array, "3 2"]:
    """Spring deflections of the double-1R model (MODEL.md sections 4 and 3a), th (3, 3) chain
    angles: d_i1 = (th_i2 - th_i1) - sigma (psi0 - delta1), d_i2 = (th_i3 - th_i2) - sigma
    (psi0 - delta3) (rad), measured from the links' tangents (delta = 0 on the centre lines)."""
    return jnp.stack(
        [
            wrap(th[:, 1] - th[:, 0] - robot.sigma * (robot.psi0 - robot.delta1)),
            wrap(th[:, 2] - th[:, 1] - robot.sigma * (robot.psi0 - robot.delta3)),
        ],
        axis=-1,
    )


def deflection_rigid(robot: Robot, th) -> Float[Array, "3"]:
    """L0 pin deflection (th_i3 - th_i1) - sigma theta_c (rad), th (3, 2)."""
    return wrap(th[:, 1] - th[:, 0] - robot.sigma * robot.theta_c)


def singularity_measure(S: Float[Array, "3 3"], r1) -> Array:
    """Inverse condition number of the actuation Jacobian S = d th_a / d X, with the translation
    columns scaled by the link length r1 so that S is dimensionless: 1 is isotropic, 0 singular."""
    Sn = S * jnp.stack([r1, r1, jnp.ones_like(r1)])[None, :]
    sv = jnp.linalg.svd(Sn, compute_uv=False)
    return sv[-1] / sv[0]
