"""Paths and command logs, as code and as data.

Paths t -> X = (x, y, phi) (m, m, rad) for scenes of one's own: `Line` (a rest-to-rest straight
move), `Waypoints` (a C2 cubic spline through poses), `Fourier` (a periodic path); `load_path`
reads a CSV file of commanded poses as `Waypoints`, `load_commands` a controller's log of
actuated angles or torques as a `CommandLog`, which gives the actuation a scene runs on.

Every path is C2 or smoother (the quasi-static start and inverse dynamics take the
acceleration by `derivatives`), an `equinox.Module` of arrays evaluated in JAX at a scalar t
(`jax.vmap` over many), under `jax.jit`, and differentiable with respect to its arrays in both
modes (a `Waypoints` also with respect to its samples: its spline is a linear function of them,
solved in JAX). Only the sample times of a `Waypoints` are host data.

The files are read by the tracker-file reader (`_data.read_columns`: the same columns, units,
encodings and messages); everything rejected raises `DataError` naming the file, the line (or,
for arrays, the sample) and the time.
"""

from __future__ import annotations

import math
from typing import Callable, Optional

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._actuation import AbstractActuation, MotionDriven, PDServo, TorqueDriven
from ._assembly import check_angle_units
from ._custom_types import Array, Float
from ._data import (
    GAP_FACTOR,
    REQUIRED,
    WORKSPACE_SCALE,
    check_gaps,
    check_pose_units,
    read_columns,
)
from ._errors import CommandLogError, DataError, check_number
from ._labels import label_field
from ._trajectory import PiecewiseCubic

#: fewest samples of a loaded path or command log: a cubic has four coefficients, and with
#: fewer samples the spline's acceleration is set by its boundary condition, not by the data
MIN_SPLINE_SAMPLES = 4
#: a command log may start later or end earlier than its path by this fraction of its median
#: sample step (`check_log_covers`): the rounding of a recorder's time stamps, not a shortfall
COVER_TOLERANCE = 0.5
#: boundary conditions of `Waypoints`
BOUNDARY = ("clamped", "natural", "not-a-knot")
#: the loaders' choices: `BOUNDARY`, or "auto" (`end_condition`)
LOAD_BOUNDARY = ("auto", *BOUNDARY)
#: `end_condition`: a file moves at an end when its first or last step is more than this
#: fraction of its largest step (in any column)
MOVING_END = 0.05


def end_condition(ts, values) -> str:
    """The spline ends that samples (n, k) at times ts (n,) call for: `"clamped"` when the
    samples are at rest at both ends (a commanded move that starts and ends still: the clamped
    spline is exact there and the scene's start needs no velocity), `"natural"` when either end
    moves (samples cut out of a motion: a clamped spline would stop the path within one sample
    step, an acceleration of the velocity over the step, and the quasi-static start may then
    find no balance).

    An end moves when its step's speed (first or last difference over its time step) exceeds
    `MOVING_END` (5 %) of the largest step's speed, in any column that changes at all. Noise
    about as large as the motion per sample can read as motion: natural ends are then chosen,
    which are right for data of any kind (clamped is exact only at rest).

    **Arguments:**

    - `ts`: sample times (n,) (s), strictly increasing.
    - `values`: samples (n, k) (poses, angles or torques).

    **Returns:** `"clamped"` or `"natural"`.
    """
    ts = np.asarray(ts, dtype=np.float64)
    v = np.diff(np.asarray(values, dtype=np.float64).reshape(ts.shape[0], -1), axis=0)
    v = np.abs(v / np.diff(ts)[:, None])
    peak = v.max(axis=0)
    moving = peak > 0
    if not moving.any():
        return "clamped"
    ends = np.maximum(v[0], v[-1])[moving] / peak[moving]
    return "natural" if float(ends.max()) > MOVING_END else "clamped"


def _check_bc(source: str, bc: str) -> None:
    """Raise `DataError` unless `bc` is one of `LOAD_BOUNDARY` (before the file is read)."""
    if bc not in LOAD_BOUNDARY:
        raise DataError(f"{source}: unknown boundary condition bc={bc!r}; allowed: "
                        f"{', '.join(LOAD_BOUNDARY)}")


def _load_bc(bc: str, ts, values) -> str:
    """The ends of a spline through the loaded samples: `bc`, with "auto" resolved."""
    return end_condition(ts, values) if bc == "auto" else bc


def _is_traced(x) -> bool:
    return isinstance(x, jax.core.Tracer)


def _at(source: str, label: str, rows, ts, i) -> str:
    """'file.csv: line 12 (t = 0.3 s)' for sample i."""
    return f"{source}: {label} {int(rows[i])} (t = {float(ts[i]):.6g} s)"


