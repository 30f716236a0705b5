"""Your own experiment as a scene: any nominal path and the drive that realises it."""

from __future__ import annotations

from typing import Callable, ClassVar, Optional

import equinox as eqx

from .._actuation import MotionDriven, TorqueDriven
from .._errors import PPRError
from .._models import AbstractModel, Reduced
from ._base import AbstractScene, SceneInput, motion_input, path_out_of_reach, torque_input

#: the drives a `PathScene` runs
DRIVES = ("torque", "motion")


class PathScene(AbstractScene):
    """A scene on any nominal path: the paper's two scenes are two of these, on a circle.

    **Arguments:**

    - `path`: the nominal pose path t -> X (3,) (m, m, rad), an `equinox.Module` that is C2 in
      t (the quasi-static start and inverse dynamics differentiate it twice): `Circle`, or
      any path of `ppr_jax` (a line, waypoints, a Fourier series, a CSV of commanded poses).
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

    The run starts, like every scene, from the model's quasi-static state on the path at the
    first output time (MODEL.md section 6), so the path's pose, rate and acceleration there
    decide the start.
    """

    path: Callable
    drive: str = eqx.field(static=True, default="torque", kw_only=True)
    command_log: Optional[Callable] = None
    # keyword-only (as the base class declares some, they would come before `path`)
    input_model: AbstractModel = eqx.field(static=True, default_factory=Reduced, kw_only=True)
    name: str = eqx.field(static=True, default="path", kw_only=True)
    thickness: float = eqx.field(static=True, default=0.3e-3, kw_only=True)

    reference: ClassVar[dict] = {}

    def __check_init__(self):
        if self.drive not in DRIVES:
            raise PPRError(f"drive must be one of {', '.join(DRIVES)}, got {self.drive!r}")
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
        if not (isinstance(self.thickness, (int, float)) and 0 < self.thickness < 1e-2):
            raise PPRError(f"thickness must be in (0, 0.01) m, got {self.thickness!r}")

    def trajectory(self):
        return self.path

    def commands(self, model, robot, traj, ts, panels):
        if self.command_log is not None:
            act = (TorqueDriven(self.command_log) if self.drive == "torque"
                   else MotionDriven(self.command_log))
            # A log's own samples are its table; the nominal path's reach is still checked.
            return SceneInput(act, out_of_reach=path_out_of_reach(self.input_model, robot, traj,
                                                                  ts))
        if self.drive == "motion":
            return motion_input(model, self.input_model, robot, traj, ts, panels)
        return torque_input(self.input_model, robot, traj, ts, panels)

    def follows_its_input(self, model):
        if self.command_log is None and model.name == self.input_model.name:
            what = ("its own inverse-dynamics torques" if self.drive == "torque"
                    else "its own inverse kinematics of the path")
            return f"it is driven by {what}, so it follows the path exactly"
        return ""
