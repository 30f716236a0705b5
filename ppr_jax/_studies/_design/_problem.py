"""A design problem as compiled programs: the metrics at one point with their Jacobian (forward
or reverse mode), and the metrics at many points in one batched call (the starts' screening,
the verification grid, the finite differences).

The programs are functions of their arguments (the variables, the base robot, the stroke and
the `Evaluation`, whose `SceneContext` holds the scene, its models and options), so every array
of them is an input and one program serves any values of the same shapes. Through
`cached_program` they are kept for later calls in the process and, given a `program_dir` (the
command line's store), exported there once and loaded by later processes, which skip tracing
them."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
from typing import Optional

import diffrax
import equinox as eqx
import jax
import numpy as np

from ..._files import write_file
from ..._params import RobotParams
from ..._programs import NotExportable, cached_program, export_tracing, program_key
from ..._scenes import on_host_threads
from .._catalogue import SceneContext, metric_values, sampled_metrics
from .._evaluation import Evaluation, equal_links
from .._jacobian import derivatives_along, forward_jacobian, jacobian_with_values

#: the raw rows of each metric (`Problem.sizes`), by the values program's key
_SIZES: dict = {}
#: points per batched call (`jax.lax.map`'s batch): bounds the memory of a large grid
BATCH = 1024


def _raw(x, base, stroke, st: Evaluation, adjoint=None):
    """The catalogue's values at the variables x (p,) replacing the fields `st.names` of
    `base`."""
    return st.values(x, base, stroke, adjoint)


def _raw_blocks(x, base, stroke, st: Evaluation, adjoint=None):
    return st.blocks(x, base, stroke, adjoint)


def _adjoint(st: Evaluation, mode: str):
    """diffrax's adjoint of the scene's solve under `mode`'s derivative (None: no scene)."""
    if st.ctx.scene is None:
        return None
    return diffrax.ForwardMode() if mode == "fwd" else diffrax.RecursiveCheckpointAdjoint()


@eqx.filter_jit
def _derivatives_fwd(x, V, base, stroke, st: Evaluation):
    # along the rows of V (the identity's, a slice of them a core: `forward_jacobian`)
    return derivatives_along(_raw, x, V, base, stroke, st, _adjoint(st, "fwd"))


@eqx.filter_jit
def _value_and_jacobian_rev(x, base, stroke, st: Evaluation):
    J, v = jacobian_with_values(_raw, x, base, stroke, st, _adjoint(st, "rev"))
    return v, J


@eqx.filter_jit
def _batch(X, base, stroke, st: Evaluation):
    return jax.lax.map(lambda x: _raw(x, base, stroke, st), X, batch_size=BATCH)


@eqx.filter_jit
def metrics_program(params, stroke, st: Evaluation):
    """`metric_values` of `st` at `params` (`st.names` unused): the L3 re-score's program."""
    return metric_values(st.metrics, params, st.ctx, stroke, None, st.equal_links, st.samples)


def program_label(st: Evaluation, kind: str) -> str:
    """The store's label of a design program: design-<scene or closed-form>-<kind>."""
    scene = "closed-form" if st.ctx.scene is None else st.ctx.scene.name
    return f"design-{scene}-{kind}"


