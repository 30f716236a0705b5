"""A smooth input evaluated once on a grid, then interpolated: what a scene does with its input.

The scenes' inputs (the `paper-circle` torques: L1 inverse dynamics along eq 55; the
`servo-circle` angles: L1 inverse kinematics) are smooth (analytic) functions of time alone, and
evaluating them at every solver stage cost about a third of L2's right-hand side. So a scene
evaluates its input once, vectorised, and the integrator interpolates.

The interpolant is piecewise Chebyshev: the horizon is cut into P equal panels, each holding the
degree m - 1 polynomial through the input's values at the m Chebyshev-Lobatto points of the panel
(`PANEL_NODES` = 16), stored as Chebyshev coefficients and evaluated by Clenshaw's recurrence.
For an analytic input the error falls geometrically with m, so few nodes give near machine
precision: on the paper's circle (one turn, 7.54 s) the torques interpolate to 4e-14 relative and
the angles to 1e-15 on panels of one radian of the motion (P = 7, 112 nodes). The previous table
(cubic Hermite on 512 uniform nodes, derivatives by central differences) gave 3e-10 with 4.6
times as many evaluations of the input, which in a batch of L1 robots was two fifths of the
whole run. Values alone are sampled (no derivatives, no nodes outside the horizon); the
integrator's time derivatives (the servo's th' and th'') are exact derivatives of the polynomial.

The panel count is static (`scene_panels`): where the horizon is known when the scene is
prepared, one panel per `PANEL_RADIANS` of the nominal motion (the circle's omega t_end), at least
`MIN_PANELS`, rounded up to `MIN_PANELS` times a power of two so that horizons of similar length
share a program; otherwise at least `MIN_PANELS` and one node per output time. The table
estimates its own error from its highest two Chebyshev coefficients in each panel
(`Chebyshev.error_estimate`: no extra evaluations; it overestimates the measured error by 3 to
30 times on the scenes' inputs); a scene whose table is coarser than `TABLE_RTOL` (a horizon or
a trajectory speed the panel count did not foresee, such as a traced t_end) fails with
`RESULTS.input_table_too_coarse` instead of integrating an inaccurate input.

The input may return an auxiliary value at each node (`scene_input(..., aux=True)`): the scenes
take their reach check of the nominal path (the loop-closure residual of the inverse kinematics
that makes the input) from the table's own evaluations instead of evaluating the kinematics again
at every output time.
"""

from __future__ import annotations

from typing import Callable, Optional

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._errors import PPRError

#: how far before the first output time (and, on a horizon shorter than this, after it) a scene's
#: input table reaches (s): the quasi-static start differentiates its balance over a stencil of
#: +-2 `_statics.QS_DT` about t0 and reads the input there, which must be the input's own
#: values, not the table's extrapolation (a start that depends on the horizon: 49 um and
#: 0.67 mrad at t_end = 50 ms for L2, 2 % of a 1 s move's tracking error)
START_MARGIN = 1e-2
#: Most breakpoints (a path's samples) an input table aligns its panels to: each is a panel of
#: `PANEL_NODES` evaluations of the input, all in one vectorised call, about 3.4 kB of memory a
#: node for the inverse dynamics (a path file of 1e6 samples asked XLA for 54 GB after 97 s of
#: compiling); 50,000 keep it under 3 GB.
MAX_BREAKS = 50_000
#: Shortest live panel of a table with breakpoints, as a fraction of its equal panels' length
#: (`scene_input`: closer bounds join; the paper's horizon's panels are 0.16 s, so samples
#: closer than 16 us share a panel): a panel's k-th derivative carries rounding / length^k.
SNAP = 1e-4
#: Chebyshev-Lobatto nodes per panel (the panel's polynomial has degree PANEL_NODES - 1).
PANEL_NODES = 16
#: Panel length in radians of the nominal motion where the horizon is known: the paper's torques
#: interpolate to 4e-14 relative at this length (2e-10 at twice the length).
PANEL_RADIANS = 1.0
#: Fewest panels a scene tabulates its input on.
MIN_PANELS = 8
#: Largest estimated error of a scene's input table, relative to the input's largest magnitude,
#: that a scene accepts.
TABLE_RTOL = 1e-8


