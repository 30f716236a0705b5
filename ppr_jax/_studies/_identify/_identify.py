"""Identification of robot parameters from measured platform trajectories (MODEL.md section 7).

`identify(experiments, unknowns=("t",), model="double1r")` fits any subset of the
float leaves of `RobotParams` to measured poses by least squares through the simulation, and
reports how well the data determine them: the Gauss-Newton covariance, 95 % intervals,
correlations, the identifiable combinations (a singular-value analysis of the relative
sensitivities) and the residuals against the stated noise.

The experiment (what the motors did) is a scene:
- by default (`scene=None`) the one that the data describe (`experiment_scene`): the data's
  own actuated angles th_1..th_3 drive the model (a motion drive; where the data hold no
  angles, their torques tau_1..tau_3: a torque drive), each experiment on its own path (its
  measured poses), its times counted from its first sample, and its start (the pose guess, and
  under torques the pose, its rate and acceleration) fitted to its first 0.1 s of poses
  (`fit_start`); the rest of the state is the model's quasi-static state under the commands
  (MODEL.md section 6). No scene of the paper is assumed. Several experiments, each on its own
  path, are fitted jointly (one drive for all);
- a named scene (a registered name or an `AbstractScene`), for the paper's own experiments:
  ``servo-circle``, motion-driven: its angles drive the model, simulated from its quasi-static
  state at t = 0 under those angles (`quasi_static_state`); ``paper-circle``, torque-driven by
  the measured torques (columns tau_1..tau_3, cubic Hermite interpolation) or, without them,
  by L1's inverse-dynamics torques of eq 55 for the commands' parameters (held fixed), from the
  nominal pose at t = 0. Sample times are those of the scene (t = 0 at the start of the
  motion).
Before anything is compiled, every experiment's first sample is checked against the model at
the initial guess (`_start.check_starts`, `check_scene_start`): a pose out of reach, angles of
another assembly mode, angles that put the platform more than 10 mm or 0.1 rad away from the
file's first pose, torques that would throw it that far within 0.1 s, or a named scene that
starts that far from it, are refused with a `StartError` naming the experiment, the sample and
the distance.

Which angles drive a motion-driven named scene (`actuation`, MODEL.md section 7):
- ``"auto"`` (default): the measured angles when every experiment holds th_1..th_3, else the
  commands. Measured angles are what the motors did; commands recomputed from a guess are not.
- ``"commanded"``: L1's inverse kinematics of eq 55 for the parameters of the model that
  computed the commands, `commands` (a `RobotParams`; default the nominal robot, `params` with
  `fixed` applied), held fixed whatever the unknowns: the motors received those commands
  whatever the robot really is. Never the unknowns' initial values: a geometric unknown (gamma,
  rho, r, theta_c, a link length) would then change the commands it is fitted against.
- ``"measured"``: the measured actuated angles th_1..th_3 drive the
  model instead of the commands, through a C2 not-a-knot cubic spline of the samples
  (`spline_pieces`; C2 because its second derivative is the prescribed acceleration). Use it
  when the servos do not follow their commands exactly: the commands then leave a tracking
  error the fit would misread as stiffness. Encoders are far finer than a tracker, so the
  spline interpolates (no smoothing); it is fourth-order accurate (1e-9 rad at 100 Hz on the
  paper's circle).
- ``initial_state``: ``"scene"`` (default) starts each experiment from the scene's quasi-static
  state at t = 0; ``"pose"`` adds each experiment's initial platform pose (x0, y0, phi0) to the
  unknowns, ``"pose-velocity"`` also its initial platform velocity, as offsets from that state
  (the platform coordinates z[:3] of every model; the actuated angles stay where the actuation
  puts them, the chains' other coordinates where the quasi-static state does). They are nuisance
  parameters: the parameters' covariance is marginal over them (their Jacobian columns projected
  out), and they are reported per experiment in `Identification.initial_state`. Use it when a
  recording starts in motion or off equilibrium.

Method, and why:
- Residuals: simulated minus measured pose at the sample times, each channel divided by its
  stated noise (`noise=(position m, phi rad)`), so x, y and phi weigh alike and the residual
  variance is about 1 when the noise is as stated. An infinite noise leaves its channel out
  (weight 0); residuals of weight 0 (that channel, padding, held-out samples) are not counted
  in N. The simulation saves at the sample times directly (no interpolation error).
- Unknowns are reparametrised for their bounds (default `PARAM_RANGES`): p = exp(log lo +
  (log hi - log lo) sigmoid(z)) for lo > 0 (relative steps, so t ~ 5e-4 and E ~ 7e10 are both
  O(1) in z), p = lo + (hi - lo) sigmoid(z) otherwise. Bounds are never crossed.
- Experiments are padded to a common length and simulated in one vmapped call, so several
  experiments cost one compilation.
- Jacobian: forward mode through diffrax (`jax.jacfwd`, `diffrax.ForwardMode`), one compiled
  function returning residuals and Jacobian together (one jvp per unknown). The default solver
  is a Levenberg-Marquardt loop on the host around that one compiled function: the same
  compilation then serves the covariance and any further fit on data of the same shapes.
  ``solver="optimistix-lm"`` / ``"optimistix-gn"`` run `optimistix.LevenbergMarquardt` /
  `optimistix.GaussNewton` instead; they compile their own loop (L2, 0.5 s experiment: about 115 s
  against 31 s for the compiled Jacobian, and 0.4 s per step against 0.12 s, because
  `jax.linearize` re-runs the solve for each tangent).
- Robust losses ``huber`` and ``cauchy`` transform each residual r into sign(r) sqrt(2 rho(r))
  (as scipy's `least_squares`), with `loss_scale` in noise units (default 3): least squares on
  the transformed residuals minimises the robust cost.
- Covariance: s^2 (J^T J)^-1 with J the Jacobian with respect to the physical parameters and
  s^2 = sum r^2 / (N - P) estimated from the (weighted) residuals, N those of weight > 0;
  intervals use Student's t."""

