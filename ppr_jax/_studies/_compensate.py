"""Compensation: the commands that make a compliant robot's platform follow its path.

A robot driven by the angles of its nominal inverse kinematics (or the torques of its nominal
inverse dynamics) misses the path by what its compliance and inertia bend it: a tenth of a
millimetre for Table 1's robot at 0.5 mm strips. `compensate` computes the commands that the
model itself needs to follow the path, replays them through the model's own simulation, and
reports both runs.

How the commands are found (measured on an L2 figure eight, 2 s at 100 Hz, 0.5 mm strips):

- **Model inversion** (`_statics.inverse_path`), for every model. The platform pose is
  prescribed; the other coordinates follow from the equations of motion's rows that carry no
  actuator torque, and the torques from the others. The inverse's own (zero) dynamics is
  non-minimum-phase for the L2 robot (a pair of roots growing at about 76 1/s): integrating it
  diverges, so its bounded solution is found pass by pass on a short stencil, as the quasi-static
  start does. It costs one vmapped solve over the command times (no simulation), and the model
  then tracks the path to 1e-7 m (motion drive) and 5e-8 m (torque drive) where the nominal
  commands miss it by 3e-4 and 8e-5 m.
- **Optimisation** (`method="optimise"`, `_compensate_fit.fit_commands`): Levenberg-Marquardt
  on a smooth correction of the inversion's commands through the simulation (forward mode), for
  what the inversion leaves to the replay, a rate bound, or a path with no inverse.
- An iteration of corrections through the simulation (u += S e, S the L1 Jacobian) was
  measured and dropped: the platform's structural modes (13.6 Hz locked) ring through each
  run, and the correction of the ringing made the next run worse.

Motion drive: the angles are written for a not-a-knot spline (`Waypoints(bc="not-a-knot")`):
the platform's balance is sensitive to the angles' accelerations (the L2 coupling of platform
and drive links), and a natural spline's zero acceleration at a moving end put the start 10 um
off the path. Torque drive is open loop: where the robot under its torques is unstable
(`_growth`: about 3.3 1/s for Table 1's L2, the rotation that diverges at home with free
actuators), any error grows as exp(rate t): the result reports the rate and flags a horizon
over which it amplifies errors a thousandfold.
"""

from __future__ import annotations

import dataclasses
from typing import Callable, Optional, Union

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._dynamics import eom_terms, generalized_force
from .._errors import PPRError, check_instance, check_int, check_number
from .._linalg import solve_spd
from .._models import AbstractModel, get_model
from .._params import RobotParams
from .._paths import CommandLog, Waypoints
from .._robot import Robot
from .._scenes import AbstractScene, PathScene, SceneOptions, run_scene, scene_params
from .._statics import STENCIL_REACH, inverse_path
from .._tabulated import breakpoints
from ._compensate_fit import JACOBIANS, fit_commands

#: the drives, and the command log's kind for each
DRIVES = {"motion": "angles", "torque": "torque"}
#: default command rate (Hz) for a path with no sample times of its own
RATE = 100.0
#: the inverse's own error estimate (the last pass's change, rad) above which it is flagged
CHANGE_TOL = 1e-8
#: open-loop amplification exp(rate T) of a torque drive above which the result is flagged
AMPLIFICATION_TOL = 1e3
#: path samples at which the open loop's growth rate is taken (`_growth`)
GROWTH_SAMPLES = 9
#: how the commands are found (`compensate`'s `method`)
METHODS = ("inversion", "optimise")
#: the limits `compensate` checks, and their units
LIMITS = {"angle": "rad", "rate": "rad/s", "torque": "N m"}


class CompensationError(PPRError):
    """The model's inverse has no solution on the path (a chain out of reach, no balance)."""


