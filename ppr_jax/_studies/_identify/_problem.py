"""The identification problem: the data the compiled residual compares, with the `Evaluation`
that predicts them (the platform poses of the scene's run at the sample times, `poses`), as one
pytree, and the residual and its Jacobian."""

from __future__ import annotations

import dataclasses
import math
from typing import Optional

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..._actuation import MotionDriven, TorqueDriven
from ..._custom_types import Array
from ..._labels import label_field
from ..._names import (  # the choices the command line offers, written there
    ACTUATIONS as ACTUATIONS,
    ID_SOLVERS,
    INITIAL_STATES as INITIAL_STATES,
    LOSSES as LOSSES,
)
from ..._params import RobotParams
from ..._paths import StartPath
from ..._robot import Robot
from ..._scenes import PathScene, SceneOptions, map_members
from ..._trajectory import Interpolated, PiecewiseCubic
from .._evaluation import Evaluation
from .._jacobian import derivatives_along, forward_jacobian

#: the least-squares solvers (`identify(solver=...)`, the CLI's --method)
SOLVERS = ID_SOLVERS

#: largest step of the Levenberg-Marquardt loop in the reparametrised unknowns z
MAX_STEP_Z = 1.0


#: the scale of the initial-state unknowns in the fit (m, m, rad, m/s, m/s, rad/s): the size of
#: offset a unit step in z makes, so that the trust region of MAX_STEP_Z means 1 mm, 10 mrad
INIT_SCALE = (1e-3, 1e-3, 1e-2, 1e-2, 1e-2, 1e-1)


INIT_NAMES = ("x0", "y0", "phi0", "xd0", "yd0", "phid0")


INIT_UNITS = ("m", "m", "rad", "m/s", "m/s", "rad/s")


#: measurement nuisance parameters, shared by every experiment (one tracker, one set-up): a
#: bias of each pose channel (the tracker's frame against the robot's) and the tracker's time
#: delay against the actuation (a pose sampled at t is the robot's at t - delay)
NUISANCE = ("bias", "delay")
MEAS_NAMES = ("bias_x", "bias_y", "bias_phi", "delay")
MEAS_UNITS = ("m", "m", "rad", "s")
#: their scale in z (a unit step: 1 mm, 1 mm, 10 mrad, 10 ms)
MEAS_SCALE = (1e-3, 1e-3, 1e-2, 1e-2)


#: residual scale s (1 = noise as stated) above which a fit does not explain the data: its
#: intervals then measure the misfit, and it is reported as a poor fit, never as converged
POOR_FIT_SCALE = 3.0


#: default noise weights: tracker position (m) and platform angle (rad), Optotrak-like
DEFAULT_NOISE = (1e-4, 1e-3)


class _Problem(eqx.Module):
    """An identification's data and the `Evaluation` its residual runs: the measured poses,
    their sample times and weights, each experiment's measured actuation (or own path), the
    unknowns' bounds and the loss. The evaluation holds the unknowns' names, the model, the
    scene (None: each experiment's own) and its prepared `SceneOptions`."""

    evaluation: Evaluation
    base: RobotParams  # the parameters with the unknowns at their initial values
    commands: RobotParams  # the parameters of the model that computed the commands (fixed)
    lo: Array  # (P,) bounds of the unknowns
    hi: Array
    ts: Array  # (E, m) simulation times per experiment (padded)
    X: Array  # (E, m, 3) measured pose (padded)
    w: Array  # (E, m, 3) weights 1/noise, 0 on padding
    tau: Optional[Array]  # (E, m, 3) measured torques or None
    th: Optional[Array]  # (E, m - 1, 4, 3) spline pieces of the measured actuated angles or None
    log: tuple = eqx.field(static=True)  # per unknown: bounds in log space
    scene: str = eqx.field(static=True)  # what the reports call the experiments' scene
    loss: Array  # index into LOSSES: traced, so that changing the loss reuses the compilation
    loss_scale: Array
    #: unknowns of each experiment's initial state (0, 3 or 6: INITIAL_STATES), after the
    #: parameters in z, as offsets in units of `init_scale` (m, m, rad, m/s, m/s, rad/s)
    n_init: int = eqx.field(static=True, default=0)
    init_scale: Optional[Array] = None
    #: indices into MEAS_NAMES of the measurement nuisance parameters estimated, the last
    #: entries of z, in units of MEAS_SCALE
    meas: tuple = eqx.field(static=True, default=())
    #: the scene's drive, "motion" or "torque" (what the measured commands are)
    drive: str = eqx.field(static=True, default="motion")
    #: (E, m - 1, 4, 3) spline pieces of each experiment's measured poses (its own scene's path)
    paths: Optional[Array] = None
    #: (E, 3, 3) each experiment's start: pose, rate and acceleration fitted to its first
    #: samples (`fit_start`), which its own scene's quasi-static start takes
    starts: Optional[Array] = None
    #: the experiments' names (messages)
    experiment_names: tuple = label_field(default=())
    #: a directory of stored programs (`_programs.py`; the command line's), where the fit's
    #: residual-and-Jacobian program is exported once and loaded by later processes; None:
    #: compiled in this process as usual
    program_dir: Optional[str] = eqx.field(static=True, default=None)

    @property
    def names(self) -> tuple:
        """The unknowns' names (the evaluation's)."""
        return self.evaluation.names

    @property
    def model(self):
        """The model simulated."""
        return self.evaluation.ctx.model

    @property
    def options(self) -> SceneOptions:
        """The prepared `SceneOptions` of every experiment's run."""
        return self.evaluation.ctx.options


