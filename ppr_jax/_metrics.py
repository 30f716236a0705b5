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
    """The output signals of a solution: pose, joint-end rotations, loop residual and energies.

    **Arguments:**

    - `model`: the model (L0-L3) whose coordinates `z` are.
    - `robot`: a `Robot` or `RobotParams`.
    - `z`, `zdot`: (m, n) coordinates and their rates at the m output times.

    **Returns:**

    `Outputs`: X (m, 3) pose (m, m, rad); end_rot (m, 2) rotations of chain 1's compliant-joint
    ends (rad); residual (m,) max loop-closure residual (m); kinetic, potential (m,) energy (J).
    """
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


def radial_error(X, center, radius, xp=jnp):
    """e_r = |(x, y) - c| - R (m) of poses X (..., 3), centre c (2,), radius R (m)."""
    c = xp.reshape(xp.asarray(center), (1,) * (X.ndim - 1) + (2,))
    return xp.linalg.norm(X[..., :2] - c, axis=-1) - radius


def _safe_sqrt(x, xp):
    """sqrt(x) for x >= 0 whose derivative at 0 is 0 rather than NaN: a model that starts on the
    path has a zero position error at t0, and a forward-mode tangent through sqrt(0) (or a
    norm of a zero vector) is NaN even where `max` then discards it."""
    pos = x > 0
    return xp.where(pos, xp.sqrt(xp.where(pos, x, 1.0)), 0.0)


def _extreme(x, axis, xp, largest: bool):
    """The max (or min) of x over `axis` (an int or the two last axes), as the element at the
    arg-max: its derivative is that element's. `jnp.max`'s own derivative spreads the tangent
    over the elements equal to the result, and XLA may compute the reduction and that equality
    test from two copies of x that round differently: no element then equals the result and
    the derivative is 0/0 (seen under LLVM -O0: the end-rotation difference's derivative over
    the whole paper circle NaN, 1243.15 under -O2). NaN propagates as in `max` (argmax points
    at it). On the host (numpy) the plain reduction."""
    if xp is np:
        return np.max(x, axis=axis) if largest else np.min(x, axis=axis)
    if isinstance(axis, tuple):  # the two last axes
        x, axis = x.reshape(*x.shape[:-2], -1), -1
    i = jnp.argmax(x, axis=axis) if largest else jnp.argmin(x, axis=axis)
    return jnp.take_along_axis(x, jnp.expand_dims(i, axis), axis=axis).squeeze(axis)


def _max(x, axis, xp):
    return _extreme(x, axis, xp, True)


def _min(x, axis, xp):
    return _extreme(x, axis, xp, False)


def is_circle(trajectory) -> bool:
    """Whether `trajectory` is a circle: a `center` and a `radius` (its radial error is
    defined)."""
    return (getattr(trajectory, "center", None) is not None
            and getattr(trajectory, "radius", None) is not None)


