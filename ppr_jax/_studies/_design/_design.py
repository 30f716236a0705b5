"""`design`: from variables, an objective and constraints to a verified optimum."""

from __future__ import annotations

import time
from typing import Mapping, Optional, Sequence

import numpy as np

from ..._errors import (
    DesignError,
)
from ..._models import get_model
from ..._names import (
    DESIGN_CANDIDATES,
    DESIGN_FD_RTOL,
    DESIGN_GRID,
    DESIGN_GRID_RTOL,
    DESIGN_STARTS,
)
from ..._params import RobotParams
from ..._scenes import SceneOptions, check_scene_commands, get_scene
from .._catalogue import (
    CATALOGUE,
    SceneContext,
    allowed_metrics,
    sampled_metrics,
    tracking_metrics,
)
from .._evaluation import equal_links
from .._sensitivity import explicit_params
from ._arguments import check_arguments
from ._goals import Constraint
from ._optimise import Scaled, optimise, screen
from ._problem import Problem
from ._rescore import rescore_l3
from ._result import Design
from ._verify import gradient_check, grid_check, kkt

#: the KKT residual (relative) below which the optimum counts as a stationary point
KKT_TOL = 1e-5
#: the finite-difference tolerance where a metric comes from an ODE solve (adaptive steps)
SCENE_FD_RTOL = 1e-3
#: the least path margins a design on a scene always keeps (`_kinematics.REACH_TOL` and
#: `SINGULAR_TOL`'s roles): a path out of reach or through a type-II singularity is infeasible
PATH_MARGIN_MIN = {"path_reach_margin": 1e-6, "path_singularity_margin": 1e-6}


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
    stroke, pose, strip_load, mode = kw["stroke"], kw["pose"], kw["strip_load"], kw["mode"]
    starts, candidates, max_iter, grid = kw["starts"], kw["candidates"], kw["max_iter"], \
        kw["grid"]
    grid_rtol, fd_rtol, seed, l3_elements = kw["grid_rtol"], kw["fd_rtol"], kw["seed"], \
        kw["l3_elements"]

    # the scene and what it allows
    ctx_scene = ctx_model = ctx_opts = None
    if scene is not None:
        ctx_scene = get_scene(scene, torque_model)
        ctx_model = get_model(model)
        opts = (SceneOptions() if options is None else options).check()
        ctx_opts = opts.prepared(ctx_model, ctx_scene.trajectory())
    allowed = allowed_metrics(None if ctx_opts is None else ctx_opts.trajectory, "design")
    if ctx_scene is not None:
        given = {c.metric for c in cons}
        cons = cons + [Constraint(m, lower=b) for m, b in PATH_MARGIN_MIN.items()
                       if m not in given]
    metrics = list(dict.fromkeys([obj.metric] + [c.metric for c in cons]))
    for m in metrics:
        if m not in allowed:
            more = "" if scene is not None else " (a scene's metrics need scene=...)"
            raise DesignError(f"unknown design metric {m!r}; allowed: {', '.join(allowed)}{more}")
    if ctx_scene is not None:
        # its tracking error only: its torques, stresses and energies are the robot's
        scene_metrics = tracking_metrics(metrics)
        follows = ctx_scene.follows_its_input(ctx_model)
        if follows and scene_metrics:
            raise DesignError(f"{', '.join(scene_metrics)} of model {ctx_model.name!r} in "
                              f"{ctx_scene.name!r} measure the integrator's error, not the robot:"
                              f" {follows}. Design with another model (double1r or beam)")
    needing = {k: [m for m in metrics if k in CATALOGUE[m].requires]
               for k in ("stroke", "strip_load")}
    if needing["stroke"] and stroke is None:
        raise DesignError(f"{', '.join(needing['stroke'])} needs stroke= (the joint rotation, "
                          f"rad, in (0, 3.14159])")
    stroke = 0.0 if stroke is None else float(stroke)
    fmodel = get_model(frequency_model)
    if needing["strip_load"]:
        if strip_load is None:
            raise DesignError(f"{', '.join(needing['strip_load'])} need strip_load=(fx, fy, m) "
                              f"(N, N, N m), three finite numbers, got None")
    else:
        strip_load = None
    pose_metrics = [m for m in metrics if CATALOGUE[m].needs == "pose"]
    if pose_metrics and fmodel.actuated_index is None:
        raise DesignError(f"{', '.join(pose_metrics)} need a "
                          f"frequency_model with free coordinates when the actuators are locked "
                          f"(double1r or beam), got {fmodel.name!r}")

    # the base robot
    if params is None:
        base = ctx_scene.default_params() if ctx_scene is not None else RobotParams()
    else:
        base = params
    if np.ndim(base.a) != 0:
        raise DesignError("a design starts from one robot, not a batch")
    if any(n in ("gamma", "rho", "K_theta") and getattr(base, n) is None for n in names):
        base = explicit_params(base)
    if ctx_scene is not None:
        check_scene_commands(ctx_scene, base, ctx_opts.trajectory, opts.t_end)
    equal = equal_links(base, names, local=False)
    k, p = len(metrics), len(names)
    mode_given = mode
    if mode is None:
        mode = "fwd" if p <= k else "rev"

    ctx = SceneContext(ctx_scene, ctx_model, ctx_opts, fmodel, pose, strip_load)
    sides = [(metrics.index(c.metric), c, side, b) for c in cons for side, b in c.sides()]
    samples = sampled_constraints(metrics, sides)
    prob = Problem(names=names, lo=lo, hi=hi, metrics=tuple(metrics), base=base, stroke=stroke,
                   ctx=ctx, mode=mode, equal_links=equal, samples=samples,
                   program_dir=program_dir)
    if mode_given is None and samples:  # the samples are rows: count them
        prob.mode = mode = "fwd" if p <= int(np.sum(prob.sizes)) else "rev"
    blocks = prob.blocks
    # one scaled constraint per raw row of the constrained metric (every sample of a sampled one)
    q_side = np.concatenate([np.full(blocks[r].size, q, dtype=int)
                             for q, (r, *_) in enumerate(sides)]) if sides else np.zeros(0, int)
    # a band to avoid: its lo as the bound, its hi beside it, scale 1 (its g is relative to
    # the band's width already)
    band = [side == "avoid" for _, _, side, _ in sides]
    edges = [b if side == "avoid" else (b, b) for _, _, side, b in sides]
    scaled = Scaled(
        problem=prob, sign=obj.sign, f_scale=None,
        rows=np.concatenate([blocks[r] for r, *_ in sides]) if sides else np.zeros(0, int),
        bounds=np.array([edges[q][0] for q in q_side], dtype=np.float64),
        upper=np.array([sides[q][2] == "upper" for q in q_side], dtype=bool),
        # the path margins are of order one however small their bound
        scale=np.array([1.0 if band[q] else _bound_scale(sides[q][1].metric, edges[q][0])
                        for q in q_side], dtype=np.float64),
        sides=q_side, avoid=np.array([band[q] for q in q_side], dtype=bool),
        band_hi=np.array([edges[q][1] for q in q_side], dtype=np.float64),
        # each edge judged as the bound it is (`Scaled.violations`): relative to its value
        edge_scale=np.array([[_bound_scale(sides[q][1].metric, e) for e in edges[q]]
                             for q in q_side], dtype=np.float64).reshape(-1, 2))

    # screen, optimise from each start, keep the best feasible
    u_base = prob.u_of([float(getattr(base, n)) for n in names])
    U0, _, _, screen_s = screen(scaled, u_base, candidates, starts, seed)
    t1 = time.perf_counter()
    runs = [optimise(scaled, u0, optimizer, max_iter) for u0 in U0]
    optimise_s = time.perf_counter() - t1
    for r, u0 in zip(runs, U0):
        r["u0"] = u0
        r["feasible"] = bool(scaled.feasible(prob.raw_value_and_jacobian(prob.x_of(r["u"]))[0]))
    feasible = [r for r in runs if r["feasible"]]
    best = (min(feasible, key=lambda r: r["fun"]) if feasible
            else min(runs, key=lambda r: (r["max_violation"], r["fun"])))

    t2 = time.perf_counter()
    if feasible:
        fd_tol = (SCENE_FD_RTOL if ctx_scene is not None else DESIGN_FD_RTOL) \
            if fd_rtol is None else fd_rtol
        kk = kkt(scaled, best["u"])
        gc = gradient_check(scaled, best["u"], fd_tol)
        gr = grid_check(scaled, best["u"], grid, grid_rtol, seed)
        verification = {"kkt_residual": kk["residual"], "kkt_tol": KKT_TOL,
                        "gradient_check": gc, "grid": gr,
                        "ok": bool(kk["residual"] <= KKT_TOL and gc["ok"] and gr["ok"])}
    else:
        kk = {"constraints": [], "bounds": []}
        verification = {"ok": False, "skipped": "no feasible optimum"}
    verify_s = time.perf_counter() - t2

    result = _assemble(prob, scaled, obj, sides, best, runs, kk, verification, optimizer, mode,
                       stroke, ctx, {"screen_s": screen_s, "optimise_s": optimise_s,
                                     "verify_s": verify_s,
                                     "total_s": time.perf_counter() - t_start})
    if feasible and l3_elements is not None:
        t3 = time.perf_counter()
        result.verification["l3"] = rescore_l3(
            prob.metrics, result.params, ctx, stroke, result.metrics, obj,
            [(c.metric, side, b) for _, c, side, b in sides], l3_elements,
            None if ctx_scene is None else (SceneOptions() if options is None else options),
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


def _bound_scale(metric: str, bound: float) -> float:
    """What a bound's violation is relative to (`Scaled.scale`, `edge_scale`): |bound|, or 1
    where the bound is 0 or the metric a path margin (of order one however small its bound)."""
    return 1.0 if bound == 0 or CATALOGUE[metric].needs == "path" else abs(float(bound))


def sampled_constraints(metrics, sides) -> tuple:
    """The constrained metrics of `sampled_metrics` given to the optimiser as their samples:
    those whose every bound is on their extreme's side (an upper bound on a max, a lower bound
    on a min: then it holds on the extreme if and only if it holds on every sample), except the
    objective's metric (`metrics[0]`). A band to avoid on such a metric is on neither side: the
    metric stays its extreme, one value, the band's constraint on it."""
    out = []
    for m in dict.fromkeys(metrics[1:]):
        kind = sampled_metrics().get(m)
        mine = [side for _, c, side, _ in sides if c.metric == m]
        if m != metrics[0] and kind and mine and all(
                side == ("upper" if kind == "max" else "lower") for side in mine):
            out.append(m)
    return tuple(out)


def _assemble(prob, scaled, obj, sides, best, runs, kk, verification, optimizer, mode, stroke,
              ctx, timing) -> Design:
    names = prob.names
    fs = scaled.f_scale
    u = best["u"]
    x = prob.x_of(u)
    v = prob.values(x)
    v0 = prob.values(prob.x_of(best["u0"]))
    raw = prob.raw_value_and_jacobian(x)[0]
    viol_rows = scaled.violations(raw) if sides else np.zeros(0)
    dc_lo, dc_hi = scaled.dc_dbounds(raw) if sides else (np.zeros(0), np.zeros(0))
    mu_rows = np.zeros(scaled.rows.size)  # the KKT multipliers (scaled) of every row
    for i, m in kk["constraints"]:
        mu_rows[i] += m
    constraints = []
    for q, (row, c, side, b) in enumerate(sides):
        mine = scaled.sides == q
        # d(optimum)/d(bound) = -mu dc/d(bound) for the scaled objective sign f/fs: relaxing an
        # upper bound by delta adds delta/scale to the c of every row of this side (each sample
        # of a sampled metric): their multipliers add up; a band's edges each have their own
        d_lo = float(-scaled.sign * fs * np.sum(mu_rows[mine] * dc_lo[mine])) + 0.0
        n_active = sum(1 for i, _ in kk["constraints"] if mine[i])
        viol = float(np.max(viol_rows[mine])) if mine.any() else 0.0
        entry = {"metric": c.metric, "side": side, "bound": b, "value": float(v[row]),
                 "active": bool(n_active), "active_samples": n_active, "multiplier": d_lo,
                 "violation": viol, "violation_abs": viol * float(scaled.scale[mine][0])}
        if side == "avoid":
            lo, hi = b
            d_hi = float(-scaled.sign * fs * np.sum(mu_rows[mine] * dc_hi[mine])) + 0.0
            edge = "lower" if v[row] <= (lo + hi) / 2 else "upper"
            entry.update(bound=[lo, hi], edge=edge, multipliers={"lower": d_lo, "upper": d_hi},
                         multiplier=d_lo if edge == "lower" else d_hi,
                         violation_abs=float(max(0.0, min(v[row] - lo, hi - v[row]))))
        constraints.append(entry)
    active_bounds = []
    for i, side, mu in kk["bounds"]:
        width = prob.hi[i] - prob.lo[i]
        d = -scaled.sign * fs * mu / width
        d = d if side == "upper" else -d
        active_bounds.append({"variable": names[i], "side": side,
                              "bound": float(prob.hi[i] if side == "upper" else prob.lo[i]),
                              "multiplier": float(d)})
    history = [{"iteration": h["iteration"],
                "x": dict(zip(names, map(float, prob.x_of(h["u"])))),
                "objective": float(scaled.sign * h["objective"] * fs),
                "max_violation": h["max_violation"]} for h in best["history"]]
    start_rows = [{"start": dict(zip(names, map(float, prob.x_of(r["u0"])))),
                   "optimum": dict(zip(names, map(float, prob.x_of(r["u"])))),
                   "objective": float(scaled.sign * r["fun"] * fs), "feasible": r["feasible"],
                   "max_violation": r["max_violation"], "iterations": r["nit"],
                   "evaluations": r["nfev"], "jacobians": r["jacobians"],
                   "success": r["success"], "message": r["message"],
                   "seconds": r["seconds"]} for r in runs]
    params = prob.base.replace(**dict(zip(names, map(float, x))))
    info = {"optimizer": optimizer, "mode": mode, "stroke_rad": stroke,
            "strip_load": ctx.strip_load, "pose": ctx.pose,
            "scene": None if ctx.scene is None else ctx.scene.name,
            "model": None if ctx.model is None else ctx.model.name,
            "frequency_model": ctx.frequency_model.name, "objective_scale": fs,
            "evaluations": prob.evaluations, "jacobians": prob.jacobians,
            "constraint_rows": int(scaled.rows.size),
            "sampled_constraints": list(prob.samples)}
    if ctx.options is not None:
        info.update(t_end=float(ctx.options.t_end), n_out=int(ctx.options.n_out))
    return Design(
        variables=list(names),
        bounds={n: (float(a), float(b)) for n, a, b in zip(names, prob.lo, prob.hi)},
        x=dict(zip(names, map(float, x))),
        x_start=dict(zip(names, map(float, prob.x_of(best["u0"])))),
        objective={"metric": obj.metric, "sense": obj.sense, "value": float(v[0]),
                   "start_value": float(v0[0])},
        constraints=constraints, active_bounds=active_bounds,
        metrics=dict(zip(prob.metrics, map(float, v))), params=params, history=history,
        starts=start_rows, verification=verification, info=info, timing=timing,
        evaluate=prob.values)
