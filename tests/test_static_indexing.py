"""The free and prescribed coordinates picked and merged by static slices (`_simulate._take`,
`_simulate._interleave`) equal NumPy's fancy indexing, for the index sets the models have."""

import jax.numpy as jnp
import numpy as np
import pytest

from ppr_jax._simulate import _interleave, _take

# L2 motion-driven (actuated 3, 6, 9 of 12), L0/L1 (actuated 0, 1, 2 of 3 or none), one more
CASES = [((0, 1, 2, 4, 5, 7, 8, 10, 11), (3, 6, 9)), ((), (0, 1, 2)), ((0, 1, 2), ()),
         ((1, 3, 4), (0, 2, 5))]


@pytest.mark.parametrize("free,pres", CASES)
def test_take_and_interleave_match_numpy(free, pres):
    n = len(free) + len(pres)
    rng = np.random.default_rng(n)
    x, M = rng.normal(size=n), rng.normal(size=(n, n))
    for idx in (free, pres):
        if idx:
            np.testing.assert_array_equal(_take(jnp.asarray(x), idx), x[list(idx)])
            np.testing.assert_array_equal(_take(jnp.asarray(M), idx, axis=1), M[:, list(idx)])
    a, b = rng.normal(size=len(free)), rng.normal(size=len(pres))
    ref = np.zeros(n)
    ref[list(free)], ref[list(pres)] = a, b
    parts = [(i, jnp.asarray(v)) for i, v in ((free, a), (pres, b)) if i]
    np.testing.assert_array_equal(_interleave(parts), ref)
