"""Planar large-deflection elastica of an (initially curved) end-loaded cantilever.

Model
-----
A planar, inextensible, unshearable Euler-Bernoulli cantilever of length ``L`` [m] and
bending stiffness ``EI`` [N m^2], clamped at arclength ``s = 0``. Unloaded it is a circular
arc of nondimensional curvature ``kappa0 = L/R`` (``kappa0 = 0``: straight beam; the rest
curvature is ``kappa0/L`` [1/m]).

Frame: the clamp's tangent frame. ``x`` is along the tangent at the clamp, the unloaded arc
bends towards ``+y`` for ``kappa0 > 0``, so the unloaded tip is at
``(R sin kappa0, R (1 - cos kappa0))`` with tangent angle ``kappa0``. The end load is a force
``(fx, fy)`` [N] of constant direction in this frame (a dead load, not a follower) and a moment
``m`` [N m], counterclockwise positive. With ``th(s)`` the tangent angle and ``M(s)`` the
bending moment (counterclockwise moment exerted by the outer part ``[s, L]`` on ``[0, s]``):

    x' = cos th,  y' = sin th,  th' = kappa0/L + M/EI,  M' = fx sin th - fy cos th,
    th(0) = 0,  x(0) = y(0) = 0,  M(L) = m.

Numerical method
----------------
Shooting on the unknown clamp moment ``M(0)``. The problem is nondimensionalized
(``s/L``, ``x/L``, ``M L/EI``, ``F L^2/EI``) and integrated over ``[0, 1]`` with the classical
fixed-step 4th-order Runge-Kutta method on a fixed grid of ``n_nodes`` output nodes with
``substeps`` RK4 steps per interval, so every array shape is static (jit/vmap friendly).
RK4's global error is ``O(h^4)``: for a pure moment (a quadrature of ``cos`` of a linear angle)
it is about ``(c h)^4/2880`` with ``c`` the total nondimensional curvature, i.e. ~1e-13 at the
default ``h = 1/400`` and ``c = pi`` (2e-11 at ``c = 2 pi``).

The root ``M(0)`` is found in two stages:

1. a robust initial guess by *load continuation*: the load is ramped ``lambda = k/K``,
   ``k = 1..K`` (``K = n_continuation``), starting from the exact unloaded solution ``M(0) = 0``,
   with an Euler (tangent) predictor ``d M(0)/d lambda`` from the implicit function theorem and
   ``n_newton`` Newton corrections per step, on a coarse grid (one RK4 step per output
   interval: the guess only has to be in the fine problem's Newton basin). This follows the
   principal (continuously loaded) branch; a step that does not converge or turns the tip by
   more than ``pi/2 + |m| L/(EI K)`` (a jump to another branch) marks the solve as failed. With
   the default ``K = 8`` loads up to ``|F| L^2/EI ~ 30`` are followed, ``K = 16`` reaches ~50
   (straight beam, transverse force). Computed under ``stop_gradient``.
2. a final ``optimistix.root_find`` (Newton) at the full load from that guess. Optimistix's
   implicit adjoint differentiates the root, so forward- and reverse-mode derivatives with
   respect to ``length, EI, kappa0, force, moment`` are exact derivatives of the discrete
   solution and cost no differentiation through the Newton iterations.

Convergence is declared when the continuation path is sound (above), the final Newton succeeded,
the nondimensional end-moment residual ``|M(L) - m| L/EI`` is below
``1e-9 * max(1, |F| L^2/EI, |m| L/EI)``, the result is finite, and the RK4 grid resolves the load
(``h * max(sqrt(|F| L^2/EI), max|th'| L) <= 0.5`` with ``h = 1/((n_nodes-1) substeps)``; beyond
that RK4 errors exceed ~1e-5 and the grid must be refined). Failure raises (see
:func:`solve_cantilever`), it never returns a silent NaN.
"""

from __future__ import annotations

import functools  # noqa: E402

import equinox as eqx  # noqa: E402
import jax
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import optimistix as optx  # noqa: E402
from jaxtyping import Array, Bool, Float  # noqa: E402

from ._errors import ElasticaConvergenceError, PPRError  # noqa: E402

__all__ = ["CantileverSolution", "ElasticaConvergenceError", "solve_cantilever"]

#: Largest ``h * (load scale)`` for which the RK4 solution is considered resolved.
_MAX_H_SCALE = 0.5
#: Relative tolerance on the nondimensional end-moment residual.
_RESIDUAL_RTOL = 1e-9
#: Largest change of the tip angle [rad] allowed between two load-continuation steps.
_MAX_TIP_ANGLE_STEP = 0.5 * 3.141592653589793


