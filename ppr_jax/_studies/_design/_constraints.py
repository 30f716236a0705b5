"""The constraints of a design as the optimiser sees them: each bound a side (metric, bound),
the sampled metrics constrained sample by sample, and the scaled rows of `Scaled` (one per raw
row of a constrained metric, each relative to its bound)."""

from __future__ import annotations

import numpy as np

from .._catalogue import CATALOGUE, sampled_metrics
from ._goals import Constraint
from ._optimise import Scaled
from ._problem import Problem

#: the least path margins a design on a scene always keeps (`_kinematics.REACH_TOL` and
#: `SINGULAR_TOL`'s roles): a path out of reach or through a type-II singularity is infeasible
PATH_MARGIN_MIN = {"path_reach_margin": 1e-6, "path_singularity_margin": 1e-6}


def with_path_margins(constraints: list) -> list:
    """`constraints` and a lower bound `PATH_MARGIN_MIN` on each path margin they leave
    unbounded: a design on a scene keeps its path in reach and off the singularities."""
    given = {c.metric for c in constraints}
    return constraints + [Constraint(m, lower=b) for m, b in PATH_MARGIN_MIN.items()
                          if m not in given]


def constraint_sides(metrics, constraints) -> list:
    """(index of the metric in `metrics`, constraint, side, bound) of every bound of
    `constraints` (`Constraint.sides`: 'upper', 'lower' or 'avoid' with its band)."""
    return [(metrics.index(c.metric), c, side, b) for c in constraints
            for side, b in c.sides()]


def bound_scale(metric: str, bound: float) -> float:
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


def scaled_problem(prob: Problem, sign: float, sides: list) -> Scaled:
    """The `Scaled` problem of `prob` (the objective's `sign`) with one scaled constraint per
    raw row of each constraint side of `sides` (`constraint_sides`; every sample of a sampled
    metric). A band to avoid has its lo as the bound, its hi beside it and scale 1 (its g is
    relative to the band's width already); each edge is judged as the bound it is
    (`Scaled.violations`): relative to its value."""
    blocks = prob.blocks
    q_side = np.concatenate([np.full(blocks[r].size, q, dtype=int)
                             for q, (r, *_) in enumerate(sides)]) if sides else np.zeros(0, int)
    band = [side == "avoid" for _, _, side, _ in sides]
    edges = [b if side == "avoid" else (b, b) for _, _, side, b in sides]
    return Scaled(
        problem=prob, sign=sign, f_scale=None,
        rows=np.concatenate([blocks[r] for r, *_ in sides]) if sides else np.zeros(0, int),
        bounds=np.array([edges[q][0] for q in q_side], dtype=np.float64),
        upper=np.array([sides[q][2] == "upper" for q in q_side], dtype=bool),
        # the path margins are of order one however small their bound
        scale=np.array([1.0 if band[q] else bound_scale(sides[q][1].metric, edges[q][0])
                        for q in q_side], dtype=np.float64),
        sides=q_side, avoid=np.array([band[q] for q in q_side], dtype=bool),
        band_hi=np.array([edges[q][1] for q in q_side], dtype=np.float64),
        edge_scale=np.array([[bound_scale(sides[q][1].metric, e) for e in edges[q]]
                             for q in q_side], dtype=np.float64).reshape(-1, 2))