def _check_samples(source: str, ts, values, *, rows=None, label: str = "sample",
                   min_samples: int = 2, max_gap: Optional[float] = None,
                   what: str = "values") -> None:
    """Raise `DataError` unless times ts (n,) are finite and strictly increasing, there are at
    least `min_samples`, no step is longer than `max_gap` times the median step (None: no gap
    check) and the values (n, k) (None when traced) are finite. `rows` labels the samples in
    the messages (file lines; default: 1-based sample index)."""
    n = ts.shape[0]
    rows = np.arange(1, n + 1) if rows is None else np.asarray(rows)
    bad = ~np.isfinite(ts)
    if values is not None:
        bad = bad | ~np.all(np.isfinite(values), axis=1)
    if bad.any():
        i = np.flatnonzero(bad)
        shown = ", ".join(str(int(r)) for r in rows[i][:10]) + (", ..." if i.size > 10 else "")
        raise DataError(f"{source}: {label}{'s' if i.size > 1 else ''} {shown}: NaN or infinite "
                        f"time or {what} ({i.size} {label}s)")
    if n < min_samples:
        raise DataError(f"{source}: too few samples: {n}; a C2 cubic spline, whose acceleration "
                        f"the quasi-static start and inverse dynamics use, needs at least "
                        f"{min_samples}")
    dt = np.diff(ts)
    back = np.flatnonzero(dt <= 0)
    if back.size:
        i = int(back[0]) + 1
        cause = "the same time as" if dt[i - 1] == 0 else "an earlier time than"
        raise DataError(f"{_at(source, label, rows, ts, i)}: {cause} {label} {int(rows[i - 1])} "
                        f"(t = {float(ts[i - 1]):.6g} s); times must be strictly increasing")
    if max_gap is not None:
        check_gaps(source, ts, rows, label, max_gap)


def _check_load_args(max_gap, min_samples) -> tuple:
    """(max_gap, min_samples) of the file loaders checked before the file is read: a factor
    of the median step in [1, 1e12] or None (below 1 every step would be a gap), an integer
    of at least 2."""
    if max_gap is not None:
        max_gap = check_number("max_gap", max_gap, 1.0, 1e12, "median time steps (or None)",
                               error=DataError)
    return max_gap, check_number("min_samples", min_samples, 2, 10**12, integer=True,
                                 error=DataError)


def _host_times(ts, source: str) -> np.ndarray:
    if _is_traced(ts):
        raise DataError(f"{source}: the sample times must be concrete values (the spline's "
                        f"system is factored on the host); only the samples may be traced")
    ts = np.asarray(ts, dtype=np.float64)
    if ts.ndim != 1:
        raise DataError(f"{source}: times must be a vector (n,), got shape {ts.shape}")
    return ts


def _spline_factors(ts: np.ndarray, bc: str):
    """Host part of the spline: the tridiagonal system for the knot slopes m (n,) (C2 at the
    interior knots, `bc` at the ends), LU-factored by the Thomas algorithm. Returns the
    recurrence coefficients (alpha, cp, den) of the forward and backward sweeps."""
    n = ts.shape[0]
    h = np.diff(ts)
    a, b, c = np.zeros(n), np.zeros(n), np.zeros(n)
    a[1:-1], b[1:-1], c[1:-1] = h[1:], 2 * (h[:-1] + h[1:]), h[:-1]
    if bc == "clamped":
        b[0] = b[-1] = 1.0
    elif bc == "natural":  # 2 m0 + m1 = 3 delta0 is y'' = 0 at the first knot, likewise last
        b[0], c[0], a[-1], b[-1] = 2.0, 1.0, 1.0, 2.0
    else:  # not-a-knot: the third derivative continuous at the second and the last but one
        # knot (scipy's CubicSpline's default), its rows kept tridiagonal; needs n >= 3
        b[0], c[0] = h[1], h[0] + h[1]
        a[-1], b[-1] = h[-1] + h[-2], h[-2]
    den, cp = np.empty(n), np.empty(n)
    den[0], cp[0] = b[0], c[0] / b[0]
    for i in range(1, n):
        den[i] = b[i] - a[i] * cp[i - 1]
        cp[i] = c[i] / den[i]
    return -a / den, cp, den


def _spline_coefficients(ts: np.ndarray, ys, bc: str):
    """`PiecewiseCubic` coefficients (n - 1, 4, k) of the C2 cubic spline through ys (n, k) at
    ts (n,) with boundary condition `bc`: a linear function of ys, evaluated in JAX (traceable
    and differentiable in ys; the factors depend on ts alone)."""
    alpha, cp, den = (jnp.asarray(v) for v in _spline_factors(ts, bc))
    h = jnp.asarray(np.diff(ts))[:, None]
    delta = (ys[1:] - ys[:-1]) / h
    inner = 3.0 * (h[1:] * delta[:-1] + h[:-1] * delta[1:])
    if bc == "clamped":  # zero velocity at both ends
        end0, end1 = jnp.zeros_like(ys[:1]), jnp.zeros_like(ys[:1])
    elif bc == "natural":
        end0, end1 = 3.0 * delta[:1], 3.0 * delta[-1:]
    else:  # not-a-knot (`_spline_factors`)
        h0, h1, g0, g1 = h[0], h[1], h[-2], h[-1]
        end0 = ((h0 + 2.0 * (h0 + h1)) * h1 * delta[0] + h0**2 * delta[1]) / (h0 + h1)
        end1 = (g1**2 * delta[-2] + (2.0 * (g0 + g1) + g1) * g0 * delta[-1]) / (g0 + g1)
        end0, end1 = end0[None], end1[None]
    d = jnp.concatenate([end0, inner, end1]) / den[:, None]

    def forward(prev, x):
        al, di = x
        cur = al * prev + di
        return cur, cur

    _, dp = jax.lax.scan(forward, jnp.zeros_like(ys[0]), (alpha, d))

    def backward(nxt, x):
        cpi, dpi = x
        cur = dpi - cpi * nxt
        return cur, cur

    _, m = jax.lax.scan(backward, jnp.zeros_like(ys[0]), (cp, dp), reverse=True)
    c1 = (3.0 * delta - 2.0 * m[:-1] - m[1:]) / h
    c0 = (m[:-1] + m[1:] - 2.0 * delta) / h**2
    return jnp.stack([c0, c1, m[:-1], ys[:-1]], axis=1)


