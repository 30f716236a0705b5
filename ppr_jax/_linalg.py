"""Small dense linear algebra in plain XLA operations (no LAPACK custom calls).

Why not `jnp.linalg.solve`
--------------------------
On CPU, `jnp.linalg.solve` and `jax.scipy.linalg.lu_factor` lower to LAPACK custom calls
(`lapack_dgetrf_ffi`). Under `vmap` a batched getrf splits its batch over XLA's intra-op thread
pool (`jax::ParallelBatchMap`) and *blocks* its calling thread until the pieces are done. XLA's
thunk executor runs independent operations of one program concurrently on the same pool, so when
two such batched factorizations are ready at once (the mass-matrix solve and the inverse-dynamics
solve of one right-hand side evaluation, say) each pool thread sits in `BlockingCounter::Wait`
for work queued behind the other: with two cores the whole process deadlocks at 0 % CPU (a native
stack of the parked threads is in the README, "Batches"). Our systems are tiny (3 x 3 to
(3 + 3N) x (3 + 3N)), so Gaussian elimination written in `jnp` operations is also faster than a
custom call per solve, fuses with its neighbours, vectorizes under `vmap` and differentiates by
plain autodiff.

`SmallLU` is the same factorization as a lineax solver, for optimistix's Newton.
"""

from __future__ import annotations

import functools
from typing import Any

import equinox.internal as eqxi
import jax
import jax.numpy as jnp
import lineax as lx
from lineax._solver.misc import (
    pack_structures,
    ravel_vector,
    transpose_packed_structures,
    unravel_solution,
)

from ._custom_types import Array, Float
from ._fusion import materialize

#: up to this size the elimination is unrolled in Python (static indices, best code); above it a
#: `lax.fori_loop` keeps the program size independent of n
UNROLL_MAX = 12
#: up to this size the factorization is written entry by entry (`_lu_unrolled`); above it its
#: O(n^3) scalar operations compiled longer than the masked rows (6 x 6, vmapped: 0.93 s
#: against 0.61 s), though they ran faster
SCALAR_MAX = 3


def _lu_step(k, A, perm):
    """One column of Doolittle elimination with partial pivoting (k may be traced)."""
    n = A.shape[-1]
    rows = jnp.arange(n)
    col = jnp.where(rows >= k, jnp.abs(A[:, k]), -1.0)
    p = jnp.argmax(col)
    rk, rp = A[k], A[p]
    A = A.at[k].set(rp).at[p].set(rk)
    pk, pp = perm[k], perm[p]
    perm = perm.at[k].set(pp).at[p].set(pk)
    below = rows > k
    l = jnp.where(below, A[:, k] / A[k, k], 0.0)
    A = A - l[:, None] * jnp.where(rows > k, A[k], 0.0)[None, :]
    A = jnp.where((rows[:, None] > k) & (rows[None, :] == k), l[:, None], A)
    return A, perm


def _lu_unrolled(A):
    """`lu_factor` of a matrix of static size, entry by entry as scalars: the pivot search a
    chain of comparisons, the row swap selects. Pivoting by a traced row index is a gather and
    a scatter, which `vmap` makes loops of their own (a vmapped 3 x 3 factor and solve, as
    forward kinematics' Newton takes them at every output time: 0.35 -> 0.15 s to compile, 87 ->
    13 us for 64 of them). The same pivots (the first row of largest magnitude, as `argmax`)
    and the same arithmetic."""
    n = A.shape[-1]
    a = [[A[i, j] for j in range(n)] for i in range(n)]
    perm = [jnp.asarray(i, dtype=jnp.int32) for i in range(n)]
    for k in range(n):
        best, p = jnp.abs(a[k][k]), jnp.asarray(k, dtype=jnp.int32)
        for i in range(k + 1, n):
            better = jnp.abs(a[i][k]) > best
            best = jnp.where(better, jnp.abs(a[i][k]), best)
            p = jnp.where(better, jnp.int32(i), p)
        hit = {i: p == i for i in range(k + 1, n)}
        row, pk = list(a[k]), perm[k]
        for i in range(k + 1, n):  # row k takes row p's entries, row p row k's
            a[k] = [jnp.where(hit[i], x, y) for x, y in zip(a[i], a[k])]
            perm[k] = jnp.where(hit[i], perm[i], perm[k])
            a[i] = [jnp.where(hit[i], x, y) for x, y in zip(row, a[i])]
            perm[i] = jnp.where(hit[i], pk, perm[i])
        for i in range(k + 1, n):
            lk = a[i][k] / a[k][k]
            a[i] = a[i][:k] + [lk] + [a[i][j] - lk * a[k][j] for j in range(k + 1, n)]
    return jnp.stack([jnp.stack(r) for r in a]), jnp.stack(perm)


