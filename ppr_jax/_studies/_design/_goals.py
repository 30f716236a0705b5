"""What a design asks for: one `Objective` and any number of `Constraint`s, each on a metric
of the catalogue (`_catalogue`)."""

from __future__ import annotations

import dataclasses
import math
from typing import Optional

from ..._errors import DesignError


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
    """A bound on a metric: `lower <= metric <= upper` (either may be None).

    **Arguments:**

    - `metric`: a name of the catalogue (`design_metrics`), SI units.
    - `upper`, `lower`: the bounds in the metric's unit (at least one).
    """

    metric: str
    upper: Optional[float] = None
    lower: Optional[float] = None

    def __post_init__(self):
        if self.upper is None and self.lower is None:
            raise DesignError(f"constraint on {self.metric!r} needs an upper or a lower bound")
        for side in ("upper", "lower"):
            v = getattr(self, side)
            if v is not None and (isinstance(v, (bool, str)) or not math.isfinite(float(v))):
                raise DesignError(f"constraint on {self.metric!r}: the {side} bound must be a "
                                  f"finite number, got {v!r}")
        if self.upper is not None and self.lower is not None and not self.lower < self.upper:
            raise DesignError(f"constraint on {self.metric!r}: lower {self.lower:g} must be "
                              f"below upper {self.upper:g}")

    def sides(self) -> list:
        """[(side, bound)] for the bounds given: 'upper' means metric <= bound."""
        return [(s, float(getattr(self, s))) for s in ("upper", "lower")
                if getattr(self, s) is not None]


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
    """`Constraint`s from themselves or dicts {"metric", "upper", "lower"}."""
    out = []
    for c in constraints or ():
        if isinstance(c, Constraint):
            out.append(c)
        elif isinstance(c, dict):
            try:
                out.append(Constraint(**c))
            except TypeError:
                raise DesignError(f"a constraint takes metric, upper and lower, got {c}") from None
        else:
            raise DesignError(f"a constraint must be a Constraint or a dict, got {c!r}")
    return out