@dataclasses.dataclass(frozen=True)
class Compensation:
    """What `compensate` found: the commands, and the model driven by them and by the nominal
    ones.

    - `ts` (n,) command times (s); `commands` (n, 3) the actuated angles (rad) or torques
      (N m); `kind` `"angles"` or `"torque"`; `drive` `"motion"` or `"torque"`.
    - `log`: the `CommandLog` that replays them (a not-a-knot spline); `nominal` (n, 3) the
      nominal commands (L1's inverse kinematics or inverse dynamics) at `ts`.
    - `before`, `after`: the `SceneReport`s of the model driven by the nominal and the
      compensated commands.
    - `error`: {"before", "after"} -> tracking errors (m, rad): `position_max`, `position_rms`,
      `position_end`, `phi_max`, `phi_rms`, `phi_end`.
    - `size`: {"before", "after"} -> `max` |command| and `rate_max` |d command/dt| (rad or
      N m, per s).
    - `method` (`"inversion"` or `"optimise"`), `change` the inversion's last change (rad: its
      error estimate); `fit` the optimisation's cost (m^2) at its start and end, iterations,
      convergence and history (None for the inversion).
    - `growth_rate` (1/s): the fastest growth of the robot with free actuators at the path's
      start (torque drive; 0 where stable, None for a motion drive); `amplification`
      exp(growth_rate T).
    - `flags`: what the user should know, one sentence each (limits exceeded with their time,
      an unstable open loop, an inversion that did not settle); empty when all is well.
    - `band`: with an `Identification`, the predicted tracking error's band (`error_band`).
    """

    ts: np.ndarray
    commands: np.ndarray
    kind: str
    drive: str
    model: str
    log: CommandLog
    nominal: np.ndarray
    before: object
    after: object
    error: dict
    size: dict
    method: str
    change: float
    growth_rate: Optional[float]
    amplification: Optional[float]
    flags: tuple
    band: Optional[dict] = None
    fit: Optional[dict] = None

    @property
    def improvement(self) -> Optional[float]:
        """Max position error before over after (None without `verify`)."""
        if self.error is None:
            return None
        return self.error["before"]["position_max"] / max(self.error["after"]["position_max"],
                                                         1e-300)

    def summary(self) -> dict:
        """JSON-ready numbers: the errors, sizes, method and flags."""
        out = {"drive": self.drive, "model": self.model, "kind": self.kind,
               "method": self.method, "samples": int(self.ts.shape[0]),
               "t_end_s": float(self.ts[-1]), "inversion_change_rad": self.change,
               "error": self.error, "commands": self.size, "position_error_before_m":
               None if self.error is None else self.error["before"]["position_max"],
               "position_error_after_m":
               None if self.error is None else self.error["after"]["position_max"],
               "improvement": self.improvement, "flags": list(self.flags)}
        if self.growth_rate is not None:
            out["open_loop_growth_rate_per_s"] = self.growth_rate
            out["open_loop_amplification"] = self.amplification
        if self.fit is not None:
            out["optimisation"] = {k: v for k, v in self.fit.items() if k != "history"}
        if self.band is not None:
            out["band"] = {k: v for k, v in self.band.items() if np.ndim(v) == 0
                           or isinstance(v, (list, tuple, str))}
        return out


def _tracking(report) -> dict:
    """The tracking errors of a run, as the metric table computes them for every path scene
    (`position_error_*_m`, `phi_error_*_rad`), under `Compensation.error`'s names."""
    m = report.metrics
    return {f"{q}_{k}": float(m[f"{q}_error_{k}_{u}"]) for q, u in (("position", "m"),
                                                                     ("phi", "rad"))
            for k in ("max", "rms", "end")}


def _size(ts, u) -> dict:
    rate = np.diff(u, axis=0) / np.diff(ts)[:, None]
    return {"max": float(np.abs(u).max()), "rate_max": float(np.abs(rate).max())}


def _grid(path, options: Optional[SceneOptions], rate: Optional[float], times=None):
    """Command times: `times` where given, else the path's own samples where it has them from
    t = 0, else `rate` Hz over the options' horizon (without options, over a sampled path's
    own span from t = 0, else the scenes' default horizon)."""
    if times is not None:
        ts = np.asarray(times, dtype=np.float64).reshape(-1)
        if (ts.shape[0] < 4 or not np.all(np.isfinite(ts)) or ts[0] != 0.0
                or not np.all(np.diff(ts) > 0)):
            raise PPRError(f"times must be at least 4 finite, strictly increasing command "
                           f"times (s) from t = 0, got {ts.shape[0]} from "
                           f"{ts[0] if ts.size else None}")
        return ts
    own = getattr(path, "ts", None)
    if rate is None and own is not None:
        ts = np.asarray(own, dtype=np.float64)
        if ts[0] == 0.0:
            return ts
    r = RATE if rate is None else check_number("rate", rate, 1e-3, 1e6)
    if options is None and own is not None and float(own[0]) == 0.0:
        t_end = float(own[-1])
    else:
        t_end = float((SceneOptions() if options is None else options).t_end)
    return np.linspace(0.0, t_end, int(round(t_end * r)) + 1)