class Line(eqx.Module):
    """A rest-to-rest straight move of the pose from `start` to `end`: X(t) = start +
    s(t / duration) (end - start) with the quintic time law s(u) = 10 u^3 - 15 u^4 + 6 u^5,
    whose velocity and acceleration vanish at both ends; it holds `start` before t = 0 and
    `end` after `duration`. C2 everywhere (the jerk jumps at the ends).

    **Arguments:**

    - `start`: the pose at t <= 0, (x, y, phi) (m, m, rad).
    - `end`: the pose at t >= `duration`, (3,) likewise.
    - `duration`: the move's duration (s), positive.
    """

    start: Float[Array, "3"]
    end: Float[Array, "3"]
    duration: Float[Array, ""]

    def __init__(self, start, end, duration):
        self.start = jnp.asarray(start, dtype=jnp.float64)
        self.end = jnp.asarray(end, dtype=jnp.float64)
        self.duration = jnp.asarray(duration, dtype=jnp.float64)
        if self.start.shape != (3,) or self.end.shape != (3,) or self.duration.shape != ():
            raise DataError(f"Line: start and end must be poses (3,) and duration a scalar, got "
                            f"{self.start.shape}, {self.end.shape}, {self.duration.shape}")
        if not _is_traced(self.duration) and not float(self.duration) > 0:
            raise DataError(f"Line: duration must be positive, got {float(self.duration)} s")

    @property
    def breakpoints(self) -> Float[Array, "2"]:
        """The times (s) where the jerk jumps: the start and the end of the move (a scene's
        input table has panel boundaries there)."""
        return jnp.stack([jnp.zeros_like(self.duration), self.duration])

    @property
    def kinks(self) -> Float[Array, "2"]:
        """The ends of the holds (s), t = 0 and `duration`, where the jerk jumps: a scene
        started at t = 0 starts at rest in the hold's balance (`_statics.start_stencil`), not
        across the jump."""
        return self.breakpoints

    def __call__(self, t) -> Float[Array, "3"]:
        u = jnp.clip(jnp.asarray(t, dtype=jnp.float64) / self.duration, 0.0, 1.0)
        s = u**3 * (10.0 + u * (-15.0 + 6.0 * u))
        return (1.0 - s) * self.start + s * self.end  # the end poses exactly at s = 0, 1


class Fourier(eqx.Module):
    """A periodic path, the Fourier series X(t) = mean + sum_k (cos_k cos(k omega t) +
    sin_k sin(k omega t)), k = 1..K. Smooth (C-infinity); period 2 pi / omega.

    **Arguments:**

    - `mean`: the mean pose (3,) (m, m, rad).
    - `cos`, `sin`: the coefficients (K, 3) of cos(k omega t) and sin(k omega t), row k - 1 for
      harmonic k (m, m, rad); K may be 0.
    - `omega`: the fundamental angular frequency (rad/s), positive.
    """

    mean: Float[Array, "3"]
    cos: Float[Array, "K 3"]
    sin: Float[Array, "K 3"]
    omega: Float[Array, ""]

    def __init__(self, mean, cos, sin, omega):
        self.mean = jnp.asarray(mean, dtype=jnp.float64)
        self.cos = jnp.asarray(cos, dtype=jnp.float64)
        self.sin = jnp.asarray(sin, dtype=jnp.float64)
        self.omega = jnp.asarray(omega, dtype=jnp.float64)
        if (self.mean.shape != (3,) or self.cos.ndim != 2 or self.cos.shape[1:] != (3,)
                or self.sin.shape != self.cos.shape or self.omega.shape != ()):
            raise DataError(f"Fourier: mean must be (3,), cos and sin (K, 3) alike and omega a "
                            f"scalar, got {self.mean.shape}, {self.cos.shape}, "
                            f"{self.sin.shape}, {self.omega.shape}")
        if not _is_traced(self.omega) and not float(self.omega) > 0:
            raise DataError(f"Fourier: omega must be positive, got {float(self.omega)} rad/s")

    def __call__(self, t) -> Float[Array, "3"]:
        k = jnp.arange(1, self.cos.shape[0] + 1, dtype=jnp.float64)
        wt = k * (self.omega * jnp.asarray(t, dtype=jnp.float64))
        return self.mean + jnp.cos(wt) @ self.cos + jnp.sin(wt) @ self.sin


