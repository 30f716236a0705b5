"""Design variables: `RobotParams` fields with bounds (SI units), checked against the
parameters' physical ranges before anything is compiled."""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from ..._errors import DesignError
from ..._names import PARAM_RANGES


def check_variables(variables: Mapping) -> tuple[list, np.ndarray, np.ndarray]:
    """The design variables as (names, lo, hi), validated.

    **Arguments:**

    - `variables`: {name: (lo, hi)}, a float field of `RobotParams` (`PARAM_RANGES`) and its
      bounds in SI units, lo < hi.

    **Returns:** (names (p,), lo (p,), hi (p,)), in the order given.

    A `DesignError` names the variable and the allowed range where a name is unknown, a bound is
    not a finite number, lo >= hi, or a bound lies outside the parameter's physical range (a
    non-positive strip thickness, an arc angle beyond 3 rad...).
    """
    if not isinstance(variables, Mapping) or not variables:
        raise DesignError("variables must be a non-empty mapping {name: (lo, hi)} of RobotParams "
                          f"fields; allowed names: {', '.join(PARAM_RANGES)}")
    names, lo, hi = [], [], []
    for name, bounds in variables.items():
        if name not in PARAM_RANGES:
            raise DesignError(f"design variable {name!r} is not a float parameter of RobotParams;"
                              f" allowed: {', '.join(PARAM_RANGES)}")
        plo, phi, unit, meaning = PARAM_RANGES[name]
        rng = f"[{plo:g}, {phi:g}] {unit}".rstrip()
        try:
            a, b = bounds
            a, b = _number(a), _number(b)
        except (TypeError, ValueError, OverflowError):
            raise DesignError(f"design variable {name!r} ({meaning}): bounds must be two finite "
                              f"numbers (lo, hi) in {unit}, got {_shown(bounds)} (physical range "
                              f"{rng})") from None
        for side, v in (("lower", a), ("upper", b)):
            if v < plo or v > phi:
                raise DesignError(f"design variable {name!r} ({meaning}): the {side} bound "
                                  f"{v:g} {unit} is outside its physical range {rng}")
        if not a < b:
            raise DesignError(f"design variable {name!r} ({meaning}): the lower bound {a:g} must "
                              f"be below the upper bound {b:g} (physical range {rng})")
        names.append(name)
        lo.append(a)
        hi.append(b)
    return names, np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)


def _shown(bounds) -> str:
    """The bounds as given, a huge integer by its digit count."""
    if isinstance(bounds, (tuple, list)):
        return "(" + ", ".join(_shown(b) for b in bounds) + ")"
    if isinstance(bounds, int) and not isinstance(bounds, bool) and abs(bounds) >= 10**30:
        return f"an integer of {len(str(abs(bounds)))} digits"
    return repr(bounds)


def _number(v) -> float:
    if isinstance(v, (bool, str, bytes)) or v is None:
        raise ValueError
    x = float(v)
    if not math.isfinite(x):
        raise ValueError
    return x