_NOT_CONVERGED_MSG = (
    "solve_cantilever: the elastica shooting solver did not converge for this load: the "
    "nondimensional end load |F| L^2/EI (or |m| L/EI) is too large for the solver. Reduce the "
    "load, or increase n_nodes/substeps (grid resolution) and n_continuation."
)


class CantileverSolution(eqx.Module):
    """Deformed shape of the cantilever, sampled on a fixed arclength grid.

    All arrays have shape ``(..., n_nodes)`` (a leading batch shape appears under ``jax.vmap``).

    Attributes:
        s: arclength of the nodes [m], ``linspace(0, L, n_nodes)``.
        x, y: node positions in the clamp frame [m].
        theta: tangent angle at the nodes [rad] (``theta[0] = 0``).
        moment: bending moment ``M(s)`` [N m] (``moment[-1] = m``).
        clamp_moment: ``M(0)`` [N m], shape ``(...)``; the reaction moment on the beam at the clamp
            is ``-M(0)``.
        residual: nondimensional end-moment residual ``(M(L) - m) L/EI`` of the shooting.
        converged: whether the solver converged and the grid resolves the load (see module doc).
    """

    s: Float[Array, "... n"]
    x: Float[Array, "... n"]
    y: Float[Array, "... n"]
    theta: Float[Array, "... n"]
    moment: Float[Array, "... n"]
    clamp_moment: Float[Array, "..."]
    residual: Float[Array, "..."]
    converged: Bool[Array, "..."]

    @property
    def tip_x(self) -> Float[Array, "..."]:
        """Tip x position [m]."""
        return self.x[..., -1]

    @property
    def tip_y(self) -> Float[Array, "..."]:
        """Tip y position [m]."""
        return self.y[..., -1]

    @property
    def tip_angle(self) -> Float[Array, "..."]:
        """Tip tangent angle [rad]."""
        return self.theta[..., -1]

    @property
    def tip(self) -> Float[Array, "... 3"]:
        """Tip pose ``(x [m], y [m], angle [rad])``, shape ``(..., 3)``."""
        return jnp.stack([self.tip_x, self.tip_y, self.tip_angle], axis=-1)


# ---------------------------------------------------------------------------------------------
# Nondimensional shooting integrator.  State u = (x/L, y/L, th, M L/EI); params p = (k0, fx, fy)
# with f = F L^2/EI.
# ---------------------------------------------------------------------------------------------


def _rhs(u, p):
    _, _, th, mu = u
    k0, fx, fy = p
    sin, cos = jnp.sin(th), jnp.cos(th)
    return jnp.stack([cos, sin, k0 + mu, fx * sin - fy * cos])


def _rk4_interval(u, p, h, substeps):
    # The substeps are unrolled in Python: fewer scan iterations -> far less per-step overhead.
    for _ in range(substeps):
        k1 = _rhs(u, p)
        k2 = _rhs(u + 0.5 * h * k1, p)
        k3 = _rhs(u + 0.5 * h * k2, p)
        k4 = _rhs(u + h * k3, p)
        u = u + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return u


def _integrate(mu0, p, n_nodes, substeps, save):
    """Integrate from s=0 with M(0)L/EI = mu0. Returns the node states (n_nodes, 4) or the end
    state."""
    h = 1.0 / ((n_nodes - 1) * substeps)
    u0 = jnp.stack([jnp.zeros_like(mu0), jnp.zeros_like(mu0), jnp.zeros_like(mu0), mu0])

    def body(u, _):
        u = _rk4_interval(u, p, h, substeps)
        return u, (u if save else None)

    u_end, us = jax.lax.scan(body, u0, None, length=n_nodes - 1)
    if save:
        return jnp.concatenate([u0[None], us], axis=0)
    return u_end


def _residual(mu0, args, n_nodes, substeps):
    k0, fx, fy, mt = args
    return _integrate(mu0, (k0, fx, fy), n_nodes, substeps, save=False)[3] - mt


