"""ppr_jax: differentiable dynamics of planar parallel robots with compliant joints.

float64 is enabled on import. See the documentation (docs/, `mkdocs serve`) for the model levels,
scenes and CLI.

The public names are loaded on first access (PEP 562 `__getattr__`): `import ppr_jax` imports
neither JAX nor the numerical modules, so the command line answers `--help` at once and a
program loads only what it uses; `from ppr_jax import simulate` imports what `simulate` needs.
float64 is enabled all the same: where JAX is imported already, at once; otherwise through
`JAX_ENABLE_X64=1` in the environment, which JAX reads when it is first imported (and which
child processes inherit). Likewise XLA's CPU settings that the library was measured with (the
loop emitters, and Runge-Kutta stages compiled as one kernel) are added to `XLA_FLAGS` where
JAX's backend has not started (`_devices`; `PPR_JAX_CPU_DEFAULTS=0` keeps XLA's defaults).
"""

import os as _os
import sys as _sys
from typing import TYPE_CHECKING as _TYPE_CHECKING

if "jax" in _sys.modules and hasattr(_sys.modules["jax"], "config"):
    _sys.modules["jax"].config.update("jax_enable_x64", True)
else:
    _os.environ["JAX_ENABLE_X64"] = "1"

# XLA's CPU settings measured for these models (`_devices`: about half a run's time and a
# quarter of its compilation), added to XLA_FLAGS before JAX's backend starts;
# PPR_JAX_CPU_DEFAULTS=0 leaves them alone
from ._devices import apply_defaults as _apply_defaults  # noqa: E402

_apply_defaults()

#: module -> the public names it gives, in the order of the floors they come from
_EXPORTS = {
    "._names": ("PARAM_RANGES", "STRIP_DYNAMICS"),
    "._params": ("RobotParams", "stack_params", "unstack_params"),
    "._params_file": ("load_params", "save_params"),
    "._prb": ("Derived", "derived"),
    "._robot": ("Robot", "RobotLike"),
    "._models": (
        "MODELS", "AbstractModel", "AbstractClosedLoop", "AbstractDouble1R", "Kin", "Motion",
        "Rigid", "Reduced", "Double1R", "AbstractBeam", "QuasiStaticBeam", "get_model",
    ),
    "._mjcf": ("to_mjcf",),
    "._models.beam": ("Beam", "solve_strip", "strip_constants"),
    "._errors": ("PPRError", "RESULTS", "RepairWarning", "SimulationError", "CommandLogError"),
    "._assembly": ("AssemblyModeError", "check_assembly_mode"),
    "._geometry": ("home_pose",),
    "._kinematics": (
        "IKResult", "inverse_kinematics", "forward_kinematics", "forward_kinematics_path",
        "jacobians", "predeflection",
    ),
    "._dynamics": ("EOM", "eom_terms", "energy", "inverse_dynamics"),
    "._trajectory": ("Circle", "Hold", "Interpolated", "derivatives"),
    "._paths": (
        "Line", "Waypoints", "Fourier", "CommandLog", "load_path", "load_commands",
        "end_condition", "check_same_rate", "check_log_covers", "StartPath", "fit_start",
    ),
    "._actuation": (
        "AbstractActuation", "TorqueDriven", "MotionDriven", "PDServo", "InverseDynamicsTorque",
        "InverseKinematicsAngles",
    ),
    "._simulate": ("simulate", "Solution"),
    "._esdirk": ("KeptKvaerno5",),
    "._rosw": ("Ros34PW2",),
    "._statics": ("static_equilibrium", "quasi_static_state"),
    "._modes": ("Modes", "modes"),
    "._metrics": ("outputs", "metrics", "metric_table"),
    "._scenes": (
        "AbstractScene", "PaperCircle", "PathScene", "register_scene", "SceneInput",
        "SceneOptions", "SceneResult", "ServoCircle", "solve_scene", "nominal_torques",
        "paper_circle", "servo_circle", "modes_scene", "scene_params", "SceneReport",
        "run_scene", "scene_metrics", "experiment_scene",
    ),
    "._cache": ("enable_compilation_cache",),
    "._devices": ("configure_cpu", "cpu_flags"),
    "._studies": (
        "SweepResult", "sweep", "shard_batch", "design_members", "Sensitivity", "sensitivity",
        "base_frequency", "Identification", "IdentificationError", "StartError", "identify",
        "FitOptions",
        "synthesize",
        "Design", "DesignError", "Objective", "Constraint", "design", "design_metrics",
        "Compensation", "CompensationError", "compensate",
        "DESIGN_METRICS", "CATALOGUE", "Metric",
    ),
    "._prb_table": ("prb_parameters", "prb_table"),
    "._data": (
        "DataError", "Experiment", "experiment", "load_csv", "load_experiments", "write_csv",
    ),
}
#: public name -> its module; `fit_prb`, `prb_error` and the `elastica` module are not in
#: `__all__` (the offline PRB fit and its scipy.optimize), as before they were lazy
_LAZY = {name: module for module, names in _EXPORTS.items() for name in names}
_LAZY.update({"fit_prb": "._prb_fit", "prb_error": "._prb_fit", "elastica": ".elastica"})

