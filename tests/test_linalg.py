"""The plain-XLA Gaussian elimination against numpy's LAPACK solve, in every mode it is used."""

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

from ppr_jax._linalg import (
    UNROLL_MAX,
    SmallLU,
    lu_factor,
    lu_solve,
    matmat,
    matvec,
    solve,
    solve_blocks,
)


@pytest.mark.parametrize("n", [1, 2, 3, 6, UNROLL_MAX, UNROLL_MAX + 1, 27])
def test_solve_and_transpose_match_numpy(n):
    rng = np.random.default_rng(n)
    for _ in range(5):
        A = rng.normal(size=(n, n)) * 10.0 ** rng.uniform(-3, 3, size=(n, 1))  # badly scaled
        b = rng.normal(size=n)
        ref = np.linalg.solve(A, b)
        x = np.asarray(solve(jnp.asarray(A), jnp.asarray(b)))
        np.testing.assert_allclose(x, ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())
        xt = np.asarray(lu_solve(lu_factor(jnp.asarray(A)), jnp.asarray(b), trans=True))
        np.testing.assert_allclose(xt, np.linalg.solve(A.T, b), rtol=1e-9,
                                   atol=1e-12 * np.abs(ref).max())


@pytest.mark.parametrize("n", [2, 3])
def test_small_solve_near_singular_within_conditioning(n):
    """Up to 3 x 3 `solve` takes the adjugate and one step of refinement, not pivoted
    elimination: near a singular matrix (a type-II singularity's S) its error stays within the
    conditioning's bound, as LAPACK's does, against a solution known exactly (b = A x formed in
    extended precision). Without the refinement the 3 x 3 error at cond 1e6 is 46 times the
    bound."""
    rng = np.random.default_rng(7)
    for cond in (1e2, 1e5, 1e8):
        for _ in range(50):
            U, _ = np.linalg.qr(rng.normal(size=(n, n)))
            V, _ = np.linalg.qr(rng.normal(size=(n, n)))
            s = np.geomspace(1.0, 1.0 / cond, n) * 10.0 ** rng.uniform(-3, 3)
            A = (U * s) @ V.T * 10.0 ** rng.uniform(-3, 3, size=(n, 1))  # rows badly scaled
            x_true = rng.normal(size=n)
            b = (A.astype(np.longdouble) @ x_true.astype(np.longdouble)).astype(np.float64)
            x = np.asarray(solve(jnp.asarray(A), jnp.asarray(b)))
            x_lapack = np.linalg.solve(A, b)
            bound = 2 * np.linalg.cond(A) * np.finfo(float).eps * np.linalg.norm(x_true)
            assert np.linalg.norm(x - x_true) <= bound
            assert np.linalg.norm(x_lapack - x_true) <= bound


def test_pivoting_zero_leading_entry():
    A = jnp.array([[0.0, 2.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 3.0]])
    b = jnp.array([1.0, 2.0, 3.0])
    ref = np.linalg.solve(np.asarray(A), np.asarray(b))
    # the elimination itself (`solve` takes it above 3 x 3), then `solve` (the adjugate here)
    np.testing.assert_allclose(lu_solve(lu_factor(A), b), ref, rtol=1e-14)
    np.testing.assert_allclose(solve(A, b), ref, rtol=1e-14, atol=1e-15)


def test_vmap_and_gradients_match_lapack():
    rng = np.random.default_rng(0)
    A = jnp.asarray(rng.normal(size=(16, 3, 3)) + 3 * np.eye(3))
    b = jnp.asarray(rng.normal(size=(16, 3)))
    np.testing.assert_allclose(jax.vmap(solve)(A, b), np.linalg.solve(A, b[..., None])[..., 0],
                               rtol=1e-12)

    def loss(s, A, b):
        return jnp.sum(jnp.sin(jax.vmap(s)(A, b)))

    g = jax.grad(loss, argnums=(1, 2))(solve, A, b)
    g_ref = jax.grad(loss, argnums=(1, 2))(jnp.linalg.solve, A, b)
    for x, y in zip(g, g_ref):
        np.testing.assert_allclose(x, y, rtol=1e-10, atol=1e-12)
    t = jax.jvp(lambda A: jax.vmap(solve)(A, b), (A,), (jnp.ones_like(A),))[1]
    t_ref = jax.jvp(lambda A: jax.vmap(jnp.linalg.solve)(A, b), (A,), (jnp.ones_like(A),))[1]
    np.testing.assert_allclose(t, t_ref, rtol=1e-10, atol=1e-12)


def test_small_lu_in_optimistix_newton_and_implicit_gradient():
    """Newton with SmallLU finds the root, and its implicit derivative (lineax transposes the
    solver) matches the closed form: x^3 = p  ->  dx/dp = 1 / (3 x^2)."""

    def root(p):
        sol = optx.root_find(lambda x, p: x**3 - p,
                             optx.Newton(1e-13, 1e-13, linear_solver=SmallLU()),
                             jnp.ones(2), args=p, max_steps=50)
        return sol.value

    p = jnp.array([8.0, 27.0])
    np.testing.assert_allclose(root(p), [2.0, 3.0], rtol=1e-12)
    J = jax.jacrev(root)(p)
    np.testing.assert_allclose(np.diag(J), [1 / 12, 1 / 27], rtol=1e-10)
    Jf = jax.jacfwd(root)(p)
    np.testing.assert_allclose(Jf, J, rtol=1e-10, atol=1e-14)


