"""The clamped-clamped Hencky strip of L3 in static equilibrium for given clamp poses.

Used by the quasi-static L3 (`beam_qs.py`). The strip of N rigid segments of chord length h has
segment angles theta_k = th_a + u_k, measured from the start clamp's tangent (the drive link's
direction th_a). Its spring deflections are u_1 - sd/2 (clamp half-spring, k_end = 2 k_in),
u_{k+1} - u_k - sd (N - 1 interior springs, k_in) and beta - u_N - sd/2 (clamp half-spring at
the connecting link), with sd = sigma dtheta the signed rest turn of an interior spring and
beta = th3 - th_a the end clamp's angle. The end position is a constraint,

    c(u) = sum_k e(u_k) - d/h = 0,      d (2,) = R(-th_a) (P2 - P1),

so the equilibrium is a stationary point of U/k_in - mu . c: N + 2 equations in (u, mu), with
mu = lam h / k_in the nondimensional force through the strip. The shape depends on the geometry
(h, sd, d, beta) only; the bending stiffness scales the energy and the forces, not the shape.

How it is solved, and why so
----------------------------
The equations are solved in every right-hand side evaluation of the quasi-static L3 (most of its
cost), so they must be cheap in XLA on a CPU, where every kernel launch and every small matrix
product (a library call) costs more than its arithmetic. The Hessian of the strip energy is
K + diag(q), K the constant tridiagonal stiffness (3, 2, ..., 2, 3 on the diagonal, -1 beside it,
in units of k_in) and q = mu . e(u) the geometric stiffness of the strip's force, small against K
for any load the strip survives (|q| / lambda_min(K) ~ F L^2 / (pi^2 EI)). The KKT matrix J is
therefore solved exactly by Thomas's elimination of the tridiagonal block and a 2 x 2 Schur
complement for the border (`solve_kkt`), with K u by shifts: no matrix products at all. The solve
starts from the unloaded arc with chord steps, q replaced by its mean (pure Newton diverges from
there for a strip loaded near its reach: the full q of an early iterate makes K + diag(q)
indefinite), and takes Newton's steps once the residual is below NEWTON_SWITCH: 3 steps to a
residual of 1e-14 at the robot's states, where the chord iteration alone, through K's
eigenvectors with six small matrix products each, took 5-7 (one quasi-static L3 right-hand
side 31 -> 20-28 us, a `paper-circle` run 1.78 -> 1.2-1.5 s on this noisy machine). The loop
tests the residual, which it needs anyway (the caller's check): an update-based test took a
fourth step to see that the third had converged (`_iterate`; the `paper-circle` run 0.65 ->
0.57 s with the block mass solve of `_linalg`). No step is unrolled before the loop: each
unrolled step is a copy of the solve in the program, vectorised wherever the strips are (the
start's stencil and its Newton points too), and since the loop of integration steps compiles as
one kernel they bought no run time (N = 16 `paper-circle`, two unrolled steps against none:
first call 26.5-27.3 -> 15.7-17.3 s, warm runs 1.02-1.06 and 1.00-1.07 s; a vmapped batch of
16 at N = 4 over 1 s: 0.66-0.68 -> 0.61-0.64 s). The solve is a `jax.custom_jvp`: the implicit
derivatives solve J dy = -dF/dp dp with the same `solve_kkt`, so derivatives of any order are
exact and never go through the iterations.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from .._custom_types import Array, Float

#: iterations at most of the strip's equilibrium
MAX_ITER = 60
#: converged when the KKT residual (rad, segment lengths) is below this
TOL = 1e-13
#: below this a residual that no longer shrinks is rounding noise (its floor grows with N)
STALL = 1e-11


def stiffness_matrix(N: int) -> np.ndarray:
    """K (N, N): Hessian of the strip's spring energy over k_in in the segment angles."""
    K = 2 * np.eye(N) - np.eye(N, k=1) - np.eye(N, k=-1)
    K[0, 0] = K[-1, -1] = 3.0
    return K


def _K_diag(N: int) -> np.ndarray:
    """The diagonal (N,) of K (`stiffness_matrix`); -1 beside it."""
    return np.diag(stiffness_matrix(N)).copy()


def apply_K(u):
    """K u for the tridiagonal K of `stiffness_matrix` by shifts (no dot: on a CPU a small
    matrix product is a library call costing more than its arithmetic)."""
    z = jnp.zeros_like(u[..., :1])
    left = jnp.concatenate([z, u[..., :-1]], axis=-1)
    right = jnp.concatenate([u[..., 1:], z], axis=-1)
    return jnp.broadcast_to(jnp.asarray(_K_diag(u.shape[-1]), u.dtype), u.shape) * u - left - right


