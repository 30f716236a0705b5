"""Actuated angles against poses, on the host, before anything is compiled: the one check of
any angle input (a command log of `simulate`, `sweep`, `sensitivity` and `synth`, a scene's
`command_log`, an identification file's angles) against the assembly mode of the robot.

A 3-RRR chain reaches a platform pose in two assembly modes, its elbow bent one way or the
other (the elbow orientation sigma of MODEL.md section 4). Angles of the other mode drive a
model without a word: the quasi-static start "finds" a balance with the strips bent by more
than 100 degrees (the PRB fit holds to 1 rad) and the run reports it as tracking error. So
every angle input is compared here with L1's closed-form inverse kinematics of its poses in
both orientations (NumPy, no compilation). Angles beyond two turns are refused first, as
probably degrees: in degrees they are far from both modes, and a mode message would mislead.
"""

from __future__ import annotations

import math
from typing import Callable, Optional

import numpy as np

from ._errors import DataError

#: an actuated angle further than this (rad) from the pose's inverse kinematics, and nearer the
#: other elbow orientation's, belongs to the other assembly mode
MODE_TOLERANCE = 0.05
#: largest |actuated angle| (rad) of an angle input: beyond two turns it is in degrees (or mrad)
MAX_ANGLE = 4 * math.pi
#: Newton iterations of the host-side forward kinematics
NEWTON_STEPS = 30


class AssemblyModeError(DataError):
    """Actuated angles that belong to the other assembly mode (elbow orientation sigma) than
    the robot's at the poses they go with, or that are beyond two turns (probably degrees):
    the message names the input, the sample, its time and the chain. Raised before anything is
    compiled."""


def wrap(a):
    """Angles wrapped to [-pi, pi)."""
    return (np.asarray(a) + math.pi) % (2 * math.pi) - math.pi


def pose_text(X) -> str:
    return f"(x, y, phi) = ({X[0]:.6g} m, {X[1]:.6g} m, {X[2]:.4g} rad)"


class HostGeometry:
    """The robot's chain geometry as NumPy numbers (concrete parameters): L1's closed-form
    inverse kinematics in both elbow orientations, the chains' reach and forward kinematics
    by Newton, at no compilation.

    **Arguments:**

    - `robot`: a `RobotParams` (one robot) or a `Robot` built from one.
    """

    def __init__(self, robot):
        from ._geometry import base_points
        from ._robot import Robot

        robot = robot if isinstance(robot, Robot) else Robot(robot)
        self.robot = robot
        self.A = np.asarray(base_points(robot), dtype=np.float64)
        self.r1, self.r2, self.r3 = (float(getattr(robot, k)) for k in ("r1", "r2", "r3"))
        self.delta1 = float(robot.delta1)
        self.sigma = int(robot.sigma)
        h = float(robot.params.h)
        self.rho_E = h / math.sqrt(3.0)
        self.beta = np.array([7 * math.pi / 6, -math.pi / 6, math.pi / 2])

    def chains(self, X):
        """(E_i - A_i (..., 3, 2), |E_i - A_i| (..., 3)) at poses X (..., 3)."""
        X = np.asarray(X, dtype=np.float64)
        ang = self.beta + X[..., 2:3]
        E = X[..., None, :2] + self.rho_E * np.stack([np.cos(ang), np.sin(ang)], axis=-1)
        d = E - self.A
        return d, np.linalg.norm(d, axis=-1)

    def ik(self, X):
        """L1's actuated angles at poses X (..., 3) in the robot's elbow orientation and in the
        other, and the closure cosine c per chain (|c| < 1: within reach), each (..., 3).
        Closed form (MODEL.md section 4; exact for r1 = r3, a guess within a fraction of a
        millimetre otherwise)."""
        d, dist = self.chains(X)
        rbar = 0.5 * (self.r1 + self.r3)
        c = (dist - self.r2) / (2 * rbar)
        v = np.arccos(np.clip(c, -1.0, 1.0))
        u = np.arctan2(d[..., 1], d[..., 0])
        own = u - self.sigma * v - self.sigma * self.delta1
        other = u + self.sigma * v + self.sigma * self.delta1
        return own, other, c

    def reach(self, c, dist):
        """A description of the chains out of reach at one pose, or ''."""
        rbar = 0.5 * (self.r1 + self.r3)
        out = []
        for i in range(3):
            if c[i] >= 1.0:
                out.append(f"chain {i + 1}'s platform joint is {1e3 * dist[i]:.4g} mm from its "
                           f"base joint, {1e3 * (dist[i] - self.r2 - 2 * rbar):.4g} mm beyond "
                           f"its reach of {1e3 * (self.r2 + 2 * rbar):.4g} mm")
            elif c[i] <= -1.0:
                out.append(f"chain {i + 1}'s platform joint is {1e3 * dist[i]:.4g} mm from its "
                           f"base joint, closer than the chain folds")
        return "; ".join(out)

    def forward(self, th, X0):
        """L1's forward kinematics of angles th by Newton from X0: (X, converged)."""
        X = np.array(X0, dtype=np.float64)
        for _ in range(NEWTON_STEPS):
            own, _, c = self.ik(X)
            if np.any(np.abs(c) >= 1.0):
                return X, False
            r = wrap(own - th)
            if np.max(np.abs(r)) < 1e-12:
                return X, True
            S = self._jacobian(X)
            try:
                step = np.linalg.solve(S, r)
            except np.linalg.LinAlgError:
                return X, False
            # a trust region: no step longer than 20 mm or 0.2 rad
            big = max(np.max(np.abs(step[:2])) / 0.02, abs(step[2]) / 0.2, 1.0)
            X = X - step / big
        return X, False

    def _jacobian(self, X, h=1e-7):
        S = np.empty((3, 3))
        for j in range(3):
            dX = np.zeros(3)
            dX[j] = h
            S[:, j] = wrap(self.ik(X + dX)[0] - self.ik(X - dX)[0]) / (2 * h)
        return S


