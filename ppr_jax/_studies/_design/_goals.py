"""What a design asks for: one `Objective` and any number of `Constraint`s, each on a metric
of the catalogue (`_catalogue`)."""

from __future__ import annotations

import dataclasses
from typing import Optional

from ..._errors import DesignError, check_bounds, check_real


@dataclasses.dataclass(frozen=True)
class Objective:
    """The metric a design minimises or maximises.

    **Arguments:**

    - `metric`: a name of the catalogue (`design_metrics`), SI units.
    - `sense`: `"max"` or `"min"`.
    """

    metric: str
    sense: str = "max"

    def __post_init__(self):
        if self.sense not in ("max", "min"):
            raise DesignError(f"objective sense must be 'max' or 'min', got {self.sense!r}")

    @property
    def sign(self) -> float:
        """+1 for a minimisation, -1 for a maximisation: the optimiser minimises sign * metric."""
        return 1.0 if self.sense == "min" else -1.0


@dataclasses.dataclass(frozen=True)
class Constraint:
    """A bound on a metric, `lower <= metric <= upper` (either may be None), or a band it must
    stay out of, `metric <= lo or metric >= hi` (`avoid=(lo, hi)`: a resonance to keep clear
    of, say).

    **Arguments:**

    - `metric`: a name of the catalogue (`design_metrics`), SI units.
    - `upper`, `lower`: the bounds in the metric's unit.
    - `avoid`: (lo, hi) with lo < hi, in the metric's unit: the open interval the metric must
      lie outside of. Not together with `upper` or `lower` (give a second `Constraint` on the
      same metric for those).

    One of `upper`, `lower`, `avoid` at least.

    **A band to avoid** reaches the optimiser as one smooth constraint,
    g = (metric - lo)(metric - hi)/(hi - lo)^2 >= 0: positive outside the band, zero on its
    edges, -1/4 at its middle; near an edge it is the distance from the edge over the band's
    width, (lo - metric)/(hi - lo) below it and (metric - hi)/(hi - lo) above. Its feasible
    set has two parts, below and above the band, and a gradient-based optimiser stays in the
    part its start leads to: `design` gives the starts' screening both parts (the best
    candidate of each side of every band is among the starts where `starts` allows) and keeps
    the best feasible optimum. Each edge has its own multiplier, d(optimum)/d lo and
    d(optimum)/d hi (at most one non-zero). On a peak or margin over samples
    (`sampled_metrics`) the band applies to the extreme itself (one constraint, a subgradient
    where samples tie), not to every sample.
    """

    metric: str
    upper: Optional[float] = None
    lower: Optional[float] = None
    avoid: Optional[tuple] = None

    def __post_init__(self):
        if self.upper is None and self.lower is None and self.avoid is None:
            raise DesignError(f"constraint on {self.metric!r} needs an upper or a lower bound "
                              f"or a band to avoid (avoid=(lo, hi))")
        if not isinstance(self.metric, str):
            raise DesignError(f"a constraint's metric must be a metric's name, got "
                              f"{self.metric!r}")
        for side in ("upper", "lower"):
            v = getattr(self, side)
            if v is not None:
                object.__setattr__(self, side, check_real(
                    f"constraint on {self.metric!r}: the {side} bound", v, error=DesignError,
                    kind="a finite number"))
        if self.upper is not None and self.lower is not None and not self.lower < self.upper:
            raise DesignError(f"constraint on {self.metric!r}: lower {self.lower:g} must be "
                              f"below upper {self.upper:g}")
        if self.avoid is not None:
            object.__setattr__(self, "avoid", self._band(self.avoid))
            if self.upper is not None or self.lower is not None:
                raise DesignError(f"constraint on {self.metric!r}: avoid=(lo, hi) takes no "
                                  f"upper or lower bound; give those as a second constraint "
                                  f"on {self.metric!r}")

    def _band(self, band) -> tuple:
        return check_bounds(f"constraint on {self.metric!r}: avoid", band, error=DesignError)

    def sides(self) -> list:
        """[(side, bound)] for the bounds given: 'upper' means metric <= bound, 'lower'
        metric >= bound, 'avoid' (bound (lo, hi)) metric outside the open interval."""
        if self.avoid is not None:
            return [("avoid", tuple(self.avoid))]
        return [(s, float(getattr(self, s))) for s in ("upper", "lower")
                if getattr(self, s) is not None]


def bound_text(side: str, bound) -> str:
    """A constraint side as text: '<= b', '>= b' or 'outside (lo, hi)'."""
    if side == "avoid":
        return f"outside ({bound[0]:g}, {bound[1]:g})"
    return f"{'<=' if side == 'upper' else '>='} {bound:g}"


def band_g(m, lo, hi):
    """The smooth constraint of a band to avoid (`Constraint`), (m - lo)(m - hi)/(hi - lo)^2,
    and its derivatives in m, lo and hi: (g, dg/dm, dg/dlo, dg/dhi), elementwise."""
    w = hi - lo
    g = (m - lo) * (m - hi) / w**2
    return (g, (2 * m - lo - hi) / w**2,
            -(m - hi) / w**2 + 2 * (m - lo) * (m - hi) / w**3,
            -(m - lo) / w**2 - 2 * (m - lo) * (m - hi) / w**3)


def as_objective(objective) -> Objective:
    """An `Objective` from itself, a metric name (maximised) or {"metric", "sense"} /
    {"maximize": name} / {"minimize": name}."""
    if isinstance(objective, Objective):
        return objective
    if isinstance(objective, str):
        return Objective(objective, "max")
    if isinstance(objective, dict):
        d = dict(objective)
        if "maximize" in d or "minimize" in d:
            if len(d) != 1:
                raise DesignError(f"objective: give one of maximize or minimize, got {d}")
            ((key, metric),) = d.items()
            return Objective(metric, "max" if key == "maximize" else "min")
        try:
            return Objective(**d)
        except TypeError:
            pass
    raise DesignError(f"objective must be a metric name, an Objective or {{'maximize': name}}, "
                      f"got {objective!r}")


def as_constraints(constraints) -> list:
    """`Constraint`s from themselves or dicts {"metric", "upper", "lower", "avoid"}."""
    if constraints is None:
        return []
    if isinstance(constraints, (Constraint, dict)):  # one constraint, not in a list
        constraints = [constraints]
    if isinstance(constraints, (str, bytes)) or not hasattr(constraints, "__iter__"):
        raise DesignError(f"constraints must be a sequence of Constraints or dicts "
                          f"{{metric, upper, lower, avoid}}, got {constraints!r}")
    out = []
    for c in constraints:
        if isinstance(c, Constraint):
            out.append(c)
        elif isinstance(c, dict):
            try:
                out.append(Constraint(**c))
            except TypeError:
                raise DesignError(f"a constraint takes metric, upper, lower and avoid, got "
                                  f"{c}") from None
        else:
            raise DesignError(f"a constraint must be a Constraint or a dict, got {c!r}")
    return out