def _to_p(prob: _Problem, z):
    s = jax.nn.sigmoid(z[:len(prob.names)])
    out = []
    for i, lg in enumerate(prob.log):
        lo, hi = prob.lo[i], prob.hi[i]
        out.append(jnp.exp(jnp.log(lo) + s[i] * (jnp.log(hi) - jnp.log(lo))) if lg
                   else lo + s[i] * (hi - lo))
    return jnp.stack(out)


def _to_z(prob_log, lo, hi, p):
    p, lo, hi = (np.asarray(v, dtype=np.float64) for v in (p, lo, hi))
    lg = np.asarray(prob_log)
    s = np.where(lg, (np.log(p) - np.log(lo)) / (np.log(hi) - np.log(lo)), (p - lo) / (hi - lo))
    return np.log(s) - np.log1p(-s)


def _dp_dz(prob: _Problem, z):
    """Diagonal of dp/dz (the reparametrisation is elementwise) of the parameters."""
    z = z[:len(prob.names)]
    s = jax.nn.sigmoid(z)
    p = _to_p(prob, z)
    ds = s * (1 - s)
    lg = jnp.asarray(prob.log)
    return jnp.where(lg, p * (jnp.log(prob.hi) - jnp.log(prob.lo)) * ds, (prob.hi - prob.lo) * ds)


def _offsets(prob: _Problem, z):
    """(E, 6) offsets of each experiment's initial platform pose and velocity (zeros where not
    estimated) from the unknowns z."""
    E = prob.ts.shape[0]
    d = jnp.zeros((E, 6))
    if prob.n_init:
        P, k = len(prob.names), prob.n_init
        d = d.at[:, :k].set(z[P:P + E * k].reshape(E, k) * prob.init_scale[None, :])
    return d


def _measurement(prob: _Problem, z):
    """(bias (3,) m, m, rad; delay s) from the last entries of z (zeros where not estimated)."""
    b = jnp.zeros(4)
    if prob.meas:
        k = len(prob.meas)
        scale = jnp.asarray([MEAS_SCALE[i] for i in prob.meas])
        b = b.at[jnp.array(prob.meas)].set(z[-k:] * scale)
    return b[:3], b[3]


def _hermite(x0, v0, x1, v1, h, u):
    """Cubic Hermite interpolation on [t0, t0 + h] at t0 + u h from values and rates."""
    u, h = u[..., None], h[..., None]
    u2, u3 = u * u, u * u * u
    return ((2 * u3 - 3 * u2 + 1) * x0 + (u3 - 2 * u2 + u) * h * v0 + (3 * u2 - 2 * u3) * x1
            + (u3 - u2) * h * v1)


def _delayed(X, V, ts, delay):
    """The simulated poses at ts - delay (E, m, 3) from X and their rates V at ts: a cubic Hermite
    on the sample interval that holds ts - delay (exact to O(h^4); for |delay| up to one sample
    spacing, beyond it the cubic extrapolates), first order at the first (delay > 0) or last
    (delay < 0) sample, which has no neighbour on that side."""
    h = ts[:, 1:] - ts[:, :-1]
    h = jnp.where(h > 0, h, 1.0)  # padding repeats the last time
    x0, v0, x1, v1 = X[:, :-1], V[:, :-1], X[:, 1:], V[:, 1:]
    later = jnp.concatenate([X[:, :1] - delay * V[:, :1],
                             _hermite(x0, v0, x1, v1, h, 1.0 - delay / h)], axis=1)
    earlier = jnp.concatenate([_hermite(x0, v0, x1, v1, h, -delay / h),
                               X[:, -1:] - delay * V[:, -1:]], axis=1)
    return jnp.where(delay >= 0, later, earlier)


def _experiment(prob: _Problem, ts, tau, th, path, start) -> tuple:
    """One experiment's own scene and actuation from its data (ts[0] = 0, the scene's start):
    a `PathScene` on its measured poses (`path`, spline pieces), started from the fit of its
    first samples (`start`), where no scene is named (else None: the named one); driven by the
    measured angles (a C2 spline through the samples) or torques, or None: the scene's
    commands for the commands' robot."""
    scene = None
    if prob.evaluation.ctx.scene is None:
        scene = PathScene(PiecewiseCubic(ts, path), drive=prob.drive,
                          start_path=StartPath(ts[0], start), name=prob.scene)
    if th is not None:
        return scene, MotionDriven(PiecewiseCubic(ts, th))
    if tau is not None:
        return scene, TorqueDriven(Interpolated(ts, tau))
    return scene, None