def scene_panels(n_out: int, span_radians: Optional[float] = None) -> int:
    """Panels of a scene's input table (static). With `span_radians` (omega t_end of the nominal
    motion, when known): one per `PANEL_RADIANS`, at least `MIN_PANELS`, rounded up to
    `MIN_PANELS` times a power of two, whatever the number of output times (the table's work is
    per node and vectorised). Without it: at least `MIN_PANELS` and about one node per output
    time, the best guess at the horizon."""
    if span_radians is None:
        return max(MIN_PANELS, -(-int(n_out) // PANEL_NODES))
    need = int(np.ceil(abs(float(span_radians)) / PANEL_RADIANS))
    if need <= MIN_PANELS:
        return MIN_PANELS
    return MIN_PANELS * 2 ** int(np.ceil(np.log2(need / MIN_PANELS)))


def _lobatto(m: int) -> np.ndarray:
    """The m Chebyshev-Lobatto points of [-1, 1], increasing."""
    return -np.cos(np.pi * np.arange(m) / (m - 1))


def _values_to_coeffs(m: int) -> np.ndarray:
    """(m, m) matrix taking values at `_lobatto(m)` to Chebyshev coefficients (the inverse of
    T_k(x_j); Chebyshev points keep it well conditioned)."""
    x = _lobatto(m)
    V = np.cos(np.arange(m)[None, :] * np.arccos(np.clip(x, -1.0, 1.0))[:, None])
    return np.linalg.inv(V)


class Chebyshev(eqx.Module):
    """f(t) (any shape) on [t0, t0 + P H]: P panels of length H, each a Chebyshev series of
    degree m - 1 (`coeffs` (P, m, ...)), and optionally one more panel of length `pre_H` just
    before t0 (`pre` (m, ...)), so that t0 is a panel boundary (a motion that starts from rest
    at t0 has a jump of a higher derivative there, which a polynomial across t0 would smear).
    Differentiable in t (so `derivatives` works through it) and in the coefficients (so
    gradients reach the parameters that made them). Outside the table the end panels'
    polynomials extrapolate.

    With `bounds` (P + 1,) (nondecreasing) the panels are [bounds[j], bounds[j + 1]] instead,
    of any lengths (`t0`, `H` and `pre` unused): a table whose panel boundaries include the
    breakpoints of a path (`scene_input(..., breaks=...)`). Empty panels (equal bounds) are
    never evaluated: `live` (2,) holds the first and last non-empty panel's index."""

    t0: Float[Array, ""]
    H: Float[Array, ""]
    coeffs: Float[Array, "P m ..."]
    pre: Optional[Float[Array, "m ..."]] = None
    pre_H: Optional[Float[Array, ""]] = None
    bounds: Optional[Float[Array, " P1"]] = None
    live: Optional[Array] = None

    def __call__(self, t):
        P, m = self.coeffs.shape[:2]
        if self.bounds is None:
            s = (t - self.t0) / self.H
            i = jnp.clip(jnp.floor(s), 0, P - 1).astype(jnp.int32)
            x = 2.0 * (s - i.astype(s.dtype)) - 1.0
        else:
            # panels of any lengths, some of them empty (a breakpoint clipped to an end of the
            # table, or on another boundary): the panel holding t, the first or last non-empty
            # one outside the table (side="right" passes over the empty ones inside)
            i = jnp.searchsorted(self.bounds, t, side="right", method="compare_all") - 1
            i = jnp.clip(i, self.live[0], self.live[1])
            a = self.bounds[i]
            x = 2.0 * (t - a) / (self.bounds[i + 1] - a) - 1.0
        c = self.coeffs[i]
        if self.pre is not None:
            before = t < self.t0
            x = jnp.where(before, 2.0 * (t - self.t0) / self.pre_H + 1.0, x)
            c = jnp.where(jnp.reshape(before, before.shape + (1,) * (c.ndim - 1)), self.pre, c)
        x = jnp.reshape(x, x.shape + (1,) * (c.ndim - 1))
        # Clenshaw: sum_k c_k T_k(x) without evaluating the T_k
        b1, b2 = jnp.zeros_like(c[0]), jnp.zeros_like(c[0])
        for k in range(m - 1, 0, -1):
            b1, b2 = 2.0 * x * b1 - b2 + c[k], b1
        return x * b1 - b2 + c[0]

    def error_estimate(self) -> Float[Array, ""]:
        """Estimated largest interpolation error relative to the largest value: the magnitude of
        the two highest Chebyshev coefficients, in the worst panel (for a series that converges
        geometrically the neglected tail is smaller than its last terms)."""
        c = jnp.abs(self.coeffs)
        if self.pre is not None:
            c = jnp.concatenate([c, jnp.abs(self.pre)[None]], axis=0)
        scale = jnp.max(jnp.sum(c, axis=1))  # bounds |f| in each panel, and is close to it
        tail = jnp.max(c[:, -1] + c[:, -2])
        return tail / (scale + jnp.finfo(self.coeffs.dtype).tiny)


def _nodes(t0, t1, panels: int, m: int):
    """(nodes (panels, m), H): Chebyshev-Lobatto nodes of `panels` equal panels of [t0, t1]."""
    t0 = jnp.asarray(t0, float)
    H = (jnp.asarray(t1, float) - t0) / panels
    local = jnp.asarray((_lobatto(m) + 1.0) / 2.0)
    return t0 + H * (jnp.arange(panels, dtype=float)[:, None] + local[None, :]), H


def _coeffs(vals, m: int):
    """Chebyshev coefficients (P, m, ...) from values (P * m, ...) at the panels' nodes."""
    vals = vals.reshape((-1, m) + vals.shape[1:])
    return jnp.einsum("kj,pj...->pk...", jnp.asarray(_values_to_coeffs(m)), vals)


def tabulate(fn: Callable, t0, t1, panels: int, nodes_per_panel: int = PANEL_NODES,
             aux: bool = False):
    """`Chebyshev` table of fn (a function of time returning an array) on `panels` equal panels
    of [t0, t1] with `nodes_per_panel` Chebyshev-Lobatto nodes each, all nodes in one vectorised
    evaluation. `aux=True`: fn returns (value, aux) and this returns (table, aux at every node
    (panels * nodes_per_panel, ...))."""
    m = int(nodes_per_panel)
    if m < 2 or int(panels) < 1:
        raise ValueError(f"need at least 1 panel and 2 nodes per panel, got {panels}, {m}")
    tn, H = _nodes(t0, t1, panels, m)
    out = jax.vmap(fn)(tn.reshape(-1))
    vals, extra = out if aux else (out, None)
    table = Chebyshev(t0=jnp.asarray(t0, float), H=H, coeffs=_coeffs(vals, m))
    return (table, extra) if aux else table


def breakpoints(path: Callable) -> Optional[Float[Array, " k"]]:
    """The times (k,) (s) where `path` is less smooth than elsewhere (the knots of a spline,
    where its third derivative jumps; the ends of a rest-to-rest move), from its `breakpoints`
    attribute, or None for a path smooth everywhere (the circle). A scene's input computed
    from the path (inverse-dynamics torques: a jump of the path's third derivative is a kink
    of the torques) is tabulated on panels that end there (`scene_input`)."""
    b = getattr(path, "breakpoints", None)
    return None if b is None else jnp.ravel(jnp.asarray(b, dtype=jnp.float64))


def scene_input(fn: Callable, ts, panels: Optional[int] = None, aux: bool = False,
                breaks: Optional[Array] = None):
    """A scene's input `fn` of time as its integrator and its start call it, for output times
    `ts`: a `Chebyshev` table on `panels` (default `scene_panels(len(ts))`) panels over
    [ts[0], max(ts[-1], ts[0] + `START_MARGIN`)] and one panel over
    [ts[0] - `START_MARGIN`, ts[0]], so that the quasi-static start reads the input's values on
    both sides of ts[0] whatever the horizon, and a motion that starts at ts[0] (from rest,
    with a jump of its third derivative there) is not smeared across it (with `aux`, also fn's
    auxiliary output at the nodes). All nodes in one vectorised evaluation (one copy of fn in
    the program). Check the table with `input_too_coarse`.

    `breaks` (k,) (s): the times where fn is less smooth (`breakpoints` of the path it is
    computed from) are panel boundaries too: the table then has `panels` + k + 1 panels (a
    static count), those from breakpoints outside the table's span empty (never evaluated
    there, but their nodes are), so that a spline's knots, where the inverse-dynamics torques
    have a kink, do not fall inside a panel (a polynomial across a kink converges slowly: on a
    spline through 100 samples per second the table stays far above `TABLE_RTOL` at any
    panel count). None: equal panels (the circle's)."""
    P = scene_panels(ts.shape[0]) if panels is None else int(panels)
    m = PANEL_NODES
    if breaks is not None and breaks.shape[0] > MAX_BREAKS:
        # judged from the static shape, before anything compiles
        raise PPRError(
            f"the path has {breaks.shape[0]} samples: its input table would hold a panel of "
            f"{m} evaluations per sample (about {breaks.shape[0] * m * 3.4e3 / 1e9:.0f} GB); "
            f"resample the path file to at most {MAX_BREAKS} samples, or split the experiment")
    t0 = jnp.asarray(ts[0], float)
    t1 = jnp.maximum(ts[-1], t0 + START_MARGIN)
    if breaks is not None:
        lo = t0 - START_MARGIN
        equal = (t0 + (t1 - t0) * jnp.arange(P + 1, dtype=float) / P).at[-1].set(t1)
        br = jnp.sort(jnp.clip(breaks, lo, t1))
        # A break a rounding away from an equal bound (a sample at 0.6000000000000001 s against
        # the bound 0.6, a sample just below t1 against t1) left a live panel of 1e-16 s whose
        # derivatives (a prescribed motion's accelerations) are rounding / 1e-32: the step size
        # collapsed there. An equal bound within SNAP of its panel from a break moves onto it
        # (the break is where fn kinks), then any bound that close to the one before joins it
        # (an empty panel), so that every live panel is longer than that.
        tiny = SNAP * (t1 - t0) / P
        if br.shape[0] > 1:
            i = jnp.clip(jnp.searchsorted(br, equal), 1, br.shape[0] - 1)
            left, right = br[i - 1], br[i]
            nearest = jnp.where(jnp.abs(equal - left) <= jnp.abs(right - equal), left, right)
        else:
            nearest = jnp.broadcast_to(br[0], equal.shape)
        equal = jnp.where(jnp.abs(equal - nearest) < tiny, nearest, equal)
        bounds = jnp.sort(jnp.concatenate([lo[None], equal, br]))
        keep = jnp.concatenate([jnp.ones(1, bool), bounds[1:] - bounds[:-1] >= tiny])
        bounds = jax.lax.cummax(jnp.where(keep, bounds, -jnp.inf))
        length = bounds[1:] - bounds[:-1]
        local = jnp.asarray((_lobatto(m) + 1.0) / 2.0)
        nodes = bounds[:-1, None] + length[:, None] * local[None, :]
        # The end nodes a hair inside their panel: each panel holds fn's one-sided limits at
        # its ends, where a piecewise path may jump (a clamped spline's acceleration at its
        # first and last sample, against the hold outside); the shift, 1e-12 of the panel or a
        # few roundings of t, moves the polynomial by about that much relative.
        ulps = 8.0 * jnp.spacing(jnp.maximum(jnp.abs(bounds[:-1]), jnp.abs(bounds[1:])))
        inset = jnp.minimum(jnp.maximum(1e-12 * length, ulps), 1e-3 * length)
        nodes = nodes.at[:, 0].add(inset).at[:, -1].add(-inset)
        out = jax.vmap(fn)(nodes.reshape(-1))
        vals, extra = out if aux else (out, None)
        live = length > 0
        n = live.shape[0]
        span = jnp.stack([jnp.argmax(live), n - 1 - jnp.argmax(live[::-1])]).astype(jnp.int32)
        table = Chebyshev(t0=lo, H=t1 - lo, coeffs=_coeffs(vals, m), bounds=bounds, live=span)
        return (table, extra) if aux else table
    main, H = _nodes(t0, t1, P, m)
    pre, pre_H = _nodes(t0 - START_MARGIN, t0, 1, m)
    out = jax.vmap(fn)(jnp.concatenate([main.reshape(-1), pre.reshape(-1)]))
    vals, extra = out if aux else (out, None)
    c = _coeffs(vals, m)
    table = Chebyshev(t0=t0, H=H, coeffs=c[:P], pre=c[P], pre_H=pre_H)
    return (table, extra) if aux else table


def input_too_coarse(inp: Callable):
    """Whether a scene input from `scene_input` is a table whose estimated relative error is
    above `TABLE_RTOL` (a traced bool), or None for an exact input (nothing to check)."""
    if not isinstance(inp, Chebyshev):
        return None
    return ~(inp.error_estimate() <= TABLE_RTOL)