class Waypoints(eqx.Module):
    """The C2 cubic spline through poses (n, 3) at times (n,): exact at the samples, continuous
    in value, velocity and acceleration.

    Boundary condition `"clamped"` (the default): zero velocity at the first and last sample,
    the robot at rest before and after the motion, as a commanded move starts and ends; the
    scene's quasi-static start then needs no initial velocity, and as the acceleration jumps
    at those two samples (`kinks`) it differentiates one-sided there. `"natural"`: zero acceleration
    at the ends instead, for samples cut out of a motion (a clamped spline would stop the path
    there, within one sample interval). Outside [ts[0], ts[-1]] the path continues with its end
    pose and velocity (a hold when clamped): C1 there, keep simulations inside the samples.
    `"not-a-knot"`: the third derivative continuous at the second and the last but one sample
    (scipy's `CubicSpline` default; at least 3 samples), fourth-order accurate up to the ends
    for samples of a smooth motion, and continued outside by its end pieces (smooth there: a
    quasi-static start's stencil at the first sample reads the motion's own rates and
    accelerations); `compensate` writes its command logs for it.

    The spline's slopes solve a tridiagonal system factored once on the host from the times;
    the rest is JAX, linear in the poses, so a `Waypoints` built from traced poses is
    differentiable with respect to them (`jax.grad`, `jax.jacfwd`). Samples of any width k
    (n, k) are splined alike (`CommandLog` uses it for angles and torques).

    **Arguments:**

    - `ts`: sample times (n,) (s), strictly increasing, n >= 2; host values, not traced.
    - `poses`: samples (n, 3) (x, y, phi) (m, m, rad).
    - `bc`: `"clamped"`, `"natural"` or `"not-a-knot"`.
    - `name`: labels the samples in error messages (a file name for `load_path`).
    """

    spline: PiecewiseCubic
    bc: str = eqx.field(static=True)
    name: str = label_field()

    def __init__(self, ts, poses, bc: str = "clamped", *, name: str = "Waypoints"):
        if bc not in BOUNDARY:
            raise DataError(f"{name}: unknown boundary condition {bc!r}; allowed: "
                            f"{', '.join(BOUNDARY)}")
        ts = _host_times(ts, name)
        ys = jnp.asarray(poses, dtype=jnp.float64)
        if ys.ndim != 2 or ys.shape[0] != ts.shape[0]:
            raise DataError(f"{name}: samples must have shape (n, k) with n = {ts.shape[0]} "
                            f"times, got {ys.shape}")
        _check_samples(name, ts, None if _is_traced(ys) else np.asarray(ys),
                       min_samples=3 if bc == "not-a-knot" else 2)
        self.spline = PiecewiseCubic(jnp.asarray(ts), _spline_coefficients(ts, ys, bc))
        self.bc, self.name = bc, name

    @property
    def ts(self) -> Float[Array, " n"]:
        """The sample times (s)."""
        return self.spline.ts

    @property
    def breakpoints(self) -> Float[Array, " n"]:
        """The knots (s), where the spline's third derivative jumps (a scene's input table has
        panel boundaries there): the sample times."""
        return self.spline.ts

    @property
    def kinks(self) -> Optional[Float[Array, "2"]]:
        """The times (s) where the path's acceleration jumps: a clamped spline's first and last
        sample (at rest outside, accelerating inside), where a scene's quasi-static start
        differentiates one-sided (`_statics.start_stencil`: started at the first sample, at
        rest in the hold's balance); None for the other ends (C2)."""
        if self.bc != "clamped":
            return None
        ts = self.spline.ts
        return jnp.stack([ts[0], ts[-1]])

    def __call__(self, t) -> Float[Array, " k"]:
        t = jnp.asarray(t, dtype=jnp.float64)
        if self.bc == "not-a-knot":  # the end pieces continue: smooth across the ends
            return self.spline(t)
        ts, c = self.spline.ts, self.spline.c
        h = ts[-1] - ts[-2]
        y1 = ((c[-1, 0] * h + c[-1, 1]) * h + c[-1, 2]) * h + c[-1, 3]
        if self.bc == "clamped":  # at rest at both ends: a hold outside, exactly
            v0 = v1 = jnp.zeros_like(y1)
        else:
            v0, v1 = c[0, 2], (3.0 * c[-1, 0] * h + 2.0 * c[-1, 1]) * h + c[-1, 2]
        # jnp.where, not a clip of t: at the end samples themselves the spline's own one-sided
        # derivatives are kept (a clip's derivative is 1/2 there)
        return jnp.where(t < ts[0], c[0, 3] + v0 * (t - ts[0]),
                         jnp.where(t > ts[-1], y1 + v1 * (t - ts[-1]), self.spline(t)))


