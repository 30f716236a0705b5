"""How `identify` fits (`FitOptions`), written once; and the keywords that spelled the fit's and
the simulation's options before, mapped into the objects that hold them now (deprecated for one
release)."""

from __future__ import annotations

import dataclasses
import warnings
from typing import Optional, Sequence, Union

import equinox as eqx

from ..._errors import IdentificationError


class FitOptions(eqx.Module):
    """How `identify` fits: the least-squares solver and its stops, the loss, the starts, the
    unknowns it adds to the parameters (each experiment's initial state, the measurement's
    nuisances), the samples it holds out and whether it runs past the preflight's refusal. The
    simulation's own options (solver, tolerances, step budget) are a `SceneOptions`'.

    The values are checked by `identify`, before anything is compiled (an
    `IdentificationError` naming the field and its allowed values or range).

    **Arguments:**

    - `solver`: "lm" (default: a Levenberg-Marquardt loop on the host around one compiled
        residual-and-Jacobian function, which then also serves the covariance and any further
        fit on data of the same shapes), "optimistix-lm" or "optimistix-gn"
        (`optimistix.LevenbergMarquardt` / `GaussNewton`, which compile their own loop).
    - `max_iter`: the most iterations, in [0, 1e5] (default 50). 0 takes no step: the result
        is the statistics (residuals, s, covariance) at the initial values (solver "lm", one
        start), how well given parameters (a table's, a datasheet's) explain the data.
    - `xtol`, `ftol`: stop when the step in the reparametrised unknowns or the relative cost
        change is below them, in [0, 1] (defaults 1e-8, 1e-10).
    - `stat_tol`: "lm" also stops when an accepted step is shorter than `stat_tol` standard
        errors, in [0, 1e3] (default 1e-2), measured with the information matrix J^T J / s^2,
        so that steps along undetermined directions do not count.
    - `loss`: "linear" (default), "huber" or "cauchy": each residual r becomes
        sign(r) sqrt(2 rho(r)) (as scipy's `least_squares`).
    - `loss_scale`: the robust loss's scale in noise units, in (0, 1e6] (default 3).
    - `starts`: "auto" (default) or an integer N in [1, 1000]. "auto" fits from the given
        start, and only when that fit does not explain the data (residual scale s above
        `POOR_FIT_SCALE`) or ends with an unknown at a bound, it refits: the cost at 8 points
        of a Latin hypercube of the unknowns within their bounds (seeded by `seed`) is
        evaluated in one vmapped call of the compiled residual, and the fit runs from the 3
        cheapest; the lowest cost of those and the given start's wins
        (`history["escalation"]`, `quality["escalated"]`: why). An integer N fits from the
        given start and from N - 1 Latin-hypercube points, every one (no screening).
    - `seed`: the Latin hypercube's seed, in [0, 2^63 - 1] (default 0).
    - `initial_state`: "scene" (default: each experiment starts from the scene's state),
        "pose" (each experiment's initial platform pose x0, y0, phi0 is estimated too) or
        "pose-velocity" (also its initial platform velocity): nuisance unknowns, marginalised
        out of the parameters' covariance and reported in `Identification.initial_state`.
    - `nuisance`: measurement parameters estimated with the unknowns and reported apart,
        shared by every experiment: "bias" (an offset of each pose channel: the tracker's frame
        against the robot's) and "delay" (the tracker's time delay against the actuation, up to
        one sample spacing). Marginalised out of the parameters' intervals.
    - `validation`: samples held out of the fit and predicted by it: None (default), a
        fraction in (0, 1), the last part of every experiment's time span, or a sequence of
        experiment names or indices held out whole (with initial_state "scene" only).
        `Identification.validation` compares their residual scale with the fit's.
    - `force`: fit even when the preflight refuses the unknowns as not identifiable from the
        data (the result's identifiability and `quality["preflight_not_identifiable"]` then
        report it); default False.
    """

    solver: str = "lm"
    max_iter: int = 50
    xtol: float = 1e-8
    ftol: float = 1e-10
    stat_tol: float = 1e-2
    loss: str = "linear"
    loss_scale: float = 3.0
    starts: Union[str, int] = "auto"
    seed: int = 0
    initial_state: str = "scene"
    nuisance: Sequence[str] = ()
    validation: Union[None, float, Sequence] = None
    force: bool = False


#: `identify`'s keywords before `FitOptions`: its fields
FIT_KEYWORDS = tuple(f.name for f in dataclasses.fields(FitOptions))

#: `identify`'s keywords before `SceneOptions` -> the field that holds each now
SCENE_KEYWORDS = {"ode_solver": "solver", "rtol": "rtol", "atol": "atol",
                  "max_steps": "max_steps"}


def deprecated_keywords(fit_options: Optional[FitOptions], keywords: dict) -> tuple:
    """The fit's options, the `SceneOptions` fields and the beam's element count that
    `identify`'s deprecated keywords give, with a `DeprecationWarning` for the fit's and the
    element count (the `SceneOptions` fields warn where `options_from` reads them).

    **Arguments:**

    - `fit_options`: `identify`'s `fit_options` (a `FitOptions` or None).
    - `keywords`: the other keywords `identify` was given.

    **Returns:**

    (`FitOptions`, {`SceneOptions` field: value}, n_elements or None).

    **Raises:**

    `TypeError` naming the keywords `identify` never took; `IdentificationError` for
    `fit_options` that is not a `FitOptions`, or given together with the keywords it replaces.
    """
    unknown = sorted(set(keywords) - set(FIT_KEYWORDS) - set(SCENE_KEYWORDS) - {"n_elements"})
    if unknown:
        raise TypeError(f"identify() got unexpected keyword argument(s) "
                        f"{', '.join(map(repr, unknown))}")
    old = {k: v for k, v in keywords.items() if k in FIT_KEYWORDS}
    if fit_options is not None:
        if not isinstance(fit_options, FitOptions):
            raise IdentificationError(f"fit_options must be a FitOptions, got "
                                      f"{type(fit_options).__name__}")
        if old:
            raise IdentificationError(
                f"identify: give the fit's options either as fit_options=FitOptions(...) or "
                f"as keywords ({', '.join(sorted(old))}), not both")
    spelled = ", ".join(f"{k}=..." for k in sorted(old))
    if old:
        warnings.warn(f"identify({spelled}) is deprecated: pass "
                      f"fit_options=FitOptions({spelled})", DeprecationWarning, stacklevel=3)
    if "n_elements" in keywords:
        warnings.warn("identify(n_elements=...) is deprecated: pass "
                      "model=get_model('beam', n_elements=...)", DeprecationWarning,
                      stacklevel=3)
    fit = fit_options if fit_options is not None else FitOptions(**old)
    scene = {new: keywords.get(k) for k, new in SCENE_KEYWORDS.items()}
    return fit, scene, keywords.get("n_elements")
