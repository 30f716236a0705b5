"""The scenes by name: a new scene is one file, one line here and its name in
`_names.SCENE_NAMES`."""

from __future__ import annotations

from typing import Union

from .._errors import PPRError
from .._models import get_model
from .._names import SCENES as SCENES  # every scene the command line runs, `modes` included
from .._params import RobotParams
from ._base import AbstractScene
from ._paper_circle import PaperCircle
from ._servo_circle import ServoCircle

#: the time-domain scenes by name (their names, in this order, are `_names.SCENE_NAMES`)
SCENE_CLASSES = {cls.name: cls for cls in (PaperCircle, ServoCircle)}
#: strip thickness of each scene (m): the paper's simulation uses 0.3 mm, its experiment 0.5 mm
SCENE_THICKNESS = {**{n: c.thickness for n, c in SCENE_CLASSES.items()}, "modes": 0.3e-3}


def get_scene(scene: Union[str, AbstractScene], torque_model=None) -> AbstractScene:
    """A scene instance from its name (or the instance itself). `torque_model` is the model
    whose inverse dynamics gives `paper-circle`'s torques (default L1)."""
    if isinstance(scene, AbstractScene):
        return scene
    if scene not in SCENE_CLASSES:
        allowed = ", ".join(SCENE_CLASSES)
        raise PPRError(f"unknown scene {scene!r}; allowed: {allowed} (or an AbstractScene)")
    cls = SCENE_CLASSES[scene]
    if cls is PaperCircle and torque_model is not None:
        return PaperCircle(torque_model=get_model(torque_model))
    return cls()


def scene_params(scene: Union[str, AbstractScene], **overrides) -> RobotParams:
    """Default parameters of a scene (Table 1 with the scene's strip thickness) with overrides
    applied."""
    if isinstance(scene, AbstractScene):
        return scene.default_params(**overrides)
    if scene not in SCENES:
        raise PPRError(f"unknown scene {scene!r}; allowed: {', '.join(SCENES)}")
    kw = {"t": SCENE_THICKNESS[scene]}
    kw.update(overrides)
    return RobotParams().replace(**kw)
