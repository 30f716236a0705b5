"""ppr_jax: differentiable dynamics of planar parallel robots with compliant joints."""

import jax as _jax

_jax.config.update("jax_enable_x64", True)

from ._params import RobotParams as RobotParams, stack_params as stack_params  # noqa: E402
from ._prb import Derived as Derived, derived as derived  # noqa: E402
from ._rigid import Rigid as Rigid  # noqa: E402
from ._reduced import Reduced as Reduced  # noqa: E402
from ._double1r import Double1R as Double1R  # noqa: E402
from ._trajectory import Circle as Circle, Hold as Hold, Interpolated as Interpolated  # noqa: E402
from ._actuation import (  # noqa: E402
    TorqueDriven as TorqueDriven,
    MotionDriven as MotionDriven,
    PDServo as PDServo,
    InverseDynamicsTorque as InverseDynamicsTorque,
    InverseKinematicsAngles as InverseKinematicsAngles,
)
from ._simulate import (  # noqa: E402
    simulate as simulate,
    Solution as Solution,
    SimulationError as SimulationError,
)
