"""`design`: from variables, an objective and constraints to a verified optimum."""

from __future__ import annotations

import time
from typing import Mapping, Optional, Sequence

from ..._errors import DesignError
from ..._names import (
    DESIGN_CANDIDATES,
    DESIGN_FD_RTOL,
    DESIGN_GRID,
    DESIGN_GRID_RTOL,
    DESIGN_STARTS,
)
from ..._params import RobotParams
from ..._scenes import SceneOptions
from ._arguments import check_arguments, check_base, check_metrics
from ._assemble import assemble
from ._constraints import constraint_sides, sampled_constraints, scaled_problem
from ._optimise import multistart
from ._problem import design_problem
from ._rescore import rescore_l3
from ._result import Design
from ._verify import verify

#: the finite-difference tolerance where a metric comes from an ODE solve (adaptive steps)
SCENE_FD_RTOL = 1e-3


def design(
    variables: Mapping,
    objective,
    constraints: Sequence = (),
    *,
    params: Optional[RobotParams] = None,
    stroke: Optional[float] = None,
    scene=None,
    model="double1r",
    torque_model=None,
    frequency_model="double1r",
    options: Optional[SceneOptions] = None,
    pose=None,
    strip_load=None,
    l3_elements: Optional[int] = 4,
    optimizer: str = "slsqp",
    mode: Optional[str] = None,
    starts: int = DESIGN_STARTS,
    candidates: int = DESIGN_CANDIDATES,
    max_iter: int = 100,
    grid: int = DESIGN_GRID,
    grid_rtol: float = DESIGN_GRID_RTOL,
    fd_rtol: Optional[float] = None,
    seed: int = 0,
    program_dir: Optional[str] = None,
) -> Design:
    """Design a robot with gradients: the `variables` (fields of `RobotParams`) within their
    bounds that optimise `objective` subject to `constraints`, found by a gradient-based
    constrained optimiser from several starts and verified.

    The starts: `candidates` points (the base robot's, clipped into the box, and a scrambled
    Sobol sequence) are evaluated in one batched call and the `starts` best (objective plus a
    penalty on violated constraints) run scipy's SLSQP or trust-constr, fed the metrics' JAX
    Jacobian (`jax.jacfwd` where there are no more variables than rows: the metrics, each
    sample of a peak constrained per sample a row; `jax.jacrev` otherwise), in variables
    normalised to [0, 1] and with the objective and constraints scaled to order one. A peak or
    margin over samples (`sampled_metrics`: stress, torque, path margins) bounded on its
    extreme's side is one constraint per sample, each smooth where the extreme has kinks at
    ties (`sampled_constraints`). A band to avoid, whose feasible set lies on both of its sides,
    has the best candidate of each side among the starts (`pick_starts`). The best feasible
    optimum is then verified
    (`Design.verification`): its Karush-Kuhn-Tucker residual with the multipliers of the
    active constraints and bounds, the JAX gradient against finite differences there, and a
    dense grid over the box (a Sobol sample beyond four variables) in one batched call, whose
    best feasible objective the optimum must be within `grid_rtol` of.

    **Arguments:**

    - `variables`: {name: (lo, hi)}: float fields of `RobotParams` and their bounds (SI),
      inside each parameter's physical range (`PARAM_RANGES`).
    - `objective`: a metric name (maximised), `Objective(metric, sense)` or
      {"maximize": name} / {"minimize": name}.
    - `constraints`: `Constraint(metric, upper=..., lower=...)`s, `Constraint(metric,
      avoid=(lo, hi))`s (the metric outside the open band; one smooth constraint, and the
      starts' screening covers both sides of the band: `Constraint`), or dicts of those
      fields.
    - `params`: the robot whose other fields stay as they are (default: the scene's, else
      Table 1). Its gamma, rho and K_theta left None follow the PRB table as theta_c changes.
    - `stroke`: the joint rotation (rad, in (0, pi]) of `pivot_stress_Pa`.
    - `scene`: a registered scene name or an `AbstractScene`, for the scene metrics; `model`,
      `torque_model`: the model it runs and the one that computes its torques (as
      `sensitivity`); `options`: its `SceneOptions`.
    - `frequency_model`: the model of `base_frequency_hz` and the compliance metrics.
    - `pose`: (x, y, phi) (m, m, rad) of the compliance metrics (default: home).
    - `strip_load`: (fx, fy, m) (N, N, N m), the end load of the elastica metrics
      (`strip_tip_rotation_rad`, `strip_elastica_stress_Pa`) in the strip's clamp frame.
    - `l3_elements`: N of the quasi-static L3 (`QuasiStaticBeam(N)`) that re-scores the optimum's
      model-dependent metrics against the PRB model's error band
      (`Design.verification["l3"]`, `_rescore`); None: not re-scored.
    - `optimizer`: 'slsqp' or 'trust-constr'.
    - `mode`: 'fwd' or 'rev' (default by the counts above).
    - `starts`, `candidates`: starts run, points screened for them.
    - `max_iter`: the optimiser's iteration limit per start.
    - `grid`: points of the verification grid; `grid_rtol`: its tolerance (relative).
    - `fd_rtol`: the finite-difference check's tolerance (default 1e-5, 1e-3 with a scene).
    - `seed`: of the Sobol sequences.
    - `program_dir`: a directory of stored programs (as `run_scene`'s; the command line's): the
      design's programs (the metrics with their Jacobian, the batch, the L3 re-score) are
      exported there once and loaded by later processes, which skip tracing them; None:
      compiled in this process (and kept for later designs of the same structure).

    **Returns:** a `Design`.

    **Raises:** `DesignError` for an unknown variable or metric, bounds outside a parameter's
    physical range, or a specification no start could meet (naming the constraint and by how
    much it is violated at the best point found; `err.result` is that `Design`).
    """
    t_start = time.perf_counter()
    names, lo, hi, obj, cons, kw = check_arguments(
        variables, objective, constraints, params, options, dict(
            stroke=stroke, scene=scene, model=model, torque_model=torque_model,
            frequency_model=frequency_model, optimizer=optimizer, mode=mode, starts=starts,
            candidates=candidates, max_iter=max_iter, grid=grid, grid_rtol=grid_rtol,
            fd_rtol=fd_rtol, seed=seed, pose=pose, strip_load=strip_load,
            l3_elements=l3_elements))
    ctx, opts, metrics, cons, stroke = check_metrics(obj, cons, scene, model, torque_model,
                                                     frequency_model, options, kw)
    base = check_base(params, ctx, opts, names)
    sides = constraint_sides(metrics, cons)
    prob = design_problem(names, lo, hi, metrics, base, stroke, ctx, kw["mode"],
                          sampled_constraints(metrics, sides), program_dir)
    scaled = scaled_problem(prob, obj.sign, sides)

    # screen, optimise from each start, keep the best feasible, verify it
    u_base = prob.u_of([float(getattr(base, n)) for n in names])
    runs, best, feasible, timing = multistart(scaled, u_base, kw["candidates"], kw["starts"],
                                              kw["seed"], optimizer, kw["max_iter"])
    t2 = time.perf_counter()
    if feasible:
        fd_tol = kw["fd_rtol"]
        if fd_tol is None:
            fd_tol = SCENE_FD_RTOL if ctx.scene is not None else DESIGN_FD_RTOL
        kk, verification = verify(scaled, best["u"], fd_tol, kw["grid"], kw["grid_rtol"],
                                  kw["seed"])
    else:
        kk = {"constraints": [], "bounds": []}
        verification = {"ok": False, "skipped": "no feasible optimum"}
    timing.update(verify_s=time.perf_counter() - t2, total_s=time.perf_counter() - t_start)

    result = assemble(prob, scaled, obj, sides, best, runs, kk, verification, optimizer,
                      prob.mode, stroke, ctx, timing)
    if feasible and kw["l3_elements"] is not None:
        t3 = time.perf_counter()
        result.verification["l3"] = rescore_l3(
            prob.metrics, result.params, ctx, stroke, result.metrics, obj,
            [(c.metric, side, b) for _, c, side, b in sides], kw["l3_elements"],
            None if ctx.scene is None else (SceneOptions() if options is None else options),
            prob.equal_links, program_dir)
        result.timing["l3_s"] = time.perf_counter() - t3
        result.timing["total_s"] = time.perf_counter() - t_start
    if not feasible:
        why = result.infeasibility or ("no start reached a point where every metric is "
                                       "finite (the scene failed)")
        err = DesignError(f"the specification cannot be met: {why}; widen the bounds or relax "
                          f"the constraint")
        err.result = result
        raise err
    return result