from __future__ import annotations

import math
import time
from typing import Optional, Sequence, Union

import jax.numpy as jnp
import numpy as np

from ..._data import DataError, Experiment
from ..._errors import IdentificationError
from ..._params import RobotParams
from ..._paths import fit_start
from ..._scenes import AbstractScene, SceneOptions, options_from
from ..._simulate import get_solver
from ._arguments import (
    check_choices,
    check_commands,
    check_experiments,
    check_model,
    check_solver_args,
    check_unknowns,
    held_out,
    resolve_scene,
    start_robot,
    unknown_bounds,
)
from ._data import _fill_prb, _pack
from ._fit import (
    _check_ok,
    _escalation_reason,
    _initial_state_guess,
    _levenberg_marquardt,
    _multi_start,
    _optimistix,
)
from ._plausible import check_plausible
from ._problem import (
    DEFAULT_NOISE,
    INIT_SCALE,
    LOSSES,
    _Problem,
    _residual_and_jacobian,
    _to_z,
)
from ._result import Identification, _finish
from ._start import check_scene_start, check_starts
from ._statistics import _preflight, _refusal_message

#: starts="auto": when the given start does not explain the data, the Latin hypercube holds
#: AUTO_STARTS - 1 points besides it, and the fit runs from the AUTO_KEEP cheapest of them
AUTO_STARTS = 9
AUTO_KEEP = 3