def _permuted(b, perm, inverse: bool = False):
    """b[perm] (`inverse`: x with x[perm] = b) as selects, no gather or scatter, for the
    unrolled sizes."""
    n = b.shape[0]
    out = []
    for i in range(n):
        x = b[0]
        for j in range(1, n):
            x = jnp.where((perm[j] == i) if inverse else (perm[i] == j), b[j], x)
        out.append(x)
    return jnp.stack(out)


# jitted: inlined inside an outer jit; called eagerly they compile once per shape instead of once
# per primitive (thousands of tiny executables exhaust the process's memory mappings).
@jax.jit
def lu_factor(A: Float[Array, "n n"]) -> tuple[Array, Array]:
    """(LU, perm) with A[perm] = L U, L unit lower triangular (below the diagonal of LU) and U
    upper triangular. A singular A gives inf/NaN, as LAPACK's getrf would."""
    n = A.shape[-1]
    if n <= SCALAR_MAX:
        return _lu_unrolled(A)
    perm = jnp.arange(n)
    if n <= UNROLL_MAX:
        for k in range(n):
            A, perm = _lu_step(k, A, perm)
        return A, perm
    return jax.lax.fori_loop(0, n, lambda k, c: _lu_step(k, *c), (A, perm))


def _triangular(T, b, lower: bool, unit: bool):
    """Solve T x = b for triangular T (lower or upper; `unit`: ones on the diagonal)."""
    n = b.shape[0]
    rows = jnp.arange(n)

    def step(j, x):
        i = j if lower else n - 1 - j
        done = rows < i if lower else rows > i
        s = jnp.sum(jnp.where(done, T[i] * x, 0.0))
        return x.at[i].set(b[i] - s if unit else (b[i] - s) / T[i, i])

    if n <= UNROLL_MAX:
        # entry by entry, stacked once: `x.at[i].set` is a scatter under `vmap`
        xs = [None] * n
        for j in range(n):
            i = j if lower else n - 1 - j
            r = b[i]
            for m in (range(i) if lower else range(i + 1, n)):
                r = r - T[i, m] * xs[m]
            xs[i] = r if unit else r / T[i, i]
        return jnp.stack(xs)
    return jax.lax.fori_loop(0, n, step, jnp.zeros_like(b))


@functools.partial(jax.jit, static_argnames="trans")
def lu_solve(lu_perm: tuple[Array, Array], b: Float[Array, " n"], trans: bool = False):
    """Solve A x = b (or A^T x = b with `trans`) from `lu_factor(A)`."""
    LU, perm = lu_perm
    small = b.shape[0] <= SCALAR_MAX
    if not trans:
        y = _triangular(LU, _permuted(b, perm) if small else b[perm], lower=True, unit=True)
        return _triangular(LU, y, lower=False, unit=False)
    # A^T = U^T L^T P: solve U^T z = b, L^T w = z, then P x = w.
    z = _triangular(LU.T, b, lower=True, unit=False)
    w = _triangular(LU.T, z, lower=False, unit=True)
    return _permuted(w, perm, inverse=True) if small else jnp.zeros_like(w).at[perm].set(w)


def _factor(A):
    # Up to 3 x 3 the adjugate (`_inverse3`), no pivot search: pivoting swaps rows by a traced
    # index, a gather and a scatter that `vmap` makes loops of their own, and the 3 x 3
    # inverse-dynamics solves of a scene's input table (one a node, vmapped) were a third of an
    # L0 scene program's XLA compilation (0.78 -> 0.59 s).
    return _inverse3(A) if A.shape[-1] <= 3 else lu_factor(A)


def _apply(F, A, b):
    if isinstance(F, tuple):
        return lu_solve(F, b)
    # The adjugate's solution is not backward stable (its error grows as cond(A)^2, not as
    # cond(A)); one step of refinement with the same inverse brings it within the conditioning's
    # bound up to cond(A) = 1e8, as pivoted elimination is (`tests/test_linalg.py`)
    x = matvec(F, b)
    return x + matvec(F, b - matvec(A, x))


@jax.custom_jvp
def _solve(A, b):
    return _apply(_factor(A), A, b)


@_solve.defjvp
def _solve_jvp(primals, tangents):
    # d(A^-1 b) = A^-1 (db - dA x) with the same factorization: derivatives never go through
    # the pivoting and elimination steps (smaller programs, faster compilation), and the
    # tangent is linear in (dA, db), so reverse mode transposes it.
    A, b = primals
    dA, db = tangents
    F = _factor(A)
    x = _apply(F, A, b)
    return x, _apply(F, A, db - (dA @ x if isinstance(F, tuple) else matvec(dA, x)))


