"""The inverse-dynamics torques along a scene's nominal path (what `paper-circle` tabulates)."""

from __future__ import annotations

from typing import Optional, Union

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._actuation import InverseDynamicsTorque
from .._errors import PPRError, check_number
from .._kinematics import inverse_kinematics
from .._models import get_model
from .._params import RobotParams
from .._programs import cached_program
from ._base import AbstractScene
from ._options import N_OUT, T_END
from ._registry import get_scene


@eqx.filter_jit
def _torques_at(torque: InverseDynamicsTorque, ts):
    """The torques (n, 3) at the times ts (n,): a function of its arguments, so that the robot
    and the path's arrays are the program's inputs (one stored program for any values)."""
    return jax.vmap(torque)(ts)


def nominal_torques(
    params: Optional[RobotParams] = None,
    *,
    model="reduced",
    scene: Union[str, AbstractScene] = "paper-circle",
    t_end: float = T_END,
    n_out: int = N_OUT,
    trajectory=None,
    program_dir: Optional[str] = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The actuator torques that move a kinematic model (L0 or L1) along the scene's nominal path,
    by inverse dynamics (MODEL.md section 5), at `n_out` equal steps over [0, t_end].

    The path is checked for reach and singularity at every output time first
    (`inverse_kinematics`), so a bad path is a `PPRError` naming the cause, never NaN torques.

    **Arguments:**

    - `params`: one robot (default: the scene's).
    - `model`: `"rigid"` or `"reduced"` (a model whose pose is its coordinates).
    - `scene`: whose nominal path (default `paper-circle`, eq 55); `trajectory` replaces it.
    - `t_end`, `n_out`: horizon (s) and number of output times.
    - `program_dir`: a directory of stored programs (`run_scene`'s; the command line's): the
      torques' program is loaded from there, or exported there on first use; None: compiled in
      this process.

    **Returns:** `(ts, tau)`: (n_out,) times (s) and (n_out, 3) torques (N m).
    """
    scene = get_scene(scene)
    params = scene.default_params() if params is None else params
    check_number("t_end", t_end, 0.0, 1e5, "s", open_lo=True)
    check_number("n_out", n_out, 2, 10_000_000, integer=True)
    model = get_model(model)
    if model.actuated_index is not None:
        raise PPRError(f"nominal torques need a model whose pose is its coordinates (rigid or "
                       f"reduced), not {model.name!r}")
    traj = scene.trajectory() if trajectory is None else trajectory
    ts = jnp.linspace(0.0, t_end, n_out)
    inverse_kinematics(params, jax.vmap(traj)(ts), model)
    args = (InverseDynamicsTorque(model, params, traj), ts)
    tau = np.asarray(cached_program(_torques_at, args, 0, program_dir,
                                    f"torques-{model.name}")(*args))
    if not np.all(np.isfinite(tau)):
        raise PPRError("inverse dynamics produced non-finite torques (singular configuration)")
    return np.asarray(ts), tau
