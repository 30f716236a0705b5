"""Explicit Runge-Kutta steps written out stage by stage, for XLA to fuse.

diffrax's `AbstractRungeKutta.step` runs the stages of any Runge-Kutta method as a loop (an
`equinox.internal.while_loop` over the stage index, writing each stage's increment into a
stacked buffer), which is general (implicit, multi-tableau, SDE) but keeps XLA from fusing one
stage's arithmetic with the next stage's vector field: on L1 `paper-circle` the stage loop,
its buffer updates and the per-leaf stage sums were about half of a step's ~870 kernels. Here
the same tableau is applied as straight-line code (the stages unrolled in Python, zero
coefficients dropped), so XLA fuses each stage's combination of increments into the vector
field that reads it. Same tableau, same dense output (diffrax's interpolation class of the
method), same error estimate, same first-same-as-last reuse: a trajectory differs from
diffrax's own solver by rounding.
"""

from __future__ import annotations

import diffrax
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
import jax.tree_util as jtu
from diffrax._misc import linear_rescale
from diffrax._solver.tsit5 import _Tsit5Interpolation


def _combine(y0, coeffs, ks):
    """y0 + sum_j coeffs[j] ks[j] leaf by leaf (y0 None: the sum alone), zero terms dropped."""
    terms = [(float(a), k) for a, k in zip(coeffs, ks) if float(a) != 0.0]

    def leaf(y, *kk):
        acc = y
        for (a, _), k in zip(terms, kk):
            acc = a * k if acc is None else acc + a * k
        return jnp.zeros_like(kk[0]) if acc is None else acc

    if y0 is None:
        return jtu.tree_map(lambda *kk: leaf(None, *kk), *[k for _, k in terms]) if terms \
            else jtu.tree_map(jnp.zeros_like, ks[0])
    return jtu.tree_map(leaf, y0, *[k for _, k in terms])


class _Unrolled(diffrax.AbstractERK):
    """An explicit Runge-Kutta method of diffrax (its `tableau`, `interpolation_cls`, orders)
    stepped as straight-line code; for ordinary differential equations (an `ODETerm`). The
    solver state of a first-same-as-last method is (first step, the vector field at the
    step's start), as diffrax's."""

    def init(self, terms, t0, t1, y0, args):
        if not self.tableau.fsal:
            return None
        # As diffrax's: the first step evaluates the vector field at its start itself (an
        # initial solver state computed here would be cut off from the derivatives by the
        # adjoints that stop gradients through it: `BacksolveAdjoint`, `ImplicitAdjoint`).
        return jnp.array(True), jtu.tree_map(jnp.zeros_like, y0)

    def step(self, terms, t0, t1, y0, args, solver_state, made_jump):
        tab = self.tableau
        control = terms.contr(t0, t1)
        dt = t1 - t0
        if tab.fsal:
            first, f0 = solver_state
            # on the first step, and after a jump (the stored value is then the left
            # limit's), the vector field at the start is evaluated again
            again = first if made_jump is False else first | made_jump
            f0 = jax.lax.cond(eqxi.unvmap_any(again),
                              lambda: terms.vf(t0, y0, args), lambda: f0)
        else:
            f0 = terms.vf(t0, y0, args)
        ks = [terms.prod(f0, control)]
        fi = f0
        yi = y0
        for a_row, c in zip(tab.a_lower, tab.c):
            yi = _combine(y0, a_row, ks)
            fi = terms.vf(t0 + float(c) * dt, yi, args)
            ks.append(terms.prod(fi, control))
        if tab.ssal:
            y1 = yi
        else:
            y1 = _combine(y0, tab.b_sol, ks)
        y_error = _combine(None, tab.b_error, ks)
        k = jtu.tree_map(lambda *kk: jnp.stack(kk), *ks)
        dense_info = dict(y0=y0, y1=y1, k=k)
        new_state = (jnp.array(False), fi) if tab.fsal else None
        return y1, y_error, dense_info, new_state, diffrax.RESULTS.successful


class _Tsit5Dense(_Tsit5Interpolation):
    """diffrax's dense output of `Tsit5` (the same polynomials, in the same form) with the sum
    over the seven stages written out: with the stage weights stacked and contracted with a
    dot, each output time cost a concatenation and a dot of its own inside the saving loop
    (10 kernels an output time on L1 `paper-circle`; 8 this way)."""

    def evaluate(self, t0, t1=None, left=True):
        del left
        if t1 is not None:
            return jtu.tree_map(lambda a, b: b - a, self.evaluate(t0), self.evaluate(t1))
        t = linear_rescale(self.t0, t0, self.t1)
        t2 = t * t
        b = (
            -1.0530884977290216 * t * (t - 1.3299890189751412)
            * (t2 - 1.4364028541716351 * t + 0.7139816917074209),
            0.1017 * t2 * (t2 - 2.1966568338249754 * t + 1.2949852507374631),
            2.490627285651252793 * t2 * (t2 - 2.38535645472061657 * t + 1.57803468208092486),
            -16.54810288924490272 * (t - 1.21712927295533244) * (t - 0.61620406037800089) * t2,
            47.37952196281928122 * (t - 1.203071208372362603) * (t - 0.658047292653547382) * t2,
            -34.87065786149660974 * (t - 1.2) * (t - 0.666666666666666667) * t2,
            2.5 * (t - 1) * (t - 0.6) * t2,
        )

        def leaf(y0, k):
            acc = y0
            for i, bi in enumerate(b):
                acc = acc + bi * k[i]
            return acc

        return jtu.tree_map(leaf, self.y0, self.k)


class FusedTsit5(_Unrolled, diffrax.Tsit5):
    """diffrax's `Tsit5` (Tsitouras' 5(4) pair, first same as last, its 5th-order dense
    output) with the stages as straight-line code (`_Unrolled`): the scenes' explicit solver
    for L0-L2."""

    interpolation_cls = _Tsit5Dense


class FusedDopri5(_Unrolled, diffrax.Dopri5):
    """diffrax's `Dopri5` (Dormand-Prince 5(4)) with the stages as straight-line code."""


class FusedDopri8(_Unrolled, diffrax.Dopri8):
    """diffrax's `Dopri8` (Dormand-Prince 8(7), 14 stages) with the stages as straight-line
    code."""