def _continuation_guess(args, n_nodes, substeps, n_continuation, n_newton):
    """Initial guess for mu0 by load continuation from the exact unloaded solution mu0 = 0.

    Runs on the coarse grid ``substeps`` (typically 1 RK4 step per output interval): the guess
    only has to lie in the fine problem's Newton basin, and the RK4 right-hand side (two
    transcendental functions) dominates the cost.
    """
    k0, fx, fy, mt = args

    def res(mu0, lam):
        return _residual(mu0, (k0, lam * fx, lam * fy, lam * mt), n_nodes, substeps)

    def newton(mu0, lam):
        def it(mu, _):
            r, dr = jax.jvp(lambda m_: res(m_, lam), (mu,), (jnp.ones_like(mu),))
            step = r / dr
            # Clip wild steps (near-singular Jacobian) so one bad step cannot throw us far away.
            step = jnp.clip(step, -(1.0 + jnp.abs(mu)), 1.0 + jnp.abs(mu))
            new = mu - step
            return jnp.where(jnp.isfinite(new), new, mu), None

        return jax.lax.scan(it, mu0, None, length=n_newton)[0]

    def tangent(mu, lam):
        # d mu0 / d lambda along the equilibrium path (implicit function theorem on res = 0).
        r_mu = jax.jvp(lambda m_: res(m_, lam), (mu,), (jnp.ones_like(mu),))[1]
        r_lam = jax.jvp(lambda l_: res(mu, l_), (lam,), (jnp.ones_like(lam),))[1]
        return -r_lam / r_mu

    dlam = 1.0 / n_continuation

    def cont(carry, lam):
        mu_prev, dmu_prev, th_prev, ok = carry
        # Euler (tangent) predictor from the previous equilibrium, then Newton corrector.
        pred = mu_prev + dlam * jnp.where(jnp.isfinite(dmu_prev), dmu_prev, 0.0)
        mu = newton(pred, lam)
        u_end = _integrate(mu, (k0, lam * fx, lam * fy), n_nodes, substeps, save=False)
        # Path-following sanity: every continuation step must converge and move the tip angle by a
        # bounded amount; a jump means Newton left the principal (continuously loaded) branch.
        scale = jnp.maximum(1.0, lam * jnp.maximum(jnp.sqrt(fx**2 + fy**2), jnp.abs(mt)))
        step_ok = (jnp.abs(u_end[3] - lam * mt) <= 1e-8 * scale) & (
            # (a pure end moment turns the tip by m L/EI / K per step: allowed on top)
            jnp.abs(u_end[2] - th_prev) <= _MAX_TIP_ANGLE_STEP + dlam * jnp.abs(mt)
        )
        return (mu, tangent(mu, lam), u_end[2], ok & step_ok), None

    lams = jnp.arange(1, n_continuation + 1, dtype=jnp.float64) / n_continuation
    k0 = jnp.asarray(k0, jnp.float64)
    zero = jnp.zeros((), jnp.float64)
    # lambda = 0 is the unloaded arc: mu0 = 0 exactly, tip angle kappa0.
    init = (zero, tangent(zero, zero), k0, jnp.asarray(True))
    (mu, _, _, ok), _ = jax.lax.scan(cont, init, lams)
    return mu, ok


@functools.partial(jax.jit, static_argnames=("n_nodes", "substeps", "n_continuation", "n_newton"))
def _solve_core(length, EI, kappa0, fx, fy, m, *, n_nodes, substeps, n_continuation, n_newton):
    length, EI, kappa0, fx, fy, m = (jnp.asarray(v, jnp.float64)
                                     for v in (length, EI, kappa0, fx, fy, m))
    # Nondimensional load: f = F L^2/EI, m~ = m L/EI.
    fxn, fyn, mn = fx * length**2 / EI, fy * length**2 / EI, m * length / EI
    args = (kappa0, fxn, fyn, mn)

    guess, path_ok = jax.lax.stop_gradient(
        _continuation_guess(args, n_nodes, 1, n_continuation, n_newton))
    sol = optx.root_find(
        lambda mu0, a: _residual(mu0, a, n_nodes, substeps),
        optx.Newton(rtol=1e-13, atol=1e-13),
        guess,
        args,
        max_steps=32,
        throw=False,
    )
    mu0 = sol.value
    us = _integrate(mu0, (kappa0, fxn, fyn), n_nodes, substeps, save=True)
    residual = us[-1, 3] - mn

    h = 1.0 / ((n_nodes - 1) * substeps)
    fmag = jnp.sqrt(fxn**2 + fyn**2)
    load_scale = jnp.maximum(jnp.sqrt(fmag), jnp.max(jnp.abs(kappa0 + us[:, 3])))
    scale = jnp.maximum(1.0, jnp.maximum(fmag, jnp.abs(mn)))
    converged = (
        path_ok
        & (sol.result == optx.RESULTS.successful)
        & jnp.all(jnp.isfinite(us))
        & (jnp.abs(residual) <= _RESIDUAL_RTOL * scale)
        & (h * load_scale <= _MAX_H_SCALE)
    )
    converged = jax.lax.stop_gradient(converged)
    s = jnp.linspace(0.0, 1.0, n_nodes) * length
    return CantileverSolution(
        s=s,
        x=us[:, 0] * length,
        y=us[:, 1] * length,
        theta=us[:, 2],
        moment=us[:, 3] * EI / length,
        clamp_moment=mu0 * EI / length,
        residual=residual,
        converged=converged,
    )


def _concrete(v):
    """``v`` as a numpy array if it is concrete (not a JAX tracer), else ``None``."""
    try:
        return np.asarray(v, dtype=np.float64)
    except (jax.errors.JAXTypeError, TypeError):
        return None


