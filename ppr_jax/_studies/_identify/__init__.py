"""Identification (MODEL.md section 7): the problem (`_problem`), the experiments' arrays
(`_data`), the fits (`_fit`), the result (`_result`) and its statistics (`_statistics`), the
entry point (`_identify`), its options (`_options`), its argument checks (`_arguments`), what it
prepares (`_setup`) and runs (`_run`), synthetic experiments (`_synthesize`) and figures
(`_plots`)."""

from ..._errors import IdentificationError
from ._identify import identify
from ._options import FitOptions
from ._plots import identification_figures, profile_figure
from ._problem import (
                       ACTUATIONS,
                       DEFAULT_NOISE,
                       INITIAL_STATES,
                       LOSSES,
                       POOR_FIT_SCALE,
                       SOLVERS,
)
from ._result import Identification
from ._start import StartError
from ._synthesize import check_synth_args, synthesize

__all__ = ["ACTUATIONS", "DEFAULT_NOISE", "FitOptions", "INITIAL_STATES", "LOSSES",
           "POOR_FIT_SCALE", "SOLVERS", "Identification", "IdentificationError", "StartError",
           "check_synth_args", "identification_figures", "identify", "profile_figure",
           "synthesize"]
