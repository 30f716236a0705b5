"""A smooth input evaluated once on a grid, then interpolated: what a scene does with its input.

The scenes' inputs (the `paper-circle` torques: L1 inverse dynamics along eq 55; the
`servo-circle` angles: L1 inverse kinematics) cost about a third of L2's right-hand side when
evaluated at every stage of the integrator. They are smooth functions of time alone, so the
scene evaluates them once, vectorised, on a uniform grid with their time derivatives (by
sixth-order central differences of the values, `tabulate`), and interpolates by Hermite
polynomials that match those derivatives at the
nodes: cubic from (f, f') and quintic from (f, f', f''), whose errors are at most
h^4/384 max|f^(4)| and h^6/46080 max|f^(6)| on a grid of spacing h. For the paper's circle
(omega = 5/6 rad/s, 512 nodes over 7.54 s) that is a relative torque error of about 3e-10
(6e-11 at 755 nodes),
far below any solver tolerance; the tests check it against the exact input.

The node count is static (`scene_nodes`): where the horizon is known when the scene is prepared,
`NODES_PER_RADIAN` per radian of the nominal motion (the circle's omega t_end), at least
`MIN_NODES`, rounded up to `MIN_NODES` times a power of two so that horizons of similar length
share a program; otherwise at least `MIN_NODES` and one per output time. The table estimates its own error from the same
bound, with the highest derivative taken from finite differences of the stored ones
(`Tabulated.error_estimate`, no extra evaluations); a scene whose table is coarser than
`TABLE_RTOL` (a horizon or a trajectory speed the node count did not foresee, such as a traced
t_end) fails with `RESULTS.input_table_too_coarse` instead of integrating an inaccurate input.
An earlier version evaluated the exact input at every stage in that case, inside a `lax.cond`:
that branch (the L1 inverse dynamics under nested derivatives) made up a third of L2's program
and doubled its compile time, for a case the node count now avoids.

Every level tabulates. L0 and L1 take fewer solver stages (about 500 for L1 at rtol 1e-6) than
the table has nodes, but the table's nodes are one vectorised evaluation while the stages run
one after another: L1 `paper-circle` took 8.7 ms with the exact torque at every stage and 6.6 ms
with the table (a batch of 256: 173 -> 234 trajectories/s), and compiles 1 s faster.
"""

from __future__ import annotations

from typing import Callable, Optional

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

#: Fewest nodes a scene tabulates its input on (more when it asks for more output times).
MIN_NODES = 512
#: Largest estimated error of a scene's input table, relative to the input's largest magnitude,
#: that a scene accepts.
TABLE_RTOL = 1e-8
#: Fewest nodes per radian of the nominal motion where the horizon is known: the paper's torques
#: interpolate to about 1e-9 relative at this spacing (6e-11 at the default 755 nodes over one
#: turn, 120 per radian; the error falls as the fourth power of the spacing).
NODES_PER_RADIAN = 60


def scene_nodes(n_out: int, span_radians: Optional[float] = None) -> int:
    """Nodes of a scene's input grid (static). With `span_radians` (omega t_end of the nominal
    motion, when known): `NODES_PER_RADIAN` per radian, at least `MIN_NODES`, rounded up to
    `MIN_NODES` times a power of two, whatever the number of output times (the table's work is
    per node and vectorised: in a batch it was a fifth of an L1 run at one node per output time).
    Without it: at least `MIN_NODES` and one per output time, the best guess at the horizon."""
    if span_radians is None:
        return max(MIN_NODES, int(n_out))
    need = int(np.ceil(NODES_PER_RADIAN * abs(float(span_radians)))) + 1
    if need <= MIN_NODES:
        return MIN_NODES
    return MIN_NODES * 2 ** int(np.ceil(np.log2(need / MIN_NODES)))


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


#: weights of the sixth-order central differences over offsets -3..3: first derivative (times
#: h) and second derivative (times h^2); errors h^6 |f^(7)|/140 and h^6 |f^(8)|/560
_D1 = np.array([-1.0, 9.0, -45.0, 0.0, 45.0, -9.0, 1.0]) / 60
_D2 = np.array([2.0, -27.0, 270.0, -490.0, 270.0, -27.0, 2.0]) / 180


def tabulate(fn: Callable, t0, t1, n: int, order: int = 1,
             derivatives: str = "exact") -> Tabulated:
    """`Tabulated` of fn (a function of time returning an array) on n uniform nodes over
    [t0, t1], with `order` time derivatives (1: cubic, 2: quintic interpolation), all nodes in
    one vectorised evaluation. `derivatives="exact"`: by forward mode (nested JVPs of fn);
    `"differences"`: sixth-order central differences of the values, on three extra nodes each
    side of [t0, t1] (fn must be defined there), truncation errors h^6 |f^(7)|/140 and
    h^6 |f^(8)|/560 (about 1e-15 relative for the paper's circle at the scenes' spacing; rounding
    adds about 1e-14), exact for polynomials of degree <= 6. The scenes use differences: fn (an
    inverse dynamics built on derivatives of the kinematics) is then traced once instead of under
    one or two more levels of JVP, which was a quarter of L2's compiled program."""
    if order not in (1, 2):
        raise ValueError(f"order must be 1 or 2, got {order}")
    if derivatives not in ("exact", "differences"):
        raise ValueError(f"derivatives must be 'exact' or 'differences', got {derivatives!r}")
    h = (jnp.asarray(t1, float) - t0) / (n - 1)
    if derivatives == "differences":
        f = jax.vmap(fn)(t0 + h * jnp.arange(-3, n + 3))

        def stencil(w):
            return sum(w[k] * f[k:k + n] for k in range(7))

        rows = [f[3:n + 3], stencil(_D1) / h]
        if order == 2:
            rows.append(stencil(_D2) / h**2)
        return Tabulated(t0=jnp.asarray(t0, float), h=h, nodes=jnp.stack(rows))
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
    return Tabulated(t0=jnp.asarray(t0, float), h=h, nodes=nodes)


def scene_input(fn: Callable, ts, order: int, nodes: Optional[int] = None) -> Tabulated:
    """A scene's input `fn` of time as its integrator calls it, for output times `ts`: a
    `Tabulated` on `nodes` (default `scene_nodes(len(ts))`) nodes over [ts[0], ts[-1]] with
    `order` derivatives. Check the table with `input_too_coarse`."""
    n = scene_nodes(ts.shape[0]) if nodes is None else int(nodes)
    return tabulate(fn, ts[0], ts[-1], n, order=order, derivatives="differences")


def input_too_coarse(inp: Callable):
    """Whether a scene input from `scene_input` is a table whose estimated relative error is
    above `TABLE_RTOL` (a traced bool), or None for an exact input (nothing to check)."""
    if not isinstance(inp, Tabulated):
        return None
    return ~(inp.error_estimate() <= TABLE_RTOL)
