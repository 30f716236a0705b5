"""A Rosenbrock-W solver for diffrax: ROS34PW2 with a Jacobian kept over several steps.

The full L3 (`Beam`, strips with their own inertia) is stiff: its strip modes reach 5e5 rad/s
at N = 16 while the robot moves at 10-70 Hz. diffrax's implicit Runge-Kutta methods evaluate the
Jacobian of the vector field at every step and iterate a Newton solve per stage; on the full L3
at N = 16 the Jacobian (102 forward-mode directions through the equations of motion) costs as
much as 22 right-hand sides, so the Jacobian alone is most of a step. A Rosenbrock-W method
needs no Newton iteration (each stage is one linear solve) and keeps its order with any
approximation of the Jacobian (Hairer and Wanner, Solving ODEs II, IV.7), so the Jacobian can be
reused over many steps: only the LU factorisation of W = I - h gamma J is redone when the step
changes, which costs a fraction of a right-hand side.

ROS34PW2 (Rang and Angermann, BIT 45 (2005) 761-787): 4 stages, order 3 as a W-method, an
embedded method of order 2 for the error estimate, L-stable (R(inf) = 0) and stiffly accurate,
so components far faster than the step are damped, not amplified, when the Jacobian is fresh;
its embedded method is not L-stable, and what a kept Jacobian costs is measured in the class's
docstring ("When not to use it").
"""

from __future__ import annotations

from typing import ClassVar

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

# ROS34PW2 in the standard form (Hairer-Wanner IV.7 (7.4)):
#   (I - h gamma J) k_i = h f(t0 + alpha_i h, y0 + sum_j a_ij k_j) + h J sum_j g_ij k_j
#                         + gamma_i h^2 f_t,      gamma_i = gamma + sum_j g_ij,
#   y1 = y0 + sum_i b_i k_i,    error = sum_i (b_i - bhat_i) k_i.
_GAMMA = 4.3586652150845900e-01
_A = np.array([
    [0.0, 0.0, 0.0, 0.0],
    [8.7173304301691801e-01, 0.0, 0.0, 0.0],
    [8.4457060015369423e-01, -1.1299064236484185e-01, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0],
])
_G = np.array([
    [0.0, 0.0, 0.0, 0.0],
    [-8.7173304301691801e-01, 0.0, 0.0, 0.0],
    [-9.0338057013044082e-01, 5.4180672388095326e-02, 0.0, 0.0],
    [2.4212380706095346e-01, -1.2232505839045147e00, 5.4526025533510214e-01, 0.0],
])
_B = np.array([2.4212380706095346e-01, -1.2232505839045147e00, 1.5452602553351020e00,
               4.3586652150845900e-01])
_BHAT = np.array([3.7810903145819369e-01, -9.6042292212423178e-02, 0.5,
                  2.1793326075422950e-01])
_ALPHA = _A.sum(axis=1)
_GAMMA_I = _GAMMA + _G.sum(axis=1)


def flat_field(terms, y0, args):
    """(y flat (n,), unravel, f(t, y flat) -> (n,)): the vector field on one vector, for the
    stiff solvers' linear algebra on any PyTree state."""
    flat, unravel = ravel_pytree(y0)

    def f(t, y):
        return ravel_pytree(terms.vf(t, unravel(y), args))[0]

    return flat, unravel, f


def check_jacobian_every(every) -> None:
    """`ValueError` unless `every` (the steps a Jacobian is kept) is an integer >= 1."""
    if not (isinstance(every, int) and every >= 1):
        raise ValueError(f"jacobian_every must be an integer >= 1, got {every!r}")


