"""A design problem as compiled programs: the metrics at one point with their Jacobian (forward
or reverse mode), and the metrics at many points in one batched call (the starts' screening,
the verification grid, the finite differences)."""

from __future__ import annotations

import dataclasses
from typing import Optional

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..._params import RobotParams
from ._catalogue import SAMPLED_METRICS, SceneContext, metric_values

#: compiled programs, shared by every design of the same structure (the variables' names, the
#: metrics, the scene, the models, the robot's static choices): values change nothing
_PROGRAMS: dict = {}
#: the raw rows of each metric (`Problem.sizes`), by the same key
_SIZES: dict = {}
#: points per batched call (`jax.lax.map`'s batch): bounds the memory of a large grid
BATCH = 1024


@dataclasses.dataclass
class Problem:
    """The metrics of a design as functions of the variables' physical values x (p,).

    `names` (p,) the variables, `lo`, `hi` (p,) their bounds; `metrics` (k,) the catalogue names
    evaluated (the objective's first); `base` the `RobotParams` the variables replace fields of;
    `stroke` (rad); `ctx` the `SceneContext`; `mode` 'fwd' (`jax.jacfwd`, one tangent per
    variable) or 'rev' (`jax.jacrev`, one cotangent per metric). `samples` names the metrics
    of `SAMPLED_METRICS` evaluated as their samples (the programs' raw values: each such metric
    a block of rows, every other metric one row; `sizes` (k,) the rows of each); the metrics
    (k,) are the raw values reduced (`reduce`: each block's max or min). `evaluations` counts
    the points evaluated (with and without the Jacobian)."""

    names: list
    lo: np.ndarray
    hi: np.ndarray
    metrics: tuple
    base: RobotParams
    stroke: float
    ctx: SceneContext
    mode: str
    equal_links: bool
    samples: tuple = ()
    evaluations: int = 0
    jacobians: int = 0
    _programs: Optional[tuple] = dataclasses.field(default=None, repr=False)
    _last: Optional[tuple] = dataclasses.field(default=None, repr=False)
    _sizes: Optional[np.ndarray] = dataclasses.field(default=None, repr=False)

    def _compiled(self):
        if self._programs is None:
            self._programs = programs(self.names, self.metrics, self.base, self.ctx, self.mode,
                                      self.equal_links, self.samples)
        return self._programs

    @property
    def sizes(self) -> np.ndarray:
        """Raw rows (k,) of each metric: its samples' count, or 1."""
        if self._sizes is None:
            key = _key(self.names, self.metrics, self.base, self.ctx, self.mode,
                       self.equal_links, self.samples)
            try:
                self._sizes = _SIZES.get(key)
            except TypeError:
                key = None
            if self._sizes is None:
                self._sizes = np.asarray([self._size(m) for m in self.metrics], dtype=int)
                if key is not None:
                    _SIZES[key] = self._sizes
        return self._sizes

    def _size(self, metric) -> int:
        if metric not in self.samples:
            return 1
        x = jax.ShapeDtypeStruct((len(self.names),), jnp.float64)
        out = jax.eval_shape(lambda x: _values(self.names, (metric,), self.ctx, self.equal_links,
                                               self.samples, x, self.base,
                                               jnp.asarray(self.stroke)), x)
        return int(out.shape[0])

    @property
    def blocks(self) -> list:
        """The raw rows of each metric: a list (k,) of index arrays."""
        edges = np.concatenate([[0], np.cumsum(self.sizes)])
        return [np.arange(a, b) for a, b in zip(edges[:-1], edges[1:])]

    def reduce(self, R, J=None):
        """The metrics (..., k) of raw values R (..., n): each sampled block's max or min (its
        `SAMPLED_METRICS` kind; NaN where any sample is); with a raw Jacobian J (n, p) of one
        point, also the metrics' Jacobian (k, p): the extreme sample's row."""
        R = np.asarray(R)
        vals, rows = [], []
        for m, idx in zip(self.metrics, self.blocks):
            block = R[..., idx]
            kind = SAMPLED_METRICS.get(m) if m in self.samples else None
            if kind is None:
                vals.append(block[..., 0])
                rows.append(idx[0])
                continue
            arg = np.argmax(block, axis=-1) if kind == "max" else np.argmin(block, axis=-1)
            v = np.take_along_axis(block, arg[..., None], axis=-1)[..., 0]
            vals.append(np.where(np.all(np.isfinite(block), axis=-1), v, np.nan))
            rows.append(idx[int(arg)] if R.ndim == 1 else None)
        v = np.stack(vals, axis=-1)
        return v if J is None else (v, np.asarray(J)[np.asarray(rows)])

    def raw_value_and_jacobian(self, x) -> tuple[np.ndarray, np.ndarray]:
        """(raw values (n,), their Jacobian (n, p) d value/d x) at x (p,), the last point's
        kept."""
        x = np.asarray(x, dtype=np.float64)
        if self._last is not None and np.array_equal(self._last[0], x):
            return self._last[1], self._last[2]
        _, vjac, _ = self._compiled()
        v, J = vjac(jnp.asarray(x), self.base, jnp.asarray(self.stroke))
        v, J = np.asarray(v), np.asarray(J)
        self.evaluations += 1
        self.jacobians += 1
        self._last = (x.copy(), v, J)
        return v, J

    def value_and_jacobian(self, x) -> tuple[np.ndarray, np.ndarray]:
        """(metrics (k,), Jacobian (k, p) d metric/d x) at x (p,) (a sampled metric's: its
        extreme sample's row, a subgradient)."""
        return self.reduce(*self.raw_value_and_jacobian(x))

    def values(self, x) -> np.ndarray:
        """The metrics (k,) at x (p,) (through the Jacobian's program: compiled already)."""
        return self.value_and_jacobian(x)[0]

    def batch_raw(self, X) -> np.ndarray:
        """The raw values (m, n) at m points X (m, p), in one batched call. The batch is padded
        to `padded_size(m)` points (copies of the first), so that a design compiles two or three
        shapes, not one per call."""
        _, _, batch = self._compiled()
        X = np.asarray(X, dtype=np.float64)
        m = X.shape[0]
        Xp = np.concatenate([X, np.repeat(X[:1], padded_size(m) - m, axis=0)], axis=0)
        self.evaluations += m
        return np.asarray(batch(jnp.asarray(Xp), self.base, jnp.asarray(self.stroke)))[:m]

    def batch(self, X) -> np.ndarray:
        """The metrics (m, k) at m points X (m, p), in one batched call (`batch_raw`)."""
        return self.reduce(self.batch_raw(X))

    def x_of(self, u) -> np.ndarray:
        """Physical values x of normalised ones u in [0, 1]^p."""
        return self.lo + np.asarray(u, dtype=np.float64) * (self.hi - self.lo)

    def u_of(self, x) -> np.ndarray:
        """Normalised values u of physical ones x."""
        return (np.asarray(x, dtype=np.float64) - self.lo) / (self.hi - self.lo)


