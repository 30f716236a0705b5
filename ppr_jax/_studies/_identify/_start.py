"""The start of each experiment, checked on the host before the simulation is compiled.

A fit whose simulation starts where the data do not is hopeless: the robot released 100 mm from
where the file says it was runs for minutes and fails with a solver error that names no cause.
So, before anything is traced, every experiment's first sample is checked against the model at
the initial guess of the parameters (the kinematic model L1, whose closed-form inverse kinematics
costs nothing on the host):

- its pose is within the chains' reach (no state of the model reaches it otherwise);
- motion drive: its actuated angles belong to the pose's assembly mode (the elbow orientation
  sigma of every chain), and they put the platform (L1's forward kinematics, Newton from the
  file's pose) within `START_TOLERANCE` of the file's pose;
- torque drive: its torques are those that move the platform as its first samples do (L1's
  inverse dynamics at the start's pose, rate and acceleration): the acceleration that the
  difference leaves may move the platform by at most `START_TOLERANCE` within
  `START_HORIZON` (0.1 s);
- a named scene (one of the paper's experiments): the file's first pose is within
  `START_TOLERANCE` of the scene's own start.

Each refusal is a `StartError` naming the experiment, the sample, the time and the distance.
"""

from __future__ import annotations

import math

import numpy as np

from ..._errors import IdentificationError

#: how far (position m, orientation rad) the state that the commands give at the first sample
#: may lie from the file's first pose: beyond it the data and the commands (or the scene) do
#: not describe one experiment. A parameter within its range moves the pose under given angles
#: by millimetres (gamma by 0.1: about 3 mm); a scene started elsewhere is off by centimetres.
START_TOLERANCE = (1e-2, 0.1)
#: the time (s) over which the acceleration that a torque drive's first torques leave unexplained
#: may move the platform by at most START_TOLERANCE
START_HORIZON = 0.1
#: an actuated angle further than this (rad) from the pose's inverse kinematics, and nearer the
#: other elbow orientation's, belongs to the other assembly mode
MODE_TOLERANCE = 0.05
#: Newton iterations of the host-side forward kinematics / balance
NEWTON_STEPS = 30


class StartError(IdentificationError):
    """An experiment's first sample cannot start the model: its pose is out of reach, its
    commands put the platform elsewhere (or cannot hold it there), its angles belong to another
    assembly mode, or a named scene starts elsewhere. Raised before anything is compiled."""


def _where(exp, i: int = 0) -> str:
    return f"{exp.name}: sample {i + 1} (t = {float(np.asarray(exp.ts)[i]):.6g} s)"


def _wrap(a):
    return (np.asarray(a) + math.pi) % (2 * math.pi) - math.pi


class _Geometry:
    """The robot's chain geometry as NumPy numbers (concrete parameters)."""

    def __init__(self, params):
        from ..._geometry import base_points
        from ..._robot import Robot

        robot = Robot(params)
        self.robot = robot
        self.A = np.asarray(base_points(robot), dtype=np.float64)
        self.r1, self.r2, self.r3 = (float(getattr(robot, k)) for k in ("r1", "r2", "r3"))
        self.delta1 = float(robot.delta1)
        self.sigma = int(robot.sigma)
        h = float(robot.params.h)
        self.rho_E = h / math.sqrt(3.0)
        self.beta = np.array([7 * math.pi / 6, -math.pi / 6, math.pi / 2])

    def chains(self, X):
        """(E_i - A_i (3, 2), |E_i - A_i| (3,))."""
        ang = self.beta + X[2]
        E = X[:2][None, :] + self.rho_E * np.stack([np.cos(ang), np.sin(ang)], axis=1)
        d = E - self.A
        return d, np.linalg.norm(d, axis=1)

    def ik(self, X):
        """L1's actuated angles at pose X in the robot's elbow orientation and in the other,
        and the closure cosine c per chain (|c| < 1: within reach). Closed form (MODEL.md
        section 4; exact for r1 = r3, a guess within a fraction of a millimetre otherwise)."""
        d, dist = self.chains(X)
        rbar = 0.5 * (self.r1 + self.r3)
        c = (dist - self.r2) / (2 * rbar)
        v = np.arccos(np.clip(c, -1.0, 1.0))
        u = np.arctan2(d[:, 1], d[:, 0])
        own = u - self.sigma * v - self.sigma * self.delta1
        other = u + self.sigma * v + self.sigma * self.delta1
        return own, other, c

    def reach(self, c, dist):
        """A description of the chains out of reach, or ''."""
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
            r = _wrap(own - th)
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
            S[:, j] = _wrap(self.ik(X + dX)[0] - self.ik(X - dX)[0]) / (2 * h)
        return S


