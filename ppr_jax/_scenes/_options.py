"""How a scene runs: the horizon, output times, solver and tolerances, written once."""

from __future__ import annotations

from typing import Callable, Optional, Union

import diffrax
import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._custom_types import Array, as_f64
from .._errors import check_number, is_traced
from .._names import (  # the scenes' defaults, written there
    ATOL as ATOL,
    MAX_STEPS as MAX_STEPS,
    N_OUT as N_OUT,
    RTOL as RTOL,
    T_END as T_END,
)
from .._simulate import default_controller, get_solver
from .._tabulated import scene_panels
from .._trajectory import Circle


def default_solver(model) -> str:
    """The name of `model`'s default solver (`AbstractModel.default_solver`)."""
    return model.default_solver


def default_tolerances(model) -> tuple:
    """(rtol, atol) of `model` where the caller gives none (`AbstractModel.default_rtol`,
    `default_atol`)."""
    return model.default_rtol, model.default_atol


def check_scene_args(t_end, n_out, rtol, atol, max_steps) -> None:
    """Validate a scene's arguments before anything is compiled (`PPRError` naming the argument
    and its allowed range). The tolerance bounds: below 1e-14 the error control chases round-off;
    above 1e-2 the result is not worth a number. A tolerance of None is the model's default
    (`default_tolerances`)."""
    if not is_traced(t_end):
        check_number("t_end", t_end, 0.0, 1e5, "s", open_lo=True)
    check_number("n_out", n_out, 2, 10_000_000, integer=True)
    check_number("max_steps", max_steps, 1, 10**9, integer=True)
    if rtol is not None and not is_traced(rtol):
        check_number("rtol", rtol, 1e-14, 1e-2)
    if atol is not None and not is_traced(atol):
        check_number("atol", atol, 1e-16, 1e-2)


def input_panels(traj, t_end, n_out: int) -> int:
    """Panels of the scene's input table (`_tabulated.scene_panels`). The count is a shape, so it
    is decided before tracing: more panels for a longer horizon where t_end and the trajectory's
    speed (`omega`) are concrete, the minimum otherwise (the scene then reports a table too
    coarse for its horizon as `RESULTS.input_table_too_coarse`). t_end None: the horizon is
    not known before tracing (a program whose sample times are its inputs)."""
    omega = getattr(traj, "omega", None)
    known = not (t_end is None or is_traced(t_end) or omega is None or is_traced(omega)
                 or np.ndim(omega) != 0)
    return scene_panels(n_out, float(t_end) * float(omega) if known else None)


def input_panels_at(traj, ts) -> int:
    """`input_panels` for output times `ts` (traced or not)."""
    t_end = ts[-1] if is_traced(ts) else float(np.asarray(ts)[-1])
    return input_panels(traj, t_end, ts.shape[0])


