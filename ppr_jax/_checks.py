"""Clear errors instead of NaN: one helper that checks eagerly when values are concrete (and names
the failing batch members) and falls back to `eqx.error_if` inside a trace."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np


class PPRError(ValueError):
    """The base of this library's errors: bad input or an infeasible request (unreachable pose,
    singular configuration, a solver that failed: `SimulationError`). A `ValueError`, so code
    that catches bad input keeps working."""


def is_traced(tree) -> bool:
    return any(isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves(tree))


def raise_if(x, bad, message: str):
    """Return `x`, raising `PPRError(message)` where `bad` holds.

    Concrete `bad`: raised now; if `bad` has a leading batch axis, the failing batch members are
    listed. Traced `bad`: `eqx.error_if` (the returned `x` must be used for the check to run)."""
    if is_traced(bad):
        return eqx.error_if(x, jnp.any(bad), message)
    b = np.asarray(bad)
    if b.any():
        if b.ndim >= 1 and b.shape[0] > 1:
            members = np.flatnonzero(b.reshape(b.shape[0], -1).any(axis=1)).tolist()
            shown = members if len(members) <= 10 else members[:10] + ["..."]
            raise PPRError(f"{message} ({len(members)} batch members: {shown})")
        raise PPRError(message)
    return x