def _values(names, metrics, ctx, equal_links, samples, x, base, stroke, adjoint=None):
    """`metric_values` at the variables x (p,) replacing the fields `names` of `base`."""
    p = eqx.tree_at(lambda q: [getattr(q, n) for n in names], base,
                    [x[i] for i in range(len(names))])
    return metric_values(tuple(metrics), p, ctx, stroke, adjoint, equal_links, tuple(samples))


def padded_size(m: int) -> int:
    """The batch size m points are padded to: 64, or a multiple of `BATCH`."""
    return 64 if m <= 64 else -(-m // BATCH) * BATCH


def _key(names, metrics, base, ctx, mode, equal_links, samples):
    static = jax.tree_util.tree_structure(base)
    scene = None if ctx.scene is None else eqx.tree_pformat(
        (ctx.scene, ctx.model, ctx.options), short_arrays=False)
    return (tuple(names), tuple(metrics), str(static), scene, ctx.frequency_model, ctx.pose,
            ctx.strip_load,
            mode, equal_links, tuple(samples))


def programs(names, metrics, base, ctx: SceneContext, mode: str, equal_links: bool,
             samples: tuple = ()):
    """(values, value_and_jacobian, batch) compiled for this structure (cached): each takes
    (x, base, stroke); batch takes X (m, p). `samples`: as `metric_values`'."""
    key = _key(names, metrics, base, ctx, mode, equal_links, samples)
    try:
        hit = _PROGRAMS.get(key)
    except TypeError:  # an unhashable model: no reuse
        key, hit = None, None
    if hit is not None:
        return hit

    def f(x, base, stroke, adjoint=None):
        return _values(names, metrics, ctx, equal_links, samples, x, base, stroke, adjoint)

    def both(x, base, stroke, adjoint):
        v = f(x, base, stroke, adjoint)
        return v, v

    if mode == "fwd":
        adj = diffrax.ForwardMode() if ctx.scene is not None else None
        jac = jax.jacfwd(lambda x, b, s: both(x, b, s, adj), has_aux=True)
    else:
        adj = diffrax.RecursiveCheckpointAdjoint() if ctx.scene is not None else None
        jac = jax.jacrev(lambda x, b, s: both(x, b, s, adj), has_aux=True)

    def vjac(x, base, stroke):
        J, v = jac(x, base, stroke)
        return v, J

    def batch(X, base, stroke):
        return jax.lax.map(lambda x: f(x, base, stroke), X, batch_size=BATCH)

    out = (eqx.filter_jit(f), eqx.filter_jit(vjac), eqx.filter_jit(batch))
    if key is not None:
        _PROGRAMS[key] = out
    return out
