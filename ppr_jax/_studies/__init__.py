"""The studies wing: what runs many scenes, or one scene many times. Sweeps (`_sweep`),
sensitivities (`_sensitivity`), identification (`_identify/`) and design (`_design/`), each
through `AbstractScene.run` and the one batch mapper of the scenes wing."""

from ._catalogue import CATALOGUE, DESIGN_METRICS, Metric, design_metrics
from ._compensate import Compensation, CompensationError, compensate, error_band
from ._design import (
                      Constraint,
                      Design,
                      DesignError,
                      Objective,
                      design,
                      load_design_spec,
)
from ._identify import (
                      FitOptions,
                      Identification,
                      IdentificationError,
                      StartError,
                      check_synth_args,
                      identification_figures,
                      identify,
                      profile_figure,
                      synthesize,
)
from ._sensitivity import (
                      PATH_SENSITIVITY_METRICS,
                      SENSITIVITY_METRICS,
                      Sensitivity,
                      allowed_metrics,
                      base_frequency,
                      default_metrics,
                      explicit_params,
                      metric_function,
                      sensitivity,
)
from ._sweep import (
                      FLOAT_PARAMS,
                      METRICS,
                      SweepResult,
                      design_members,
                      library_digest,
                      shard_batch,
                      sweep,
                      sweep_metrics,
                      validate_members,
)

__all__ = [
    "Compensation", "CompensationError", "compensate", "error_band",
    "CATALOGUE", "DESIGN_METRICS", "Metric",
    "Constraint", "Design", "DesignError", "Objective", "design", "design_metrics",
    "load_design_spec",
    "FLOAT_PARAMS", "FitOptions", "METRICS", "PATH_SENSITIVITY_METRICS", "SENSITIVITY_METRICS",
    "StartError", "allowed_metrics", "default_metrics",
    "Identification", "IdentificationError", "Sensitivity", "SweepResult", "base_frequency",
    "check_synth_args", "design_members", "identification_figures", "profile_figure",
    "explicit_params", "identify", "library_digest",
    "metric_function", "sensitivity", "shard_batch", "sweep", "sweep_metrics", "synthesize",
    "validate_members",
]