def _limit_flags(ts, u, kind, limits) -> list:
    flags = []
    checks = {"angle": (u, "angles"), "torque": (u, "torque"),
              "rate": (np.diff(u, axis=0) / np.diff(ts)[:, None], "angles")}
    for name, bound in (limits or {}).items():
        if name not in LIMITS:
            raise PPRError(f"limits: unknown limit {name!r}; allowed: {', '.join(LIMITS)}")
        bound = check_number(f"limits[{name!r}]", bound, 0.0, float("inf"))
        values, applies = checks[name]
        if applies != kind:
            continue
        over = np.nonzero(np.abs(values) > bound)[0]
        if over.size:
            k = int(over[0])
            flags.append(f"{name} limit {bound:g} {LIMITS[name]} exceeded from t = "
                         f"{ts[k]:.4g} s (max {np.abs(values).max():.4g} {LIMITS[name]})")
    return flags


def _path_of(scene) -> tuple:
    """(path, its drive, its default robot) of `compensate`'s `scene` argument."""
    if isinstance(scene, str):
        if scene not in ("paper-circle", "servo-circle"):
            raise PPRError(f"scene: a path, a PathScene, 'paper-circle' or 'servo-circle', got "
                           f"{scene!r}")
        from .._trajectory import Circle

        drive = "torque" if scene == "paper-circle" else "motion"
        return Circle(), drive, scene_params(scene)
    if isinstance(scene, PathScene):
        if scene.command_log is not None:
            raise PPRError("scene: a PathScene that replays a command log; compensate computes "
                           "the commands itself: pass its path (scene.path)")
        return scene.path, scene.drive, scene.default_params()
    if callable(scene):
        return scene, "motion", PathScene(scene, drive="motion").default_params()
    raise PPRError(f"scene: a path, a PathScene, 'paper-circle' or 'servo-circle', got "
                   f"{type(scene).__name__}")


