"""ppr_jax: differentiable dynamics of planar parallel robots with compliant joints.

float64 is enabled on import. See the documentation (docs/, `mkdocs serve`) for the model levels,
scenes and CLI.
"""

from typing import TYPE_CHECKING as _TYPE_CHECKING

import jax as _jax

_jax.config.update("jax_enable_x64", True)

from ._params import (  # noqa: E402
    RobotParams as RobotParams,
    PARAM_RANGES as PARAM_RANGES,
    stack_params as stack_params,
    unstack_params as unstack_params,
)
from ._params_file import load_params as load_params, save_params as save_params  # noqa: E402
from ._prb import Derived as Derived, derived as derived  # noqa: E402
from ._robot import Robot as Robot, RobotLike as RobotLike  # noqa: E402
from ._models import (  # noqa: E402
    MODELS as MODELS,
    AbstractModel as AbstractModel,
    AbstractClosedLoop as AbstractClosedLoop,
    AbstractDouble1R as AbstractDouble1R,
    Kin as Kin,
    Motion as Motion,
    Rigid as Rigid,
    Reduced as Reduced,
    Double1R as Double1R,
    AbstractBeam as AbstractBeam,
    QuasiStaticBeam as QuasiStaticBeam,
    STRIP_DYNAMICS as STRIP_DYNAMICS,
    get_model as get_model,
)
from ._mjcf import to_mjcf as to_mjcf  # noqa: E402
from ._models.beam import (  # noqa: E402
    Beam as Beam,
    solve_strip as solve_strip,
    strip_constants as strip_constants,
)
from ._errors import (  # noqa: E402
    PPRError as PPRError,
    RESULTS as RESULTS,
    RepairWarning as RepairWarning,
    SimulationError as SimulationError,
)
from ._geometry import home_pose as home_pose  # noqa: E402
from ._kinematics import (  # noqa: E402
    IKResult as IKResult,
    inverse_kinematics as inverse_kinematics,
    forward_kinematics as forward_kinematics,
    forward_kinematics_path as forward_kinematics_path,
    jacobians as jacobians,
    predeflection as predeflection,
)
from ._dynamics import (  # noqa: E402
    EOM as EOM,
    eom_terms as eom_terms,
    energy as energy,
    inverse_dynamics as inverse_dynamics,
)
from ._trajectory import (  # noqa: E402
    Circle as Circle,
    Hold as Hold,
    Interpolated as Interpolated,
    derivatives as derivatives,
)
from ._paths import (  # noqa: E402
    Line as Line,
    Waypoints as Waypoints,
    Fourier as Fourier,
    CommandLog as CommandLog,
    load_path as load_path,
    load_commands as load_commands,
    check_same_rate as check_same_rate,
)
from ._actuation import (  # noqa: E402
    AbstractActuation as AbstractActuation,
    TorqueDriven as TorqueDriven,
    MotionDriven as MotionDriven,
    PDServo as PDServo,
    InverseDynamicsTorque as InverseDynamicsTorque,
    InverseKinematicsAngles as InverseKinematicsAngles,
)
from ._simulate import (  # noqa: E402
    simulate as simulate,
    Solution as Solution,
)
from ._esdirk import KeptKvaerno5 as KeptKvaerno5  # noqa: E402
from ._rosw import Ros34PW2 as Ros34PW2  # noqa: E402
from ._statics import (  # noqa: E402
    static_equilibrium as static_equilibrium,
    quasi_static_state as quasi_static_state,
)
from ._modes import Modes as Modes, modes as modes  # noqa: E402
from ._metrics import (  # noqa: E402
    outputs as outputs,
    metrics as metrics,
    metric_table as metric_table,
)
from ._scenes import (  # noqa: E402
    AbstractScene as AbstractScene,
    PaperCircle as PaperCircle,
    PathScene as PathScene,
    register_scene as register_scene,
    SceneInput as SceneInput,
    SceneOptions as SceneOptions,
    SceneResult as SceneResult,
    ServoCircle as ServoCircle,
    solve_scene as solve_scene,
    nominal_torques as nominal_torques,
    paper_circle as paper_circle,
    servo_circle as servo_circle,
    modes_scene as modes_scene,
    scene_params as scene_params,
)
from ._scenes import (  # noqa: E402
    SceneReport as SceneReport,
    run_scene as run_scene,
    scene_metrics as scene_metrics,
)

from ._cache import enable_compilation_cache as enable_compilation_cache  # noqa: E402
from ._devices import configure_cpu as configure_cpu, cpu_flags as cpu_flags  # noqa: E402
from ._studies import (  # noqa: E402
    SweepResult as SweepResult,
    sweep as sweep,
    shard_batch as shard_batch,
    design_members as design_members,
)
from ._studies import (  # noqa: E402
    Sensitivity as Sensitivity,
    sensitivity as sensitivity,
    base_frequency as base_frequency,
)

from ._prb_table import (  # noqa: E402
    prb_parameters as prb_parameters,
    prb_table as prb_table,
)

from ._data import (  # noqa: E402
    DataError as DataError,
    Experiment as Experiment,
    experiment as experiment,
    load_csv as load_csv,
    load_experiments as load_experiments,
    write_csv as write_csv,
)
from ._studies import (  # noqa: E402
    Identification as Identification,
    IdentificationError as IdentificationError,
    identify as identify,
    synthesize as synthesize,
)

try:
    from importlib.metadata import PackageNotFoundError as _PackageNotFoundError
    from importlib.metadata import version as _version

    __version__ = _version("ppr_jax")
except _PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0+unknown"

# The offline PRB fit and the elastica solver it uses (and scipy.optimize) are loaded on first
# access (PEP 562), so that `import ppr_jax` stays light: the robot needs only the shipped table.
_LAZY = {
    "fit_prb": "._prb_fit",
    "prb_error": "._prb_fit",
    "elastica": ".elastica",
}

if _TYPE_CHECKING:
    from . import elastica as elastica  # noqa: F401
    from ._prb_fit import fit_prb as fit_prb, prb_error as prb_error  # noqa: F401


def __getattr__(name):
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    module = importlib.import_module(_LAZY[name], __name__)
    value = module if name == "elastica" else getattr(module, name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
