"""Compensation by optimisation: Levenberg-Marquardt on a smooth correction of the commands,
through the differentiable simulation.

The commands are u(t) = u0(t) + B(t) c: u0 the start (the inversion's commands, or the nominal
ones where the inversion has no solution), B the not-a-knot cubic spline basis on `knots` evenly
spaced knots (so the correction is smooth and has knots x 3 unknowns c), sampled at the command
times and splined again as the command log is. The residuals are the replayed tracking error
at the output times (x, y in m; phi weighted by `PHI_SCALE` m/rad) and, with a rate bound, the
rates' excess over it (weighted by `RATE_WEIGHT`). The Jacobian is forward mode through the
scene's solve (diffrax's `ForwardMode`), knots x 3 tangents (`jacobian="forward"`), or by
forward differences of one batch of knots x 3 + 1 replays (`jacobian="differences"`, the
default). Measured on an L2 figure eight (6 s, 601 commands, 36 unknowns, 2 cores,
`benchmarks/results/compensate.json`): the differences took 0.37 / 0.30 s (motion / torque
drive) and forward mode 4.1 / 1.5 s, agreeing to 8e-6 / 3e-4 relative (the torque drive's open
loop is unstable). The
difference step `FD_STEP` x max |u0| (1e-6 rad for angles of order 1) keeps the columns' error
(truncation, and the members' own adaptive steps) near 1e-6 relative; Levenberg-Marquardt
needs no more. A batch with a failed member falls back to forward mode.

What it is for: what the inversion leaves (the replay's start and the command spline's
interpolation, 3e-5 m for L0 on a path of cubic samples), commands under a rate bound, and any
model or path where the inversion does not hold. What it is not for: an open-loop torque drive
over a horizon where the robot's instability amplifies errors (a replay flagged so): its
Jacobian is then as ill-conditioned as the amplification.
"""

from __future__ import annotations

import dataclasses
from typing import Optional

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import PPRError, result_code
from .._paths import CommandLog, Waypoints
from .._scenes import PathScene, SceneOptions, map_members, on_host_threads, solve_scene

#: m per rad: the orientation error's weight against the position error's
PHI_SCALE = 0.1
#: weight of a rate's excess over its bound (m per rad/s, or per N m/s)
RATE_WEIGHT = 10.0
#: forward differences' step, relative to the largest start command
FD_STEP = 1e-6
#: how the Jacobian is computed (`fit_commands`' `jacobian`)
JACOBIANS = ("differences", "forward")


class _Fit(eqx.Module):
    """The residuals of a correction c (knots, 3): static structure, array inputs."""

    path: object
    u0: jnp.ndarray
    basis: jnp.ndarray
    ts: tuple = eqx.field(static=True)
    drive: str = eqx.field(static=True)
    kind: str = eqx.field(static=True)
    model: object
    options: SceneOptions
    rate_bound: Optional[float] = eqx.field(static=True, default=None)

    def commands(self, c):
        return self.u0 + self.basis @ c

    def log(self, c) -> CommandLog:
        return CommandLog(Waypoints(np.asarray(self.ts), self.commands(c), bc="not-a-knot",
                                    name="compensated"), kind=self.kind)

    def residuals(self, c, params):
        scene = PathScene(self.path, drive=self.drive, command_log=self.log(c),
                          name="compensated")
        res = solve_scene(scene, params, model=self.model, options=self.options, throw=False)
        e = res.X - res.X_nominal
        r = [e[:, :2].ravel(), PHI_SCALE * e[:, 2]]
        if self.rate_bound is not None:
            u = self.commands(c)
            rate = jnp.diff(u, axis=0) / jnp.diff(jnp.asarray(self.ts))[:, None]
            r.append(RATE_WEIGHT * jax.nn.relu(jnp.abs(rate) - self.rate_bound).ravel())
        return jnp.concatenate(r), result_code(res.result)


@eqx.filter_jit
def _values(fit, c, params):
    return fit.residuals(c, params)


@eqx.filter_jit
def _jacobian(fit, c, params):
    return jax.jacfwd(lambda c: fit.residuals(c, params)[0])(c)


@eqx.filter_jit
def _replays(cs, fit, params):
    """The residuals (k, m) and status codes (k,) of k corrections cs (k, ...) replayed as one
    batch (`map_members`: on a CPU one after another, each on the lean loop; vmapped, the
    loop of steps is one for all of them: 37 replays of 1 s of L2 took 62 ms against 54 ms on
    diffrax's vmapped loop)."""
    return map_members(lambda ci, f, p: f.residuals(ci, p))(cs, fit, params)


def _differences(fit, c, params, h):
    """Forward differences (m, p) of the residuals in each of c's p entries, by step h (s), from
    one batch of p + 1 replays, in slices on host threads, one a core (`on_host_threads`: 37
    replays at 12 knots); and the batch's worst status code. The corrections are the program's
    input, so any h and commands' scale run the same program."""
    c = np.asarray(c, dtype=np.float64)
    p, h = c.size, float(h)
    cs = c[None] + np.concatenate([np.zeros((1, p)), h * np.eye(p)]).reshape(p + 1, *c.shape)
    r, code = on_host_threads(_replays, p + 1, argnum=0)(cs, fit, params)
    r = np.asarray(r)
    return ((r[1:] - r[:1]) / h).T, int(np.max(np.asarray(code)))


