"""The start of each experiment, checked on the host before the simulation is compiled.

A fit whose simulation starts where the data do not is hopeless: the robot released 100 mm from
where the file says it was runs for minutes and fails with a solver error that names no cause.
So, before anything is traced, every experiment's first sample is checked against the model at
the initial guess of the parameters (the kinematic model L1, whose closed-form inverse kinematics
costs nothing on the host):

- its pose is within the chains' reach (no state of the model reaches it otherwise);
- motion drive: its actuated angles, at every sample, belong to the assembly mode of the
  sample's pose (the elbow orientation sigma of every chain; angles beyond two turns are named
  as degrees first: `_assembly.check_assembly_mode`, the one check of every angle input), and
  the first ones put the platform (L1's forward kinematics, Newton from the file's pose) within
  `START_TOLERANCE` of the file's pose;
- torque drive: its torques are those that move the platform as its first samples do (L1's
  inverse dynamics at the start's pose, rate and acceleration): the acceleration that the
  difference leaves may move the platform by at most `START_TOLERANCE` within
  `START_HORIZON` (0.1 s);
- a named scene (one of the paper's experiments): the file's first pose is within
  `START_TOLERANCE` of the scene's own start.

Each refusal is a `StartError` naming the experiment, the sample, the time and the distance.
"""

from __future__ import annotations

import numpy as np

from ..._assembly import (
    HostGeometry as _Geometry,
    check_assembly_mode,
    pose_text as _pose,
    wrap as _wrap,
)
from ..._errors import IdentificationError

#: how far (position m, orientation rad) the state that the commands give at the first sample
#: may lie from the file's first pose: beyond it the data and the commands (or the scene) do
#: not describe one experiment. A parameter within its range moves the pose under given angles
#: by millimetres (gamma by 0.1: about 3 mm); a scene started elsewhere is off by centimetres.
START_TOLERANCE = (1e-2, 0.1)
#: the time (s) over which the acceleration that a torque drive's first torques leave unexplained
#: may move the platform by at most START_TOLERANCE
START_HORIZON = 0.1


class StartError(IdentificationError):
    """An experiment's first sample cannot start the model: its pose is out of reach, its
    commands put the platform elsewhere (or cannot hold it there), its angles belong to another
    assembly mode, or a named scene starts elsewhere. Raised before anything is compiled."""


def _where(exp, i: int = 0) -> str:
    return f"{exp.name}: sample {i + 1} (t = {float(np.asarray(exp.ts)[i]):.6g} s)"


def _distance(X, X0) -> str:
    return (f"{1e3 * float(np.hypot(*(X[:2] - X0[:2]))):.4g} mm and "
            f"{abs(float(X[2] - X0[2])):.3g} rad")


def _too_far(X, X0, fitted=(True, True)) -> bool:
    """X further than `START_TOLERANCE` from X0 in a fitted channel (`fitted`: position,
    orientation; a channel of infinite noise is not fitted, and its data are not checked)."""
    return bool((fitted[0] and not np.hypot(*(X[:2] - X0[:2])) <= START_TOLERANCE[0])
                or (fitted[1] and not abs(X[2] - X0[2]) <= START_TOLERANCE[1]))


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
        own, _, c = geo.ik(X0)
        _, dist = geo.chains(X0)
        far = geo.reach(c, dist)
        if far:
            raise StartError(f"{_where(exp)}: no state of the model reaches the pose "
                             f"{_pose(X0)}: {far}")
        if drive == "motion":
            _check_angles(exp, geo, X0, own, fitted)
        else:
            _check_torques(exp, geo, start, fitted)


def _check_angles(exp, geo, X0, own, fitted):
    # the one check of any angle input's units and assembly mode, at every sample
    check_assembly_mode(exp.th, exp.X, None, lambda i: _where(exp, i), error=StartError,
                        geometry=geo)
    th = np.asarray(exp.th[0], dtype=np.float64)
    d_own = np.abs(_wrap(th - own))
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
