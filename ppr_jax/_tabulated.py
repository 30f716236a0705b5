"""A smooth input evaluated once on a grid, then interpolated: what a scene does with its input.

The scenes' inputs (the `paper-circle` torques: L1 inverse dynamics along eq 55; the
`servo-circle` angles: L1 inverse kinematics) cost about a third of L2's right-hand side when
evaluated at every stage of the integrator. They are smooth functions of time alone, so the
scene evaluates them once, vectorised, on a uniform grid with their exact time derivatives
(forward mode), and interpolates by Hermite polynomials that match those derivatives at the
nodes: cubic from (f, f') and quintic from (f, f', f''), whose errors are at most
h^4/384 max|f^(4)| and h^6/46080 max|f^(6)| on a grid of spacing h. For the paper's circle
(omega = 5/6 rad/s, 755 nodes over 7.54 s: one per output time) that is a relative torque error
of about 6e-11,
far below any solver tolerance; the tests check it against the exact input.

The table estimates its own error from the same bound, with the highest derivative taken from
finite differences of the stored ones (`Tabulated.error_estimate`, no extra evaluations). Where
it is coarser than `TABLE_RTOL` (a long horizon with few output times, a fast trajectory), the
scene evaluates the exact input at every stage instead (`TableOrExact`): slower, never less
accurate.

Only the models whose right-hand side is expensive tabulate (L2, L3); L0 and L1 take fewer
steps than the table has nodes at the usual tolerances, so they evaluate the exact input at
every stage.
"""

from __future__ import annotations

from typing import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

#: Fewest nodes a scene tabulates its input on (more when it asks for more output times).
MIN_NODES = 512
#: Largest estimated error of a scene's input table, relative to the input's largest magnitude,
#: that a scene accepts.
TABLE_RTOL = 1e-8


def scene_nodes(n_out: int) -> int:
    """Nodes of a scene's input grid for `n_out` output times (static): at least `MIN_NODES`,
    and one per output time beyond that, so that a long horizon can ask for a fine table."""
    return max(MIN_NODES, int(n_out))


class Tabulated(eqx.Module):
    """f(t) (any shape) from its values and derivatives on a uniform grid: Hermite
    interpolation, cubic (f and f' stored) or quintic (f, f', f''). Differentiable in t (so
    `derivatives` works through it) and in the tabulated values (so gradients reach the
    parameters that made them). Outside [t0, t0 + (n - 1) h] the end polynomials extrapolate."""

    t0: Float[Array, ""]
    h: Float[Array, ""]
    nodes: Float[Array, "order_plus_1 n ..."]

    def __call__(self, t):
        n = self.nodes.shape[1]
        s = (t - self.t0) / self.h
        i = jnp.clip(jnp.floor(s), 0, n - 2).astype(jnp.int32)
        u = s - i
        f, g = self.nodes[:, i], self.nodes[:, i + 1]
        h = self.h
        if self.nodes.shape[0] == 2:
            u2, u3 = u * u, u * u * u
            return ((2 * u3 - 3 * u2 + 1) * f[0] + (u3 - 2 * u2 + u) * h * f[1]
                    + (-2 * u3 + 3 * u2) * g[0] + (u3 - u2) * h * g[1])
        u2 = u * u
        u3, u4, u5 = u2 * u, u2 * u2, u2 * u2 * u
        return ((1 - 10 * u3 + 15 * u4 - 6 * u5) * f[0]
                + (u - 6 * u3 + 8 * u4 - 3 * u5) * h * f[1]
                + (0.5 * u2 - 1.5 * u3 + 1.5 * u4 - 0.5 * u5) * h * h * f[2]
                + (0.5 * u3 - u4 + 0.5 * u5) * h * h * g[2]
                + (-4 * u3 + 7 * u4 - 3 * u5) * h * g[1]
                + (10 * u3 - 15 * u4 + 6 * u5) * g[0])

    def error_estimate(self) -> Float[Array, ""]:
        """Estimated largest interpolation error relative to the largest tabulated value: the
        Hermite bound of the module docstring with f^(4) from third differences of f' / h^3
        (cubic) or f^(6) from fourth differences of f'' / h^4 (quintic)."""
        scale = jnp.max(jnp.abs(self.nodes[0])) + jnp.finfo(self.nodes.dtype).tiny
        if self.nodes.shape[0] == 2:
            est = self.h * jnp.max(jnp.abs(jnp.diff(self.nodes[1], n=3, axis=0))) / 384
        else:
            est = self.h**2 * jnp.max(jnp.abs(jnp.diff(self.nodes[2], n=4, axis=0))) / 46080
        return est / scale


@jax.custom_batching.custom_vmap
def _whole_batch(ok):
    """`ok` for one member; under `vmap`, whether it holds for every member, unbatched."""
    return ok


@_whole_batch.def_vmap
def _whole_batch_rule(axis_size, in_batched, ok):
    (batched,) = in_batched
    return (jnp.all(ok) if batched else ok), False


class TableOrExact(eqx.Module):
    """The input `exact` of time, read from `table` where the table's estimated error is within
    `TABLE_RTOL` and evaluated exactly otherwise, by one `lax.cond` per call so that only the
    chosen branch runs. Under `vmap` the choice is made once for the whole batch (the table
    only if every member's is fine: the exact input is right for all): a per-member choice
    would be batched, and a batched `cond` runs both branches for everyone."""

    table: Tabulated
    exact: Callable
    use_table: Array

    def __init__(self, table: Tabulated, exact: Callable):
        self.table, self.exact = table, exact
        self.use_table = _whole_batch(table.error_estimate() <= TABLE_RTOL)

    def __call__(self, t):
        # Closures, not the modules themselves: lax.cond hashes its branch functions.
        return jax.lax.cond(self.use_table, lambda t: self.table(t), lambda t: self.exact(t), t)


def tabulate(fn: Callable, t0, t1, n: int, order: int = 1) -> Tabulated:
    """`Tabulated` of fn (a function of time returning an array) on n uniform nodes over
    [t0, t1], with `order` exact time derivatives (1: cubic, 2: quintic interpolation), all
    nodes in one vectorised evaluation."""
    if order not in (1, 2):
        raise ValueError(f"order must be 1 or 2, got {order}")
    ts = jnp.linspace(t0, t1, n)

    def derivs(t):
        if order == 1:
            f, df = jax.jvp(fn, (t,), (jnp.ones_like(t),))
            return jnp.stack([f, df])

        def d1(t):
            return jax.jvp(fn, (t,), (jnp.ones_like(t),))

        (f, df), (_, ddf) = jax.jvp(d1, (t,), (jnp.ones_like(t),))
        return jnp.stack([f, df, ddf])

    nodes = jnp.moveaxis(jax.vmap(derivs)(ts), 0, 1)
    return Tabulated(t0=jnp.asarray(t0, float), h=(jnp.asarray(t1, float) - t0) / (n - 1),
                     nodes=nodes)


def scene_input(model, fn: Callable, ts, order: int) -> Callable:
    """A scene's input `fn` of time as its integrator calls it, for output times `ts`: for the
    models with an expensive right-hand side (level >= 2) a `TableOrExact` on `scene_nodes`
    nodes over [ts[0], ts[-1]] with `order` derivatives; for L0/L1 `fn` itself."""
    if model.level < 2:
        return fn
    return TableOrExact(tabulate(fn, ts[0], ts[-1], scene_nodes(ts.shape[0]), order=order), fn)