@jax.jit
def solve(A: Float[Array, "n n"], b: Float[Array, " n"]) -> Float[Array, " n"]:
    """x with A x = b: up to 3 x 3 by the adjugate and one step of refinement, above by
    Gaussian elimination with partial pivoting (module docstring); differentiable in A and b,
    forward and reverse mode."""
    return _solve(A, b)


def _adjugate_blocks(A):
    """(adj (b, k, k), det (b,)) of a stack of 2 x 2 or 3 x 3 blocks."""
    if A.shape[-1] == 2:
        det = A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0]
        adj = jnp.stack(
            [jnp.stack([A[:, 1, 1], -A[:, 0, 1]], -1), jnp.stack([-A[:, 1, 0], A[:, 0, 0]], -1)], 1
        )
        return adj, det
    c0 = jnp.cross(A[:, :, 1], A[:, :, 2])
    c1 = jnp.cross(A[:, :, 2], A[:, :, 0])
    c2 = jnp.cross(A[:, :, 0], A[:, :, 1])
    adj = jnp.stack([c0, c1, c2], axis=1)  # rows: the adjugate's rows
    return adj, jnp.sum(A[:, :, 0] * c0, axis=-1)


@jax.custom_jvp
def _cramer_blocks(A, B):
    adj, det = _adjugate_blocks(A)
    return (adj @ B) / det[:, None, None]


@_cramer_blocks.defjvp
def _cramer_blocks_jvp(primals, tangents):
    # the tangent A^-1 (dB - dA X) as elementwise sums: under several tangents the products
    # are not matrix-vector ones, which XLA's CPU code makes library calls that keep a loop of
    # steps from compiling as one kernel (an identification from angles, two tangents: 0.41 s
    # against 0.08 s for one). The primal keeps its dot: as sums, XLA recomputed the blocks'
    # entries in every product's element (an L2 forward-mode sensitivity 128 -> 190 ms).
    A, B = primals
    dA, dB = tangents
    adj, det = _adjugate_blocks(A)
    X = (adj @ B) / det[:, None, None]
    inv = materialize(adj / det[:, None, None])
    dX = matmat(inv, materialize(dB) - matmat(materialize(dA), materialize(X)))
    return X, dX


def solve_blocks(A: Float[Array, "b k k"], B: Float[Array, "b k m"]) -> Float[Array, "b k m"]:
    """X with A[i] X[i] = B[i] for a stack of small blocks: Cramer's rule (the adjugate) for
    k <= 3, every index static so XLA fuses it, its derivative without dots
    (`_cramer_blocks_jvp`); `solve` per block above that. For the loop closures' 2 x 2 and
    3 x 3 blocks, which are well conditioned wherever the kinematics are (a singular block is
    a singular configuration, which the margins report)."""
    k = A.shape[-1]
    if k == 1:
        return B / A
    if k <= 3:
        return _cramer_blocks(A, B)
    return jax.vmap(jax.vmap(solve, in_axes=(None, 1), out_axes=1))(A, B)


class SmallLU(lx.AbstractLinearSolver):
    """`lineax.LU` with the factorization above instead of LAPACK (module docstring): for
    square nonsingular operators, e.g. `optimistix.Newton(..., linear_solver=SmallLU())`."""

    def init(self, operator, options: dict[str, Any]):
        del options
        if operator.in_size() != operator.out_size():
            raise ValueError("SmallLU may only be used for square linear systems")
        return lu_factor(operator.as_matrix()), pack_structures(operator), eqxi.Static(False)

    def compute(self, state, vector, options: dict[str, Any]):
        del options
        lu_perm, packed, transpose = state
        x = lu_solve(lu_perm, ravel_vector(vector, packed), trans=transpose.value)
        return unravel_solution(x, packed), lx.RESULTS.successful, {}

    def transpose(self, state, options: dict[str, Any]):
        lu_perm, packed, transpose = state
        return (lu_perm, transpose_packed_structures(packed), eqxi.Static(not transpose.value)), {}

    def conj(self, state, options: dict[str, Any]):
        (lu, perm), packed, transpose = state
        return ((lu.conj(), perm), packed, transpose), {}

    def assume_full_rank(self):
        return True


def matvec(A, v):
    """A v (A (..., m, n), v (n,)) by columns, as elementwise products of slices: no dot.

    XLA's CPU compiler makes a product of small matrices a dot, and a dot that is not a
    matrix-vector product (the one a forward-mode derivative makes of A v when it carries
    several tangents) is a library call, which keeps the loop of steps that holds it from
    compiling as one kernel (`_devices`)."""
    out = A[..., :, 0] * v[0]
    for k in range(1, A.shape[-1]):
        out = out + A[..., :, k] * v[k]
    return out


