"""The argument checks of `identify`, before anything is compiled: each names the argument, the
experiment or the sample, and what is allowed (`IdentificationError`, `DataError`)."""

from __future__ import annotations

import math

import numpy as np

from ..._data import DataError, Experiment
from ..._errors import (
    IdentificationError,
    PPRError,
    check_bounds,
    check_instance,
    check_mapping,
    check_names,
    check_number,
    check_real,
)
from ..._models import get_model
from ..._params import PARAM_RANGES, RobotParams
from ..._scenes import experiment_drive, get_scene
from ._data import _fill_prb
from ._problem import ACTUATIONS, INITIAL_STATES, LOSSES, NUISANCE, SOLVERS


def check_experiments(experiments) -> list:
    """The experiments as a list: one `Experiment` or a sequence of them, none given twice
    (`DataError` otherwise)."""
    exps = [experiments] if isinstance(experiments, Experiment) else list(experiments)
    if not exps:
        raise DataError("no experiment given")
    for e in exps:
        if not isinstance(e, Experiment):
            raise DataError(f"experiments must be Experiment objects (load_csv), got "
                            f"{type(e).__name__}")
    _check_distinct(exps)
    return exps


def check_choices(actuation, initial_state, starts, nuisance, loss, solver, max_iter) -> tuple:
    """The named choices checked against their allowed values: (n_init, meas), the number of
    initial-state unknowns per experiment and the indices of the measurement nuisances."""
    if actuation not in ACTUATIONS:
        raise IdentificationError(f"unknown actuation {actuation!r}; allowed: "
                                  f"{', '.join(ACTUATIONS)}")
    if initial_state not in INITIAL_STATES:
        raise IdentificationError(f"unknown initial_state {initial_state!r}; allowed: "
                                  f"{', '.join(INITIAL_STATES)}")
    n_init = INITIAL_STATES[initial_state]
    if not (isinstance(starts, str) and starts == "auto") and (
            isinstance(starts, bool) or not isinstance(starts, (int, np.integer))
            or not 1 <= starts <= 1000):
        raise IdentificationError(f"starts must be 'auto' or an integer in [1, 1000], got "
                                  f"{starts!r}")
    nuisance = check_names("nuisance", nuisance, NUISANCE, error=IdentificationError)
    meas = tuple(sorted(({0, 1, 2} if "bias" in nuisance else set())
                        | ({3} if "delay" in nuisance else set())))
    if loss not in LOSSES:
        raise IdentificationError(f"unknown loss {loss!r}; allowed: {', '.join(LOSSES)}")
    if solver not in SOLVERS:
        raise IdentificationError(f"unknown solver {solver!r}; allowed: {', '.join(SOLVERS)}")
    if max_iter == 0 and (solver != "lm" or starts not in ("auto", 1)):
        raise IdentificationError(
            f"max_iter = 0 (no step: the statistics at the initial values) needs solver='lm' "
            f"and one start, got solver={solver!r}, starts={starts!r}")
    return n_init, meas