def compensate(scene: Union[AbstractScene, Callable, str], model: Union[AbstractModel, str],
               params=None, *, drive: Optional[str] = None,
               options: Optional[SceneOptions] = None, rate: Optional[float] = None,
               limits: Optional[dict] = None, band_level: float = 0.95,
               verify: bool = True, method: str = "inversion", knots: int = 12,
               max_iter: int = 8, jacobian: str = "differences",
               times=None) -> Compensation:
    """The commands that make `model`'s platform follow a path, by model inversion.

    **Arguments:**

    - `scene`: a path t -> (x, y, phi) (a `Waypoints` from `load_path`, `Fourier`, `Line`,
      ...), a `PathScene` (its path and drive), or `"paper-circle"` / `"servo-circle"`
      (eq 55 with their drives).
    - `model`: the model that computes and replays the commands (L0-L3, or its name).
    - `params`: the robot (`RobotParams`), or an `Identification` (its robot; the result then
      carries the predicted error's band over the identification's covariance); None: the
      scene's defaults (Table 1; a path's as `PathScene`'s, 0.3 mm strips, as `simulate
      --path` takes them).
    - `drive`: `"motion"` (actuated angles) or `"torque"`; None: the scene's (a path: motion).
    - `options`: a `SceneOptions` for the two runs (horizon when the path has no samples of
      its own, tolerances, solver); its `n_out` is replaced by the command times.
    - `rate`: command rate (Hz); None: the path's own sample times (a `Waypoints` starting at
      t = 0), else 100 Hz. At a rate, the commands span `options.t_end`, or without options
      a sampled path's own span (else the scenes' default horizon).
    - `times`: the command times (n,) (s) instead, from t = 0, increasing (a controller's own
      clock); the replays then run to its last time.
    - `limits`: optional bounds {"angle": rad, "rate": rad/s, "torque": N m} on |commands|:
      exceeding one is flagged with its first time.
    - `band_level`: the probability of the band (with an `Identification`).
    - `method`: `"inversion"` (the model's inverse, the default), or `"optimise"`:
      Levenberg-Marquardt on a smooth correction of the inversion's commands (of the nominal
      ones where the inversion has no solution) through the simulation, minimising the
      replayed tracking error, with `limits["rate"]` as a bound on the rates
      (`_compensate_fit.fit_commands`).
    - `knots`, `max_iter`: the optimisation's correction spline knots (3 x knots unknowns,
      3 to the command count) and iterations (at least 1).
    - `jacobian`: how the optimisation differentiates the replay: `"differences"` (one
      batch of 3 x knots + 1 replays, in slices on host threads, one a core, the
      default: on 2 CPU cores 4-11 times faster than forward mode on a 6 s figure eight,
      agreeing to 8e-6 relative under the motion drive) or `"forward"` (forward mode through the
      solve).
    - `verify`: replay the nominal and the compensated commands through the model (the
      result's `before`, `after`, `error`; the band needs them); False: the inversion only
      (those fields None), for commands to check elsewhere.

    **Returns:** a `Compensation`. Raises `CompensationError` naming the first time where the
    inverse has no solution, and the scene's errors for a path out of reach or through a
    singularity.
    """
    from ._identify import Identification

    ident = params if isinstance(params, Identification) else None
    path, scene_drive, default = _path_of(scene)
    drive = scene_drive if drive is None else drive
    if drive not in DRIVES:
        raise PPRError(f"drive must be one of {', '.join(DRIVES)}, got {drive!r}")
    model = get_model(model) if isinstance(model, str) else model
    check_instance("model", model, AbstractModel)
    robot_params = ident.params if ident is not None else (default if params is None
                                                           else params)
    check_instance("params", robot_params, RobotParams)
    if np.ndim(robot_params.t) != 0:
        raise PPRError(f"params: one robot, not a batch of {np.shape(robot_params.t)[0]} "
                       f"(compensate one robot at a time: each has its own commands)")
    ts = _grid(path, options, rate, times)
    options = SceneOptions() if options is None else options
    opts = dataclasses.replace(options, t_end=float(ts[-1]), n_out=int(ts.shape[0]))
    robot = Robot(robot_params)

    if method not in METHODS:
        raise PPRError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    if method == "optimise":
        check_int("knots", knots, 3, int(ts.shape[0]))
        check_int("max_iter", max_iter, 1)
        if jacobian not in JACOBIANS:
            raise PPRError(f"jacobian must be one of {', '.join(JACOBIANS)}, got {jacobian!r}")
    z, zd, th_a, tau, change, change_t, failed = (np.asarray(a) for a in
                                                  _invert(model, robot, path, ts))
    bad = failed | ~np.isfinite(th_a).all(1) | ~np.isfinite(tau).all(1)
    kind = DRIVES[drive]
    if bad.any() and method == "optimise":
        # no inverse: the optimisation starts from the nominal commands
        th_a, tau = _nominal_at(path, robot, ts)
        change = np.array(0.0)
    elif bad.any():
        k = int(np.nonzero(bad)[0][0])
        raise CompensationError(
            f"compensate: the {model.name} model has no inverse on the path at t = {ts[k]:.4g} s "
            f"(no balance of the platform on the prescribed pose, or a chain out of reach)")
    u = th_a if kind == "angles" else tau
    log = CommandLog(Waypoints(ts, jnp.asarray(u), bc="not-a-knot", name="compensated"),
                     kind=kind)
    fitted = None
    if method == "optimise":
        rate_bound = (limits or {}).get("rate") if kind == "angles" else None
        fitted = fit_commands(path, drive, kind, model, robot_params, opts, ts, u,
                              knots=knots, rate_bound=rate_bound, max_iter=max_iter,
                              jacobian=jacobian)
        u, log = fitted["commands"], fitted["log"]
    flags = _limit_flags(ts, u, kind, limits)
    change = float(np.max(change))
    if change > CHANGE_TOL:
        flags.append(_unsettled(path, change, float(change_t)))
    growth = amplification = None
    if drive == "torque":
        pick = np.unique(np.linspace(0, ts.shape[0] - 1, GROWTH_SAMPLES).astype(int))
        A = np.asarray(_growth(model, robot, jnp.asarray(z[pick]), jnp.asarray(zd[pick]),
                               jnp.asarray(tau[pick])))
        growth = max(0.0, float(np.max(np.linalg.eigvals(A).real)))
        amplification = float(np.exp(min(growth * ts[-1], 700.0)))
        if amplification > AMPLIFICATION_TOL:
            flags.append(f"open loop unstable: with free actuators the robot diverges at "
                         f"{growth:.3g} 1/s, so any error grows {amplification:.3g} times over "
                         f"{ts[-1]:.3g} s; replay the torques under a servo")
    if fitted is not None and not fitted["converged"]:
        flags.append(f"the optimisation stopped after {fitted['iterations']} iterations "
                     f"(max_iter) still improving")
    common = dict(ts=ts, commands=np.asarray(u), kind=kind, drive=drive, model=model.name,
                  log=log, method=method, change=change, growth_rate=growth,
                  amplification=amplification, fit=None if fitted is None else
                  {k: v for k, v in fitted.items() if k not in ("commands", "log")})
    if not verify:
        return Compensation(nominal=None, before=None, after=None, error=None,
                            size={"after": _size(ts, u)}, flags=tuple(flags), **common)
    before = run_scene(PathScene(path, drive=drive, name="nominal"), robot_params, model=model,
                       options=opts)
    after = run_scene(PathScene(path, drive=drive, command_log=log, name="compensated"),
                      robot_params, model=model, options=opts)
    nominal = np.asarray(before.result.tau if kind == "torque" else _angles(before))
    error = {"before": _tracking(before), "after": _tracking(after)}
    size = {"before": _size(ts, nominal), "after": _size(ts, u)}
    # (L0/L1 under their own nominal commands follow to rounding either way: no flag)
    if error["after"]["position_max"] > max(error["before"]["position_max"], 1e-12):
        flags.append(f"the compensated commands miss the path by "
                     f"{error['after']['position_max']:.3g} m, no better than the nominal "
                     f"{error['before']['position_max']:.3g} m")
    band = None
    if ident is not None:
        band = error_band(ident, model, path, drive, log, opts, after, band_level)
    return Compensation(nominal=nominal, before=before, after=after, error=error, size=size,
                        flags=tuple(flags), band=band, **common)


