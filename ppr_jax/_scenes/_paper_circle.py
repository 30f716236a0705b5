"""Scene `paper-circle` (paper Fig 8-12): torque-driven along the circle of eq 55."""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx

from .._models import AbstractModel, Reduced
from .._trajectory import CIRCLE
from ._base import AbstractScene, torque_input


class PaperCircle(AbstractScene):
    """Torques from `torque_model`'s inverse dynamics along eq 55 (default L1; `Rigid()` gives
    the paper's "simplified model" torques), tabulated over the horizon; the model simulated
    torque-driven from its quasi-static state at t = 0. Default thickness 0.3 mm (the paper's
    simulation); `reference` holds its section 2.2 numbers (theory vs ADAMS-ANSYS). A nominal
    path through a type-II singularity of `torque_model` (where its torques are unbounded) is
    `RESULTS.singular_path`."""

    torque_model: AbstractModel = eqx.field(static=True, default_factory=Reduced)

    name: ClassVar[str] = "paper-circle"
    drive: ClassVar[str] = "torque"
    thickness: ClassVar[float] = 0.3e-3
    reference: ClassVar[dict] = {
        "source": "paper section 2.2, theory vs ADAMS-ANSYS, t = 0.3 mm",
        "radial_error_max_m": 2.41e-3,
        "radial_error_min_m": -0.99e-3,
        "radial_error_mean_m": 0.84e-3,
        "radial_error_max_relative_percent": 2.41,
        "end_rotation_diff_max_deg": 5.60,
        "end_rotation_diff_min_deg": -7.62,
        "end_rotation_diff_mean_deg": -0.04,
        "end_rotation_diff_max_relative_percent": 6.60,
        "computation_time_s": 60.0,
        "cosimulation_time_s": 28 * 60.0,
    }

    @property
    def input_model(self) -> AbstractModel:
        return self.torque_model

    def trajectory(self):
        return CIRCLE

    def commands(self, model, robot, traj, ts, panels):
        return torque_input(self.torque_model, robot, traj, ts, panels)

    def follows_its_input(self, model):
        if model.name == self.torque_model.name:
            return (f"it is driven by its own inverse-dynamics torques (torque_model="
                    f"{self.torque_model.name!r}), so it follows the circle exactly")
        return ""
