"""Synthetic experiments: a scene's output with independent Gaussian noise."""

from __future__ import annotations

import math
from typing import Optional, Union

import equinox as eqx
import jax
import numpy as np

from ..._data import DataError, Experiment
from ..._models import get_model
from ..._params import RobotParams
from ..._programs import cached_program
from ..._robot import Robot
from ..._scenes import T_END, AbstractScene, SceneOptions, get_scene, solve_scene


@eqx.filter_jit
def _actuated_angles(model, robot, z):
    return jax.vmap(lambda z: model.kinematics(robot, z).th_a)(z)


def check_synth_args(noise_pos, noise_phi, rate, t_end) -> None:
    """`synthesize`'s numbers, checked before anything is compiled (`DataError` naming them)."""
    for what, v in (("noise_pos", noise_pos), ("noise_phi", noise_phi), ("rate", rate),
                    ("t_end", t_end)):
        if not math.isfinite(v):  # a NaN noise wrote a file of NaN poses
            raise DataError(f"{what} must be finite: {v!r} is not finite")
    if not (rate > 0 and t_end > 0):
        raise DataError(f"rate and t_end must be > 0, got rate={rate}, t_end={t_end}")
    if noise_pos < 0 or noise_phi < 0:
        raise DataError(f"noise must be >= 0, got noise_pos={noise_pos}, noise_phi={noise_phi}")


def synthesize(
    scene: Union[str, AbstractScene] = "servo-circle",
    model="double1r",
    params: Optional[RobotParams] = None,
    *,
    noise_pos: float = 0.1e-3,
    noise_phi: float = 1e-3,
    rate: float = 100.0,
    t_end: float = T_END,
    seed: int = 0,
    name: str = "synthetic",
    n_elements: Optional[int] = None,
    program_dir: Optional[str] = None,
    **scene_kw,
) -> Experiment:
    """A tracker-like `Experiment` from a scene: the simulated pose with independent Gaussian
    noise, the actuated angles (noise-free: encoders are far finer than a tracker) and the
    torques (applied, or the reactions of a motion-driven scene).

    **Arguments:**

    - `scene`: a registered name (default `servo-circle`) or an `AbstractScene` (a `PathScene`
      on your own path).
    - `model`: the simulated model, a name or instance (default `double1r`, L2).
    - `params`: one `RobotParams`; None (default): the scene's.
    - `noise_pos`: standard deviation of the noise on x and y (m, >= 0, default 1e-4).
    - `noise_phi`: standard deviation of the noise on phi (rad, >= 0, default 1e-3).
    - `rate`: sampling rate (Hz, > 0, default 100).
    - `t_end`: the samples run from t = 0 to `t_end` (s, > 0, default 7.54), rounded down to
      whole samples.
    - `seed`: the noise's seed (`numpy.random.default_rng(seed)`, default 0).
    - `name`: the experiment's name (default "synthetic").
    - `n_elements`: beam elements per strip when `model` is `beam` (`get_model`).
    - `program_dir`: a directory of stored programs (`solve_scene`'s; the command line's), or
      None (default): compiled in this process.
    - `scene_kw`: `torque_model` (a registered torque-driven scene's) and `SceneOptions`'
      fields (solver, tolerances).

    **Returns:**

    An `Experiment` with ts (n,) s, X (n, 3) m, m, rad, th (n, 3) rad and tau (n, 3) N m.

    **Raises:**

    `DataError` for a non-finite, negative or zero number among `noise_pos`, `noise_phi`,
    `rate`, `t_end` (noise may be 0), fewer than 2 samples, or an unknown keyword in
    `scene_kw`.
    """
    scene_ = get_scene(scene, scene_kw.pop("torque_model", None))
    try:
        options = SceneOptions().updated(**scene_kw)
    except TypeError as err:
        raise DataError(f"synthesize: {err}") from None
    check_synth_args(noise_pos, noise_phi, rate, t_end)
    n = int(math.floor(t_end * rate + 1e-9)) + 1
    if n < 2:
        raise DataError(f"t_end = {t_end} s at {rate} Hz gives fewer than 2 samples")
    mdl = get_model(model, n_elements)
    params = scene_.default_params() if params is None else params
    res = solve_scene(scene_, params, model=mdl,
                      options=options.updated(t_end=(n - 1) / rate, n_out=n),
                      program_dir=program_dir)
    args = (mdl, Robot(params), res.z)
    angles = cached_program(_actuated_angles, args, 0, program_dir, f"synth-angles-{mdl.name}")
    th = np.asarray(angles(*args))
    rng = np.random.default_rng(seed)
    X = np.asarray(res.X).copy()
    X[:, :2] += noise_pos * rng.standard_normal((n, 2))
    X[:, 2] += noise_phi * rng.standard_normal(n)
    return Experiment(ts=np.asarray(res.ts), X=X, th=th, tau=np.asarray(res.tau), name=name)