def _unsettled(path, change: float, t: float) -> str:
    """The flag of an inversion whose last pass still changed the unknowns by `change` (rad),
    most at the time t (s). Near a knot of the path (a cubic spline's sample, `breakpoints`)
    the cause is the knot, not the path's speed: the path's jerk jumps there, and the
    balances' accelerations, differences of the balances, read its fourth derivative, which a
    cubic spline does not have. A random clamped spline of 9 samples over 0.8 s at 8.9 m/s^2
    (Table 1's robot) changed 9.7e-3 rad in its second pass and was NaN at the knots in its
    third; a slow 9-sample spline, 4-7e-4 rad; a formula path or a quintic time law, 3e-6 rad
    or less."""
    head = (f"the inversion had not settled (last change {change:.2g} rad > {CHANGE_TOL:g}, "
            f"largest at t = {t:.4g} s)")
    knots = breakpoints(path)
    if knots is not None:
        knots = np.asarray(knots)
        k = knots[np.argmin(np.abs(knots - t))]
        if abs(k - t) <= STENCIL_REACH:
            return (f"{head}: the path's jerk jumps at its knot t = {k:.4g} s, and the inverse "
                    f"reads the path's fourth derivative; about its knots the commands are the "
                    f"best pass's (a path smooth to its fourth derivative settles)")
    return f"{head}: the path is fast for the inverse's own dynamics"


def _invert(model, robot, path, ts):
    """`inverse_path` at the host times ts (n,): one program per model, path structure and
    grid (the times are static: they fix the grid)."""
    return _invert_jit(model, robot, path, _Static(tuple(float(t) for t in ts)))


class _Static(eqx.Module):
    ts: tuple = eqx.field(static=True)


@eqx.filter_jit
def _invert_jit(model, robot, path, static):
    return inverse_path(model, robot, path, np.asarray(static.ts))


