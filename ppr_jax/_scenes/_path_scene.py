"""Your own experiment as a scene: any nominal path and the drive that realises it."""

from __future__ import annotations

from typing import Callable, ClassVar, Optional, Union

import equinox as eqx

from .._actuation import MotionDriven, TorqueDriven
from .._errors import PPRError
from .._labels import label_field
from .._models import AbstractModel, Reduced, get_model
from .._paths import check_log_covers
from ._base import (
    AbstractScene,
    SceneInput,
    motion_input,
    path_out_of_reach,
    step_times,
    torque_input,
)

#: the drives a `PathScene` runs
DRIVES = ("torque", "motion")


class PathScene(AbstractScene):
    """A scene on any nominal path: the paper's two scenes are two of these, on a circle.

    **Arguments:**

    - `path`: the nominal pose path t -> X (3,) (m, m, rad), an `equinox.Module` that is C2 in
      t (the quasi-static start and inverse dynamics differentiate it twice): `Circle`, or
      any path of `ppr_jax` (a line, waypoints, a Fourier series, a CSV of commanded poses).
      A path whose acceleration jumps somewhere (a clamped `Waypoints` at its ends) names
      those times in a `kinks` attribute (s); a start there differentiates one-sided.
    - `drive`: `"torque"`: the actuators apply `input_model`'s inverse-dynamics torques along
      the path (open loop, as `paper-circle`), or the torques of `command_log`; `"motion"`: the
      actuated angles follow `input_model`'s inverse kinematics of the path (as
      `servo-circle`), or the angles of `command_log`.
    - `command_log`: a command log t -> (3,), the torques (N m) or actuated angles (rad) a
      controller recorded (C2 in t; `load_commands` reads one from a CSV file); None:
      computed from the path.
    - `input_model`: the model (L0 or L1) whose inverse dynamics or kinematics gives the input
      and whose reach and type-II singularities along the path are checked (default L1).
    - `name`: the scene's label in reports and the registry.
    - `thickness`: the strip thickness (m) of `default_params` (default Table 1's 0.3 mm).
    - `start_path`: a pose path whose pose, rate and acceleration at the first output time the
      start takes instead of `path`'s (a `StartPath`: `experiment_scene` fits one to an
      experiment's first samples, whose noise would make an interpolating spline's rates
      useless); None: `path`'s own.

    The run starts, like every scene, from the model's quasi-static state on the path at the
    first output time (MODEL.md section 6), so the path's pose, rate and acceleration there
    (or `start_path`'s) decide the start.
    """

    path: Callable
    drive: str = eqx.field(static=True, default="torque", kw_only=True)
    command_log: Optional[Callable] = None
    # keyword-only (as the base class declares some, they would come before `path`)
    input_model: AbstractModel = eqx.field(static=True, default_factory=Reduced, kw_only=True)
    name: str = label_field(default="path", kw_only=True)
    thickness: float = eqx.field(static=True, default=0.3e-3, kw_only=True)
    start_path: Optional[Callable] = eqx.field(default=None, kw_only=True)

    reference: ClassVar[dict] = {}

    def __check_init__(self):
        if self.drive not in DRIVES:
            raise PPRError(f"drive must be one of {', '.join(DRIVES)}, got {self.drive!r}")
        if not isinstance(self.input_model, AbstractModel):
            raise PPRError(f"input_model must be a kinematic model, Rigid() or Reduced() (or "
                           f"its name, 'rigid' or 'reduced', where a function takes one), got "
                           f"{type(self.input_model).__name__} {self.input_model!r}")
        if self.input_model.actuated_index is not None:
            raise PPRError(f"input_model must be a kinematic model (rigid or reduced: its "
                           f"coordinates are the pose), got {self.input_model.name!r}")
        if not callable(self.path):
            raise PPRError(f"path must be a time function t -> (x, y, phi), got "
                           f"{type(self.path).__name__}")
        if self.command_log is not None and not callable(self.command_log):
            raise PPRError(f"command_log must be a time function t -> (3,) or None, got "
                           f"{type(self.command_log).__name__}")
        kind = getattr(self.command_log, "kind", None)  # a `CommandLog` says what it holds
        if (kind, self.drive) in (("angles", "torque"), ("torque", "motion")):
            raise PPRError(f"command_log holds {kind} but drive={self.drive!r}: an angle log "
                           f"drives a motion, a torque log a torque drive")
        # a log that does not cover its path is refused here, before any run (every command
        # and study builds a `PathScene` where a log meets a path)
        check_log_covers(self.path, self.command_log)
        if self.start_path is not None and not callable(self.start_path):
            raise PPRError(f"start_path must be a time function t -> (x, y, phi) or None, got "
                           f"{type(self.start_path).__name__}")
        if not (isinstance(self.thickness, (int, float)) and 0 < self.thickness < 1e-2):
            raise PPRError(f"thickness must be in (0, 0.01) m, got {self.thickness!r}")

    def trajectory(self):
        return self.path

    def check_commands(self, params, traj, t_end):
        """A command log against the path the run follows (`traj`: the scene's, or the
        options'): its span covers the path's samples, or for a path without samples the
        horizon [0, t_end] (`check_log_covers`); an angle log's samples within that span belong
        to the robot's assembly mode at the path's poses (`check_assembly_mode`; angles beyond
        two turns refused first, as degrees)."""
        (err,) = self.check_members([params], traj, t_end)
        if err is not None:
            raise err

    def check_members(self, members, traj, t_end):
        """`check_commands` of each robot of `members` (`AbstractScene.check_members`): the
        log's span checked once (it raises), its samples and the path's poses evaluated once,
        their assembly mode judged for each robot."""
        import jax
        import jax.numpy as jnp
        import numpy as np

        from .._assembly import AssemblyModeError, check_assembly_mode

        none = [None] * len(members)
        log = self.command_log
        if log is None:
            return none
        check_log_covers(traj, log, t_end=t_end)
        ts = getattr(log, "ts", None)
        if self.drive != "motion" or ts is None:
            return none
        ts = np.asarray(ts, dtype=np.float64)
        span = getattr(traj, "ts", None)
        lo, hi = ((float(span[0]), float(span[-1])) if span is not None
                  else (0.0, np.inf if t_end is None else float(t_end)))
        ts = ts[(ts >= lo) & (ts <= hi)]
        if ts.size == 0:
            return none
        t = jnp.asarray(ts)

        def at(fn):
            # NumPy leaves (a `PiecewiseCubic`'s knots) as JAX arrays, so that vmap can index
            fn = jax.tree_util.tree_map(
                lambda x: jnp.asarray(x) if isinstance(x, np.ndarray) else x, fn)
            return np.asarray(jax.vmap(fn)(t))

        th, X = at(log), at(traj)
        name = getattr(log, "name", None) or self.name
        out = []
        for params in members:
            try:
                check_assembly_mode(th, X, params,
                                    lambda i: f"{name}: sample at t = {ts[i]:.6g} s")
                out.append(None)
            except AssemblyModeError as err:
                out.append(err)
        return out

    def start_trajectory(self, traj):
        return traj if self.start_path is None else self.start_path

    def commands(self, model, robot, traj, ts, panels):
        if self.command_log is not None:
            act = (TorqueDriven(self.command_log) if self.drive == "torque"
                   else MotionDriven(self.command_log))
            # A log's own samples are its table; the nominal path's reach is still checked.
            return SceneInput(act, out_of_reach=path_out_of_reach(self.input_model, robot, traj,
                                                                  ts),
                              step_ts=step_times(self.command_log, traj))
        if self.drive == "motion":
            return motion_input(model, self.input_model, robot, traj, ts, panels)
        return torque_input(self.input_model, robot, traj, ts, panels)

    def follows_its_input(self, model):
        if self.command_log is None and model.name == self.input_model.name:
            what = ("its own inverse-dynamics torques" if self.drive == "torque"
                    else "its own inverse kinematics of the path")
            return f"it is driven by {what}, so it follows the path exactly"
        return ""


