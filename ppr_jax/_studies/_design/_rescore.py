"""The optimum re-scored with the quasi-static L3 (`QuasiStaticBeam(N)`), against the
pseudo-rigid-body model's error band.

A design's metrics come from the PRB models (L1, L2: the double-1R joint) where they depend on
a model at all. L3 bends each strip as a chain of N elements (the strip's own elastica, its
clamps where they are), so it is the check of a PRB design: the metrics that depend on a model
(`base_frequency_hz` and the compliance through `frequency_model`, the scene metrics through
`model`) are evaluated again at the optimum with L3 in both roles; the closed forms (`pivot_*`,
`moving_mass_kg`) and the path margins (the input model's kinematics) do not depend on them.

**The band.** The PRB parameters come from Howell & Midha's fit to the elastica of the
initially curved half-joint (docs/prb_fit.md, the shipped table): over the fit's load range
(14 load directions, up to 1 rad of tip rotation) the PRB torque at a given PRB angle is off
the elastica's by at most `load_error_max`, at the design's kappa0 = theta_c/2 (interpolated
linearly in the table: 3.5 % at kappa0 = 0, 19 % at Table 1's 0.94, 34 % at 2). The joint's
stiffness is therefore uncertain by e = `load_error_max`, and a metric proportional to it (or
to its inverse: stresses, torques, compliances) by the same relative e; a frequency, as
sqrt(K), by 1 - sqrt(1 - e). A tracking error or an energy has no such bound: the band e is
reported for them as a scale, not a derived bound. What the band does not contain: the
geometry of the PRB chain itself (the paper's centre-line chain is about 2.3 times softer than
L3 in the robot's compliance, docs/models.md; `joint_geometry="strip"` brings it to 8 %), which
a design on the default geometry will show as outside the band.
"""

from __future__ import annotations

import dataclasses
from typing import Optional

import jax.numpy as jnp
import numpy as np

from ..._prb_table import prb_table
from ..._programs import cached_program
from .._catalogue import CATALOGUE, SceneContext
from .._evaluation import Evaluation
from ._problem import metrics_program, program_label

#: the metrics that are frequencies (their band is that of sqrt(K))
FREQUENCY_METRICS = ("base_frequency_hz",)


def prb_band(theta_c: float) -> tuple[float, float]:
    """(kappa0, e): the half-joint's initial curvature theta_c/2 and the PRB fit's largest
    relative torque error against the elastica there (module docstring), interpolated
    linearly in the shipped table."""
    t = prb_table()
    kappa0 = float(theta_c) / 2
    e = float(np.interp(kappa0, np.asarray(t["kappa0"]), np.asarray(t["load_error_max"])))
    return kappa0, e


def metric_band(name: str, e: float) -> float:
    """The relative band of metric `name` for a stiffness uncertain by e (module docstring)."""
    return 1.0 - float(np.sqrt(1.0 - e)) if name in FREQUENCY_METRICS else e


def model_dependent(names) -> list:
    """The metrics of `names` that depend on the model (not closed forms, not path margins):
    those of the catalogue that need the scene's run or a pose of `frequency_model`."""
    return [n for n in names if CATALOGUE[n].needs in ("run", "pose")]


def rescore_l3(names, params, ctx: SceneContext, stroke: float, prb_values: dict, objective,
               constraints, n_elements: int, raw_options=None, equal_links: bool = True,
               program_dir: Optional[str] = None) -> dict:
    """The model-dependent metrics at the optimum with `QuasiStaticBeam(n_elements)`, against
    the PRB values and the band (module docstring).

    **Arguments:**

    - `names`: the design's metrics; `params`: the optimum's `RobotParams`; `ctx`: the design's
      `SceneContext`; `stroke`: of `pivot_stress_Pa`; `prb_values` {name: value} at the optimum.
    - `objective`: the `Objective`; `constraints`: [(metric, side, bound)] (side 'avoid':
      bound (lo, hi), met outside the open band).
    - `n_elements`: L3's segments per strip.
    - `raw_options`: the scene's `SceneOptions` before `prepared` (re-prepared for L3).
    - `equal_links`: `Robot`'s static choice.
    - `program_dir`: a directory of stored programs (`Problem`'s), or None.

    **Returns:** {model, n_elements, kappa0, band (e), band_source, metrics: {name: {prb, l3,
    relative, band, within}}, objective_within, constraints_met (per constraint side, with
    L3's value), within (every model-dependent metric inside its band), note}.
    """
    from ..._models import QuasiStaticBeam

    kappa0, e = prb_band(float(params.theta_c))
    dep = model_dependent(names)
    out = {"model": "beam (quasi-static strips)", "n_elements": int(n_elements),
           "kappa0": kappa0, "band": e,
           "band_source": "the PRB fit's largest torque error against the elastica over its "
                          "load range at kappa0 = theta_c/2 (docs/prb_fit.md, shipped table)",
           "metrics": {}, "constraints_met": []}
    if not dep:
        out.update(objective_within=True, within=True,
                   note="no metric of this design depends on the model (closed forms and path "
                        "margins): L3 gives the same values")
        return out
    l3 = QuasiStaticBeam(int(n_elements))
    scene_opts = None
    if ctx.scene is not None and raw_options is not None:
        scene_opts = raw_options.prepared(l3, ctx.scene.trajectory())
    ctx3 = dataclasses.replace(ctx, model=None if ctx.model is None else l3,
                               options=scene_opts if scene_opts is not None else ctx.options,
                               frequency_model=l3)
    st = Evaluation((), tuple(dep), bool(equal_links), (), ctx3)
    args = (params, jnp.asarray(stroke, dtype=jnp.float64), st)
    values = cached_program(metrics_program, args, 0, program_dir, program_label(st, "l3"))
    v = np.asarray(values(*args))
    for n, v3 in zip(dep, map(float, v)):
        prb = float(prb_values[n])
        rel = abs(v3 - prb) / max(abs(prb), 1e-300) if np.isfinite(v3) else float("nan")
        band = metric_band(n, e)
        out["metrics"][n] = {"prb": prb, "l3": v3, "relative": rel, "band": band,
                             "within": bool(np.isfinite(rel) and rel <= band)}
    for metric, side, bound in constraints:
        val = out["metrics"][metric]["l3"] if metric in out["metrics"] else float(
            prb_values[metric])
        if side == "avoid":
            met = val <= bound[0] or val >= bound[1]
        else:
            met = (val <= bound) if side == "upper" else (val >= bound)
        out["constraints_met"].append({"metric": metric, "side": side, "bound": bound,
                                       "l3": val, "met": bool(np.isfinite(val) and met)})
    out["objective_within"] = (out["metrics"][objective.metric]["within"]
                               if objective.metric in out["metrics"] else True)
    out["within"] = all(m["within"] for m in out["metrics"].values())
    out["note"] = ("inside the PRB model's error band" if out["within"] else
                   "NOT inside the PRB model's error band: " + ", ".join(
                       f"{n} {m['relative']:.1%} > {m['band']:.1%}"
                       for n, m in out["metrics"].items() if not m["within"]))
    return out

