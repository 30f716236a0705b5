"""Actuation modes (MODEL.md section 5): torque-driven, motion-driven and PD servo.

An actuation holds time functions (see `_trajectory.py`); the inverse-dynamics torque and the
inverse-kinematics angles of a model along a platform trajectory are time functions too, evaluated
exactly at every solver stage instead of being tabulated.
"""

from __future__ import annotations

from typing import Callable, Optional

import equinox as eqx

from ._custom_types import Array
from ._dynamics import inverse_dynamics
from ._model import AbstractModel
from ._params import RobotParams
from ._prb import derived
from ._trajectory import derivatives


class TorqueDriven(eqx.Module):
    """Actuator torques tau_a(t) (3,) in N m on th_i1."""

    torque: Callable


class MotionDriven(eqx.Module):
    """Actuated angles th_i1(t) (3,) prescribed (rad); the torques are reaction outputs."""

    angles: Callable


class PDServo(eqx.Module):
    """tau = feedforward(t) + Kp (th_d - th) + Kd (th_d' - th'); gains (3,) or scalar,
    Kp in N m/rad, Kd in N m s/rad."""

    angles: Callable
    Kp: Array
    Kd: Array
    feedforward: Optional[Callable] = None

    def __call__(self, t, th, thdot):
        thd, thd_dot, _ = derivatives(self.angles, t)
        tau = self.Kp * (thd - th) + self.Kd * (thd_dot - thdot)
        if self.feedforward is not None:
            tau = tau + self.feedforward(t)
        return tau


class InverseDynamicsTorque(eqx.Module):
    """tau_a(t) of `model` (L0 or L1) moving its platform along `trajectory` (eq 54 solved for
    the torques); evaluated exactly at any t."""

    model: AbstractModel
    params: RobotParams
    trajectory: Callable

    def __call__(self, t):
        X, Xd, Xdd = derivatives(self.trajectory, t)
        tau, _ = inverse_dynamics(self.model, self.params, derived(self.params), X, Xd, Xdd)
        return tau


class InverseKinematicsAngles(eqx.Module):
    """Actuated angles th_i1(t) of `model`'s inverse kinematics along `trajectory`."""

    model: AbstractModel
    params: RobotParams
    trajectory: Callable

    def __call__(self, t):
        dv = derived(self.params)
        z = self.model.coords_from_pose(self.params, dv, self.trajectory(t))
        return self.model.kinematics(self.params, dv, z).th_a