def check_angle_units(th, where: Callable[[int], str], error=AssemblyModeError) -> None:
    """Refuse (`error`, default `AssemblyModeError`) actuated angles th (n, 3) beyond two turns
    (`MAX_ANGLE`): probably degrees read as radians. `where(i)` names sample i (its file, line
    and time)."""
    th = np.asarray(th, dtype=np.float64).reshape(-1, 3)
    if th.shape[0] == 0:
        return
    big = np.max(np.abs(th), axis=1)
    i = int(np.argmax(big))
    if big[i] > MAX_ANGLE:
        raise error(f"{where(i)}: actuated angle {float(big[i]):.4g} rad, beyond two turns: "
                    f"probably degrees read as radians; declare the unit (column 'th_1[deg]', "
                    f"header '# units: angle=deg', or angle_unit='deg')")


def check_assembly_mode(th, X, robot, where: Callable[[int], str], *,
                        error=AssemblyModeError,
                        geometry: Optional[HostGeometry] = None) -> None:
    """Refuse (`error`, default `AssemblyModeError`) the first sample whose actuated angles
    belong to the other assembly mode than the robot's at its pose: an angle further than
    `MODE_TOLERANCE` (0.05 rad) from L1's inverse kinematics of the pose in the robot's elbow
    orientation sigma, and nearer the other orientation's. Angles beyond two turns are refused
    first (`check_angle_units`). Poses out of the chains' reach are skipped (the reach has its
    own checks, which name the cause).

    **Arguments:**

    - `th`: actuated angles (n, 3) (rad) or (3,).
    - `X`: the poses (n, 3) or (3,) (m, m, rad) they go with (the path at the angles' times).
    - `robot`: the robot (`RobotParams` of one robot, or a `Robot`); unused with `geometry`.
    - `where`: `where(i)` names sample i in the message (input, sample or line, time).
    - `error`: the exception class raised.
    - `geometry`: a `HostGeometry` already built for the robot.

    **Returns:** None.
    """
    th = np.asarray(th, dtype=np.float64).reshape(-1, 3)
    X = np.asarray(X, dtype=np.float64).reshape(-1, 3)
    check_angle_units(th, where, error)
    geo = HostGeometry(robot) if geometry is None else geometry
    own, other, c = geo.ik(X)
    d_own, d_other = np.abs(wrap(th - own)), np.abs(wrap(th - other))
    bad = (d_own > MODE_TOLERANCE) & (d_other < d_own) & np.all(np.abs(c) < 1.0, axis=1)[:, None]
    if not bad.any():
        return
    k, i = (int(v[0]) for v in np.nonzero(bad))
    raise error(
        f"{where(k)}: the actuated angle th_{i + 1} = {th[k, i]:.6g} rad belongs to the other "
        f"assembly mode of chain {i + 1} (elbow orientation sigma = {-geo.sigma:+d}) than the "
        f"robot's (sigma = {geo.sigma:+d}) at the pose {pose_text(X[k])}: {d_own[k, i]:.4g} rad "
        f"from the robot's mode ({own[k, i]:.6g} rad), {d_other[k, i]:.3g} rad from the "
        f"other's ({int(bad.any(axis=1).sum())} of {th.shape[0]} samples); set "
        f"sigma={-geo.sigma} if the robot is assembled that way, or check the angles' zero "
        f"and sign")
