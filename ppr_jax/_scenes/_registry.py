"""The scenes by name, in one registry: a new scene is one file, one line here and its name in
`_names.SCENE_NAMES` (the command line's choices, read without JAX), or one call of
`register_scene` from your own code."""

from __future__ import annotations

import dataclasses
from typing import Callable, Union

from .._errors import PPRError
from .._models import get_model
from .._params import RobotParams
from ._base import AbstractScene
from ._paper_circle import PaperCircle
from ._servo_circle import ServoCircle

#: the registry: name -> a factory of the scene (a scene class, or a function returning an
#: `AbstractScene`); the command line's `--scene` choices
SCENES: dict[str, Callable[..., AbstractScene]] = {
    cls.name: cls for cls in (PaperCircle, ServoCircle)
}


def register_scene(name: str, factory: Union[AbstractScene, Callable[..., AbstractScene]]
                   ) -> None:
    """Register a scene under `name`, so that `run_scene(name)`, the studies and
    identification find it: a scene instance (for example a `PathScene` on your path), or a
    function of no arguments returning one. Replaces an earlier scene of that name."""
    if not isinstance(name, str) or not name:
        raise PPRError(f"a scene's name must be a non-empty string, got {name!r}")
    if isinstance(factory, AbstractScene):
        scene = factory
        factory = lambda: scene  # noqa: E731
    elif not callable(factory):
        raise PPRError(f"register_scene({name!r}, ...) takes an AbstractScene or a function "
                       f"returning one, got {type(factory).__name__}")
    SCENES[name] = factory


def scene_names() -> tuple:
    """The registered scenes' names."""
    return tuple(SCENES)


def get_scene(scene: Union[str, AbstractScene], torque_model=None) -> AbstractScene:
    """A scene instance from its registered name (or the instance itself). `torque_model`:
    the model whose inverse dynamics gives a torque-driven registered scene's torques, for a
    scene that has that field (`PaperCircle`; default its own)."""
    if isinstance(scene, AbstractScene):
        return scene
    if not isinstance(scene, str) or scene not in SCENES:
        raise PPRError(f"unknown scene {scene!r}; allowed: {', '.join(SCENES)} (or an "
                       f"AbstractScene, such as a PathScene)")
    factory = SCENES[scene]
    # A registered scene class builds the same immutable module every time: built once per
    # (class, torque model named), as a warm call's scene took 50-120 us to build on a 2-core
    # CPU. A factory function is called every time (it may build a different scene).
    key = (scene, factory, torque_model) if (
        isinstance(factory, type) and (torque_model is None or isinstance(torque_model, str))
    ) else None
    obj = _BUILT.get(key) if key is not None else None
    if obj is not None:
        return obj
    obj = factory()
    if not isinstance(obj, AbstractScene):
        raise PPRError(f"the scene registered as {scene!r} made a {type(obj).__name__}, "
                       f"not an AbstractScene")
    if torque_model is not None and "torque_model" in {f.name for f in dataclasses.fields(obj)}:
        obj = dataclasses.replace(obj, torque_model=get_model(torque_model))
    if key is not None:
        _BUILT[key] = obj
    return obj


#: the registered scene classes' instances (`get_scene`), keyed by (name, class, torque model)
_BUILT: dict = {}


def scene_params(scene: Union[str, AbstractScene], **overrides) -> RobotParams:
    """Default parameters of a scene (Table 1 with the scene's strip thickness) with overrides
    applied."""
    return get_scene(scene).default_params(**overrides)
