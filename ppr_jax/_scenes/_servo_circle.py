"""Scene `servo-circle` (paper Fig 17-18): the actuated angles follow L1's inverse kinematics."""

from __future__ import annotations

from typing import ClassVar

from .._models import AbstractModel, Reduced
from .._trajectory import CIRCLE
from ._base import AbstractScene, motion_input


class ServoCircle(AbstractScene):
    """The actuated angles follow L1's inverse kinematics of eq 55 exactly (motion-driven); the
    platform's response of the model. L0/L1 need no ODE (forward kinematics + inverse dynamics,
    from the exact angles); L2/L3 take the angles tabulated (th, th' and th'' at every stage from
    the table's polynomials). Default thickness 0.5 mm (the paper's experiment); `reference`
    holds its section 3 numbers (theory vs experiment)."""

    name: ClassVar[str] = "servo-circle"
    drive: ClassVar[str] = "motion"
    thickness: ClassVar[float] = 0.5e-3
    reference: ClassVar[dict] = {
        "source": "paper section 3, theory vs experiment (NDI Optotrak), t = 0.5 mm",
        "radial_error_max_m": 4.69e-3,
        "radial_error_min_m": -3.59e-3,
        "radial_error_mean_m": 0.71e-3,
        "radial_error_max_relative_percent": 4.69,
    }

    @property
    def input_model(self) -> AbstractModel:
        return Reduced()

    def trajectory(self):
        return CIRCLE

    def commands(self, model, robot, traj, ts, panels):
        return motion_input(model, self.input_model, robot, traj, ts, panels)

    def follows_its_input(self, model):
        if model.name == "reduced":
            return ("its angles are its own inverse kinematics of the circle, so it follows it "
                    "exactly")
        return ""