class CommandLog(eqx.Module):
    """A controller's command log: actuated angles th_i1 (rad) or actuator torques (N m) (3,)
    over time, splined as `Waypoints` (C2), evaluated by `__call__(t)` as the time function
    that the actuations take. `actuation()` gives the scene's input.

    **Arguments:**

    - `spline`: the `Waypoints` through the logged samples (n, 3).
    - `kind`: `"angles"` or `"torque"` (static).
    """

    spline: Waypoints
    kind: str = eqx.field(static=True)

    def __check_init__(self):
        if self.kind not in ("angles", "torque"):
            raise DataError(f"{self.spline.name}: kind must be 'angles' or 'torque', got "
                            f"{self.kind!r}")

    @property
    def ts(self) -> Float[Array, " n"]:
        """The sample times (s)."""
        return self.spline.ts

    @property
    def name(self) -> str:
        return self.spline.name

    @property
    def breakpoints(self) -> Float[Array, " n"]:
        """The spline's knots (s), the sample times: the integrator steps to them."""
        return self.spline.ts

    @property
    def kinks(self) -> Optional[Float[Array, "2"]]:
        """The times (s) where the logged commands' second derivative jumps (`Waypoints.kinks`)."""
        return self.spline.kinks

    def __call__(self, t) -> Float[Array, "3"]:
        return self.spline(t)

    def actuation(self, Kp=None, Kd=None, feedforward: Optional[Callable] = None
                  ) -> AbstractActuation:
        """The actuation that replays the log: `TorqueDriven` for torques; for angles
        `MotionDriven` (prescribed), or, given gains, a `PDServo` tracking them.

        **Arguments:**

        - `Kp`, `Kd`: PD gains (3,) or scalar (N m/rad, N m s/rad), angle logs only.
        - `feedforward`: a torque time function (N m) added by the servo.
        """
        if self.kind == "torque":
            if Kp is not None or Kd is not None or feedforward is not None:
                raise DataError(f"{self.name}: a torque log drives the actuators directly; "
                                f"servo gains apply to an angle log")
            return TorqueDriven(self)
        if Kp is None and Kd is None:
            if feedforward is not None:
                raise DataError(f"{self.name}: a feedforward torque needs servo gains Kp, Kd")
            return MotionDriven(self)
        if Kp is None or Kd is None:
            raise DataError(f"{self.name}: a servo needs both gains Kp and Kd")
        return PDServo(self, jnp.asarray(Kp, dtype=jnp.float64),
                       jnp.asarray(Kd, dtype=jnp.float64), feedforward)


#: a stray pose (`_check_strays`): one further from the chord of its two neighbours than
#: STRAY_FACTOR times both the neighbours' own distance and the file's median step, and than
#: STRAY_FLOOR (m, rad: far above a tracker's noise)
STRAY_FACTOR = 10.0
STRAY_FLOOR = (5e-3, 0.05)


def _check_strays(source: str, rows, ts, X) -> None:
    """Raise `DataError` at the first single pose out of line with its path: further from the
    chord of its two neighbours (at its time) than `STRAY_FACTOR` times the larger of the
    neighbours' distance and the median step, and than `STRAY_FLOOR`, in position or in
    rotation. One such pose (a typo, a tracker's glitch) would be splined into the path and
    found only when the run leaves the chains' reach; a sharp corner or a reversal is no
    stray (its neighbours, or the median step, are as far apart as it is from them)."""
    if X.shape[0] < 3:
        return
    w = ((ts[1:-1] - ts[:-2]) / (ts[2:] - ts[:-2]))[:, None]
    chord = (1 - w) * X[:-2] + w * X[2:]
    for cols, floor, unit, scale in ((slice(0, 2), STRAY_FLOOR[0], "mm", 1e3),
                                     (slice(2, 3), STRAY_FLOOR[1], "rad", 1.0)):
        off = np.linalg.norm(X[1:-1, cols] - chord[:, cols], axis=1)
        span = np.linalg.norm(X[2:, cols] - X[:-2, cols], axis=1)
        med = float(np.median(np.linalg.norm(np.diff(X[:, cols], axis=0), axis=1)))
        bad = np.flatnonzero((off > floor) & (off > STRAY_FACTOR * np.maximum(span, med)))
        if bad.size:
            i = int(bad[np.argmax(off[bad])]) + 1
            raise DataError(
                f"{_at(source, 'line', rows, ts, i)}: a stray pose, {scale * off[i - 1]:.4g} "
                f"{unit} off the line between its neighbours (lines {int(rows[i - 1])} and "
                f"{int(rows[i + 1])}), whose own distance is {scale * span[i - 1]:.3g} {unit} "
                f"and the file's median step {scale * med:.3g} {unit}: a typo or a tracker's "
                f"glitch; fix or drop the line (check_units=False skips this check)")


def _check_poses(source: str, rows, ts, X) -> None:
    """`check_pose_units` on the single poses most out of the workspace's scale and of the
    rotation's range, so that the message names their lines (one stray row in other units
    included)."""
    d = np.hypot(X[:, 0], X[:, 1])
    for i in (int(np.argmax(np.abs(np.log(np.maximum(d, 1e-300) / WORKSPACE_SCALE)))),
              int(np.argmax(np.abs(X[:, 2])))):
        check_pose_units(_at(source, "line", rows, ts, i), X[i:i + 1])