@dataclasses.dataclass
class Problem:
    """The metrics of a design as functions of the variables' physical values x (p,).

    `names` (p,) the variables, `lo`, `hi` (p,) their bounds; `metrics` (k,) the catalogue names
    evaluated (the objective's first); `base` the `RobotParams` the variables replace fields of;
    `stroke` (rad); `ctx` the `SceneContext`; `mode` 'fwd' (`jax.jacfwd`, one tangent per
    variable) or 'rev' (`jax.jacrev`, one cotangent per metric). `samples` names the metrics
    of `sampled_metrics` evaluated as their samples (the programs' raw values: each such metric
    a block of rows, every other metric one row; `sizes` (k,) the rows of each); the metrics
    (k,) are the raw values reduced (`reduce`: each block's max or min). `evaluations` counts
    the points evaluated (with and without the Jacobian). `program_dir`: a directory of stored
    programs (`cached_program`'s; the command line's), None: compiled in this process."""

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
    program_dir: Optional[str] = None
    _last: Optional[tuple] = dataclasses.field(default=None, repr=False)
    _sizes: Optional[np.ndarray] = dataclasses.field(default=None, repr=False)
    _callables: dict = dataclasses.field(default_factory=dict, repr=False)
    _structure: Optional[Evaluation] = dataclasses.field(default=None, repr=False)

    @property
    def structure(self) -> Evaluation:
        if self._structure is None:
            self._structure = Evaluation(tuple(self.names), tuple(self.metrics),
                                        bool(self.equal_links), tuple(self.samples), self.ctx)
        return self._structure

    def _args(self, x) -> tuple:
        # NumPy arrays: the compiled call places them itself (an optimiser calls this for
        # every iterate; `jnp.asarray` was a third of a closed-form design's time)
        return (np.asarray(x, dtype=np.float64), self.base, np.float64(self.stroke),
                self.structure)

    def _program(self, fn, kind: str, args: tuple, template):
        # kept per problem by kind and shape (its base, stroke and structure are fixed), so an
        # optimiser's iterations do not key `cached_program` afresh each time
        key = (fn, kind, args[0].shape)
        if key not in self._callables:
            self._callables[key] = cached_program(fn, args, template, self.program_dir,
                                                  program_label(self.structure, kind))
        return self._callables[key]

    @property
    def sizes(self) -> np.ndarray:
        """Raw rows (k,) of each metric: its samples' count, or 1. Found by tracing the metrics'
        shapes (the scene's solve, a second or more), so they are kept by the values' key in
        this process and, with a `program_dir`, beside the stored programs."""
        if self._sizes is not None:
            return self._sizes
        args = self._args(np.zeros(len(self.names)))
        try:
            key = program_key(args, "design-sizes")
        except NotExportable:
            key = None
        path = None if key is None or self.program_dir is None else os.path.join(
            self.program_dir, f"design-sizes-{key}.json")
        sizes = _SIZES.get(key)
        if sizes is None and path is not None and os.path.exists(path):
            try:
                with open(path) as f:
                    sizes = np.asarray(json.loads(f.read()), dtype=int)
                if sizes.shape != (len(self.metrics),):
                    sizes = None
            except (OSError, ValueError, TypeError):
                sizes = None
        if sizes is None:
            # in the state the programs are exported in: the export reuses this trace's
            # inner traces (the scene's solve)
            with export_tracing() if path is not None else contextlib.nullcontext():
                out = eqx.filter_eval_shape(_raw_blocks, *args)
            sizes = np.asarray([int(np.prod(b.shape)) for b in out], dtype=int)
            if path is not None:
                try:
                    os.makedirs(self.program_dir, exist_ok=True)
                    with write_file(path) as f:
                        f.write(json.dumps(sizes.tolist()))
                except OSError:
                    pass
        if key is not None:
            _SIZES[key] = sizes
        self._sizes = sizes
        return sizes

    @property
    def blocks(self) -> list:
        """The raw rows of each metric: a list (k,) of index arrays."""
        edges = np.concatenate([[0], np.cumsum(self.sizes)])
        return [np.arange(a, b) for a, b in zip(edges[:-1], edges[1:])]

    def reduce(self, R, J=None):
        """The metrics (..., k) of raw values R (..., n): each sampled block's max or min (its
        `sampled_metrics` kind; NaN where any sample is); with a raw Jacobian J (n, p) of one
        point, also the metrics' Jacobian (k, p): the extreme sample's row."""
        R = np.asarray(R)
        vals, rows = [], []
        for m, idx in zip(self.metrics, self.blocks):
            block = R[..., idx]
            kind = sampled_metrics().get(m) if m in self.samples else None
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
        args = self._args(x)
        if self.mode == "fwd":
            J, v = forward_jacobian(_derivatives_fwd, *args,
                                    run=lambda fn, a: self._program(fn, "fwd", a, (0, 0))(*a))
        else:
            v, J = self._program(_value_and_jacobian_rev, "rev", args, (0, 0))(*args)
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
        X = np.asarray(X, dtype=np.float64)
        m = X.shape[0]
        Xp = np.concatenate([X, np.repeat(X[:1], padded_size(m) - m, axis=0)], axis=0)
        self.evaluations += m
        args = self._args(Xp)
        # the points in slices on host threads, one a core (`on_host_threads`)
        fn = on_host_threads(_batch, Xp.shape[0], argnum=0)
        return np.asarray(self._program(fn, "batch", args, 0)(*args))[:m]

    def batch(self, X) -> np.ndarray:
        """The metrics (m, k) at m points X (m, p), in one batched call (`batch_raw`)."""
        return self.reduce(self.batch_raw(X))

    def x_of(self, u) -> np.ndarray:
        """Physical values x of normalised ones u in [0, 1]^p."""
        return self.lo + np.asarray(u, dtype=np.float64) * (self.hi - self.lo)

    def u_of(self, x) -> np.ndarray:
        """Normalised values u of physical ones x."""
        return (np.asarray(x, dtype=np.float64) - self.lo) / (self.hi - self.lo)


def design_problem(names, lo, hi, metrics, base: RobotParams, stroke: float, ctx: SceneContext,
                   mode: Optional[str], samples: tuple,
                   program_dir: Optional[str] = None) -> Problem:
    """The `Problem` of a design, its robot's structural choice decided once (`equal_links`:
    l1 == l3 only while neither is a variable) and its derivative's mode `mode`, or where None
    'fwd' where there are no more variables than rows (the metrics, each sample of the metrics
    `samples` a row), 'rev' otherwise."""
    p = len(names)
    prob = Problem(names=names, lo=lo, hi=hi, metrics=tuple(metrics), base=base, stroke=stroke,
                   ctx=ctx, mode=mode or ("fwd" if p <= len(metrics) else "rev"),
                   equal_links=equal_links(base, names, local=False), samples=samples,
                   program_dir=program_dir)
    if mode is None and samples:  # the samples are rows: count them
        prob.mode = "fwd" if p <= int(np.sum(prob.sizes)) else "rev"
    return prob


def padded_size(m: int) -> int:
    """The batch size m points are padded to: 64, or a multiple of `BATCH`."""
    return 64 if m <= 64 else -(-m // BATCH) * BATCH