@pytest.mark.parametrize("n", [1, 3, 5, 6, 9, UNROLL_MAX, UNROLL_MAX + 3])
def test_spd_solve_matches_numpy_with_derivatives(n):
    """The Cholesky solve of the mass matrices against numpy, and its derivatives against the
    same expression through LAPACK's solve."""
    from ppr_jax._linalg import solve_spd

    rng = np.random.default_rng(n)
    B = rng.normal(size=(n, n))
    A = jnp.asarray(B @ B.T + n * np.eye(n) * 10.0 ** rng.uniform(-2, 2))
    b = jnp.asarray(rng.normal(size=n))
    np.testing.assert_allclose(solve_spd(A, b), np.linalg.solve(A, b), rtol=1e-11, atol=1e-13)

    def loss(s, A, b):
        return jnp.sum(jnp.sin(s((A + A.T) / 2, b)))

    g = jax.grad(loss, argnums=(1, 2))(solve_spd, A, b)
    g_ref = jax.grad(loss, argnums=(1, 2))(jnp.linalg.solve, A, b)
    for x, y in zip(g, g_ref):
        np.testing.assert_allclose(x, y, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("s, k", [(3, 3), (2, 4), (4, 2)])
def test_arrow_solve_matches_numpy_with_derivatives(s, k):
    """The arrow solve (a diagonal block eliminated first: L2's mass matrix with its chains'
    own coordinates) against numpy on a random arrow matrix (heavy tails: mass ratios of
    1e4), and its forward and reverse derivatives against LAPACK's solve on the same matrix."""
    from ppr_jax._linalg import solve_arrow

    rng = np.random.default_rng(10 * s + k)
    n = s + k

    def arrow(A11, A12, d):
        return jnp.block([[A11, A12], [A12.T, jnp.diag(d)]])

    d = 10.0 ** rng.uniform(-2, 2, k)
    A12 = rng.normal(size=(s, k)) * np.sqrt(d) * 0.5
    C = rng.normal(size=(s, s))
    A11 = C @ C.T + (A12 / d) @ A12.T + s * np.eye(s)  # positive definite Schur complement
    A = arrow(*map(jnp.asarray, (A11, A12, d)))
    assert np.all(np.linalg.eigvalsh(A) > 0)
    b = jnp.asarray(rng.normal(size=n))
    np.testing.assert_allclose(solve_arrow(A, b, k), np.linalg.solve(A, b), rtol=1e-11,
                               atol=1e-13)

    def loss(solver, A11, A12, d, b):
        return jnp.sum(jnp.sin(solver(arrow((A11 + A11.T) / 2, A12, d), b)))

    args = tuple(map(jnp.asarray, (A11, A12, d))) + (b,)
    ours = lambda M, b: solve_arrow(M, b, k)  # noqa: E731
    g = jax.grad(loss, argnums=(1, 2, 3, 4))(ours, *args)
    g_ref = jax.grad(loss, argnums=(1, 2, 3, 4))(jnp.linalg.solve, *args)
    for x, y in zip(g, g_ref):
        np.testing.assert_allclose(x, y, rtol=1e-9, atol=1e-12)
    tangents = tuple(jnp.asarray(rng.normal(size=np.shape(a))) for a in args)
    _, t = jax.jvp(lambda *a: loss(ours, *a), args, tangents)
    _, t_ref = jax.jvp(lambda *a: loss(jnp.linalg.solve, *a), args, tangents)
    np.testing.assert_allclose(t, t_ref, rtol=1e-9)


@pytest.mark.parametrize("A, v", [((6, 6), (6,)), ((3, 2, 6), (6,)), ((6, 3), (3,))])
def test_matvec_is_the_product(A, v):
    """`matvec` (elementwise sums) against NumPy's product, with batch dimensions on A."""
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=A), rng.normal(size=v)
    np.testing.assert_allclose(matvec(jnp.asarray(a), jnp.asarray(b)),
                               np.einsum("...mn,n->...m", a, b), rtol=0, atol=1e-14)


@pytest.mark.parametrize("A, B", [((3, 2, 2), (3, 2, 6)), ((3, 3), (3, 4)), ((2, 2), (3, 2, 5)),
                                  ((3, 2, 2), (2, 1))])
def test_matmat_is_the_product(A, B):
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=A), rng.normal(size=B)
    np.testing.assert_allclose(matmat(jnp.asarray(a), jnp.asarray(b)), a @ b, rtol=0,
                               atol=1e-14)


@pytest.mark.parametrize("k, m", [(2, 6), (2, 1), (3, 4)])
def test_solve_blocks_and_its_derivatives_match_numpy(k, m):
    """Cramer's rule on stacks of 2 x 2 and 3 x 3 blocks, and its own derivative (elementwise
    sums, `_cramer_blocks_jvp`) in forward and reverse mode, against LAPACK's solve and its
    derivative; several tangents at once as `jacfwd` vmaps them."""
    rng = np.random.default_rng(k * 10 + m)
    A = jnp.asarray(rng.normal(size=(3, k, k)) + 3.0 * np.eye(k))
    B = jnp.asarray(rng.normal(size=(3, k, m)))
    np.testing.assert_allclose(solve_blocks(A, B), np.linalg.solve(A, B), rtol=1e-13,
                               atol=1e-14)
    for jac in (jax.jacfwd, jax.jacrev):
        ours = jac(solve_blocks, argnums=(0, 1))(A, B)
        ref = jax.jacfwd(jnp.linalg.solve, argnums=(0, 1))(A, B)
        for a, b in zip(ours, ref):
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-13)