def _distance(X, X0) -> str:
    return (f"{1e3 * float(np.hypot(*(X[:2] - X0[:2]))):.4g} mm and "
            f"{abs(float(X[2] - X0[2])):.3g} rad")


def _too_far(X, X0, fitted=(True, True)) -> bool:
    """X further than `START_TOLERANCE` from X0 in a fitted channel (`fitted`: position,
    orientation; a channel of infinite noise is not fitted, and its data are not checked)."""
    return bool((fitted[0] and not np.hypot(*(X[:2] - X0[:2])) <= START_TOLERANCE[0])
                or (fitted[1] and not abs(X[2] - X0[2]) <= START_TOLERANCE[1]))


def _pose(X) -> str:
    return f"(x, y, phi) = ({X[0]:.6g} m, {X[1]:.6g} m, {X[2]:.4g} rad)"


def _allowed() -> str:
    return f"allowed {1e3 * START_TOLERANCE[0]:g} mm and {START_TOLERANCE[1]:g} rad"


def check_starts(exps, drive: str, params, starts, fitted=(True, True)) -> None:
    """Refuse (`StartError`) the first experiment whose first sample cannot start the model
    (module docstring): its pose `starts[k][0]` (the start's fit of its first samples) out of
    reach; with `drive="motion"` its angles of another assembly mode, or putting the platform
    further than `START_TOLERANCE` from the pose; with `drive="torque"` its torques
    accelerating the platform by more than `START_TOLERANCE` away within `START_HORIZON`.
    `params`: the robot at the initial guess (concrete); `fitted`: whether the position and the
    orientation are fitted (a channel of infinite noise is not, and is not compared)."""
    geo = _Geometry(params)
    for exp, start in zip(exps, starts):
        X0 = np.asarray(start[0], dtype=np.float64)
        own, other, c = geo.ik(X0)
        _, dist = geo.chains(X0)
        far = geo.reach(c, dist)
        if far:
            raise StartError(f"{_where(exp)}: no state of the model reaches the pose "
                             f"{_pose(X0)}: {far}")
        if drive == "motion":
            _check_angles(exp, geo, X0, own, other, fitted)
        else:
            _check_torques(exp, geo, start, fitted)


def _check_angles(exp, geo, X0, own, other, fitted):
    th = np.asarray(exp.th[0], dtype=np.float64)
    d_own, d_other = np.abs(_wrap(th - own)), np.abs(_wrap(th - other))
    for i in range(3):
        if d_own[i] > MODE_TOLERANCE and d_other[i] < d_own[i]:
            raise StartError(
                f"{_where(exp)}: the actuated angle th_{i + 1} = {th[i]:.6g} rad belongs to "
                f"the other assembly mode of chain {i + 1} (elbow orientation sigma = "
                f"{-geo.sigma:+d}) than the robot's (sigma = {geo.sigma:+d}) at the pose "
                f"{_pose(X0)}: {d_own[i]:.4g} rad from the robot's mode ({own[i]:.6g} rad), "
                f"{d_other[i]:.3g} rad from the other's; set sigma={-geo.sigma} if the robot "
                f"is assembled that way, or check the angles' zero and sign")
    X, ok = geo.forward(th, X0)
    if not ok:
        raise StartError(
            f"{_where(exp)}: no state of the model reaches the actuated angles th = "
            f"({th[0]:.6g}, {th[1]:.6g}, {th[2]:.6g}) rad near the pose {_pose(X0)} (forward "
            f"kinematics from there leaves the chains' reach; the angles are "
            f"{np.max(d_own):.4g} rad from the pose's inverse kinematics): the angles and the "
            f"poses do not describe one experiment (another zero, sign or unit of the angles?)")
    if _too_far(X, X0, fitted):
        raise StartError(
            f"{_where(exp)}: the actuated angles put the platform at {_pose(X)}, "
            f"{_distance(X, X0)} from the file's first pose {_pose(X0)} ({_allowed()}): the "
            f"angles and the poses do not describe one experiment (another zero, sign or unit "
            f"of the angles, or of the tracker's frame?)")


