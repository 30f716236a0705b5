"""The argument checks of `sweep`, before anything is compiled: the scene and its base robot, the
chunk size against the devices, the options (the scenes' checks), the model against the scene
(a warning where its tracking error is the solver's), and the settings the sweep records and
keys its stored chunks by."""

from __future__ import annotations

import dataclasses
import hashlib
import warnings

import equinox as eqx
import numpy as np

from .._errors import PPRError, check_number
from .._models import get_model
from .._scenes import SceneOptions, check_scene_commands, get_scene


def plain(v):
    """A parameter field as JSON: None, a static choice (int, str) as is, else a float."""
    return v if v is None or isinstance(v, (int, str)) else float(v)


def check_arguments(scene, base_params, torque_model, chunk_size, devices, options,
                    option_fields: dict) -> tuple:
    """`sweep`'s scene (`get_scene`), base robot (one, not a batch; default the scene's),
    `chunk_size` (1 to 10^6, divisible by the number of `devices`) and options (`options` with
    `option_fields` replacing its fields where not None, checked: a NaN rtol would run every
    member to max_steps, max_steps 0 fail every member inside diffrax).

    **Returns:** (the scene, the base `RobotParams`, chunk_size, the devices as a list or None,
    the checked `SceneOptions`)."""
    scene_ = get_scene(scene, torque_model)
    base = scene_.default_params() if base_params is None else base_params
    if np.ndim(base.a) != 0:
        raise PPRError("base_params must be one robot, not a batch")
    chunk_size = check_number("chunk_size", chunk_size, 1, 10**6, integer=True)
    devices = None if devices is None else list(devices)
    if devices is not None and chunk_size % len(devices):
        raise PPRError(f"chunk_size {chunk_size} must be divisible by the number of devices "
                       f"({len(devices)})")
    opts = (SceneOptions() if options is None else options).updated(**option_fields).check()
    return scene_, base, chunk_size, devices, opts


def check_model(scene_, model, base, opts: SceneOptions) -> tuple:
    """The swept model (`get_model`), with a `UserWarning` (at `sweep`'s caller) where it
    follows the scene's input (its tracking-error columns are the solver's error), and the
    options prepared for it; the scene's commands checked against the base robot.

    **Returns:** (the model, the prepared `SceneOptions`)."""
    model_ = get_model(model)
    follows = scene_.follows_its_input(model_)
    if follows:
        warnings.warn(
            f"model {model_.name!r} in {scene_.name!r}: {follows}; the tracking-error columns "
            f"of this sweep are the solver's error, not the robot's (sweep double1r or beam, "
            f"or drive it by another model's input, for a physical one)", UserWarning,
            stacklevel=3)
    prepared = opts.prepared(model_, scene_.trajectory())
    check_scene_commands(scene_, base, prepared.trajectory, opts.t_end)
    return model_, prepared


def settings(scene, scene_, model_, base, opts: SceneOptions, trajectory, *, vary, design, n,
             seed, chunk_size) -> dict:
    """The sweep's settings (`SweepResult.info`, and the digest of its stored chunks): the
    scene, models, design, options and the base robot; for a scene object (not a registered
    name), a digest of it and its path, which decide the numbers."""
    rtol, atol = opts.tolerances(model_)
    info = dict(scene=scene_.name, model=model_.name,
                input_model=scene_.input_model.name, design=design, n=n,
                seed=seed, vary={k: [float(x) for x in np.atleast_1d(v)] for k, v in
                                 (vary or {}).items()},
                t_end=float(opts.t_end), n_out=int(opts.n_out), solver=str(opts.solver),
                rtol=float(rtol), atol=float(atol), max_steps=int(opts.max_steps),
                chunk_size=chunk_size,
                base={f.name: plain(getattr(base, f.name)) for f in dataclasses.fields(base)})
    if not isinstance(scene, str):
        info["scene_digest"] = hashlib.sha256(eqx.tree_pformat(
            (scene_, trajectory), short_arrays=False).encode()).hexdigest()[:16]
    return info
