"""Time functions: the nominal platform trajectory (eq 55) and actuator inputs.

Every time function is an `equinox.Module` with `__call__(t) -> array`; `derivatives(f, t)`
returns (f, f', f'') by forward-mode differentiation, so analytic inputs are exact to rounding.
"""

from __future__ import annotations

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._custom_types import Array, Float, as_f64


def derivatives(f, t):
    """(f(t), f'(t), f''(t)) of a time function by two nested forward-mode JVPs."""
    t = jnp.asarray(t, dtype=jnp.float64)
    one = jnp.ones_like(t)

    def first(t):
        return jax.jvp(f, (t,), (one,))

    (x, xd), (_, xdd) = jax.jvp(first, (t,), (one,))
    return x, xd, xdd


class Circle(eqx.Module):
    """The paper's nominal motion (eq 55): x = cx + R cos(omega t), y = cy + R sin(omega t),
    phi = -phi_amp sin(omega t). Defaults: c = (0.45, 0.15 sqrt 3) m, R = 0.1 m,
    omega = 5/6 rad/s, phi_amp = 0.05 rad, t in [0, 7.54] s (one turn is 2 pi/omega = 7.54 s)."""

    # numpy float64 leaves (`as_f64`): a scene builds its circle on every call, and host
    # values cost no device transfer
    center: Array = eqx.field(
        default_factory=lambda: as_f64(np.array([0.45, 0.15 * np.sqrt(3.0)])))
    radius: Array = eqx.field(default_factory=lambda: as_f64(0.1))
    omega: Array = eqx.field(default_factory=lambda: as_f64(5.0 / 6.0))
    phi_amp: Array = eqx.field(default_factory=lambda: as_f64(0.05))

    def __call__(self, t) -> Float[Array, "3"]:
        wt = self.omega * t
        return jnp.stack(
            [
                self.center[0] + self.radius * jnp.cos(wt),
                self.center[1] + self.radius * jnp.sin(wt),
                -self.phi_amp * jnp.sin(wt),
            ]
        )


def _read_only(tree):
    for leaf in jax.tree_util.tree_leaves(tree):
        if isinstance(leaf, np.ndarray):
            leaf.flags.writeable = False
    return tree


#: The default circle of eq 55, one object for the circle scenes: a scene's options are
#: prepared once per default trajectory (`SceneOptions.prepared`). Its arrays are read-only.
CIRCLE = _read_only(Circle())


class Hold(eqx.Module):
    """A constant value (e.g. zero torque or locked actuators)."""

    value: Array

    def __call__(self, t):
        return self.value + 0.0 * t


class Interpolated(eqx.Module):
    """Cubic Hermite interpolation of samples ys (m, k) at increasing times ts (m,) (C1, exact at
    the samples; tangents from backward differences as diffrax.backward_hermite_coefficients).
    Outside [ts[0], ts[-1]] it extrapolates the end cubic: keep simulations inside the data."""

    interp: diffrax.CubicInterpolation

    def __init__(self, ts, ys):
        ts = jnp.asarray(ts, dtype=jnp.float64)
        ys = jnp.asarray(ys, dtype=jnp.float64)
        coeffs = diffrax.backward_hermite_coefficients(ts, ys)
        self.interp = diffrax.CubicInterpolation(ts, coeffs)

    @property
    def breakpoints(self) -> Float[Array, " m"]:
        """The sample times ts (s), where the second derivative jumps (an integrator steps to
        them, `SceneInput.step_ts`)."""
        return self.interp.ts

    def __call__(self, t):
        return self.interp.evaluate(t)


class PiecewiseCubic(eqx.Module):
    """A piecewise cubic time function: breakpoints ts (m,) and coefficients c (m - 1, 4, k)
    in powers of (t - ts[j]) from the highest: f(t) = ((c0 s + c1) s + c2) s + c3 on
    [ts[j], ts[j + 1]]. Outside the breakpoints the end pieces continue. Built by `spline_pieces`
    (C2: its second derivative, a prescribed motion's acceleration, is continuous)."""

    ts: Float[Array, " m"]
    c: Float[Array, "m1 4 k"]

    @property
    def breakpoints(self) -> Float[Array, " m"]:
        """The breakpoints ts (s), where the third derivative jumps (a scene's input table has
        panel boundaries there)."""
        return self.ts

    def __call__(self, t):
        j = jnp.clip(jnp.searchsorted(self.ts, t, side="right") - 1, 0, self.ts.shape[0] - 2)
        s = t - self.ts[j]
        c = self.c[j]
        return ((c[0] * s + c[1]) * s + c[2]) * s + c[3]


def spline_pieces(ts_grid, ts, ys):
    """Coefficients (len(ts_grid) - 1, 4, k) of `PiecewiseCubic` on the breakpoints `ts_grid`
    for the not-a-knot cubic spline through samples ys (n, k) at ts (n,) (scipy's
    `CubicSpline`: C2, fourth-order accurate for smooth data). `ts_grid` holds ts and may add
    points before ts[0] (the spline's first piece continues there) and after ts[-1] (a linear
    continuation with the end value and slope: padding, C1). NumPy, on the host."""
    import numpy as np
    from scipy.interpolate import CubicSpline

    g = np.asarray(ts_grid, dtype=np.float64)
    ts = np.asarray(ts, dtype=np.float64)
    ys = np.asarray(ys, dtype=np.float64)
    sp = CubicSpline(ts, ys, axis=0)
    left, right = g[:-1], g[1:]
    inside = left < ts[-1]
    mid = np.where(inside, (left + right) / 2, ts[-1])
    d3 = sp(mid, 3)  # constant on each piece of the spline
    c = np.stack([d3 / 6, sp(left, 2) / 2, sp(left, 1), sp(left)], axis=1)
    v_end, y_end = sp(ts[-1], 1), sp(ts[-1])
    lin = np.stack([np.zeros_like(c[:, 0]), np.zeros_like(c[:, 0]),
                    np.broadcast_to(v_end, c[:, 0].shape),
                    y_end + (left - ts[-1])[:, None] * v_end], axis=1)
    return np.where(inside[:, None, None], c, lin)
