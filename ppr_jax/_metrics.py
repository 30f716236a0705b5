"""Metrics of MODEL.md section 6, in the paper's terms.

`outputs` (jit-able, vmappable) turns a trajectory of coordinates into physical signals; `metrics`
reduces them to the numbers the paper reports. JSON keys are SI (m, rad, J, s) except where the key
says otherwise (`_deg`, `_percent`).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._custom_types import Array
from ._dynamics import energy_of
from ._models import AbstractModel
from ._robot import Robot, as_robot


class Outputs(eqx.Module):
    """Signals at the output times: X (m, 3) pose; end_rot (m, 2) rotations of chain 1's
    compliant-joint ends (rad, see `AbstractModel.joint_end_rotations`); residual (m,) max
    loop-closure residual (m); kinetic, potential (m,) energy (J)."""

    X: Array
    end_rot: Array
    residual: Array
    kinetic: Array
    potential: Array


def outputs(model: AbstractModel, robot: Robot, z, zdot) -> Outputs:
    robot = as_robot(robot)

    def one(z, zd):
        # one evaluation of the kinematics serves the pose, residual and both energies
        k, kd = jax.jvp(lambda z: model.kinematics(robot, z), (z,), (zd,))
        res = jnp.max(jnp.linalg.norm(model.loop_residual(robot, k), axis=-1))
        T, U = energy_of(model, robot, k, kd)
        return k.X, model.joint_end_rotations(robot, k)[0], res, T, U

    X, er, res, T, U = jax.vmap(one)(z, zdot)
    return Outputs(X=X, end_rot=er, residual=res, kinetic=T, potential=U)


def radial_error(X, center, radius):
    """e_r = |(x, y) - c| - R (m)."""
    return jnp.linalg.norm(X[..., :2] - center, axis=-1) - radius


def metrics(out: Outputs, X_nominal, center, radius) -> dict:
    """The scene metrics (floats) from `outputs` and the nominal pose samples (m, 3)."""
    X = np.asarray(out.X)
    Xn = np.asarray(X_nominal)
    er = np.asarray(radial_error(X, np.asarray(center), float(radius)))
    dphi = X[:, 2] - Xn[:, 2]
    rot = np.degrees(np.asarray(out.end_rot))
    diff = rot[:, 0] - rot[:, 1]
    scale = max(float(np.max(np.abs(rot))), 1e-300)
    E = np.asarray(out.kinetic) + np.asarray(out.potential)
    return {
        "radial_error_max_m": float(er.max()),
        "radial_error_min_m": float(er.min()),
        "radial_error_mean_m": float(er.mean()),
        "radial_error_max_relative_percent": float(np.abs(er).max() / float(radius) * 100),
        "position_error_max_m": float(np.linalg.norm(X[:, :2] - Xn[:, :2], axis=-1).max()),
        "phi_error_max_rad": float(np.abs(dphi).max()),
        "phi_error_rms_rad": float(np.sqrt(np.mean(dphi**2))),
        "end_rotation_1_max_deg": float(rot[:, 0].max()),
        "end_rotation_1_min_deg": float(rot[:, 0].min()),
        "end_rotation_2_max_deg": float(rot[:, 1].max()),
        "end_rotation_2_min_deg": float(rot[:, 1].min()),
        "end_rotation_diff_max_deg": float(diff.max()),
        "end_rotation_diff_min_deg": float(diff.min()),
        "end_rotation_diff_mean_deg": float(diff.mean()),
        "end_rotation_diff_max_relative_percent": float(np.abs(diff).max() / scale * 100),
        "constraint_residual_max_m": float(np.asarray(out.residual).max()),
        "energy_initial_J": float(E[0]),
        "energy_final_J": float(E[-1]),
        "energy_min_J": float(E.min()),
        "energy_max_J": float(E.max()),
    }
