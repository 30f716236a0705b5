"""The jaxtyping names used in the annotations across ppr_jax.

Shape names: ``batch`` a leading parameter-batch axis, ``n`` generalized coordinates of a model,
``m`` output times, ``N`` elements of a strip.
"""

from jaxtyping import Array, ArrayLike, Bool, Float, Int  # noqa: F401