class Ros34PW2(diffrax.AbstractAdaptiveSolver):
    """The Rosenbrock-W method ROS34PW2 (Rang and Angermann 2005) for stiff ODEs, with the
    Jacobian reused over `jacobian_every` accepted steps.

    Each step factorises W = I - h gamma J once (LU) and solves four linear systems; there is no
    nonlinear iteration, so no step fails for a Newton solve that does not converge (diffrax
    issues 386 and 752). J and the time derivative f_t are the forward-mode Jacobian of the
    vector field with respect to (y, t), evaluated at the start of a step when the last one is
    `jacobian_every` accepted steps old: a W-method keeps its order with a lagged Jacobian, and
    the stiff part of the full L3's Jacobian (the strips' stiffness and inertia) changes slowly
    with the configuration. `jacobian_every=1` is a classical Rosenbrock method with a fresh
    Jacobian at every step. The vector field at the end of an accepted step is the next step's
    first stage (first-same-as-last), and with the start's it gives the cubic Hermite dense
    output.

    Order 3, error estimate of order 2 (the step-size controller's exponent 1/3). Works on any
    PyTree state (flattened to one vector for the linear algebra); ODE terms only.

    **When not to use it.** On the full L3 over the whole paper-circle (N = 16, rtol 1e-4,
    `benchmarks/results/l3_whole_scene.json`) it took 65,066 steps and rejected 31 % of them
    (about 10 % with `jacobian_every=1`, a measurement not kept in the JSON), against
    Kvaerno5's 2,754 steps and 3 %: 4.4 times `kvaerno5-kept`'s run time. Prefer
    `kvaerno5-kept` (the full L3's default) for long runs and for undamped stiff modes; this
    solver saves little compilation (54 s against 58 s there). The causes, measured in numpy
    on the coefficients above:

    - not its order conditions: with the exact Jacobian, a perturbed one, J = 0 or f_t = 0 the
      local errors of the solution and of the embedded method fall as h^4 and h^3 (orders 3
      and 2 as a W-method, as Rang and Angermann state);
    - its embedded method is not L-stable: a stiff component of amplitude a at the start of a
      step shows in the error estimate as 0.45-0.48 a for every h lambda from -1e2 to -1e4
      and 1e2 i to 1e4 i, while the solution damps it to |R| = 3e-4 (h lambda = -1e4). With a
      fresh Jacobian the stiff components are gone after one step; with a kept one whose stiff
      eigenvalue has drifted by a relative delta since it was taken, |R| becomes about
      1.8 delta (0.002 at delta = 1e-3, 0.02 at 1e-2, 0.18 at 1e-1), the strips' modes (whose
      frequencies move with the configuration) survive from step to step, and each step's
      estimate sees half of them: the rejections that a fresh Jacobian avoids;
    - and, on smooth non-stiff motion too, its order-2 estimate is some 40 times the order-3
      step's error, so its steps are sized for the lower order: on a two-degree-of-freedom
      forced oscillator at rtol 1e-4 it took 577 steps (18 % rejected, with the PI controller;
      23 % with the I controller) against Kvaerno5's 61, with any Jacobian age.

    Filtering the estimate through W (solving W e' = e, as Radau5 does) would remove the stiff
    part of the estimate; it is not done here.

    **Arguments:**

    - `jacobian_every`: accepted steps a Jacobian is kept (static, >= 1; default 10).
    """

    jacobian_every: int = eqx.field(static=True, default=10)

    term_structure: ClassVar = diffrax.AbstractTerm
    interpolation_cls: ClassVar = diffrax.ThirdOrderHermitePolynomialInterpolation

    def __check_init__(self):
        check_jacobian_every(self.jacobian_every)

    def order(self, terms):
        return 3

    def error_order(self, terms):
        return 3

    def _jacobian(self, f, t, y):
        # One forward-mode pass over (y, t): the last column is f_t.
        def g(yt):
            return f(yt[-1], yt[:-1])

        Jt = jax.jacfwd(g)(jnp.concatenate([y, jnp.reshape(t, (1,)).astype(y.dtype)]))
        return Jt[:, :-1], Jt[:, -1]

    def init(self, terms, t0, t1, y0, args):
        y, _, f = flat_field(terms, y0, args)
        J, ft = self._jacobian(f, t0, y)
        # age = jacobian_every: the first step computes its own Jacobian at (t0, y0)
        return f(t0, y), J, ft, jnp.asarray(self.jacobian_every)

    def step(self, terms, t0, t1, y0, args, solver_state, made_jump):
        y, unravel, f = flat_field(terms, y0, args)
        f0, J, ft, age = solver_state
        if made_jump is not False:
            f0 = jax.lax.cond(made_jump, lambda: f(t0, y), lambda: f0)
        refresh = age >= self.jacobian_every
        J, ft = jax.lax.cond(refresh, lambda: self._jacobian(f, t0, y), lambda: (J, ft))
        age = jnp.where(refresh, 0, age)
        h = t1 - t0
        n = y.shape[0]
        lu = jax.scipy.linalg.lu_factor(jnp.eye(n, dtype=y.dtype) - (h * _GAMMA) * J)
        ks = []
        for i in range(4):
            yi = y + sum(_A[i, j] * ks[j] for j in range(i) if _A[i, j] != 0.0) if i else y
            fi = f(t0 + _ALPHA[i] * h, yi) if i else f0
            rhs = h * fi + (_GAMMA_I[i] * h * h) * ft
            if i:
                rhs = rhs + h * (J @ sum(_G[i, j] * ks[j] for j in range(i)))
            ks.append(jax.scipy.linalg.lu_solve(lu, rhs))
        y1 = y + sum(_B[i] * ks[i] for i in range(4))
        err = sum((_B[i] - _BHAT[i]) * ks[i] for i in range(4))
        f1 = f(t1, y1)
        dense_info = dict(y0=y0, y1=unravel(y1), k0=unravel(h * f0), k1=unravel(h * f1))
        return (unravel(y1), unravel(err), dense_info, (f1, J, ft, age + 1),
                diffrax.RESULTS.successful)

    def func(self, terms, t0, y0, args):
        return terms.vf(t0, y0, args)