def load_path(path: str, *, bc: str = "auto", max_gap: Optional[float] = GAP_FACTOR,
              min_samples: int = MIN_SPLINE_SAMPLES, time_unit: Optional[str] = None,
              length_unit: Optional[str] = None, angle_unit: Optional[str] = None,
              drop_nan: bool = False, check_units: bool = True) -> Waypoints:
    """Read a CSV file of commanded poses as a `Waypoints` path (C2 spline) in SI units.

    The file is a tracker table (`load_csv`): columns `time, x, y, phi` (other known columns,
    th_* and tau_*, are ignored), units in the column names (`x[mm]`, `phi[deg]`), a header
    comment (`# units: length=mm, angle=deg`) or the options, `#` comments.

    **Arguments:**

    - `path`: the CSV file.
    - `bc`: the spline's boundary condition, `"clamped"` or `"natural"` (see `Waypoints`), or
      `"auto"` (the default): clamped when the file is at rest at both ends, natural when it
      starts or ends moving (`end_condition`).
    - `max_gap`: a time step longer than this many median steps is a gap (`GAP_FACTOR`, 10);
      None accepts uneven sampling (hand-written waypoints).
    - `min_samples`: fewest rows (at least 4, `MIN_SPLINE_SAMPLES`).
    - `time_unit`, `length_unit`, `angle_unit`: units of undeclared columns (as `load_csv`).
    - `drop_nan`: drop rows with NaN or empty cells instead of raising.
    - `check_units`: refuse a pose about 30 times off the workspace's scale or |phi| > pi/2,
      and a single stray pose out of line with its neighbours (`_check_strays`).

    **Returns:** the `Waypoints`, named by the file. Raises `DataError` naming the file, the line
    and the time for: NaN or infinite values, fewer than `min_samples` rows, times not strictly
    increasing, a gap, a pose far outside the workspace, a stray pose; and whatever `load_csv`
    refuses (columns, units, numbers, encodings).
    """
    max_gap, min_samples = _check_load_args(max_gap, min_samples)
    _check_bc(path, bc)
    table = read_columns(path, required=REQUIRED, time_unit=time_unit, length_unit=length_unit,
                         angle_unit=angle_unit, drop_nan=drop_nan)
    col, lines, source = table.columns, table.lines, table.source
    ts = col["time"]
    X = np.column_stack([col["x"], col["y"], col["phi"]])
    _check_samples(source, ts, X, rows=lines, label="line", max_gap=max_gap,
                   min_samples=max(min_samples, MIN_SPLINE_SAMPLES), what="pose")
    if check_units:
        _check_poses(source, lines, ts, X)
        _check_strays(source, lines, ts, X)
    return Waypoints(ts, X, _load_bc(bc, ts, X), name=source)


def load_commands(path: str, *, kind: Optional[str] = None, bc: str = "auto",
                  max_gap: Optional[float] = GAP_FACTOR, min_samples: int = MIN_SPLINE_SAMPLES,
                  time_unit: Optional[str] = None, angle_unit: Optional[str] = None,
                  torque_unit: Optional[str] = None, drop_nan: bool = False,
                  check_units: bool = True) -> CommandLog:
    """Read a controller's command log, actuated angles or torques over time, as a
    `CommandLog` (C2 spline, SI units).

    The file is a table in the tracker files' format (`load_csv`): a `time` column and either
    `th_1, th_2, th_3` (rad unless declared, `th_1[deg]`) or `tau_1, tau_2, tau_3` (N m unless
    declared, `tau_1[Nmm]`); pose columns may be present and are ignored.

    **Arguments:**

    - `path`: the CSV file.
    - `kind`: `"angles"` or `"torque"`: which columns to read when the file holds both; None
      takes the one present.
    - `bc`: the spline's boundary condition (see `Waypoints`): `"auto"` (the default: the one
      the file's header declares, `# spline: not-a-knot` as `compensate` writes, else as
      `load_path`: natural when the log starts or ends changing), `"clamped"`, `"natural"` or
      `"not-a-knot"`.
    - `max_gap`, `min_samples`, `drop_nan`: as `load_path`.
    - `time_unit`, `angle_unit`, `torque_unit`: units of undeclared columns.
    - `check_units`: refuse angles beyond two turns (degrees read as radians) and a step of more
      than pi between samples (an angle wrapped at +-pi: unwrap it first).

    **Returns:** the `CommandLog`; `.actuation()` replays it. Raises `DataError` naming the file,
    the line and the time, as `load_path`.
    """
    if kind not in (None, "angles", "torque"):
        raise DataError(f"{path}: kind must be 'angles', 'torque' or None, got {kind!r}")
    max_gap, min_samples = _check_load_args(max_gap, min_samples)
    _check_bc(path, bc)
    table = read_columns(path, required=("time",), time_unit=time_unit, angle_unit=angle_unit,
                         torque_unit=torque_unit, drop_nan=drop_nan)
    col, lines, source = table.columns, table.lines, table.source
    have = {k: p in col for k, p in (("angles", "th_1"), ("torque", "tau_1"))}
    if kind is None:
        if have["angles"] and have["torque"]:
            raise DataError(f"{source}: the file holds both angles (th_1..th_3) and torques "
                            f"(tau_1..tau_3): pass kind='angles' or kind='torque'")
        if not have["angles"] and not have["torque"]:
            raise DataError(f"{source}: a command log needs columns th_1, th_2, th_3 (angles) "
                            f"or tau_1, tau_2, tau_3 (torques); found neither")
        kind = "angles" if have["angles"] else "torque"
    elif not have[kind]:
        raise DataError(f"{source}: kind={kind!r} but the file has no "
                        f"{'th_1..th_3' if kind == 'angles' else 'tau_1..tau_3'} columns")
    prefix = "th" if kind == "angles" else "tau"
    ts = col["time"]
    V = np.column_stack([col[f"{prefix}_{k}"] for k in (1, 2, 3)])
    _check_samples(source, ts, V, rows=lines, label="line", max_gap=max_gap,
                   min_samples=max(min_samples, MIN_SPLINE_SAMPLES),
                   what="angles" if kind == "angles" else "torques")
    if kind == "angles" and check_units:
        check_angle_units(V, lambda i: _at(source, "line", lines, ts, i), DataError)
        step = np.max(np.abs(np.diff(V, axis=0)), axis=1)
        if np.max(step) > math.pi:
            i = int(np.argmax(step > math.pi)) + 1
            raise DataError(f"{_at(source, 'line', lines, ts, i)}: an actuated angle jumps by "
                            f"{float(step[i - 1]):.4g} rad from line {int(lines[i - 1])}: wrapped "
                            f"at +-pi? unwrap it (numpy.unwrap) before loading")
    if bc == "auto" and _declared_spline(path) is not None:
        bc = _declared_spline(path)
    return CommandLog(Waypoints(ts, V, _load_bc(bc, ts, V), name=source), kind)