__all__ = [name for names in _EXPORTS.values() for name in names]

if _TYPE_CHECKING:  # what static tools (type checkers, IDEs, docs) read
    from ._names import (
        PARAM_RANGES as PARAM_RANGES,
        STRIP_DYNAMICS as STRIP_DYNAMICS,
    )
    from ._params import (
        RobotParams as RobotParams,
        stack_params as stack_params,
        unstack_params as unstack_params,
    )
    from ._params_file import load_params as load_params, save_params as save_params
    from ._prb import Derived as Derived, derived as derived
    from ._robot import Robot as Robot, RobotLike as RobotLike
    from ._models import (
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
        get_model as get_model,
    )
    from ._mjcf import to_mjcf as to_mjcf
    from ._models.beam import (
        Beam as Beam,
        solve_strip as solve_strip,
        strip_constants as strip_constants,
    )
    from ._errors import (
        PPRError as PPRError,
        RESULTS as RESULTS,
        RepairWarning as RepairWarning,
        SimulationError as SimulationError,
        CommandLogError as CommandLogError,
    )
    from ._assembly import (
        AssemblyModeError as AssemblyModeError,
        check_assembly_mode as check_assembly_mode,
    )
    from ._geometry import home_pose as home_pose
    from ._kinematics import (
        IKResult as IKResult,
        inverse_kinematics as inverse_kinematics,
        forward_kinematics as forward_kinematics,
        forward_kinematics_path as forward_kinematics_path,
        jacobians as jacobians,
        predeflection as predeflection,
    )
    from ._dynamics import (
        EOM as EOM,
        eom_terms as eom_terms,
        energy as energy,
        inverse_dynamics as inverse_dynamics,
    )
    from ._trajectory import (
        Circle as Circle,
        Hold as Hold,
        Interpolated as Interpolated,
        derivatives as derivatives,
    )
    from ._paths import (
        Line as Line,
        Waypoints as Waypoints,
        Fourier as Fourier,
        CommandLog as CommandLog,
        load_path as load_path,
        load_commands as load_commands,
        end_condition as end_condition,
        check_same_rate as check_same_rate,
        check_log_covers as check_log_covers,
        StartPath as StartPath,
        fit_start as fit_start,
    )
    from ._actuation import (
        AbstractActuation as AbstractActuation,
        TorqueDriven as TorqueDriven,
        MotionDriven as MotionDriven,
        PDServo as PDServo,
        InverseDynamicsTorque as InverseDynamicsTorque,
        InverseKinematicsAngles as InverseKinematicsAngles,
    )
    from ._simulate import simulate as simulate, Solution as Solution
    from ._esdirk import KeptKvaerno5 as KeptKvaerno5
    from ._rosw import Ros34PW2 as Ros34PW2
    from ._statics import (
        static_equilibrium as static_equilibrium,
        quasi_static_state as quasi_static_state,
    )
    from ._modes import Modes as Modes, modes as modes
    from ._metrics import outputs as outputs, metrics as metrics, metric_table as metric_table
    from ._scenes import (
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
        SceneReport as SceneReport,
        run_scene as run_scene,
        scene_metrics as scene_metrics,
        experiment_scene as experiment_scene,
    )
    from ._cache import enable_compilation_cache as enable_compilation_cache
    from ._devices import configure_cpu as configure_cpu, cpu_flags as cpu_flags
    from ._studies import (
        SweepResult as SweepResult,
        sweep as sweep,
        shard_batch as shard_batch,
        design_members as design_members,
        Sensitivity as Sensitivity,
        sensitivity as sensitivity,
        base_frequency as base_frequency,
        Identification as Identification,
        IdentificationError as IdentificationError,
        StartError as StartError,
        identify as identify,
        FitOptions as FitOptions,
        synthesize as synthesize,
        Design as Design,
        DesignError as DesignError,
        Objective as Objective,
        Constraint as Constraint,
        design as design,
        design_metrics as design_metrics,
        Compensation as Compensation,
        CompensationError as CompensationError,
        compensate as compensate,
        DESIGN_METRICS as DESIGN_METRICS,
        CATALOGUE as CATALOGUE,
        Metric as Metric,
    )
    from ._prb_table import prb_parameters as prb_parameters, prb_table as prb_table
    from ._data import (
        DataError as DataError,
        Experiment as Experiment,
        experiment as experiment,
        load_csv as load_csv,
        load_experiments as load_experiments,
        write_csv as write_csv,
    )
    from . import elastica as elastica
    from ._prb_fit import fit_prb as fit_prb, prb_error as prb_error

try:
    from importlib.metadata import PackageNotFoundError as _PackageNotFoundError
    from importlib.metadata import version as _version

    __version__ = _version("ppr_jax")
except _PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0+unknown"


def __getattr__(name):
    import importlib

    module_name = _LAZY.get(name)
    if module_name is None:
        if name.startswith("_") and not name.startswith("__"):
            # a private module (`ppr_jax._scenes`), reachable as when the package imported all
            try:
                return importlib.import_module(f".{name}", __name__)
            except ModuleNotFoundError as err:
                if err.name != f"{__name__}.{name}":
                    raise
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    module = importlib.import_module(module_name, __name__)
    value = module if name == "elastica" else getattr(module, name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
