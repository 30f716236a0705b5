"""Values that XLA's CPU compiler computes once: `materialize`, and tangents: `tangents_once`.

XLA's CPU fusion copies a cheap-looking elementwise producer into every fusion that consumes
it, and it counts sines and cosines as cheap enough: a right-hand side whose dozen angles feed
the mass matrix's entries, the convective terms and the springs computed each sine once per
kernel that reads it. Measured on L2's compiled right-hand side (`paper-circle`): 30 sines and
30 cosines as traced, 77 and 77 as compiled. XLA does not copy an expensive producer into a
consumer that reads each of its elements more than once, so a value with such a consumer is
computed once, by a kernel of its own, and every other kernel reads it. `materialize` makes
that consumer a running sum over a zero and the value: one small `reduce_window` kernel, exact
and linear. (An identity product does the same, but a batch's product goes to YNNPACK under
XLA's default flags.)

Under `vmap` it keeps its kernel, batched or not: a vectorised program (the input table's
nodes, the path's checks and the outputs at every output time, a batch's members) reads a
batched sine in several kernels as a single run reads one (L1 `paper-circle`: outputs 1,067 ->
943 us, input table 580 -> 380 us). Its derivative is the identity; `tangents_once` computes a
list's tangents once where a derivative needs it.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ._custom_types import Array, Float


def _running_sum(x):
    return jax.lax.cumsum(jnp.stack([jnp.zeros_like(x), x]), axis=0)[1]


@jax.custom_jvp
def materialize(x: Float[Array, "..."]) -> Float[Array, "..."]:
    """`x`, computed once by XLA however many kernels read it (module docstring).

    **Arguments:**

    - `x`: a floating array; stack the values that many kernels read into one (one kernel for
      all of them).

    **Returns:** `x`'s values, except that a negative zero comes back as +0.0 (it is 0 + x):
    use it on values that feed arithmetic, not on the sign-sensitive `arctan2` of a zero.
    The same under `vmap`; for tangents, the identity.
    """
    return _running_sum(x)


@materialize.defjvp
def _materialize_jvp(primals, tangents):
    return materialize(primals[0]), tangents[0]


def cos_sin(*angles: Float[Array, " k"]) -> tuple[list, list]:
    """The cosines and the sines of 1-D arrays of angles, all computed once (`materialize`, one
    kernel for all of them): ([cos a for a in angles], [sin a for a in angles]). Their
    derivatives read the same values (d cos a = -sin a da): differentiated through `jnp.cos`
    and `jnp.sin`, every derivative would evaluate each sine again, outside the kernel that
    computed it (L1's path check: 21 sines a pose for the 12 it needs)."""
    trig = _cos_sin_once(jnp.concatenate(angles))
    ends = [0]
    for a in angles:
        ends.append(ends[-1] + a.shape[0])
    half = ends[-1]
    return ([trig[a:b] for a, b in zip(ends, ends[1:])],
            [trig[half + a : half + b] for a, b in zip(ends, ends[1:])])


def cos_sin_of(a: Float[Array, "..."]) -> tuple[Array, Array]:
    """(cos a, sin a) of a scalar or 1-D array, in a's shape, computed once however many
    kernels read them (`cos_sin`): a robot's fixed angle (a link's offset, L1's c2) or the
    platform's, which XLA otherwise copied into every kernel that reads it (up to nine)."""
    (c,), (s,) = cos_sin(jnp.atleast_1d(a))
    return c.reshape(jnp.shape(a)), s.reshape(jnp.shape(a))


@jax.custom_jvp
def _cos_sin_once(a):
    """(cos a, sin a) of a 1-D array, concatenated and computed once (`materialize`)."""
    return materialize(jnp.concatenate([jnp.cos(a), jnp.sin(a)]))


@_cos_sin_once.defjvp
def _cos_sin_once_jvp(primals, tangents):
    (a,), (da,) = primals, tangents
    cs = _cos_sin_once(a)  # through this rule again at higher orders
    k = a.shape[0]
    return cs, jnp.concatenate([-cs[k:] * da, cs[:k] * da])


@jax.custom_jvp
def tangents_once(xs: list) -> list:
    """`xs` (a list of arrays) unchanged; their tangents computed once, by one kernel for all
    of them (as `materialize` does for values). Differentiated straight-line arithmetic
    otherwise recomputes a shared tangent, and the values it is multiplied with, inside every
    fusion that reads it, and the copies multiply along a chain of products: the tangents of
    L2's fused balance over 19 parameters took 1.2 ms a right-hand side without it, 0.08 ms
    with it."""
    return xs


@tangents_once.defjvp
def _tangents_once_jvp(primals, tangents):
    (xs,), (ts,) = primals, tangents
    flat = _running_sum(jnp.concatenate([jnp.ravel(t) for t in ts]))
    out, i = [], 0
    for t in ts:
        out.append(flat[i : i + t.size].reshape(t.shape))
        i += t.size
    return xs, out