def _jacobian_of(fit, c, params, how: str, h: float, m: int) -> np.ndarray:
    if how == "differences":
        J, code = _differences(fit, c, params, h)
        if code == 0:
            return np.asarray(J)
    return np.asarray(_jacobian(fit, c, params)).reshape(m, -1)


def fit_commands(path, drive: str, kind: str, model, params, options: SceneOptions, ts, u0,
                 *, knots: int = 12, rate_bound: Optional[float] = None, max_iter: int = 8,
                 rtol: float = 1e-3, jacobian: str = "differences") -> dict:
    """Levenberg-Marquardt on the smooth correction of commands u0 (module docstring).

    **Arguments:**

    - `path`, `drive`, `kind`, `model`, `params`: the path, the drive and its log's kind, the
      model and robot the commands are replayed through.
    - `options`: the replay's `SceneOptions` (its output times the command times).
    - `ts` (n,), `u0` (n, 3): command times (s) and the start commands.
    - `knots`: knots of the correction's spline (at least 3); 3 x knots unknowns.
    - `rate_bound`: a bound on |du/dt| (rad/s or N m/s), or None.
    - `max_iter`: accepted Levenberg-Marquardt steps at most; `rtol`: stop when an accepted
      step lowers the cost by less than this fraction. The Jacobian is computed at the start
      and then updated by Broyden's rank-one secant of each accepted step; it is computed anew
      only where the updated one finds no step that lowers the cost (a minimum is declared
      where a fresh one finds none either).
    - `jacobian`: `"differences"` (one batch of replays, the default) or `"forward"` (forward
      mode through the solve): module docstring.

    **Returns:** {"commands" (n, 3), "log", "cost_start", "cost", "iterations" (accepted
    steps), "jacobians" (computed), "converged", "history" (costs)}; cost = sum of squared
    residuals (m^2).
    """
    ts = np.asarray(ts, dtype=np.float64)
    tk = np.linspace(ts[0], ts[-1], int(knots))
    basis = np.asarray(jax.vmap(Waypoints(tk, np.eye(int(knots)), bc="not-a-knot"))(
        jnp.asarray(ts)))
    fwd = dataclasses.replace(options, adjoint=diffrax.ForwardMode())
    fit = _Fit(path=path, u0=jnp.asarray(u0), basis=jnp.asarray(basis),
               ts=tuple(float(t) for t in ts), drive=drive, kind=kind, model=model,
               options=fwd, rate_bound=rate_bound)
    if jacobian not in JACOBIANS:
        raise PPRError(f"jacobian must be one of {', '.join(JACOBIANS)}, got {jacobian!r}")
    h = FD_STEP * max(float(np.max(np.abs(u0))), 1e-12)
    c = jnp.zeros((int(knots), 3))
    r, code = _values(fit, c, params)
    cost = float(jnp.sum(r**2)) if int(code) == 0 else float("inf")
    history, lam, converged, it, jacobians = [cost], 1e-3, False, 0, 0
    J, fresh = None, False
    while it < max_iter:
        if J is None:
            J, fresh = _jacobian_of(fit, c, params, jacobian, h, r.shape[0]), True
            jacobians += 1
        g, A = J.T @ np.asarray(r), J.T @ J
        d = np.diag(A).copy() + 1e-300
        accepted = False
        for _ in range(8 if fresh else 3):  # raise the damping until a step lowers the cost
            step = -np.linalg.solve(A + lam * np.diag(d), g)
            c_new = c + jnp.asarray(step.reshape(c.shape))
            r_new, code = _values(fit, c_new, params)
            new = float(jnp.sum(r_new**2)) if int(code) == 0 else float("inf")
            if new < cost:
                accepted, lam = True, max(lam / 3.0, 1e-9)
                break
            lam *= 10.0
        if not accepted and fresh:
            converged = True  # no step lowers the cost: a minimum to the damping's resolution
            break
        if not accepted:
            J = None  # the updated Jacobian has gone stale: take it anew
            continue
        it += 1
        # Broyden's rank-one update: the Jacobian of the secant through the accepted step
        dr = np.asarray(r_new) - np.asarray(r)
        J = J + np.outer(dr - J @ step, step) / (step @ step)
        fresh = False
        gain = (cost - new) / cost
        c, r, cost = c_new, r_new, new
        history.append(cost)
        if gain < rtol:
            converged = True
            break
    return {"commands": np.asarray(fit.commands(c)), "log": fit.log(c),
            "cost_start": history[0], "cost": cost, "iterations": it,
            "jacobians": jacobians, "converged": converged, "history": history}


__all__ = ["fit_commands", "FD_STEP", "JACOBIANS", "PHI_SCALE", "RATE_WEIGHT"]