def experiment_scene(experiment, *, drive: Optional[str] = None,
                     input_model: Union[None, str, AbstractModel] = None,
                     name: Optional[str] = None) -> PathScene:
    """The scene that a measured experiment describes: its own commands drive the model along
    its own path, from the state its first samples give.

    - the command log: the experiment's actuated angles th_1..th_3 (a motion drive), or its
      torques tau_1..tau_3 (a torque drive), through a not-a-knot cubic spline (C2: its
      second derivative is a prescribed motion's acceleration);
    - the path, which the tracking error is measured against: the measured poses, splined
      likewise;
    - the start (`start_path`): the pose, its rate and acceleration at the first sample from a
      least-squares quadratic through the first 0.1 s of poses (`fit_start`).
    Times are counted from the first sample (the scenes start at t = 0).

    **Arguments:**

    - `experiment`: an `Experiment` (`load_csv`) holding angles or torques.
    - `drive`: `"motion"` (the angles) or `"torque"` (the torques); None: the angles where the
      experiment holds them (MODEL.md section 7), else the torques.
    - `input_model`: the kinematic model (L0 or L1, or its name) whose reach the path is
      checked against (default L1).
    - `name`: the scene's name (default the experiment's).

    **Returns:** a `PathScene` (run it with `run_scene`, register it with `register_scene`).
    """
    import numpy as np

    from .._data import DataError, Experiment
    from .._paths import StartPath, fit_start
    from .._trajectory import PiecewiseCubic, spline_pieces

    if not isinstance(experiment, Experiment):
        raise DataError(f"experiment_scene takes an Experiment (load_csv), got "
                        f"{type(experiment).__name__}")
    drive = experiment_drive(experiment, drive)
    if isinstance(input_model, str):  # a model's name
        input_model = get_model(input_model)
    ts = np.asarray(experiment.ts, dtype=np.float64)
    ts = ts - ts[0]
    log = experiment.th if drive == "motion" else experiment.tau
    path = PiecewiseCubic(ts, spline_pieces(ts, ts, experiment.X))
    command_log = PiecewiseCubic(ts, spline_pieces(ts, ts, log))
    return PathScene(path, drive=drive, command_log=command_log,
                     input_model=Reduced() if input_model is None else input_model,
                     name=experiment.name if name is None else name,
                     start_path=StartPath(0.0, fit_start(ts, experiment.X)))


def experiment_drive(experiment, drive: Optional[str] = None) -> str:
    """The drive an experiment's own commands give: `drive` checked against what it holds, or,
    for None, "motion" where it holds actuated angles, else "torque" where it holds torques.
    Raises `DataError` naming the experiment when it holds neither (or not the one asked)."""
    from .._data import DataError

    if drive is not None and drive not in DRIVES:
        raise DataError(f"drive must be one of {', '.join(DRIVES)} or None, got {drive!r}")
    has = {"motion": experiment.th is not None, "torque": experiment.tau is not None}
    if drive is None:
        if not any(has.values()):
            raise DataError(
                f"{experiment.name}: the data hold no actuated angles (th_1, th_2, th_3) and no "
                f"torques (tau_1, tau_2, tau_3): nothing says what drove the robot; add the "
                f"commanded or measured angles (or torques) to the file, or name the paper's "
                f"experiment it is (scene='servo-circle', CLI --scene servo-circle)")
        return "motion" if has["motion"] else "torque"
    if not has[drive]:
        what = "actuated angles th_1..th_3" if drive == "motion" else "torques tau_1..tau_3"
        raise DataError(f"{experiment.name}: drive={drive!r} needs the {what}, which the data "
                        f"do not hold")
    return drive