def check_unknowns(unknowns, fixed, initial, bounds, params, commands, noise) -> tuple:
    """The unknowns, the dicts of fixed values, start values and bounds, the robots and the
    noise, checked: (names, fixed, initial, bounds), the dicts with checked values."""
    if isinstance(unknowns, str):  # one name, not its letters
        unknowns = (unknowns,)
    if not hasattr(unknowns, "__iter__") or isinstance(unknowns, (bytes, dict)):
        raise IdentificationError(f"unknowns must be a sequence of parameter names, got "
                                  f"{unknowns!r}; allowed: {', '.join(PARAM_RANGES)}")
    names = tuple(unknowns)
    if not names:
        raise IdentificationError("no unknown given; choose among " + ", ".join(PARAM_RANGES))
    for n in names:
        if not isinstance(n, str) or n not in PARAM_RANGES:
            raise IdentificationError(f"unknown {n!r} is not a float parameter; allowed: "
                                      f"{', '.join(PARAM_RANGES)}")
    if len(set(names)) != len(names):
        raise IdentificationError(f"an unknown is repeated: {list(names)}")
    # the dicts' keys and values, their types and counts, before anything else reads them
    fixed = check_mapping("fixed", fixed, error=IdentificationError, what="{name: value}")
    initial = check_mapping("initial", initial, error=IdentificationError,
                            what="{unknown: start value}")
    initial = {k: check_real(f"initial value of {k!r}", v, error=IdentificationError,
                             allowed=_range_text(k)) for k, v in initial.items()}
    bounds = check_mapping("bounds", bounds, error=IdentificationError,
                           what="{unknown: (lo, hi)}")
    bounds = {k: check_bounds(f"bounds of {k!r}", v, error=IdentificationError, ordered=False,
                              unit=PARAM_RANGES[k][2] if k in PARAM_RANGES else "")
              for k, v in bounds.items()}
    for what, robot in (("params", params), ("commands", commands)):
        if robot is not None:
            check_instance(what, robot, RobotParams, error=IdentificationError,
                           what="a RobotParams")
    clash = set(fixed) & set(names)
    if clash:
        raise IdentificationError(f"parameter(s) {sorted(clash)} are both unknown and fixed")
    try:
        ok = (len(noise) == 2 and all(float(v) > 0 for v in noise)  # NaN fails too
              and not all(math.isinf(float(v)) for v in noise))
    except (TypeError, ValueError):  # a bare number, or not numbers
        ok = False
    if not ok:
        raise IdentificationError(f"noise must be (position m, phi rad), both > 0 (inf: that "
                                  f"channel is not fitted; not both), got {noise!r}")
    stray = set(initial) - set(names)
    if stray:
        raise IdentificationError(f"initial values given for {sorted(stray)}, which are not "
                                  f"unknowns (to hold a parameter at a value, use fixed=)")
    return names, fixed, initial, bounds


def resolve_scene(scene, exps, actuation, commands) -> tuple:
    """The experiments' scene and drive, and the actuation that drives the model:
    (own, scene_obj, drive, label, actuation); `own` when each experiment is its own scene
    (`scene=None`), then `scene_obj` is None."""
    own = scene is None  # each experiment's own scene, driven by its own commands
    if own:
        if actuation == "commanded" or commands is not None:
            raise IdentificationError(
                "without a scene the data's own angles or torques drive the model: actuation="
                "'commanded' and commands= apply to a named scene (scene='servo-circle', "
                "'paper-circle' or an AbstractScene) whose commands are computed")
        drive = _common_drive(exps)
        if actuation == "measured" and drive == "torque":
            raise IdentificationError("actuation 'measured' (the measured angles drive the "
                                      "model) needs th_1..th_3 in every experiment; these "
                                      "data drive it by their torques (actuation='auto')")
        scene_obj = None
        label = "experiment's own" if len(exps) == 1 else "experiments' own"
        actuation = "measured" if drive == "motion" else "commanded"
    else:
        try:
            scene_obj = get_scene(scene)
        except PPRError as err:
            raise IdentificationError(str(err)) from None
        drive, label = scene_obj.drive, scene_obj.name
        if actuation == "auto":
            # named commands are asked for; otherwise what the files hold
            has_th = all(e.th is not None for e in exps)
            measured = commands is None and drive == "motion" and has_th
            actuation = "measured" if measured else "commanded"
        if actuation == "measured" and drive != "motion":
            raise IdentificationError(
                f"actuation 'measured' (the measured angles drive the model) applies to a "
                f"motion-driven scene; {scene_obj.name} is {drive}-driven (it uses the measured "
                f"torques tau_1..tau_3 when the data give them)")
    return own, scene_obj, drive, label, actuation


