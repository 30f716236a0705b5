"""The data's units and robot, checked against the nominal robot before anything is compiled.

`load_csv` checks the pose columns alone (a position 30 times off the workspace, |phi| > pi/2).
What it cannot see needs the robot: actuated angles in degrees or mrad, torques in N mm, poses
that this robot cannot reach (data from another robot or in another frame). A wrong column
otherwise ends in a failed simulation at the start of the fit, after minutes of compiling."""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..._data import DataError
from ..._kinematics import path_margins
from ..._models import Reduced

#: actuated angles (rad) further than this from the nominal robot's inverse kinematics of the
#: measured pose are not this robot's (the joints' deflections under load are some 10 mrad)
ANGLE_TOL = 0.3
#: torques (N m) above this many times the joint springs' stiffness K (N m/rad) would bend a
#: joint by this many radians: no flexure joint turns that far (measured data: |tau| / K ~ 1)
TORQUE_RATIO = 100.0
#: a pose out of the nominal robot's reach by more than this (its reach margin 1 - |cos| of
#: the chain's elbow below -REACH_SLACK: `_kinematics.PathMargins.reach`) is not this robot's;
#: measured poses a little beyond the nominal reach are noise or the joints' deflection
REACH_SLACK = 0.1
#: units an angle column is commonly mistaken in: (name, unit as declared, factor to SI)
_ANGLE_FACTORS = (("degrees", "deg", math.pi / 180.0), ("mrad", "mrad", 1e-3))
#: samples of each experiment checked (spread over its duration)
_SAMPLES = 5


def _wrap(x):
    return x - 2 * np.pi * np.round(x / (2 * np.pi))


@eqx.filter_jit
def _ik_samples(robot, X):
    """L1's reach check (`path_margins`) of the measured poses X (k, 3) (m, m, rad), one
    compiled program for the samples of an experiment. Returns the actuated angles th_i1
    (k, 3) (rad) and the reach margins (k, 3)."""
    margins = path_margins(Reduced(), robot, X)
    return margins.th_a, margins.reach


def check_plausible(experiments, params, scene: str, *, angles: bool, torques: bool) -> None:
    """Raise `DataError` naming the experiment, the column and the likely factor when the data
    cannot be this robot's in SI units. `params`: the nominal `RobotParams` (the unknowns at
    their initial values); `angles`, `torques`: the measured angles or torques drive the model
    (then they are checked). Host-side arithmetic and one small compiled inverse kinematics
    of a few samples per experiment, nothing compiled beyond it."""
    from ..._prb import derived
    from ..._robot import as_robot

    robot = as_robot(params)
    K = float(derived(params).K)
    for e in experiments:
        ts, X = np.asarray(e.ts), np.asarray(e.X)
        idx = np.unique(np.linspace(0, len(ts) - 1, _SAMPLES).round().astype(int))
        th_ik, margin = (np.asarray(v) for v in _ik_samples(robot, jnp.asarray(X[idx])))
        worst = np.unravel_index(np.argmin(margin), margin.shape)
        if margin[worst] < -REACH_SLACK:
            i, c = idx[worst[0]], worst[1] + 1
            raise DataError(
                f"{e.name}: the measured pose at time {ts[i]:.6g} s (x = {X[i, 0] * 1e3:.4g} mm, "
                f"y = {X[i, 1] * 1e3:.4g} mm, phi = {X[i, 2]:.4g} rad) is out of the reach of "
                f"chain {c} of this robot (scene {scene}, base side a = {float(params.a):.4g} "
                f"m): the data are far from any state the model reaches; data from another "
                f"robot or in another frame? (give its parameters: params= / --params-file)")
        if angles and e.th is not None:
            th = np.asarray(e.th)[idx]
            dev = np.abs(_wrap(th - th_ik))
            for j in range(3):
                if np.max(dev[:, j]) <= ANGLE_TOL:
                    continue
                col = f"th_{j + 1}"
                for unit, short, f in _ANGLE_FACTORS:
                    if np.max(np.abs(_wrap(th[:, j] * f - th_ik[:, j]))) <= ANGLE_TOL:
                        raise DataError(
                            f"{e.name}: column {col} looks like {unit} read as radians: it is "
                            f"{1 / f:.4g} times the angle this robot needs for the measured "
                            f"pose (at time {ts[idx[0]]:.6g} s: {th[0, j]:.6g} against "
                            f"{th_ik[0, j]:.4g} rad); declare the unit ('{col}[{short}]', '# "
                            f"units: angle={short}' or angle_unit='{short}' / --angle-unit "
                            f"{short})")
                k = int(np.argmax(dev[:, j]))
                raise DataError(
                    f"{e.name}: column {col} is {dev[k, j]:.3g} rad from the angle this robot "
                    f"needs for the measured pose (at time {ts[idx[k]]:.6g} s: {th[k, j]:.6g} "
                    f"against {th_ik[k, j]:.4g} rad; the joints deflect by some 0.01 rad): the "
                    f"data are far from any state the model reaches; another zero of the "
                    f"angles, another robot, or the angles in other units?")
        if torques and e.tau is not None:
            tau = np.abs(np.asarray(e.tau))
            ratio = tau.max(axis=0) / K
            j = int(np.argmax(ratio))
            if ratio[j] > TORQUE_RATIO:
                col = f"tau_{j + 1}"
                k = int(np.argmax(tau[:, j]))
                guess = (" probably N mm read as N m (a factor 1000): declare the unit "
                         f"('{col}[N mm]', '# units: torque=N mm' or load_csv(..., "
                         f"torque_unit='N mm'))"
                         if ratio[j] > 300 else " torques in other units, another robot, or an "
                         "initial thickness far too small?")
                raise DataError(
                    f"{e.name}: column {col} reaches {tau[k, j]:.4g} N m (time {ts[k]:.6g} s), "
                    f"{ratio[j]:.0f} times the joint springs' stiffness K = {K:.4g} N m/rad "
                    f"of this robot at the initial guess (strip thickness t = "
                    f"{float(params.t) * 1e3:.4g} mm): it would bend a joint by "
                    f"{ratio[j]:.0f} rad, far from any state the model reaches;{guess}")
