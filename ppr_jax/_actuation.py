"""Actuation modes (MODEL.md section 5): torque-driven, motion-driven and PD servo.

An actuation holds time functions (see `_trajectory.py`); the inverse-dynamics torque and the
inverse-kinematics angles of a model along a platform trajectory are time functions too, exact at
any t. The scenes tabulate them once per run (`_tabulated.py`); passed to `simulate` directly they
are evaluated at every solver stage.
"""

import abc
from typing import Callable, Optional

import equinox as eqx
import jax.numpy as jnp

from ._custom_types import Array, Float
from ._dynamics import inverse_dynamics
from ._kinematics import relative_det
from ._models import AbstractModel
from ._robot import Robot, RobotLike, as_robot
from ._trajectory import derivatives


class AbstractActuation(eqx.Module):
    """What the actuators do, as an interface the simulator asks (the way diffrax asks a
    step-size controller): whether they prescribe the actuated angles, which angles at time t,
    and which torque they apply. A new actuation is one final subclass implementing the two
    abstract methods and the class variable."""

    #: True when the actuated angles are prescribed functions of time (motion-driven): they then
    #: leave the model's free coordinates and the torques become reaction outputs
    prescribes_angles: eqx.AbstractClassVar[bool]

    @abc.abstractmethod
    def angles_at(self, t) -> Optional[tuple[Array, Array, Array]]:
        """(th_a, th_a', th_a'') (3,) each (rad, rad/s, rad/s^2) prescribed at time t, or None
        when the angles are free."""

    @abc.abstractmethod
    def torque_at(self, t, th_a: Float[Array, "3"], thdot_a: Float[Array, "3"]) -> Array:
        """Applied actuator torques (3,) (N m) at time t for actuated angles th_a and rates
        thdot_a (zero for a prescribed motion: its torques are reactions)."""


class TorqueDriven(AbstractActuation):
    """Actuator torques tau_a(t) (3,) in N m on th_i1."""

    torque: Callable
    prescribes_angles = False

    def angles_at(self, t):
        return None

    def torque_at(self, t, th_a, thdot_a):
        return self.torque(t)


class MotionDriven(AbstractActuation):
    """Actuated angles th_i1(t) (3,) prescribed (rad); the torques are reaction outputs."""

    angles: Callable
    prescribes_angles = True

    def angles_at(self, t):
        return derivatives(self.angles, t)

    def torque_at(self, t, th_a, thdot_a):
        return jnp.zeros(3)


class PDServo(AbstractActuation):
    """tau = feedforward(t) + Kp (th_d - th) + Kd (th_d' - th'); gains (3,) or scalar,
    Kp in N m/rad, Kd in N m s/rad."""

    angles: Callable
    Kp: Array
    Kd: Array
    feedforward: Optional[Callable] = None
    prescribes_angles = False

    def angles_at(self, t):
        return None

    def torque_at(self, t, th_a, thdot_a):
        thd, thd_dot, _ = derivatives(self.angles, t)
        tau = self.Kp * (thd - th_a) + self.Kd * (thd_dot - thdot_a)
        if self.feedforward is not None:
            tau = tau + self.feedforward(t)
        return tau


class _AlongPath(eqx.Module):
    """A time function of `model` moving its platform along `trajectory`: its value at t, and
    with it the largest loop-closure residual (m) of the inverse kinematics there
    (`with_residual`), from which the scenes check the nominal path's reach."""

    model: AbstractModel
    robot: Robot
    trajectory: Callable

    def __init__(self, model: AbstractModel, robot: RobotLike, trajectory: Callable):
        self.model, self.robot, self.trajectory = model, as_robot(robot), trajectory

    def __call__(self, t):
        return self.with_residual(t)[0]

    @abc.abstractmethod
    def with_residual(self, t):
        """(the value at t, the largest loop-closure residual (m) of the inverse kinematics)."""

    def with_checks(self, t):
        """(the value at t, (the residual of `with_residual`, the relative determinant of
        S = d th_a/dX at t (`relative_det`) or None where the value does not need S, t)): what
        a scene's input table checks the nominal path by, from its own evaluations."""
        value, resid = self.with_residual(t)
        return value, (resid, None, t)


class InverseDynamicsTorque(_AlongPath):
    """tau_a(t) of `model` (L0 or L1) moving its platform along `trajectory` (eq 54 solved for
    the torques); evaluated exactly at any t."""

    def with_residual(self, t):
        """(tau_a (3,), the largest loop-closure residual (m) of the inverse kinematics at t):
        the scenes check the nominal path's reach from the same evaluation."""
        tau, eom = self._solve(t)
        return tau, _max_residual(self.model, self.robot, eom.kin)

    def with_checks(self, t):
        # S is the matrix the torques were solved with (eq 54): its determinant costs nothing
        tau, eom = self._solve(t)
        return tau, (_max_residual(self.model, self.robot, eom.kin),
                     relative_det(eom.Jth, self.robot.r1), t)

    def _solve(self, t):
        X, Xd, Xdd = derivatives(self.trajectory, t)
        return inverse_dynamics(self.model, self.robot, X, Xd, Xdd)


class InverseKinematicsAngles(_AlongPath):
    """Actuated angles th_i1(t) of `model`'s inverse kinematics along `trajectory`."""

    def with_residual(self, t):
        """(th_a (3,), the largest loop-closure residual (m) of the inverse kinematics at t)."""
        z = self.model.coords_from_pose(self.robot, self.trajectory(t))
        k = self.model.kinematics(self.robot, z)
        return k.th_a, _max_residual(self.model, self.robot, k)


def _max_residual(model, robot, k):
    return jnp.max(jnp.linalg.norm(model.loop_residual(robot, k), axis=-1))