#: the header comment by which a command log names its spline (`compensate` writes it)
SPLINE_COMMENT = "# spline:"


def _declared_spline(path: str):
    """The spline a file's header declares (`# spline: not-a-knot`), else None."""
    with open(path, encoding="utf-8", errors="replace") as f:
        for line in f:
            if not line.startswith("#"):
                return None
            if line.lower().startswith(SPLINE_COMMENT):
                name = line[len(SPLINE_COMMENT):].strip()
                if name not in BOUNDARY:
                    raise DataError(f"{path}: the header declares spline {name!r}; allowed: "
                                    f"{', '.join(BOUNDARY)}")
                return name
    return None


def check_same_rate(a, b, *, rtol: float = 0.01) -> float:
    """Check that two sampled signals paired sample by sample share their sampling rate: a pose
    file (`load_path`) and a torque or angle log (`load_commands`), or `Experiment`s.

    **Arguments:**

    - `a`, `b`: anything with sample times `ts` (a `Waypoints`, `CommandLog`, `Experiment`);
      their `name` labels the message.
    - `rtol`: the relative difference of the median time steps allowed (1 %).

    **Returns:** the common median time step (s). Raises `DataError` naming both sources, their
    rates and median steps when they differ by more than `rtol`.
    """
    rtol = check_number("rtol", rtol, 0.0, 1.0, error=DataError)
    steps = []
    for which, x in (("a", a), ("b", b)):
        ts = getattr(x, "ts", None)
        try:
            ts = np.asarray(ts, dtype=np.float64)
        except (TypeError, ValueError):
            ts = None
        if ts is None or ts.ndim != 1:
            raise DataError(f"check_same_rate: {which} must have sample times ts (a Waypoints, "
                            f"CommandLog or Experiment), got {type(x).__name__}")
        if ts.shape[0] < 2:
            raise DataError(f"{getattr(x, 'name', 'signal')}: needs at least two sample times")
        steps.append(float(np.median(np.diff(ts))))
    da, db = steps
    if abs(da - db) > rtol * max(da, db):
        na, nb = getattr(a, "name", "first"), getattr(b, "name", "second")
        apart = abs(da - db) / max(da, db)
        raise DataError(f"{na} is sampled at {1 / da:.6g} Hz (median step {da:.6g} s) but {nb} "
                        f"at {1 / db:.6g} Hz (median step {db:.6g} s), {apart:.2%} apart "
                        f"(allowed {rtol:.2%}): resample one onto the other's times before "
                        f"pairing them")
    return da


def _span(x):
    """(first, last) sample time (s) of `x` (its `ts`), or None where it has no concrete sample
    times (a path given as a formula, or traced)."""
    ts = getattr(x, "ts", None)
    if ts is None or _is_traced(ts):
        return None
    ts = np.asarray(ts, dtype=np.float64)
    if ts.ndim != 1 or ts.shape[0] < 2:
        return None
    return float(ts[0]), float(ts[-1]), float(np.median(np.diff(ts)))