def _check_torques(exp, geo, start, fitted):
    import jax
    import jax.numpy as jnp

    from ..._dynamics import inverse_dynamics
    from ..._models import Reduced

    robot = geo.robot
    X0, Xd, Xdd = (jnp.asarray(start[k]) for k in range(3))
    tau0 = np.asarray(exp.tau[0], dtype=np.float64)

    def torque(a):
        # L1's inverse dynamics at the start's pose and rate: affine in the acceleration
        return inverse_dynamics(Reduced(), robot, X0, Xd, a)[0]

    # one small program (the simulation is compiled later)
    tau_need = np.asarray(jax.jit(torque)(Xdd))
    A = np.asarray(jax.jit(jax.jacfwd(torque))(Xdd))
    # Under torques the start holds the file's pose and rate; torques that differ from what
    # moves the platform as the first samples do accelerate it away. (A static balance under
    # the file's torques is no measure: with the actuators free the platform's rotation is
    # nearly unstiffened, and a torque error of 1 % turns it by tenths of a radian.)
    dXdd, *_ = np.linalg.lstsq(A, tau0 - tau_need, rcond=None)
    T = START_HORIZON
    drift = 0.5 * dXdd * T**2
    if not np.all(np.isfinite(drift)) or _too_far(drift, np.zeros(3), fitted):
        raise StartError(
            f"{_where(exp)}: the torques tau = ({tau0[0]:.6g}, {tau0[1]:.6g}, {tau0[2]:.6g}) "
            f"N m are not what moves the platform as the first samples do (the robot at the "
            f"initial guess needs ({tau_need[0]:.6g}, {tau_need[1]:.6g}, {tau_need[2]:.6g}) "
            f"N m there): the difference accelerates it by ({dXdd[0]:.4g} m/s^2, "
            f"{dXdd[1]:.4g} m/s^2, {dXdd[2]:.4g} rad/s^2), {_distance(drift, np.zeros(3))} "
            f"away from the file's first pose {_pose(np.asarray(X0))} within "
            f"{START_HORIZON:g} s ({_allowed()}): the torques and the poses do not describe "
            f"one experiment (another sign or unit of the torques?)")


def check_scene_start(exps, scene, offsets, fitted=(True, True)) -> None:
    """Refuse (`StartError`) the first experiment whose first pose (`offsets[k]`: the start's
    fit of its first samples) is further than `START_TOLERANCE` from the named scene's own
    path at that time, in a fitted channel (`fitted`: position, orientation): the data do not
    come from that experiment."""
    import jax.numpy as jnp

    traj = scene.trajectory()
    for exp, X0 in zip(exps, offsets):
        t0 = float(np.asarray(exp.ts)[0])
        X = np.asarray(traj(jnp.asarray(t0)), dtype=np.float64)
        X0 = np.asarray(X0, dtype=np.float64)
        if _too_far(X, X0, fitted):
            raise StartError(
                f"{_where(exp)}: the file's first pose {_pose(X0)} is {_distance(X, X0)} from "
                f"where the {scene.name} scene starts, {_pose(X)} ({_allowed()}): the data do "
                f"not come from that experiment; without a scene (CLI: without --scene) the "
                f"fit follows the experiment that the data describe, driven by their own "
                f"angles or torques")
