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


#: the output times are evaluated in this many vectorised chunks (`outputs`)
OUTPUT_CHUNKS = 5


def outputs(model: AbstractModel, robot: Robot, z, zdot) -> Outputs:
    robot = as_robot(robot)

    def one(z, zd):
        # one evaluation of the kinematics serves the pose, residual and both energies
        k, kd = jax.jvp(lambda z: model.kinematics(robot, z), (z,), (zd,))
        res = jnp.max(jnp.linalg.norm(model.loop_residual(robot, k), axis=-1))
        T, U = energy_of(model, robot, k, kd)
        return k.X, model.joint_end_rotations(robot, k)[0], res, T, U

    # Five chunks of output times, each vectorised: under a batch's vmap one chunk's
    # temporaries stay in cache (L1, 1,024 robots x 755 times: 20 % faster than one vmap)
    X, er, res, T, U = jax.lax.map(
        lambda a: one(*a), (z, zdot), batch_size=-(-z.shape[0] // OUTPUT_CHUNKS)
    )
    return Outputs(X=X, end_rot=er, residual=res, kinetic=T, potential=U)


def radial_error(X, center, radius):
    """e_r = |(x, y) - c| - R (m)."""
    return jnp.linalg.norm(X[..., :2] - center, axis=-1) - radius


def metric_arrays(out: Outputs, X_nominal, center, radius) -> dict:
    """The scene metrics as NumPy arrays over any leading batch axes of `out` (time is the
    last axis of the scalar outputs): one vectorised pass for a whole batch, where a loop of
    `metrics` per member cost more than the batch's simulation (1,024 L1 robots: 0.8 s)."""
    X = np.asarray(out.X)
    Xn = np.asarray(X_nominal)
    er = np.linalg.norm(X[..., :2] - np.asarray(center), axis=-1) - float(radius)
    dphi = X[..., 2] - Xn[..., 2]
    rot = np.degrees(np.asarray(out.end_rot))
    diff = rot[..., 0] - rot[..., 1]
    scale = np.maximum(np.abs(rot).max(axis=(-2, -1)), 1e-300)
    E = np.asarray(out.kinetic) + np.asarray(out.potential)
    return {
        "radial_error_max_m": er.max(-1),
        "radial_error_min_m": er.min(-1),
        "radial_error_mean_m": er.mean(-1),
        "radial_error_max_relative_percent": np.abs(er).max(-1) / float(radius) * 100,
        "position_error_max_m": np.linalg.norm(X[..., :2] - Xn[..., :2], axis=-1).max(-1),
        "phi_error_max_rad": np.abs(dphi).max(-1),
        "phi_error_rms_rad": np.sqrt(np.mean(dphi**2, axis=-1)),
        "end_rotation_1_max_deg": rot[..., 0].max(-1),
        "end_rotation_1_min_deg": rot[..., 0].min(-1),
        "end_rotation_2_max_deg": rot[..., 1].max(-1),
        "end_rotation_2_min_deg": rot[..., 1].min(-1),
        "end_rotation_diff_max_deg": diff.max(-1),
        "end_rotation_diff_min_deg": diff.min(-1),
        "end_rotation_diff_mean_deg": diff.mean(-1),
        "end_rotation_diff_max_relative_percent": np.abs(diff).max(-1) / scale * 100,
        "constraint_residual_max_m": np.asarray(out.residual).max(-1),
        "energy_initial_J": E[..., 0],
        "energy_final_J": E[..., -1],
        "energy_min_J": E.min(-1),
        "energy_max_J": E.max(-1),
    }


def metrics(out: Outputs, X_nominal, center, radius) -> dict:
    """The scene metrics (floats) from `outputs` and the nominal pose samples (m, 3)."""
    return {k: float(v) for k, v in metric_arrays(out, X_nominal, center, radius).items()}
