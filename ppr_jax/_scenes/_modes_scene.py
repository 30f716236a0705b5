"""Scene `modes`: natural frequencies about a static equilibrium (no time integration)."""

from __future__ import annotations

import time
from typing import Optional

import jax
import numpy as np

from .._models import get_model
from .._modes import modes as _modes
from .._params import RobotParams


def modes_scene(
    params: Optional[RobotParams] = None,
    *,
    model="double1r",
    actuators: str = "locked",
    X=None,
    program_dir: Optional[str] = None,
) -> dict:
    """Scene `modes`: natural frequencies (Hz, signed: negative = unstable) about the static
    equilibrium near pose X, actuators locked or free (`modes`).

    **Arguments:**

    - `params`: a `RobotParams`; None (default): Table 1.
    - `model`: a model name or instance (default `double1r`, L2).
    - `actuators`: "locked" (default) or "free", as `modes`.
    - `X`: (3,) pose near which the equilibrium is sought (m, m, rad); None (default): home.
    - `program_dir`: a directory of stored programs, as `modes`'.

    **Returns:**

    A dict (JSON-ready): scene, model, actuators, n_free_coordinates, frequencies_hz,
    unstable_growth_rates_per_s, eigenvalues_rad2_per_s2, equilibrium_z, a note and
    wall_time_s (s).

    **Raises:**

    `PPRError` as `modes`.
    """
    model = get_model(model)
    # `modes` is no registered scene: Table 1 (the command line's base for it too)
    params = RobotParams() if params is None else params
    t0 = time.perf_counter()
    r = _modes(model, params, X, actuators=actuators, program_dir=program_dir)
    jax.block_until_ready(r)
    wall = time.perf_counter() - t0
    free = len(r.free)
    return {
        "scene": "modes",
        "model": model.name,
        "actuators": actuators,
        "n_free_coordinates": free,
        "frequencies_hz": [float(f) for f in np.asarray(r.freq_hz)],
        "unstable_growth_rates_per_s": [float(g) for g in np.asarray(r.growth_rate) if g > 0],
        "eigenvalues_rad2_per_s2": [float(v) for v in np.asarray(r.eigvals)],
        "equilibrium_z": [float(v) for v in np.asarray(r.z_eq)],
        "note": (
            "no free coordinate: with locked actuators the pose of this model follows from the "
            "actuated angles (a kinematic model has no vibration modes)"
            if free == 0 else
            "negative frequency = unstable mode (negative stiffness), magnitude sqrt(|lambda|)/2pi"
        ),
        "wall_time_s": wall,
    }