def identify(
    experiments: Union[Experiment, Sequence[Experiment]],
    unknowns: Sequence[str] = ("t",),
    *,
    model="double1r",
    scene: Union[None, str, AbstractScene] = None,
    actuation: str = "auto",
    initial_state: str = "scene",
    params: Optional[RobotParams] = None,
    commands: Optional[RobotParams] = None,
    fixed: Optional[dict] = None,
    initial: Optional[dict] = None,
    bounds: Optional[dict] = None,
    noise: tuple = DEFAULT_NOISE,
    loss: str = "linear",
    loss_scale: float = 3.0,
    solver: str = "lm",
    max_iter: int = 50,
    xtol: float = 1e-8,
    ftol: float = 1e-10,
    stat_tol: float = 1e-2,
    options: Optional[SceneOptions] = None,
    ode_solver=None,
    rtol: Optional[float] = None,
    atol: Optional[float] = None,
    max_steps: Optional[int] = None,
    n_elements: Optional[int] = None,
    validation=None,
    nuisance: Sequence[str] = (),
    starts: Union[str, int] = "auto",
    seed: int = 0,
    force: bool = False,
    program_dir: Optional[str] = None,
) -> Identification:
    """Fit `unknowns` (names of `RobotParams` float leaves) to measured experiments.

    Before fitting, a preflight checks the identifiability of the unknowns at the initial
    guess, from the data's own sampling and the stated noise (residual scale s = 1): the same
    singular-value analysis of the relative sensitivities that the result reports
    (`Identification.identifiability`), on the residual Jacobian at the start (the one the
    first Levenberg-Marquardt iteration uses anyway), with the nuisance unknowns (initial
    states, measurement parameters) marginalised out. A combination of the unknowns that is
    "not identifiable from these data" (relative std >= 1) is refused with an
    `IdentificationError` naming it, its relative std and what would make it identifiable,
    unless `force=True`; `history["preflight"]` keeps the verdict.

    **Arguments:**

    - `experiments`: one `Experiment` or several (fitted jointly; `load_csv`,
        `load_experiments`).
    - `unknowns`: the parameters to fit. Default `("t",)`: the strip thickness, with K_theta
        from the PRB table. t and K_theta act on the motion through the joint stiffness
        E w t^3 K_theta (only the strip mass separates them), so the preflight refuses the pair
        on the usual data: on 0.6 s of the servo circle t^3 K_theta has a relative std of 6 %
        and t^-1 K_theta^3 of 1e6 % at 5 um / 0.05 mrad of noise. Fit the pair with
        `force=True` to see the combinations in the result.
    - `model`: "double1r" (L2, default), "reduced" (L1), "rigid" (L0) or a model instance.
    - `scene`: None (default): each experiment's own scene, driven by its own angles (or
        torques) along its own path from its own first samples (module docstring); or the
        paper's experiment the data come from, a registered name ("servo-circle",
        "paper-circle") or an `AbstractScene`, whose drive (`AbstractScene.drive`) says
        whether angles or torques drive it.
    - `actuation`: "auto" (default: the data's th_1..th_3 drive the model when every
        experiment holds them and no `commands` are named, else the commands), "commanded" (a
        named scene's commands, or torques, computed for `commands`) or "measured" (a
        motion-driven scene: the data's angles). Without a scene the data's own commands
        drive the model ("auto" or "measured"). `Identification.actuation` says which drove
        the fit.
    - `initial_state`: "scene" (default), "pose" or "pose-velocity": what of each
        experiment's initial state is estimated (module docstring).
    - `params`: the robot (default: a named scene's `default_params()`, else Table 1,
        `RobotParams()`).
    - `commands`: the `RobotParams` of the model that computed the commands (default the
        nominal robot, `params` with `fixed`; never the unknowns' initial values).
    - `fixed`: {name: value} overrides applied to `params`.
    - `initial`: {name: value} start values of unknowns (default: the robot's).
    - `bounds`: {name: (lo, hi)} (default `PARAM_RANGES`).
    - `noise`: (position m, phi rad), the residual weights (their scale is estimated from the
        fit; the report compares the RMS of the residuals to them). Both > 0; one may be
        infinite: that channel is then not fitted (weight 0, not counted as residuals).
    - `loss`, `loss_scale`: "linear", "huber" or "cauchy", with the scale in noise units.
    - `solver`: "lm" (host Levenberg-Marquardt on the compiled Jacobian), "optimistix-lm",
        "optimistix-gn".
    - `max_iter`, `xtol`, `ftol`, `stat_tol`: stop when the step in z or the relative cost
        change is below `xtol`, `ftol`; "lm" also stops when an accepted step is shorter than
        `stat_tol` standard errors (measured with the information matrix J^T J / s^2, so that
        steps along undetermined directions do not count). `max_iter=0` takes no step: the
        result is the statistics (residuals, s, covariance) at the initial values (solver "lm",
        one start), how well given parameters (a table's, a datasheet's) explain the data.
    - `options`: a `SceneOptions`: its `solver`, `rtol`, `atol` and `max_steps` are the
        simulation's (default the model's solver and tolerances, `AbstractModel.default_solver`,
        `default_rtol`, `default_atol`, and the scenes' step budget); the horizon and output
        times are the experiments' own. `ode_solver`, `rtol`, `atol`, `max_steps`: deprecated
        spellings of those fields (a `DeprecationWarning`; not together with `options`).
    - `n_elements`: the beam model's element count.
    - `validation`: samples held out of the fit and predicted by it: a fraction in (0, 1),
        the last part of every experiment's time span (by time: the model must extrapolate its
        own motion), or a sequence of experiment names or indices held out whole (with
        initial_state "scene" only). `Identification.validation` reports their residual scale
        against the fit's; above twice the fit's (or 1) the model does not generalise, which
        `quality` reports as a problem.
    - `nuisance`: measurement parameters estimated with the unknowns and reported apart,
        shared by every experiment: "bias" (an offset of each pose channel x, y, phi: the
        tracker's frame against the robot's) and "delay" (the tracker's time delay against the
        actuation: the pose sampled at t is the robot's at t - delay, interpolated between the
        simulated samples by a cubic Hermite of their poses and rates; up to one sample
        spacing). Their uncertainty is marginalised out of the parameters' intervals, as the
        initial state's is.
    - `starts`: "auto" (default) or an integer N in [1, 1000]. "auto" fits from the given
        start, and only when that fit does not explain the data (residual scale s above
        `POOR_FIT_SCALE`, the threshold of `quality`) or ends with an unknown at a bound, it
        refits: the cost at 8 points of a Latin hypercube of the unknowns within their bounds
        (seeded by `seed`) is evaluated in one vmapped call of the compiled residual, and the
        fit runs from the 3 cheapest; the lowest cost of those and the given start's wins.
        `history["escalation"]` and `quality["escalated"]` say why it happened (None: it did
        not). A well-posed fit therefore costs what one start costs. An integer N fits from
        the given start and from N - 1 Latin-hypercube points, every one (no screening).
        `history["starts"]` and `quality["starts"]` say whether the given start ended in a
        local minimum.
    - `seed`: the Latin hypercube's seed.
    - `force`: fit even when the preflight refuses (the result's identifiability and
        `quality["preflight_not_identifiable"]` then report it).
    - `program_dir`: a directory of stored programs (as `run_scene`'s; the command line's):
        the fit's residual-and-Jacobian program is exported there once and loaded by later
        processes, which then skip its trace (most of a warm fit's wait). None: compiled in
        this process as usual. The results are the same either way.

    **Returns:**

    An `Identification`.

    **Raises:**

    `IdentificationError` for unknown or fixed names that are not leaves, a numeric option out
    of its range (loss_scale in (0, 1e6], max_iter in [0, 1e5], xtol and ftol in [0, 1],
    stat_tol in [0, 1e3], rtol in [1e-14, 1e-2], atol in [1e-16, 1e-2], max_steps in
    [1, 1e9], seed in [0, 2^63 - 1]; checked before anything is compiled), bounds outside the
    physical range, an initial value outside its bounds, a bad option (naming it and its
    allowed values), a simulation that fails at the initial values (naming the experiment and
    the cause), or a preflight refusal; its subclass `StartError`, before anything is
    compiled, for an experiment whose first sample cannot start the model (module docstring);
    `DataError` for unusable data (without a scene: data that hold neither angles nor
    torques).
    """
    opts = options_from(options, "identify", True, solver=ode_solver, rtol=rtol, atol=atol,
                        max_steps=max_steps)
    ode_solver, rtol, atol, max_steps = opts.solver, opts.rtol, opts.atol, opts.max_steps
    check_solver_args(loss_scale, max_iter, xtol, ftol, stat_tol, rtol, atol, max_steps, seed)
    exps = check_experiments(experiments)
    n_init, meas = check_choices(actuation, initial_state, starts, nuisance, loss, solver,
                                 max_iter)
    names, fixed, initial, bounds = check_unknowns(unknowns, fixed, initial, bounds, params,
                                                   commands, noise)
    own, scene_obj, drive, label, actuation = resolve_scene(scene, exps, actuation, commands)
    mdl = check_model(model, n_elements, n_init, drive, initial_state)
    base, nominal = start_robot(params, own, scene_obj, fixed, initial, names)
    lo, hi, lg = unknown_bounds(names, base, bounds)
    ts, X, W, tau, th, mask, paths, start_fits = _pack(exps, float(noise[0]),
                                                       float(noise[1]), drive, actuation,
                                                       own=own)
    # Before anything is compiled: can each experiment's first sample start the model? (In the
    # channels that are fitted: a channel of infinite noise is not.)
    fitted = tuple(math.isfinite(float(v)) for v in noise)
    if own:
        check_starts(exps, drive, base, start_fits, fitted)
    else:
        check_scene_start(exps, scene_obj, [fit_start(e.ts, e.X)[0] for e in exps], fitted)
    # then the units and robot of the columns that drive the model, over the whole record
    check_plausible(exps, base, "from the data" if own else getattr(scene_obj, "name", scene),
                    angles=th is not None, torques=tau is not None)
    held = held_out(validation, ts, mask, [e.name for e in exps], n_init)
    if held is not None:
        W_all = W
        mask = mask & ~held[0]
        W = W * mask[..., None]
    n_res = int(np.count_nonzero(W))  # weight 0 (infinite noise, held out): no information
    n_unknown = len(names) + n_init * len(exps) + len(meas)
    if n_res <= n_unknown:
        raise DataError(f"{n_res} residuals cannot determine {n_unknown} unknowns")
    from ..._robot import equal_links_of

    eq = equal_links_of(base) and "l1" not in names and "l3" not in names
    ode = get_solver(mdl.default_solver if ode_solver is None else ode_solver)
    rtol = mdl.default_rtol if rtol is None else rtol
    atol = mdl.default_atol if atol is None else atol
    check_commands(commands, actuation)
    # the PRB parameters the commands use as explicit leaves, so that the default (the table's
    # values) and named commands are one structure: one compiled fit for both
    cmd = _fill_prb(nominal if commands is None else commands, ("gamma", "K_theta", "rho"))
    whose = ("each experiment's own" if len(exps) > 1 else "the experiment's own") if own \
        else "the"
    if actuation == "measured":
        driven_by = f"{whose} measured actuated angles th_1..th_3"
    elif drive == "torque" and tau is not None:
        driven_by = f"{whose} measured torques tau_1..tau_3"
    else:
        what = "commanded angles" if drive == "motion" else "inverse-dynamics torques"
        driven_by = (f"the {what} of the nominal robot (params with fixed), held fixed"
                     if commands is None
                     else f"the {what} of the given commands model, held fixed")
    if own:
        driven_by += (" along its own path, from the state its first samples give"
                      if len(exps) == 1 else
                      " along their own paths, from the states their first samples give")
    prob = _Problem(
        base=base, commands=cmd, lo=jnp.asarray(lo), hi=jnp.asarray(hi), ts=jnp.asarray(ts),
        X=jnp.asarray(X), w=jnp.asarray(W), tau=None if tau is None else jnp.asarray(tau),
        th=None if th is None else jnp.asarray(th),
        rtol=jnp.asarray(rtol, dtype=jnp.float64), atol=jnp.asarray(atol, dtype=jnp.float64),
        names=names, log=tuple(lg), model=mdl, scene=label, equal_links=eq, solver=ode,
        max_steps=int(max_steps), loss=jnp.asarray(LOSSES.index(loss)),
        loss_scale=jnp.asarray(float(loss_scale), dtype=jnp.float64),
        n_init=n_init, init_scale=jnp.asarray(INIT_SCALE[:n_init]) if n_init else None,
        meas=meas, scene_obj=scene_obj, drive=drive,
        paths=None if paths is None else jnp.asarray(paths),
        starts=None if start_fits is None else jnp.asarray(start_fits),
        experiment_names=tuple(e.name for e in exps), program_dir=program_dir,
    )
    p0 = np.array([float(getattr(base, n)) for n in names])
    z0 = np.concatenate([_to_z(lg, lo, hi, p0), np.zeros(n_init * len(exps) + len(meas))])
    if n_init:
        z0 = _initial_state_guess(prob, z0, mask)

    # Preflight: the identifiability of the unknowns at the start, from the data's sampling and
    # the stated noise (s = 1), before anything is fitted. Its residual and Jacobian are the
    # first Levenberg-Marquardt iteration's.
    t_pre = time.perf_counter()
    r0, J0, ok0, X0 = _residual_and_jacobian(prob, jnp.asarray(z0))
    J0 = np.asarray(J0)
    pre_s = time.perf_counter() - t_pre
    _check_ok(ok0, z0, prob, start=True)
    t_an = time.perf_counter()
    pre = _preflight(prob, z0, J0)
    an_s = time.perf_counter() - t_an
    if pre["refused"] and not force:
        raise IdentificationError(_refusal_message(pre, names))
    preflight = {"combinations": pre["combinations"], "condition_number":
                 pre["condition_number"], "refused": [c["expression"] for c in pre["refused"]],
                 "forced": bool(pre["refused"]) and bool(force),
                 # the residual and Jacobian at the start (the first call compiles them; the
                 # first iteration reuses them) and the analysis alone
                 "run_s": pre_s, "analysis_s": an_s,
                 "note": "identifiability at the initial guess with the stated noise (s = 1), "
                         "before the fit"}

    def fit_one(z, first=None):
        if solver == "lm":
            return _levenberg_marquardt(prob, z, max_iter, xtol, ftol, stat_tol, first=first)
        return _optimistix(prob, z, solver, max_iter, xtol, ftol)

    guess = (lambda z: _initial_state_guess(prob, z, mask)) if n_init else None
    given = fit_one(z0, (r0, J0, ok0, X0, pre_s))
    escalation = None
    if starts == "auto" and max_iter > 0:
        why = _escalation_reason(prob, given[0], n_res - n_unknown)
        if why:
            z, hist = _multi_start(prob, z0, AUTO_STARTS, seed, fit_one, guess,
                                   screen=AUTO_KEEP, given=given)
            escalation = {"reason": why, "points": AUTO_STARTS - 1, "fitted": AUTO_KEEP,
                          "note": f"refitted from {AUTO_STARTS - 1} Latin-hypercube points "
                                  f"within the bounds (their costs screened in one vmapped "
                                  f"call, the fit run from the {AUTO_KEEP} cheapest) besides "
                                  f"the given start; the lowest cost wins"}
        else:
            z, hist = given
    elif starts != "auto" and starts > 1:
        z, hist = _multi_start(prob, z0, int(starts), seed, fit_one, guess, given=given)
    else:
        z, hist = given
    hist = dict(hist)
    if "compile_s" in given[1]:  # the first call's (the preflight's), whichever start won
        hist["compile_s"] = given[1]["compile_s"]
    hist["total_s"] = time.perf_counter() - t_pre  # preflight, every start and screening
    hist["starts_option"] = starts
    hist["escalation"] = escalation
    hist["preflight"] = preflight
    return _finish(prob, z, p0, hist, exps, mask, tuple(float(v) for v in noise), driven_by,
                   held=None if held is None else (W_all, held[0], held[1]))