def check_log_covers(path, log, *, t_end: Optional[float] = None,
                     tolerance: float = COVER_TOLERANCE) -> None:
    """Refuse a command log that does not cover its path: the one check of a log of actuated
    angles or torques against the path it drives (every `PathScene` makes it, so the command
    line's `--angles` and `--torques`, the studies and the API alike).

    Outside its samples a log's spline is extrapolated: commands no controller gave, which
    drive the model off the path and are reported as the robot's tracking error. So the log
    must span the path's samples (a path with sample times: `Waypoints`, a loaded file) or,
    for a path given as a formula (`Line`, `Fourier`, `Circle`), the run's horizon [0, t_end];
    it may start later or end earlier by at most `tolerance` times its median sample step
    (half a step by default: the recorder's stamps). A log stamped from another start (0.2 to
    1.2 s against a path from 0 s) is refused alike. A log longer than the path is accepted.

    **Arguments:**

    - `path`: the nominal path (anything with sample times `ts`, or a time function).
    - `log`: the command log (`CommandLog`, or anything with sample times `ts`; a time
      function without samples covers every time and is not checked).
    - `t_end`: the run's horizon (s), for a path without sample times; None: not checked.
    - `tolerance`: the allowed shortfall at either end, in median sample steps of the log.

    **Returns:** None. Raises `CommandLogError` (a `DataError`) naming the log, its span, the
    path's span and the shortfall.
    """
    have = _span(log)
    if have is None:
        return
    lo, hi, step = have
    need = _span(path)
    if need is not None:
        t0, t1, what = need[0], need[1], f"the path {getattr(path, 'name', 'path')} spans"
    elif t_end is not None:
        t0, t1, what = 0.0, float(t_end), "the run spans"
    else:
        return
    tol = tolerance * step
    short = []
    if lo > t0 + tol:
        short.append(f"it starts {lo - t0:.6g} s after")
    if hi < t1 - tol:
        short.append(f"it ends {t1 - hi:.6g} s before")
    if short:
        name = getattr(log, "name", "the command log")
        raise CommandLogError(
            f"{name}: the command log spans t = {lo:.6g} to {hi:.6g} s but {what} t = "
            f"{t0:.6g} to {t1:.6g} s: {' and '.join(short)} it (allowed {tolerance:g} sample "
            f"step, {tol:.3g} s); outside its samples the log would be extrapolated, commands "
            f"no controller gave: give a log over the whole span (times counted from the "
            f"path's first), or cut the path (or the horizon) to the log's")


#: the first samples of an experiment from which its start is estimated (`fit_start`): those
#: within START_WINDOW seconds of the first, at least START_MIN_SAMPLES of them
START_WINDOW = 0.1
START_MIN_SAMPLES = 5


class StartPath(eqx.Module):
    """The pose near a start, X(t) = X0 + X0' (t - t0) + X0'' (t - t0)^2 / 2: what a scene's
    quasi-static start takes from its path (the pose, its rate and acceleration at t0), given
    apart from the path (`PathScene.start_path`), as `fit_start` estimates it from an
    experiment's first samples.

    **Arguments:**

    - `t0`: the start time (s).
    - `coefficients`: (3, 3), rows X0 (m, m, rad), X0' (m/s, m/s, rad/s), X0'' (m/s^2, m/s^2,
      rad/s^2).
    """

    t0: Float[Array, ""]
    coefficients: Float[Array, "3 3"]

    def __init__(self, t0, coefficients):
        self.t0 = jnp.asarray(t0, dtype=jnp.float64)
        self.coefficients = jnp.asarray(coefficients, dtype=jnp.float64)
        if self.coefficients.shape[-2:] != (3, 3):
            raise DataError(f"StartPath: coefficients must be (3, 3) (pose, rate, acceleration), "
                            f"got {self.coefficients.shape}")

    def __call__(self, t) -> Float[Array, "3"]:
        s = jnp.asarray(t, dtype=jnp.float64) - self.t0
        c = self.coefficients
        return c[0] + s * c[1] + 0.5 * s * s * c[2]


def fit_start(ts, X, *, window: float = START_WINDOW,
              min_samples: int = START_MIN_SAMPLES) -> np.ndarray:
    """The pose, its rate and acceleration at the first sample time from the first samples: a
    least-squares quadratic in t - ts[0] through the samples within `window` seconds of the
    first (at least `min_samples`, at most all). Tracker noise makes an interpolating spline's
    derivatives useless at an end (its acceleration error is about noise / dt^2: 1 m/s^2 for
    0.1 mm at 100 Hz); the fit over 0.1 s leaves about 1e-3 m/s and 0.1 m/s^2 of that noise,
    and a bias of the path's jerk times the window (about 1e-2 m/s^2 on the paper's circle).

    **Arguments:**

    - `ts`: sample times (n,) (s), increasing; `X`: samples (n, k) (a pose: m, m, rad).
    - `window`: the length (s) of the fitted stretch; `min_samples`: fewest samples in it (at
      least 3).

    **Returns:** (3, k) NumPy array: the value, rate and acceleration at ts[0].
    """
    ts = np.asarray(ts, dtype=np.float64)
    X = np.asarray(X, dtype=np.float64)
    n = ts.shape[0]
    if n < 3:
        raise DataError(f"fit_start needs at least 3 samples, got {n}")
    k = int(np.count_nonzero(ts - ts[0] <= window))
    k = min(n, max(k, int(min_samples), 3))
    s = ts[:k] - ts[0]
    scale = max(float(s[-1]), 1e-300)  # conditioning: powers of s / scale
    A = np.column_stack([np.ones(k), s / scale, 0.5 * (s / scale) ** 2])
    c, *_ = np.linalg.lstsq(A, X[:k], rcond=None)
    return c / np.array([1.0, scale, scale**2])[:, None]