def check_model(model, n_elements, n_init, drive, initial_state):
    """The model (`get_model`), refused when an estimated initial state has no free coordinate
    to act on."""
    mdl = get_model(model, n_elements)
    if n_init and drive == "motion" and mdl.actuated_index is None:
        raise IdentificationError(f"initial_state={initial_state!r}: the {mdl.name} model has no "
                                  f"free initial state under prescribed angles (a motion drive: "
                                  f"its pose follows from the angles); use initial_state='scene'")
    return mdl


def start_robot(params, own, scene_obj, fixed, initial, names) -> tuple:
    """(base, nominal): the robot at the start values of the unknowns, and the nominal robot
    (`params` with `fixed`, before the start values)."""
    if params is None:
        base = RobotParams() if own else scene_obj.default_params()
    else:
        base = params
    try:
        base = base.replace(**fixed) if fixed else base
        nominal = base
        base = base.replace(**initial)
    except ValueError as err:
        raise IdentificationError(str(err)) from None
    base = _fill_prb(base, names)
    return base, nominal


def unknown_bounds(names, base, bounds) -> tuple:
    """(lo, hi, log) of each unknown: its bounds, inside its physical range, with its start
    value strictly inside them, and whether it is reparametrised in log (lo > 0)."""
    bounds = dict(bounds)
    lo, hi, lg = [], [], []
    for n in names:
        plo, phi_, unit, _ = PARAM_RANGES[n]
        b_lo, b_hi = bounds.pop(n, (plo, phi_))
        if not (plo <= b_lo < b_hi <= phi_):
            raise IdentificationError(f"bounds of {n!r} must satisfy {plo:g} <= lo < hi <= "
                                      f"{phi_:g} {unit}, got ({b_lo:g}, {b_hi:g})")
        v = float(getattr(base, n))
        if not (b_lo < v < b_hi):
            raise IdentificationError(f"initial value of {n!r} = {v:g} {unit} is not strictly "
                                      f"inside its bounds ({b_lo:g}, {b_hi:g}); give initial="
                                      f"{{{n!r}: value}}")
        lo.append(b_lo)
        hi.append(b_hi)
        lg.append(b_lo > 0)
    if bounds:
        raise IdentificationError(f"bounds given for parameters that are not unknowns: "
                                  f"{sorted(bounds)}")
    return lo, hi, lg


def check_commands(commands, actuation) -> None:
    """`commands`, the model that computed the commands (a `RobotParams`: `check_unknowns`), not
    with measured angles (which then drive the model)."""
    if commands is not None and actuation == "measured":
        raise IdentificationError("commands= names the model that computed the commands; with "
                                  "actuation='measured' the measured angles drive the model")


def _common_drive(exps) -> str:
    """The drive that every experiment's own commands give (`experiment_drive`): the angles
    where every experiment holds them (MODEL.md section 7), else the torques where every one
    holds them; a `DataError` naming the experiments otherwise."""
    drives = [experiment_drive(e) for e in exps]  # names an experiment that holds neither
    if all(e.th is not None for e in exps):
        return "motion"
    if all(e.tau is not None for e in exps):
        return "torque"
    angles = [e.name for e, d in zip(exps, drives) if d == "motion"]
    torques = [e.name for e, d in zip(exps, drives) if d == "torque"]
    raise DataError(f"experiments fitted together share one drive: {', '.join(angles)} hold "
                    f"actuated angles, {', '.join(torques)} torques only; fit them apart")