def metric_table(res, trajectory, xp=jnp) -> dict:
    """The scene metrics of MODEL.md section 6, computed once for every user: inside the
    compiled programs of sweeps and sensitivities (`xp=jax.numpy`: traced, vmappable,
    differentiable) and on the host for reports (`xp=numpy`: one vectorised pass for a whole
    batch, where a loop per member cost more than the batch's simulation).

    **Arguments:**

    - `res`: a `SceneResult` (or anything with its signals: X, X_nominal, end_rot, residual,
      kinetic, potential, and optionally tau), with any leading batch axes; time is the axis
      after them.
    - `trajectory`: the nominal path; the radial-error metrics need a circle (`is_circle`:
      a `center` and a `radius`), the others hold for any path.
    - `xp`: the array namespace (`jax.numpy` or `numpy`).

    **Returns:** {name: array over the batch axes}, SI unless the name says otherwise
    (`_deg`, `_percent`). Radial error e_r = |(x, y) - c| - R (m); its max and min are the
    exact max / min over the output samples, whose derivative is that of the arg-max sample (a
    subgradient, exact while the arg-max sample does not change). Position and phi errors
    against the nominal pose (the largest, the RMS over the output times, at the last one);
    chain 1's joint end rotations and their difference (deg); the peak actuator torque
    max |tau| (N m); the largest loop-closure residual (m); the energy.
    """
    X, Xn = xp.asarray(res.X), xp.asarray(res.X_nominal)
    out = {}
    if is_circle(trajectory):
        # in xp's arrays (numpy on the host: no XLA program per operation)
        radius = xp.asarray(trajectory.radius)
        er = radial_error(X, trajectory.center, radius, xp)
        out.update(
            radial_error_max_m=_max(er, -1, xp),
            radial_error_min_m=_min(er, -1, xp),
            radial_error_mean_m=xp.mean(er, axis=-1),
            radial_error_max_relative_percent=_max(xp.abs(er), -1, xp) / radius * 100,
        )
    dphi = X[..., 2] - Xn[..., 2]
    dpos2 = xp.sum((X[..., :2] - Xn[..., :2]) ** 2, axis=-1)
    dpos = _safe_sqrt(dpos2, xp)
    rot = xp.degrees(xp.asarray(res.end_rot))
    diff = rot[..., 0] - rot[..., 1]
    scale = xp.maximum(_max(xp.abs(rot), (-2, -1), xp), 1e-300)
    E = xp.asarray(res.kinetic) + xp.asarray(res.potential)
    out.update(
        position_error_max_m=_max(dpos, -1, xp),
        position_error_rms_m=_safe_sqrt(xp.mean(dpos2, axis=-1), xp),
        position_error_end_m=dpos[..., -1],
        phi_error_max_rad=_max(xp.abs(dphi), -1, xp),
        phi_error_rms_rad=_safe_sqrt(xp.mean(dphi**2, axis=-1), xp),
        phi_error_end_rad=xp.abs(dphi[..., -1]),
        end_rotation_1_max_deg=_max(rot[..., 0], -1, xp),
        end_rotation_1_min_deg=_min(rot[..., 0], -1, xp),
        end_rotation_2_max_deg=_max(rot[..., 1], -1, xp),
        end_rotation_2_min_deg=_min(rot[..., 1], -1, xp),
        end_rotation_diff_max_deg=_max(diff, -1, xp),
        end_rotation_diff_min_deg=_min(diff, -1, xp),
        end_rotation_diff_mean_deg=xp.mean(diff, axis=-1),
        end_rotation_diff_max_relative_percent=_max(xp.abs(diff), -1, xp) / scale * 100,
        constraint_residual_max_m=_max(xp.asarray(res.residual), -1, xp),
        energy_initial_J=E[..., 0],
        energy_final_J=E[..., -1],
        energy_min_J=_min(E, -1, xp),
        energy_max_J=_max(E, -1, xp),
    )
    tau = getattr(res, "tau", None)
    if tau is not None:
        out["torque_peak_Nm"] = _max(xp.abs(xp.asarray(tau)), (-2, -1), xp)
    return out


class _Signals(eqx.Module):
    X: Array
    X_nominal: Array
    end_rot: Array
    residual: Array
    kinetic: Array
    potential: Array


class _Circle(eqx.Module):
    center: Array
    radius: Array


def metric_arrays(out: Outputs, X_nominal, center, radius) -> dict:
    """`metric_table` (NumPy) of `outputs` and the nominal pose samples (m, 3) about the circle
    (center (2,), radius) (m): arrays over any leading batch axes."""
    sig = _Signals(X=out.X, X_nominal=X_nominal, end_rot=out.end_rot, residual=out.residual,
                   kinetic=out.kinetic, potential=out.potential)
    sig = jax.tree_util.tree_map(np.asarray, sig)
    return metric_table(sig, _Circle(np.asarray(center), float(radius)), xp=np)


def metrics(out: Outputs, X_nominal, center, radius) -> dict:
    """The scene metrics (floats) from `outputs` and the nominal pose samples (m, 3).

    **Arguments:**

    - `out`: the `Outputs` of one run (no batch axis).
    - `X_nominal`: (m, 3) nominal pose at the same output times (m, m, rad).
    - `center`: (2,) centre of the reference circle (m).
    - `radius`: radius of the reference circle (m).

    **Returns:**

    A dict {metric name: float} (`metric_table`).
    """
    return {k: float(v) for k, v in metric_arrays(out, X_nominal, center, radius).items()}
