"""Type aliases used across ppr_jax (jaxtyping shapes).

Shape names: ``batch`` a leading parameter-batch axis, ``n`` generalized coordinates of a model,
``times`` output times, ``bodies`` rigid bodies of a model.
"""

from typing import Union

import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int  # noqa: F401

Scalar = Float[Array, ""]
ScalarLike = Union[float, int, Float[ArrayLike, ""]]
Pose = Float[Array, "3"]  # platform pose X = (x [m], y [m], phi [rad])
PoseLike = Union[Float[ArrayLike, "3"], tuple, list, np.ndarray]
Angles3 = Float[Array, "3"]  # one value per chain
ChainAngles = Float[Array, "3 3"]  # [chain i, (th_i1, th_i2, th_i3)]
Coords = Float[Array, " n"]
