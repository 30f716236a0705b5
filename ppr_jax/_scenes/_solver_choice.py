"""`solver="auto"`: explicit or implicit integration, chosen from a stiffness estimate.

An explicit Runge-Kutta method is stable only for steps h <= `EXPLICIT_STABILITY` / omega_max,
omega_max the highest natural frequency (rad/s) of the linearised robot; an implicit one is not
bound by it and takes the steps its error control asks for, each `IMPLICIT_STEP_COST` times
dearer. The problem is stiff, and Kvaerno5 faster, when the explicit method's stable step rate
omega_max / `EXPLICIT_STABILITY` (per second of motion) exceeds `IMPLICIT_STEP_COST` times the
implicit method's accuracy-bound step rate `implicit_step_rate(rtol)`. The constants are
measured on the L2 servo-circle at t = 2 and 4 mm (`benchmarks/implicit_l2.py`, 2-core CPU):

- `EXPLICIT_STABILITY`: Tsit5 at t = 4 mm takes 1,660 accepted steps per second at every
  rtol from 1e-3 to 1e-5 (stability-bound) against omega_max = 3,656 rad/s (581.8 Hz).
- `IMPLICIT_STEP_COST`: a Kvaerno5 step (five stages, chord iterations, one Jacobian) costs
  0.94 ms against Tsit5's 0.067 ms.
- `implicit_step_rate`: Kvaerno5's steps per second against rtol (33 at 1e-4, 129 at 1e-5,
  278 at 1e-6 at 4 mm; 46, 110, 194 at 2 mm).

On those measurements the rule picks Kvaerno5 at 4 mm for rtol >= 1e-5 (3.1-4.9 times faster at
rtol 1e-4) and Tsit5 at 1e-6 and tighter; at 2 mm Kvaerno5 at rtol 1e-4 (break-even) and Tsit5
below; at the paper's 0.3 mm always the explicit default. The step rates are those of the
robot's circle scenes (a path period of 7.54 s); a much faster motion needs more accuracy-bound
steps, which the rule does not see. The step cost is L2's: for the full L3 strips (3 + 3N
coordinates, omega_max 2.3e4 rad/s at N = 4) an implicit step costs more than 14 explicit ones,
so the rule leans towards implicit there.

Deciding costs one `modes` evaluation: its compilation (7-15 s, once per model and process, or
from the persistent cache) before the scene's own.

omega_max is the highest free-actuator frequency (`modes(..., actuators="free")`) at home: an
upper bound of the locked one (a constraint cannot raise the highest eigenvalue), so a
motion-driven scene may be called stiff a little early. For a batch, the member with the
stiffest joints (largest E t^3) decides for all.
"""

from __future__ import annotations

import numpy as np

from .._errors import PPRError, is_traced
from .._params import member_params
from .._simulate import get_solver, is_stiff_solver

#: h omega_max at Tsit5's stability-bound step (module docstring)
EXPLICIT_STABILITY = 2.2
#: cost of one Kvaerno5 step in Tsit5 steps (module docstring)
IMPLICIT_STEP_COST = 14.0
#: the implicit solver `auto` picks
IMPLICIT = "kvaerno5"


def implicit_step_rate(rtol: float) -> float:
    """Kvaerno5's accuracy-bound steps per second of the circle scenes at `rtol` (measured:
    33 at 1e-4, scaling as rtol^-0.45)."""
    return 33.0 * (1e-4 / float(rtol)) ** 0.45


def highest_frequency(model, params) -> float:
    """omega_max (rad/s): the highest free-actuator natural frequency at home of `model` for
    `params` (the stiffest member of a batch); NaN where no static equilibrium is found."""
    from .._modes import modes

    if np.ndim(params.t) == 1:
        k = int(np.argmax(np.asarray(params.E) * np.asarray(params.t) ** 3))
        params = member_params(params, k)
    try:
        f = np.asarray(modes(model, params, actuators="free").freq_hz)
    except PPRError:
        return float("nan")
    return float(2 * np.pi * np.max(np.abs(f))) if f.size else 0.0


def choose_solver(model, params, rtol, default: str) -> tuple:
    """(solver name, reason) for `solver="auto"`: `IMPLICIT` where the stable explicit step
    rate omega_max / `EXPLICIT_STABILITY` exceeds `IMPLICIT_STEP_COST` x
    `implicit_step_rate(rtol)`, else `default` (module docstring). A traced rtol or no
    equilibrium to linearise about leaves the default."""
    if is_stiff_solver(get_solver(default)):
        return default, "the model's default solver is one for stiff problems"
    if is_traced(rtol):  # no decision before tracing
        return default, "rtol traced, model default"
    rtol = float(rtol)
    w = highest_frequency(model, params)
    if not np.isfinite(w):
        return default, "no static equilibrium to estimate stiffness, model default"
    explicit = w / EXPLICIT_STABILITY
    implicit = IMPLICIT_STEP_COST * implicit_step_rate(rtol)
    name = IMPLICIT if explicit > implicit else default
    return name, (f"omega_max {w:.4g} rad/s: explicit stable steps {explicit:.3g}/s vs "
                  f"implicit cost {implicit:.3g}/s")