class SceneOptions(eqx.Module):
    """How a scene runs: every scene, sweep, sensitivity and identification takes one.

    **Arguments:**

    - `t_end`: horizon (s); the output times are `n_out` equal steps over [0, t_end].
    - `n_out`: number of output times (static: a shape).
    - `solver`: a diffrax solver or its name (`tsit5`, `dopri5`, `dopri8`, `kvaerno3`,
      `kvaerno5`, `kvaerno5-kept`, `ros34pw2`); None: the model's default
      (`default_solver`); `"auto"`: Kvaerno5 where a stiffness estimate says the problem is
      stiff, else the default (the full L3's default is for stiff problems already), decided
      on the concrete parameters by the scene functions and `run_scene` (`_solver_choice`;
      where the parameters are not at hand, as in sweeps, the default).
    - `rtol`, `atol`: the step-size controller's tolerances (arrays inside a program, so
      changing them does not recompile); None: the model's (`default_tolerances`: 1e-8 and
      1e-10, the full L3 1e-4 and 1e-6).
    - `max_steps`: the solver's step budget (static).
    - `adjoint`: diffrax's adjoint; None: `RecursiveCheckpointAdjoint` (reverse mode);
      `diffrax.ForwardMode()` for `jax.jvp` / `jax.jacfwd` through the scene.
    - `controller`: a step-size controller replacing the default (`default_controller`: the
      I controller for explicit solvers, the PI controller for implicit ones).
    - `trajectory`: the nominal pose path t -> X (3,) (m, m, rad), an `equinox.Module`;
      None: the scene's own (the circle of eq 55 for the circle scenes).
    - `panels`: panels of the tabulated input (static); None: decided by `prepared` from the
      horizon and the trajectory's speed (`input_panels`).
    """

    t_end: Union[float, Array] = T_END
    n_out: int = eqx.field(static=True, default=N_OUT)
    solver: Union[str, diffrax.AbstractSolver, None] = None
    rtol: Union[float, Array, None] = None
    atol: Union[float, Array, None] = None
    max_steps: int = eqx.field(static=True, default=MAX_STEPS)
    adjoint: Optional[diffrax.AbstractAdjoint] = None
    controller: Optional[diffrax.AbstractStepSizeController] = None
    trajectory: Optional[Callable] = None
    panels: Optional[int] = eqx.field(static=True, default=None)

    def updated(self, **overrides) -> "SceneOptions":
        """These options with the fields given as not None replaced: the studies and commands
        take one `SceneOptions` and, for convenience, its fields as keywords that default to
        None, so that every default is written once, here."""
        import dataclasses

        unknown = set(overrides) - {f.name for f in dataclasses.fields(self)}
        if unknown:
            raise TypeError(f"SceneOptions has no field {sorted(unknown)[0]!r}")
        kw = {k: v for k, v in overrides.items() if v is not None}
        return dataclasses.replace(self, **kw) if kw else self

    @property
    def auto_solver(self) -> bool:
        """The solver is to be chosen from a stiffness estimate (`solver="auto"`)."""
        return isinstance(self.solver, str) and self.solver.lower() == "auto"

    def check(self) -> "SceneOptions":
        """Raise `PPRError` naming the first argument out of its range; returns self."""
        check_scene_args(self.t_end, self.n_out, self.rtol, self.atol, self.max_steps)
        return self

    def prepared(self, model, default_trajectory: Optional[Callable] = None) -> "SceneOptions":
        """The options with every choice made, in Python before tracing: the solver an instance
        (the model's default where None), the tolerances and horizon arrays (so that changing
        them reuses a compiled program), the controller, adjoint and trajectory built, and the
        input table's panel count fixed.

        Options of Python numbers (hashable: a scene's defaults, the command line's) are
        prepared once per process for each model and default trajectory (by identity) and
        given back from a cache (`_PREPARED`): building the
        controller, solver, adjoint and options is a dozen equinox modules, about a tenth of a
        warm L1 `paper-circle` call. Options that hold arrays are prepared afresh each time."""
        # the default trajectory by identity (a scene's is one object; the circle's holds
        # arrays, which do not hash), kept in the entry so that its id is not reused
        key = (self, model, id(default_trajectory))
        try:
            hit = _PREPARED.get(key)
        except TypeError:  # an array among the options' fields: not hashable
            return self._prepare(model, default_trajectory)
        if hit is not None and hit[0] is default_trajectory:
            return hit[1]
        if len(_PREPARED) >= _PREPARED_MAX:
            _PREPARED.clear()
        out = self._prepare(model, default_trajectory)
        _PREPARED[key] = (default_trajectory, out)
        return out

    def _prepare(self, model, default_trajectory: Optional[Callable]) -> "SceneOptions":
        rtol, atol = self.tolerances(model)
        traj = self.trajectory
        if traj is None:
            traj = Circle() if default_trajectory is None else default_trajectory
        default = self.solver is None or self.auto_solver
        solver = get_solver(default_solver(model) if default else self.solver)
        controller = (default_controller(solver, rtol, atol)
                      if self.controller is None else self.controller)
        panels = (input_panels(traj, self.t_end, self.n_out) if self.panels is None
                  else self.panels)
        return SceneOptions(
            t_end=as_f64(self.t_end), n_out=self.n_out, solver=solver,
            rtol=as_f64(rtol), atol=as_f64(atol), max_steps=self.max_steps,
            adjoint=(diffrax.RecursiveCheckpointAdjoint() if self.adjoint is None
                     else self.adjoint),
            controller=controller, trajectory=traj, panels=panels,
        )

    def tolerances(self, model) -> tuple:
        """(rtol, atol), None replaced by `model`'s default (`default_tolerances`)."""
        rtol, atol = default_tolerances(model)
        return (rtol if self.rtol is None else self.rtol,
                atol if self.atol is None else self.atol)

    def times(self) -> Array:
        """(n_out,) output times (s)."""
        return jnp.linspace(0.0, self.t_end, self.n_out)

    def solver_name(self, model) -> str:
        """The solver's name as reports print it."""
        s = default_solver(model) if self.solver is None or self.auto_solver else self.solver
        return str(s) if isinstance(s, str) else type(s).__name__


