"""Design with gradients: design variables with bounds (`_variables`), the objective and
constraints (`_goals`) on the metrics of one catalogue (`_catalogue`), the compiled problem
(`_problem`), the constrained optimiser and the starts' screening (`_optimise`), the
verification of the optimum (`_verify`), the result (`_result`), the entry point (`_design`)
and its argument checks (`_arguments`), and the specification file of the command line
(`_spec`)."""

from ..._errors import DesignError
from .._catalogue import (
                         compliance,
                         design_metrics,
                         moving_mass,
                         path_margins,
                         pivot_frequency,
                         pivot_stress,
                         strip_elastica,
                         strip_stress_peak,
                         torque_rms,
)
from ._design import design
from ._goals import Constraint, Objective
from ._result import Design
from ._spec import load_design_spec
from ._variables import check_variables

__all__ = ["Constraint", "Design", "DesignError", "Objective",
           "check_variables", "compliance", "design", "design_metrics", "load_design_spec",
           "moving_mass", "path_margins", "pivot_frequency", "pivot_stress", "strip_elastica",
           "strip_stress_peak", "torque_rms"]
