"""The run of a prepared identification (`_setup.Prepared`): the preflight (the identifiability
of the unknowns at the start), the fit from the given start and, where asked for or needed,
from more starts (`_fit`), and the result (`_result._finish`)."""

from __future__ import annotations

import time

import jax.numpy as jnp
import numpy as np

from ..._errors import IdentificationError
from ._fit import (
    _check_ok,
    _escalation_reason,
    _initial_state_guess,
    _levenberg_marquardt,
    _multi_start,
    _optimistix,
)
from ._problem import _residual_and_jacobian
from ._result import Identification, _finish
from ._statistics import _preflight, _refusal_message

#: starts="auto": when the given start does not explain the data, the Latin hypercube holds
#: AUTO_STARTS - 1 points besides it, and the fit runs from the AUTO_KEEP cheapest of them
AUTO_STARTS = 9
AUTO_KEEP = 3


def run(prep, fit) -> Identification:
    """Fit the prepared problem `prep` (a `_setup.Prepared`) with the `FitOptions` `fit`.

    **Returns:**

    The `Identification`.

    **Raises:**

    `IdentificationError` for a simulation that fails at the start or a preflight refusal
    (unless `fit.force`).
    """
    prob, z0 = prep.prob, prep.z0
    t_pre = time.perf_counter()
    first, preflight = preflight_of(prob, z0, fit.force)

    def fit_one(z, first=None):
        if fit.solver == "lm":
            return _levenberg_marquardt(prob, z, fit.max_iter, fit.xtol, fit.ftol,
                                        fit.stat_tol, first=first)
        return _optimistix(prob, z, fit.solver, fit.max_iter, fit.xtol, fit.ftol)

    guess = (lambda z: _initial_state_guess(prob, z, prep.mask)) if prob.n_init else None
    given = fit_one(z0, first)
    escalation = None
    if fit.starts == "auto" and fit.max_iter > 0:
        why = _escalation_reason(prob, given[0], prep.dof)
        if why:
            z, hist = _multi_start(prob, z0, AUTO_STARTS, fit.seed, fit_one, guess,
                                   screen=AUTO_KEEP, given=given)
            escalation = {"reason": why, "points": AUTO_STARTS - 1, "fitted": AUTO_KEEP,
                          "note": f"refitted from {AUTO_STARTS - 1} Latin-hypercube points "
                                  f"within the bounds (their costs screened in one vmapped "
                                  f"call, the fit run from the {AUTO_KEEP} cheapest) besides "
                                  f"the given start; the lowest cost wins"}
        else:
            z, hist = given
    elif fit.starts != "auto" and fit.starts > 1:
        z, hist = _multi_start(prob, z0, int(fit.starts), fit.seed, fit_one, guess,
                               given=given)
    else:
        z, hist = given
    hist = dict(hist)
    if "compile_s" in given[1]:  # the first call's (the preflight's), whichever start won
        hist["compile_s"] = given[1]["compile_s"]
    hist["total_s"] = time.perf_counter() - t_pre  # preflight, every start and screening
    hist["starts_option"] = fit.starts
    hist["escalation"] = escalation
    hist["preflight"] = preflight
    return _finish(prob, z, prep.p0, hist, prep.exps, prep.mask, prep.noise, prep.driven_by,
                   held=prep.held)


def preflight_of(prob, z0, force: bool) -> tuple:
    """The identifiability of the unknowns at the start, from the data's sampling and the
    stated noise (s = 1), before anything is fitted; its residual and Jacobian are the first
    Levenberg-Marquardt iteration's.

    **Arguments:**

    - `prob`: the `_Problem`.
    - `z0`: the start in the fit's unknowns.
    - `force`: go on where the unknowns are not identifiable.

    **Returns:**

    ((r, J, result codes, X, seconds) at z0, the preflight's record for `history`).

    **Raises:**

    `IdentificationError` where the simulation fails at z0, or (without `force`) naming a
    combination of the unknowns that the data do not determine.
    """
    t_pre = time.perf_counter()
    r0, J0, ok0, X0 = _residual_and_jacobian(prob, jnp.asarray(z0))
    J0 = np.asarray(J0)
    pre_s = time.perf_counter() - t_pre
    _check_ok(ok0, z0, prob, start=True)
    t_an = time.perf_counter()
    pre = _preflight(prob, z0, J0)
    an_s = time.perf_counter() - t_an
    if pre["refused"] and not force:
        raise IdentificationError(_refusal_message(pre, prob.names))
    record = {"combinations": pre["combinations"], "condition_number":
              pre["condition_number"], "refused": [c["expression"] for c in pre["refused"]],
              "forced": bool(pre["refused"]) and bool(force),
              # the residual and Jacobian at the start (the first call compiles them; the
              # first iteration reuses them) and the analysis alone
              "run_s": pre_s, "analysis_s": an_s,
              "note": "identifiability at the initial guess with the stated noise (s = 1), "
                      "before the fit"}
    return (r0, J0, ok0, X0, pre_s), record