def matmat(A, B):
    """A B (A (..., m, n), B (..., n, p), either without the leading axes) by columns of A,
    as `matvec`."""
    A = A.reshape((1,) * (B.ndim - A.ndim) + A.shape)
    B = B.reshape((1,) * (A.ndim - B.ndim) + B.shape)
    out = A[..., :, 0:1] * B[..., 0:1, :]
    for k in range(1, A.shape[-1]):
        out = out + A[..., :, k : k + 1] * B[..., k : k + 1, :]
    return out


def _inverse3(A):
    """Inverse of a 1 x 1 to 3 x 3 matrix by its adjugate: one division."""
    n = A.shape[-1]
    if n == 1:
        return 1.0 / A
    if n == 2:
        adj = jnp.stack([jnp.stack([A[1, 1], -A[0, 1]]), jnp.stack([-A[1, 0], A[0, 0]])])
        return adj * (1.0 / (A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]))
    c0 = jnp.cross(A[:, 1], A[:, 2])
    c1 = jnp.cross(A[:, 2], A[:, 0])
    c2 = jnp.cross(A[:, 0], A[:, 1])
    det = A[0, 0] * c0[0] + A[1, 0] * c0[1] + A[2, 0] * c0[2]
    return jnp.stack([c0, c1, c2]) * (1.0 / det)


def _block_factor(A):
    """(A11^-1, X = A11^-1 A12, the factors of S) of A = [[A11, A12], [A12^T, A22]] split after
    row 3, with S = A22 - A12^T X its Schur complement, factored the same way (block LDL^T by
    3 x 3 blocks: no pivoting for a symmetric positive definite A, whose Schur complements are
    too). One division a block (the adjugate's determinant) instead of Cholesky's 2 n square
    roots and divisions in sequence, each of which XLA's CPU fusion keeps as a kernel boundary
    (L2's 6 x 6 mass-matrix solve was about 30 kernels, L3's 9 x 9 64)."""
    n = A.shape[-1]
    if n <= 3:
        return _inverse3(A), None, None
    P = _inverse3(A[:3, :3])
    X = matmat(P, A[:3, 3:])
    S = A[3:, 3:] - matmat(A[:3, 3:].T, X)
    return P, X, _block_factor(S)


def _block_solve(F, b):
    P, X, F_S = F
    if X is None:
        return matvec(P, b)
    x2 = _block_solve(F_S, b[3:] - matvec(X.T, b[:3]))
    return jnp.concatenate([matvec(P, b[:3]) - matvec(X, x2), x2])


@jax.custom_jvp
def _solve_spd(A, b):
    return _block_solve(_block_factor(A), b)


@_solve_spd.defjvp
def _solve_spd_jvp(primals, tangents):
    A, b = primals
    dA, db = tangents
    F = _block_factor(A)
    x = _block_solve(F, b)
    return x, _block_solve(F, db - matvec(dA, x))


@jax.jit
def solve_spd(A: Float[Array, "n n"], b: Float[Array, " n"]) -> Float[Array, " n"]:
    """x with A x = b for a symmetric positive definite A (a mass matrix): in plain XLA, up to
    `UNROLL_MAX` by 3 x 3 blocks and their adjugates (`_block_factor`), `solve` above that. A
    matrix that is not positive definite gives a meaningless x (a mass matrix always is)."""
    if A.shape[-1] > UNROLL_MAX:
        return solve(A, b)
    return _solve_spd(A, b)


def solve_arrow(A: Float[Array, "n n"], b: Float[Array, " n"], k: int) -> Float[Array, " n"]:
    """x with A x = b for a symmetric positive definite A whose last `k` rows and columns couple
    with the first n - k and with themselves only (an arrow matrix: [[A11, A12], [A12^T, D]]
    with D diagonal, L2's mass matrix with its chains' own coordinates last). The diagonal is
    eliminated first: S = A11 - A12 D^-1 A12^T, x1 = S^-1 (b1 - A12 D^-1 b2),
    x2 = D^-1 (b2 - A12^T x1); k divisions and one (n - k) x (n - k) solve. The entries of the
    diagonal block off its diagonal are not read."""
    s = A.shape[-1] - k
    A12 = A[:s, s:]
    d = jnp.stack([A[s + i, s + i] for i in range(k)])
    W = A12 * (1.0 / d)[None, :]  # (s, k): A12 D^-1
    S = A[:s, :s] - matmat(W, A12.T)
    b1, b2 = b[:s], b[s:]
    x1 = solve_spd(S, b1 - matvec(W, b2))
    x2 = (b2 - matvec(A12.T, x1)) / d
    return jnp.concatenate([x1, x2])