@eqx.filter_jit
def _growth(model, robot, z, zd, tau):
    """The linearised torque-driven dynamics d(z, z')/dt (k, 2n, 2n) about each state (k, n) of
    the path under its torques held as functions of time (open loop): the largest real part of
    their eigenvalues (NumPy's, on the host) is the fastest growth of a small deviation (1/s).
    For Table 1's L2 robot on the figure eight it is 3.3 1/s at every sample, as the home
    pose's free rotation mode (`modes(actuators="free")`). The model's own replay still
    follows (1.5e-9 m over 6 s: nothing disturbs it but rounding), but any difference between
    model and robot, or a disturbance, grows as exp(rate t)."""

    def one(z, zd, tau):
        def acc(y):
            q, qd = y[:z.shape[0]], y[z.shape[0]:]
            eom = eom_terms(model, robot, q, qd)
            return solve_spd(eom.M, generalized_force(eom, tau, jnp.zeros(3)) - eom.h)

        n = z.shape[0]
        A = jax.jacfwd(acc)(jnp.concatenate([z, zd]))
        return jnp.concatenate([jnp.concatenate([jnp.zeros((n, n)), jnp.eye(n)], axis=1), A])

    return jax.vmap(one)(z, zd, tau)


def _nominal_at(path, robot, ts):
    """The nominal commands at ts: L1's inverse-kinematics angles and inverse-dynamics
    torques along the path (what a `PathScene` without a log plays)."""
    from .._actuation import InverseDynamicsTorque, InverseKinematicsAngles
    from .._models import Reduced

    t = jnp.asarray(ts)
    th = jax.vmap(InverseKinematicsAngles(Reduced(), robot, path))(t)
    tau = jax.vmap(InverseDynamicsTorque(Reduced(), robot, path))(t)
    return np.asarray(th), np.asarray(tau)


def _angles(report) -> np.ndarray:
    """The actuated angles (m, 3) of a run: the model's coordinates where they hold them,
    else the kinematics' (L0/L1)."""
    res = report.result
    model = get_model(res.model)
    if model.actuated_index is not None:
        return np.asarray(res.z)[:, list(model.actuated_index)]
    from .._kinematics import inverse_kinematics

    return np.asarray(inverse_kinematics(report.params, jnp.asarray(res.X), model).th_a)


def error_band(ident, model, path, drive, log, options, after, level: float = 0.95) -> dict:
    """The predicted tracking error of the compensated commands over an identification's
    uncertainty: linearised, e(p) = e(p_hat) + J (p - p_hat) with J the error's Jacobian in the
    identified parameters (forward mode through the simulation), and a simultaneous band:
    half-width sqrt(chi2_k(level)) sqrt(J_i C J_i^T) at every output and coordinate holds the
    whole error of every robot inside the covariance C's `level` ellipsoid (Scheffe's
    projection), so of a fraction `level` of the robots, as far as the linearisation holds.

    **Arguments:**

    - `ident`: the `Identification` (names, estimate, covariance, params).
    - `model`, `path`, `drive`, `log`: what `compensate` ran.
    - `options`: the runs' `SceneOptions`; `after`: the run at the estimate.
    - `level`: the band's probability.

    **Returns:** {"names", "level", "error" (m, 3) at the estimate, "half_width" (m, 3),
    "position_bound" (m, the largest |error| the band allows), "jacobian" (m, 3, k)}.
    """
    import diffrax
    from scipy.stats import chi2

    from .._scenes import solve_scene
    from ._evaluation import params_at

    names = tuple(ident.names)
    x0 = jnp.asarray(np.asarray(ident.estimate, dtype=np.float64))
    base = ident.params
    scene = PathScene(path, drive=drive, command_log=log, name="compensated")
    fwd = dataclasses.replace(options, adjoint=diffrax.ForwardMode())

    def err(x):
        res = solve_scene(scene, params_at(base, names, x), model=model, options=fwd,
                          throw=False)
        return res.X - res.X_nominal

    J = np.asarray(jax.jacfwd(err)(x0))  # (m, 3, k)
    C = np.asarray(ident.covariance, dtype=np.float64)
    var = np.einsum("mik,kl,mil->mi", J, C, J)
    half = np.sqrt(chi2.ppf(level, len(names))) * np.sqrt(np.maximum(var, 0.0))
    e0 = np.asarray(after.result.X) - np.asarray(after.result.X_nominal)
    bound = float(np.max(np.linalg.norm(np.abs(e0[:, :2]) + half[:, :2], axis=1)))
    return {"names": list(names), "level": float(level), "error": e0, "half_width": half,
            "position_bound": bound, "jacobian": J}


__all__ = ["Compensation", "CompensationError", "compensate", "error_band", "DRIVES"]
