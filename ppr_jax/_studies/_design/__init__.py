"""Design with gradients: design variables with bounds (`_variables`), the objective and
constraints (`_goals`) on the metrics of one catalogue (`_catalogue`), the compiled problem
(`_problem`), the constraints as the optimiser sees them (`_constraints`), the constrained
optimiser and the starts' screening (`_optimise`), the verification of the optimum (`_verify`),
the result (`_result`) assembled from the runs (`_assemble`), the entry point (`_design`) and
its argument checks (`_arguments`), and the specification file of the command line
(`_spec`)."""

from ..._errors import DesignError
from ._design import design
from ._goals import Constraint, Objective
from ._result import Design
from ._spec import load_design_spec
from ._variables import check_variables

__all__ = ["Constraint", "Design", "DesignError", "Objective", "check_variables", "design",
           "load_design_spec"]
