"""A design's result assembled from its runs: the optimum, the constraints with their
multipliers (d optimum / d bound), the active bounds, the history and every start."""

from __future__ import annotations

import numpy as np

from ._result import Design


def assemble(prob, scaled, obj, sides, best, runs, kk, verification, optimizer, mode, stroke,
             ctx, timing) -> Design:
    """The `Design` of the best run `best` of `runs` (`multistart`) of the `Scaled` problem
    `scaled` over `prob`: the optimum and its metrics, each constraint side of `sides` with its
    value, violation and multiplier d(optimum)/d(bound) (from the KKT multipliers `kk`), the
    active bounds, the best run's history, every start, the `verification`, the settings and
    the `timing`."""
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
