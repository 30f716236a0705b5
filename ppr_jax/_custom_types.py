"""The jaxtyping names used in the annotations across ppr_jax.

Shape names: ``batch`` a leading parameter-batch axis, ``n`` generalized coordinates of a model,
``m`` output times, ``N`` elements of a strip.
"""

from jaxtyping import Array, ArrayLike, Bool, Float, Int  # noqa: F401


def as_f64(x):
    """`x` as a float64 array: a host number or numpy array stays a numpy array, anything else
    (a JAX array, a tracer) becomes JAX's. A jitted call takes either alike (the same program),
    and a value kept on the host costs no transfer and no XLA program (a scene's options and
    default parameters are built on every call)."""
    import numpy as np

    if isinstance(x, (int, float, np.ndarray, np.generic)) and not isinstance(x, bool):
        return np.asarray(x, dtype=np.float64)
    import jax.numpy as jnp

    return jnp.asarray(x, dtype=jnp.float64)