def kkt_residual(y: Float[Array, " n2"], p: Float[Array, "4"]) -> Float[Array, " n2"]:
    """KKT residual of the strip, y = (u (N,), mu (2,)), p = (d_x/h, d_y/h, beta, sd): the
    gradient of U/k_in - mu . c in u, then c (module docstring)."""
    N = y.shape[0] - 2
    u, mu = y[:N], y[N:]
    # dU/du / k_in = K u - b with b = (0, ..., 0, 2 beta): the rest turns cancel (every spring's
    # k r is k_in sd and the deflections sum to beta - N sd whatever u), which is also why the
    # shape depends on sd only through beta's rest value
    b = jnp.zeros(N, y.dtype).at[-1].set(2 * p[2])
    Ku = apply_K(u)
    s, c = jnp.sin(u), jnp.cos(u)
    g = Ku - b - (-mu[0] * s + mu[1] * c)
    return jnp.concatenate([g, jnp.stack([jnp.sum(c) - p[0], jnp.sum(s) - p[1]])])


#: below this residual the strip's iteration uses the exact Jacobian (Newton), above it the chord's
NEWTON_SWITCH = 1e-2

#: up to this N the Thomas sweeps are unrolled in Python; above it a `lax.scan`
UNROLL_MAX = 16


def _pivots(diag):
    """g (N,) the inverse pivots of Thomas's elimination (no pivoting) of the symmetric
    tridiagonal A with diagonal `diag` (N,) and -1 beside it (K + diag(q)). Stable where A is
    positive definite: a strip loaded to the edge of buckling (|q| near lambda_min(K)) fails its
    Newton iteration, which the scenes report as a loop-closure failure."""
    N = diag.shape[0]
    if N <= UNROLL_MAX:
        g = [1 / diag[0]]
        for i in range(1, N):
            g.append(1 / (diag[i] - g[-1]))
        return jnp.stack(g)

    def step(g_prev, d):
        g = 1 / (d - g_prev)
        return g, g

    return jax.lax.scan(step, jnp.zeros((), diag.dtype), diag)[1]


def _sweeps(g, R):
    """A^-1 R (N, k) for the inverse pivots g of `_pivots`: linear in R (transposable)."""
    N = g.shape[0]
    if N <= UNROLL_MAX:
        r = [R[0]]
        for i in range(1, N):
            r.append(R[i] + r[-1] * g[i - 1])
        x = [r[-1] * g[-1]]
        for i in range(N - 2, -1, -1):
            x.append((r[i] + x[-1]) * g[i])
        return jnp.stack(x[::-1])

    def fwd(r_prev, gR):
        g_prev, Ri = gR
        r = Ri + r_prev * g_prev
        return r, r

    g_prev = jnp.concatenate([jnp.zeros(1, g.dtype), g[:-1]])
    _, r = jax.lax.scan(fwd, jnp.zeros_like(R[0]), (g_prev, R))

    def back(x_next, gr):
        g_i, r_i = gr
        x = (r_i + x_next) * g_i
        return x, x

    return jax.lax.scan(back, jnp.zeros_like(R[0]), (g, r), reverse=True)[1]


def solve_kkt(y: Float[Array, " n2"], R: Float[Array, "n2 k"]) -> Float[Array, "n2 k"]:
    """J^-1 R, J = dF/dy the KKT matrix of `kkt_residual` at y = (u, mu), R (N + 2, k):
    J = [[K + diag(q), -C^T], [C, 0]] with q = mu . e(u) and C = dc/du (2, N); the tridiagonal
    block by Thomas's elimination (`_pivots`, `_sweeps`), the border by its 2 x 2 Schur
    complement."""
    return _solve_kkt_q(y, _geometric_stiffness(y), R)


def _geometric_stiffness(y):
    """q (N,) = mu . e(u): the force's contribution to the diagonal of the KKT matrix."""
    N = y.shape[0] - 2
    u, mu = y[:N], y[N:]
    return mu[0] * jnp.cos(u) + mu[1] * jnp.sin(u)


