"""Scene `servo-circle` (paper Fig 17-18): the actuated angles follow L1's inverse kinematics."""

from __future__ import annotations

from typing import ClassVar

from .._actuation import InverseKinematicsAngles, MotionDriven
from .._models import Reduced
from .._trajectory import Circle
from ._base import AbstractScene, SceneInput, path_out_of_reach, tabulated


class ServoCircle(AbstractScene):
    """The actuated angles follow L1's inverse kinematics of eq 55 exactly (motion-driven); the
    platform's response of the model. L0/L1 need no ODE (forward kinematics + inverse dynamics,
    from the exact angles); L2/L3 take the angles tabulated (th, th' and th'' at every stage from
    the table's polynomials). Default thickness 0.5 mm (the paper's experiment); `reference`
    holds its section 3 numbers (theory vs experiment)."""

    name: ClassVar[str] = "servo-circle"
    thickness: ClassVar[float] = 0.5e-3
    reference: ClassVar[dict] = {
        "source": "paper section 3, theory vs experiment (NDI Optotrak), t = 0.5 mm",
        "radial_error_max_m": 4.69e-3,
        "radial_error_min_m": -3.59e-3,
        "radial_error_mean_m": 0.71e-3,
        "radial_error_max_relative_percent": 4.69,
    }

    def trajectory(self):
        return Circle()

    def commands(self, model, robot, traj, ts, panels):
        angles = InverseKinematicsAngles(Reduced(), robot, traj)
        if model.actuated_index is None:
            return SceneInput(MotionDriven(angles),
                              out_of_reach=path_out_of_reach(Reduced(), robot, traj, ts))
        table, coarse, out = tabulated(angles, ts, panels)
        return SceneInput(MotionDriven(table), out_of_reach=out, coarse=coarse)

    def follows_its_input(self, model):
        if model.name == "reduced":
            return ("its angles are its own inverse kinematics of the circle, so it follows it "
                    "exactly")
        return ""
