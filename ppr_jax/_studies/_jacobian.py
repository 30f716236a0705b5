"""The metrics with their Jacobian in one program, as sensitivities and designs take them."""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp

from .._scenes import on_host_threads


def jacobian_with_values(f: Callable, x, *args):
    """(J (m, p), v (m,)) of `f(x, *args)` -> v (m,) with respect to x (p,), in reverse mode.

    The values are the derivative's own primal (`jax.jacrev` with `has_aux`): the pullback
    starts from the same solve, so one program gives both and the values need no program of
    their own. Measured on L1 paper-circle (three metrics, 2-core CPU): a separate values
    program was 2.0 s of tracing and 2.0 s of XLA compilation beside the Jacobian's 6.2 s and
    4.9 s. Forward mode: `derivatives_along` and `forward_jacobian`.

    **Arguments:**

    - `f`: a traceable function of (x, *args) returning a 1-D array.
    - `x`: the point (p,); `args`: the rest of f's arguments (not differentiated).

    **Returns:** (J, v).
    """
    def both(x, *a):
        v = f(x, *a)
        return v, v

    return jax.jacrev(both, has_aux=True)(x, *args)


def derivatives_along(f: Callable, x, V, *args, has_aux: bool = False):
    """(V J^T (k, m), v repeated (k, m)): the derivatives of `f(x, *args)` -> v (m,) along the
    rows of V (k, p), in forward mode, their primal solve shared, and the values repeated on
    every row, so that every array of the result has a row a direction: `on_host_threads`
    splits the directions (V's rows) over a CPU's cores, each slice's program solving the
    primal once with its own tangents (`forward_jacobian`).

    With `has_aux`, f returns (v, aux), aux a pytree of arrays (any dtype: result codes) that
    is not differentiated, and it comes back as a third element, each leaf repeated on every
    row as v is.

    **Returns:** (V J^T, v repeated), or (V J^T, v repeated, aux repeated).
    """
    def along(d):
        out = jax.jvp(lambda y: f(y, *args), (x,), (d,), has_aux=has_aux)
        return (out[0], out[1], out[2]) if has_aux else (out[0], out[1], None)

    v, jt, aux = jax.vmap(along, out_axes=(None, 0, None))(V)
    rows = lambda a: jnp.broadcast_to(a, (V.shape[0], *jnp.shape(a)))  # noqa: E731
    if not has_aux:
        return jt, rows(v)
    return jt, rows(v), jax.tree_util.tree_map(rows, aux)


def forward_jacobian(program: Callable, x, *args, run: Callable = None):
    """(J (m, p), v (m,)) of a jitted `program(x, V, *args)` = `derivatives_along(f, x, V,
    *args)`, the p directions of the identity split over the host's cores (one slice of them a
    thread, `_scenes.on_host_threads`; one slice on one core); (J, v, aux) where the program
    is `derivatives_along(..., has_aux=True)`. `run(fn, args)` (default: call it) compiles and
    calls, as the caller's program store does.

    On a CPU a forward-mode Jacobian's tangents ride on one solve: its arithmetic grows with
    the parameters while one core does it. In slices, each core solves the primal once more
    and carries its share of the tangents (L2 `paper-circle` over 1 s, 19 parameters, 2
    cores: see `sensitivity`)."""
    p = x.shape[0]
    V = jnp.eye(p, dtype=x.dtype)
    fn = on_host_threads(program, p, argnum=1)
    call_args = (x, V, *args)
    out = fn(*call_args) if run is None else run(fn, call_args)
    jt, vs = out[0], out[1]
    if len(out) == 2:
        return jt.T, vs[0]
    return jt.T, vs[0], jax.tree_util.tree_map(lambda a: a[0], out[2])