def _solve_kkt_q(y, q, R):
    """`solve_kkt` with the tridiagonal block's diagonal K + q for a given q (N,)."""
    N = y.shape[0] - 2
    u = y[:N]
    C = jnp.stack([-jnp.sin(u), jnp.cos(u)])
    diag = jnp.asarray(_K_diag(N)) + q
    g = _pivots(diag)
    # apart, not as one right-hand side: W_R is linear in R (transposed in reverse mode), W_C not
    W_R, W_C = _sweeps(g, R[:N]), _sweeps(g, C.T)
    # products as broadcast sums, not dots (module docstring)
    S = jnp.sum(C[:, :, None] * W_C[None], axis=1)
    rhs = R[N:] - jnp.sum(C[:, :, None] * W_R[None], axis=1)
    det = S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0]
    m = jnp.stack([S[1, 1] * rhs[0] - S[0, 1] * rhs[1], S[0, 0] * rhs[1] - S[1, 0] * rhs[0]]) / det
    return jnp.concatenate([W_R + jnp.sum(W_C[:, :, None] * m[None], axis=1), m])


def _iterate(step, residual, y0):
    """(y, max |residual(y)|): steps y <- step(y) until the residual is below TOL, or below
    STALL and no longer shrinking (the rounding floor), at most MAX_ITER. At the robot's states
    three steps: the convergence test is one residual where an update-based test took a fourth
    step to see the third's."""
    y = y0

    def err(y):
        return jnp.max(jnp.abs(residual(y)))

    def body(carry):
        y, r, _, i = carry
        y = step(y)
        return y, err(y), r, i + 1

    def cond(carry):
        _, r, r_old, i = carry
        # the stall test only near convergence: far from it a chord step may not shrink r
        stalled = (r < STALL) & (r >= 0.9 * r_old)
        return (r > TOL) & ~stalled & (i < MAX_ITER)

    inf = jnp.asarray(jnp.inf, y0.dtype)
    y, r, _, _ = jax.lax.while_loop(cond, body, (y, err(y), inf, 0))
    return y, r


@partial(jax.custom_jvp, nondiff_argnums=(0,))
def _root(N: int, p: Array):
    k = jnp.arange(N, dtype=p.dtype) + 0.5
    y0 = jnp.concatenate([p[2] * k / N, jnp.zeros(2, p.dtype)])  # constant curvature, no force
    def step(y):
        r = kkt_residual(y, p)
        q = _geometric_stiffness(y)
        # Far from the root the chord's averaged q: from the unloaded arc, the full q of an early
        # iterate can make K + diag(q) indefinite and Newton diverge (a strip loaded near its
        # reach, `tests/test_beam_qs.py`); near it the exact q, so the last steps are Newton's.
        q = jnp.where(jnp.max(jnp.abs(r)) < NEWTON_SWITCH, q, jnp.mean(q))
        return y - _solve_kkt_q(y, q, r[:, None])[:, 0]

    return _iterate(step, lambda y: kkt_residual(y, p), y0)


@_root.defjvp
def _root_jvp(N, primals, tangents):
    (p,), (dp,) = primals, tangents
    y, err = _root(N, p)
    # F(y(p), p) = 0  ->  J dy = -dF/dp dp
    _, Fp_dp = jax.jvp(lambda p: kkt_residual(y, p), (p,), (dp,))
    dy = -solve_kkt(y, Fp_dp[:, None])[:, 0]
    return (y, err), (dy, jnp.zeros_like(err))


def shape_sensitivity(y: Float[Array, "c n2"], p: Float[Array, "c 4"]) -> Float[Array, "c n2 4"]:
    """dy/dp (c, N + 2, 4) of c strips' equilibria y = (u, mu) at their solutions for p =
    (d_x/h, d_y/h, beta, sd) (`kkt_residual`): -J^-1 F_p (`solve_kkt`), the implicit function
    theorem. Exact only where y solves the equations."""
    F_p = jax.vmap(jax.jacfwd(kkt_residual, argnums=1))(y, p)
    return -jax.vmap(solve_kkt)(y, F_p)


def strip_equilibrium(
    n_elements: int, h, sd, d: Float[Array, "2"], beta
) -> tuple[Float[Array, " N"], Float[Array, "2"], Array]:
    """Equilibrium shape of one strip (module docstring).

    n_elements N (static); h segment chord (m); sd = sigma dtheta signed rest turn of an interior
    spring (rad); d (2,) end position P2 - P1 in the start clamp's frame (m); beta end clamp angle
    relative to the start clamp (rad). Returns (u (N,) segment angles from the start clamp's
    tangent (rad), lam (2,) the force through the strip over k_in (1/m) in the start clamp's
    frame, err the final residual (rad, segment lengths): above ~1e-10 the iteration failed and
    the shape must not be used (the caller reports it). Differentiable in h, sd, d and beta to
    any order (implicit function theorem)."""
    p = jnp.stack([d[0] / h, d[1] / h, beta, sd])
    y, err = _root(n_elements, p)
    return y[:n_elements], y[n_elements:] / h, err
