"""The scenes wing: one interface (`AbstractScene`, `SceneOptions`), one file per scene, one
registry line per scene (`_registry.py`), one batch mapper (`_batch.py`)."""

from ._base import (
    AbstractScene,
    SceneInput,
    check_scene_commands,
    kinematic_motion,
    motion_input,
    path_out_of_reach,
    tabulated,
    torque_input,
)
from ._batch import (
    MEMBER_CHUNK,
    batch_devices,
    chunked_vmap,
    compress_shared,
    map_members,
    on_host_threads,
    shared_mask,
)
from ._modes_scene import modes_scene
from ._options import (
    ATOL,
    MAX_STEPS,
    N_OUT,
    RTOL,
    T_END,
    SceneOptions,
    check_scene_args,
    deprecated_keywords,
    input_panels,
    input_panels_at,
    options_from,
)
from ._paper_circle import PaperCircle
from ._path_scene import DRIVES, PathScene, experiment_drive, experiment_scene
from ._registry import SCENES, get_scene, register_scene, scene_names, scene_params
from ._report import SceneReport, run_scene, scene_metrics
from ._result import SceneResult, failure_detail, finish, result_template
from ._run import SceneCall, paper_circle, prepare, servo_circle, solve_scene
from ._servo_circle import ServoCircle
from ._torques import nominal_torques

__all__ = [
    "ATOL", "AbstractScene",
    "MAX_STEPS", "N_OUT", "RTOL", "T_END",
    "DRIVES", "MEMBER_CHUNK", "PaperCircle", "PathScene", "SCENES", "SceneReport",
    "SceneCall", "SceneInput", "SceneOptions",
    "SceneResult", "ServoCircle", "batch_devices", "check_scene_args", "options_from",
    "deprecated_keywords",
    "check_scene_commands", "chunked_vmap",
    "failure_detail", "finish", "get_scene", "input_panels", "input_panels_at",
    "compress_shared", "experiment_drive", "experiment_scene", "kinematic_motion",
    "map_members", "on_host_threads", "modes_scene", "motion_input", "nominal_torques",
    "paper_circle",
    "path_out_of_reach", "prepare", "result_template", "run_scene", "scene_metrics",
    "register_scene", "scene_names", "scene_params", "servo_circle", "shared_mask",
    "solve_scene",
    "tabulated", "torque_input",
]