def _robust(r, loss, c):
    """sign(r) sqrt(2 rho(r)) for the loss with index `loss` in LOSSES (all three are computed
    and one selected: cheap, and the loss stays a traced value)."""
    a = jnp.abs(r)
    # Huber: rho = r^2/2 inside c, c (|r| - c/2) outside (max(...) keeps sqrt's argument safe)
    huber = jnp.where(a <= c, r, jnp.sign(r) * jnp.sqrt(jnp.maximum(2 * c * a - c * c, c * c)))
    cauchy = jnp.sign(r) * c * jnp.sqrt(jnp.log1p((r / c) ** 2))
    return jnp.select([loss == 0, loss == 1], [r, huber], cauchy)


def _weighted_residuals(prob: _Problem, p, d0, meas=None):
    """(E, m, 3) weighted residuals (predicted - measured) / noise, raw (before the loss), the
    predicted poses and the result code (E,) of every experiment's simulation (0: success,
    `result_code`); d0 (E, 6)
    initial-state offsets; meas (bias (3,), delay) the measurement model: the pose predicted at
    t is the simulated one at t - delay, plus the bias."""
    commands = Robot(jax.lax.stop_gradient(prob.commands))
    tau, th = prob.tau, prob.th
    paths, starts = prob.paths, prob.starts

    def one(data, evaluation, p, commands):
        ts, tau, th, d0, path, start = data
        scene, act = _experiment(prob, ts, tau, th, path, start)
        return evaluation.poses(p, prob.base, ts, act, d0, commands, scene)

    # the experiments as a batch's members (`map_members`): on a CPU one after another, each
    # on the lean loop (under `vmap` its loop of steps would be one over the experiments:
    # an L2 `servo-circle` evaluation, 7.54 s and 2 unknowns, took 0.41 s vmapped)
    X, V, codes = map_members(one)((prob.ts, tau, th, d0, paths, starts), prob.evaluation, p,
                                   commands)
    if prob.meas:
        bias, delay = meas
        X = _delayed(X, V, prob.ts, delay) + bias[None, None, :]
    # Padding rows have weight 0; a failed simulation may be NaN there, keep it out of sums.
    r = jnp.where(prob.w > 0, (X - prob.X) * prob.w, 0.0)
    return r, X, codes


def _residual_vector(prob: _Problem, z):
    r, X, codes = _weighted_residuals(prob, _to_p(prob, z), _offsets(prob, z),
                                   _measurement(prob, z))
    return _robust(r.reshape(-1), prob.loss, prob.loss_scale), (codes, X)


def _anonymous(prob: _Problem) -> _Problem:
    """The problem without the experiments' names and the program directory (static, they
    would key the compilation: a second file of the same shapes must reuse the compiled
    program)."""
    if prob.experiment_names or prob.program_dir is not None:
        return dataclasses.replace(prob, experiment_names=(), program_dir=None)
    return prob


def _residual_and_jacobian(prob: _Problem, z):
    """(r (N,), J (N, P) = dr/dz, the simulations' result codes (E,) (0: success; `_succeeded`),
    simulated pose (E, m, 3)) in one compiled forward-mode pass: the fit, the covariance and the
    fitted trajectory share it.

    With `prob.program_dir` the program comes from the program store (`_programs.py`): a later
    process with a problem of the same structure and shapes (another file, other numbers)
    loads it instead of tracing it (the trace is most of a warm fit's wait: 8 s of L2's)."""
    from ..._programs import cached_program

    directory, prob = prob.program_dir, _anonymous(prob)

    def run(fn, args):
        # (V J^T, values, (codes, poses)): the result's structure is all the store needs (no
        # trace for it)
        return cached_program(fn, args, (0, 0, (0, 0)), directory,
                              f"identify-{prob.model.name}")(*args)

    J, r, (codes, X) = forward_jacobian(_residual_and_jacobian_jit, z, prob, run=run)
    return r, J, codes, X.reshape(prob.X.shape)


@eqx.filter_jit
def _residual_and_jacobian_jit(z, V, prob: _Problem):
    # along the rows of V (the identity's, a slice of them a core: `forward_jacobian`). On a
    # CPU each slice's loop of steps is one kernel where it carries one tangent; jax.jacfwd's
    # two tangents of an L2 `servo-circle` fit (7.54 s) were not, and took 0.41 s against one
    # tangent's 0.08 s
    # the result codes and the simulated poses ride along, not differentiated
    return derivatives_along(lambda z, prob: _residual_vector(prob, z), z, V, prob,
                             has_aux=True)


def _succeeded(codes) -> bool:
    """Every experiment's simulation succeeded (host side: result codes (E,) all 0)."""
    return bool(np.all(np.asarray(codes) == 0))


def noise_text(noise) -> str:
    """The stated noise (position m, phi rad) in words: mm and mrad, or "not fitted" for a
    channel of infinite noise."""
    pos = f"{noise[0] * 1e3:.3g} mm" if math.isfinite(noise[0]) else "x, y not fitted"
    phi = f"{noise[1] * 1e3:.3g} mrad" if math.isfinite(noise[1]) else "phi not fitted"
    return f"{pos}, {phi}"