def solve_cantilever(
    length,
    EI,
    kappa0=0.0,
    force=(0.0, 0.0),
    moment=0.0,
    *,
    n_nodes: int = 101,
    substeps: int = 4,
    n_continuation: int = 8,
    n_newton: int = 5,
    throw: bool = True,
) -> CantileverSolution:
    """Solve the planar elastica of an end-loaded, initially circular cantilever.

    Args:
        length: beam length ``L`` [m], scalar > 0.
        EI: bending stiffness [N m^2], scalar > 0.
        kappa0: nondimensional initial curvature ``L/R`` (0: straight; > 0 curves towards +y).
        force: end force ``(fx, fy)`` [N] in the clamp tangent frame, constant direction (dead
            load). A pair of scalars or an array of shape ``(2,)``.
        moment: end moment ``m`` [N m], counterclockwise positive.
        n_nodes: number of output nodes of the fixed arclength grid (static).
        substeps: RK4 steps per grid interval (static); the RK4 step is
            ``L/((n_nodes-1) substeps)``.
        n_continuation: number of load-continuation steps for the initial guess (static).
        n_newton: Newton iterations per continuation step (static).
        throw: raise on bad input or non-convergence (default). With ``throw=False`` the result is
            returned as is; check ``converged``.

    Returns:
        A :class:`CantileverSolution` (tip via ``.tip``/``.tip_x``/``.tip_y``/``.tip_angle``).

    Raises:
        PPRError (a ValueError): ``length <= 0`` or ``EI <= 0`` (or non-finite inputs), when inputs
            are concrete.
        ElasticaConvergenceError: non-convergence, when inputs are concrete (message gives the
            load).
        equinox's runtime error (``eqx.error_if``): the same two failures under ``jit``/``vmap``.

    All scalar inputs may be traced; the function is jit-able, vmappable and differentiable in
    forward and reverse mode w.r.t. ``length, EI, kappa0, force, moment``. For batches use
    ``jax.vmap``.
    """
    fx, fy = force[0], force[1]
    values = {"length": length, "EI": EI, "kappa0": kappa0, "fx": fx, "fy": fy, "moment": moment}
    concrete = {k: _concrete(v) for k, v in values.items()}
    eager = all(v is not None for v in concrete.values())
    if eager:
        for name, v in concrete.items():
            if v.shape != ():
                raise PPRError(
                    f"solve_cantilever: {name} must be a scalar (got shape {v.shape}); "
                    "use jax.vmap for batches."
                )
            if not np.isfinite(v):
                raise PPRError(f"solve_cantilever: {name} must be finite (got {float(v)}).")
        for name in ("length", "EI"):
            if not concrete[name] > 0:
                raise PPRError(
                    f"solve_cantilever: {name} must be > 0 (allowed range (0, inf)); "
                    f"got {float(concrete[name])}."
                )
    kwargs = dict(n_nodes=n_nodes, substeps=substeps, n_continuation=n_continuation,
                  n_newton=n_newton)
    if n_nodes < 2 or substeps < 1 or n_continuation < 1 or n_newton < 1:
        raise PPRError("solve_cantilever: need n_nodes >= 2 and substeps, n_continuation, "
                       "n_newton >= 1.")
    if not eager and throw:
        length, EI = jnp.asarray(length, jnp.float64), jnp.asarray(EI, jnp.float64)
        length = eqx.error_if(length, ~(length > 0),
                              "solve_cantilever: length must be > 0 (allowed range (0, inf)).")
        EI = eqx.error_if(EI, ~(EI > 0),
                          "solve_cantilever: EI must be > 0 (allowed range (0, inf)).")
    sol = _solve_core(length, EI, kappa0, fx, fy, moment, **kwargs)
    if not throw:
        return sol
    try:
        converged = bool(sol.converged)
    except jax.errors.JAXTypeError:
        # Traced (inside jit/vmap/grad, even with concrete inputs): raise at run time.
        return eqx.error_if(sol, ~sol.converged, _NOT_CONVERGED_MSG)
    if not converged:
        c = concrete
        L, ei = float(c["length"]), float(c["EI"])
        raise ElasticaConvergenceError(
            "solve_cantilever: the elastica shooting solver did not converge for the load "
            f"force=({float(c['fx'])}, {float(c['fy'])}) N, moment={float(c['moment'])} N m "
            f"on a beam with length={L} m, EI={ei} N m^2, kappa0={float(c['kappa0'])} "
            f"(nondimensional |F| L^2/EI = {float(np.hypot(c['fx'], c['fy'])) * L**2 / ei:.6g}, "
            f"|m| L/EI = {abs(float(c['moment'])) * L / ei:.6g}; "
            f"residual {float(sol.residual):.3g}). The load is too large for the solver: "
            "reduce it, or increase n_nodes/substeps and n_continuation."
        )
    return sol
