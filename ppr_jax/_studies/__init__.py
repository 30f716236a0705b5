"""The studies wing: what runs many scenes, or one scene many times. Sweeps (`_sweep`),
sensitivities (`_sensitivity`) and identification (`_identify/`), each through
`AbstractScene.run` and the one batch mapper of the scenes wing."""

from ._identify import (
                        ACTUATIONS,
                        DEFAULT_NOISE,
                        ID_SCENES,
                        INITIAL_STATES,
                        LOSSES,
                        POOR_FIT_SCALE,
                        SOLVERS,
                        Identification,
                        IdentificationError,
                        check_synth_args,
                        identification_figures,
                        identify,
                        profile_figure,
                        synthesize,
)
from ._sensitivity import (
                        SENSITIVITY_METRICS,
                        Sensitivity,
                        base_frequency,
                        explicit_params,
                        metric_function,
                        sensitivity,
)
from ._sweep import (
                        FLOAT_PARAMS,
                        METRICS,
                        SWEEP_SCENES,
                        SweepResult,
                        design_members,
                        library_digest,
                        shard_batch,
                        sweep,
                        traced_metrics,
                        validate_members,
)

__all__ = [
    "ACTUATIONS", "DEFAULT_NOISE", "FLOAT_PARAMS", "ID_SCENES", "INITIAL_STATES", "LOSSES",
    "METRICS", "POOR_FIT_SCALE", "SENSITIVITY_METRICS", "SOLVERS", "SWEEP_SCENES",
    "Identification", "IdentificationError", "Sensitivity", "SweepResult", "base_frequency",
    "check_synth_args", "design_members", "identification_figures", "profile_figure",
    "explicit_params", "identify", "library_digest",
    "metric_function", "sensitivity", "shard_batch", "sweep", "synthesize", "traced_metrics",
    "validate_members",
]