def held_out(validation, ts, mask, names, n_init):
    """(held (E, m) bool, description) of the samples `validation` holds out, or None: a
    fraction in (0, 1) holds out that last part of every experiment's time span; a sequence of
    experiment names or indices holds out those experiments whole."""
    if validation is None:
        return None
    if isinstance(validation, (int, float)) and not isinstance(validation, bool):
        v = float(validation)
        if not 0.0 < v < 1.0:
            raise IdentificationError(f"validation: a fraction of each experiment's time span "
                                      f"must be in (0, 1), got {validation!r}")
        held = np.zeros_like(mask)
        for k in range(mask.shape[0]):
            t = ts[k][mask[k]]
            held[k] = mask[k] & (ts[k] > t[0] + (1.0 - v) * (t[-1] - t[0]))
        what = f"the last {v:.0%} of each experiment"
    else:
        sel = set()
        for item in validation:
            if isinstance(item, str) and item in names:
                sel.add(names.index(item))
            elif isinstance(item, (int, np.integer)) and 0 <= int(item) < len(names):
                sel.add(int(item))
            else:
                raise IdentificationError(
                    f"validation: {item!r} is not one of the experiments ({', '.join(names)}) "
                    f"or their indices 0..{len(names) - 1}")
        if len(sel) == len(names):
            raise IdentificationError("validation holds out every experiment: nothing is left "
                                      "to fit")
        if n_init:
            raise IdentificationError(
                "validation by whole experiments with an estimated initial state: a held-out "
                "experiment's initial state would be unknown; hold out the last part of each "
                "experiment instead (validation=0.3), or initial_state='scene'")
        held = np.zeros_like(mask)
        for k in sel:
            held[k] = mask[k]
        what = "experiments " + ", ".join(names[k] for k in sorted(sel))
    if not held.any():
        raise IdentificationError("validation holds out no sample")
    return held, what


def _range_text(name: str) -> str:
    """"allowed range [lo, hi] unit" of a float parameter (empty for another name)."""
    if name not in PARAM_RANGES:
        return ""
    lo, hi, unit, _ = PARAM_RANGES[name]
    return f"allowed range [{lo:g}, {hi:g}] {unit}".rstrip()


def check_solver_args(loss_scale, max_iter, xtol, ftol, stat_tol, rtol, atol, max_steps,
                       seed) -> None:
    """The fit's and the simulation's numeric options, checked before anything is compiled
    (`IdentificationError` naming the argument and its allowed range): a NaN tolerance would
    run the whole fit and end in advice about tolerances, a zero loss scale be blamed on the
    data. The simulation's ranges are the scenes' (`check_scene_args`)."""
    checks = [("loss_scale", loss_scale, 0.0, 1e6, "noise units", False, True),
              ("max_iter", max_iter, 0, 100_000, "", True, False),
              ("xtol", xtol, 0.0, 1.0, "", False, False),
              ("ftol", ftol, 0.0, 1.0, "", False, False),
              ("stat_tol", stat_tol, 0.0, 1e3, "standard errors", False, False),
              ("max_steps", max_steps, 1, 10**9, "", True, False),
              ("seed", seed, 0, 2**63 - 1, "", True, False)]
    if rtol is not None:
        checks.append(("rtol", rtol, 1e-14, 1e-2, "", False, False))
    if atol is not None:
        checks.append(("atol", atol, 1e-16, 1e-2, "", False, False))
    for name, value, lo, hi, unit, integer, open_lo in checks:
        try:
            check_number(name, value, lo, hi, unit, integer=integer, open_lo=open_lo)
        except PPRError as err:
            raise IdentificationError(str(err)) from None


def _check_distinct(exps) -> None:
    """Refuse an experiment given twice (`DataError` naming both): its residuals would count
    as independent samples of new noise and narrow every interval by sqrt 2."""
    def key(e):
        return tuple(None if a is None else np.asarray(a).tobytes()
                     for a in (e.ts, e.X, e.th, e.tau))

    seen = {}
    for i, e in enumerate(exps):
        k = key(e)
        if k in seen:
            j = seen[k]
            raise DataError(f"experiments {j} ({exps[j].name!r}) and {i} ({e.name!r}) hold the "
                            f"same samples: given twice, they would count as independent "
                            f"measurements and narrow every interval by sqrt 2; give each "
                            f"experiment once")
        seen[k] = i