#: {(options, model, id(default trajectory)): (default trajectory, prepared options)}
#: (`SceneOptions.prepared`)
_PREPARED: dict = {}
_PREPARED_MAX = 32  # each entry holds its trajectory (a path scene's samples)

#: the `SceneOptions` fields that the scene functions also took as keywords
OPTION_KEYWORDS = ("t_end", "n_out", "solver", "rtol", "atol", "max_steps", "trajectory",
                   "adjoint")
#: the `SceneOptions` fields that `run_scene` and the studies took as keywords (deprecated)
STUDY_KEYWORDS = ("trajectory", "t_end", "n_out", "solver", "rtol", "atol", "max_steps")


def deprecated_keywords(where: str, keywords: dict, warn: bool = False) -> dict:
    """`keywords`, the `**` of a function that still takes `SceneOptions`' fields
    (`STUDY_KEYWORDS`) as keywords, checked: another name is a `TypeError`, as Python's own.
    With `warn`, those given (not None) raise a `DeprecationWarning` at the function's caller.

    **Arguments:**

    - `where`: the function's name, for the messages.
    - `keywords`: {name: value} as given.
    - `warn`: warn here (where the function does not build its options by `options_from`).

    **Returns:** `keywords`.
    """
    unknown = sorted(set(keywords) - set(STUDY_KEYWORDS))
    if unknown:
        raise TypeError(f"{where}() got an unexpected keyword argument {unknown[0]!r}")
    given = sorted(k for k, v in keywords.items() if v is not None)
    if warn and given:
        import warnings

        warnings.warn(_deprecation(where, given), DeprecationWarning, stacklevel=3)
    return keywords


def _deprecation(where: str, given) -> str:
    return (f"{where}({', '.join(f'{k}=...' for k in given)}) is deprecated: pass "
            f"options=SceneOptions({', '.join(f'{k}=...' for k in given)})")


def options_from(options: Optional["SceneOptions"], where: str, deprecated: bool,
                 **keywords) -> "SceneOptions":
    """The one `SceneOptions` of a call that takes `options` and, for compatibility, its fields
    as keywords (`keywords`: those given, None for those left out). Both at once is an error;
    the keywords alone build the options, with a `DeprecationWarning` where `deprecated`
    (`run_scene`; the `paper_circle`/`servo_circle` conveniences keep them).

    **Arguments:**

    - `options`: a `SceneOptions` or None.
    - `where`: the function's name, for the messages.
    - `deprecated`: warn when keywords are given.
    - `keywords`: `SceneOptions` fields (`OPTION_KEYWORDS`), None where not given.

    **Returns:** a `SceneOptions`.
    """
    from .._errors import PPRError

    given = {k: v for k, v in keywords.items() if v is not None}
    if options is not None:
        if not isinstance(options, SceneOptions):
            raise PPRError(f"{where}: options must be a SceneOptions, got "
                           f"{type(options).__name__}")
        if given:
            raise PPRError(f"{where}: give the options either as options=SceneOptions(...) or "
                           f"as keywords ({', '.join(sorted(given))}), not both")
        return options
    if given and deprecated:
        import warnings

        warnings.warn(_deprecation(where, sorted(given)), DeprecationWarning, stacklevel=3)
    return SceneOptions(**given)
