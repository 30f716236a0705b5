"""What `identify` prepares before it fits: the arguments checked (`_arguments`, `_start`,
`_plausible`) in an order that refuses a bad call before anything is compiled, the experiments
packed into arrays (`_data`), and the problem (`_Problem`) with the fit's start."""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple, Optional

import diffrax
import jax.numpy as jnp
import numpy as np

from ..._data import DataError
from ..._paths import fit_start
from ..._scenes import SceneOptions, input_panels
from ..._simulate import get_solver
from .._catalogue import SceneContext
from .._evaluation import Evaluation, equal_links
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
from ._fit import _initial_state_guess
from ._plausible import check_plausible
from ._problem import INIT_SCALE, LOSSES, _Problem, _to_z
from ._start import check_scene_start, check_starts


class Prepared(NamedTuple):
    """A checked identification, ready to fit."""

    prob: _Problem
    exps: list
    #: the start in the fit's unknowns, and the parameters' initial values
    z0: np.ndarray
    p0: np.ndarray
    #: (E, m) the samples fitted (padding and held-out samples False)
    mask: np.ndarray
    #: None, or (the weights with the held-out samples, held (E, m), their description)
    held: Optional[tuple]
    #: residuals of weight > 0 less the unknowns
    dof: int
    noise: tuple
    #: what drove the model, in words (`Identification.actuation`)
    driven_by: str


def prepare(experiments, unknowns, call: dict, fit, options, n_elements) -> Prepared:
    """Check `identify`'s arguments and build its problem.

    **Arguments:**

    - `experiments`, `unknowns`: `identify`'s.
    - `call`: `identify`'s other arguments: model, scene, actuation, params, commands, fixed,
        initial, bounds, noise, program_dir.
    - `fit`: the `FitOptions`.
    - `options`: the `SceneOptions` (its solver, tolerances and step budget).
    - `n_elements`: the beam's element count (deprecated keyword) or None.

    **Returns:**

    A `Prepared`.
    """
    c = call
    check_solver_args(fit.loss_scale, fit.max_iter, fit.xtol, fit.ftol, fit.stat_tol,
                      options.rtol, options.atol, options.max_steps, fit.seed)
    exps = check_experiments(experiments)
    n_init, meas = check_choices(c["actuation"], fit.initial_state, fit.starts, fit.nuisance,
                                 fit.loss, fit.solver, fit.max_iter)
    names, fixed, initial, bounds = check_unknowns(unknowns, c["fixed"], c["initial"],
                                                   c["bounds"], c["params"], c["commands"],
                                                   c["noise"])
    own, scene_obj, drive, label, actuation = resolve_scene(c["scene"], exps, c["actuation"],
                                                            c["commands"])
    mdl = check_model(c["model"], n_elements, n_init, drive, fit.initial_state)
    base, nominal = start_robot(c["params"], own, scene_obj, fixed, initial, names)
    lo, hi, lg = unknown_bounds(names, base, bounds)
    n_unknown = len(names) + n_init * len(exps) + len(meas)
    data, mask, held, n_res = _packed(exps, c, fit, (own, scene_obj, drive, actuation), base,
                                      n_init, n_unknown)
    solver = get_solver(mdl.default_solver if options.solver is None else options.solver)
    check_commands(c["commands"], actuation)
    # the PRB parameters the commands use as explicit leaves, so that the default (the table's
    # values) and named commands are one structure: one compiled fit for both
    cmd = _fill_prb(nominal if c["commands"] is None else c["commands"],
                    ("gamma", "K_theta", "rho"))
    prob = _problem(base, cmd, (names, lo, hi, lg), data, c, fit, options, mdl, solver,
                    (n_init, meas, scene_obj, drive, label), exps)
    p0 = np.array([float(getattr(base, n)) for n in names])
    z0 = np.concatenate([_to_z(lg, lo, hi, p0), np.zeros(n_init * len(exps) + len(meas))])
    if n_init:
        z0 = _initial_state_guess(prob, z0, mask)
    return Prepared(prob, exps, z0, p0, mask, held, n_res - n_unknown,
                    tuple(float(v) for v in c["noise"]),
                    driven_by(own, len(exps), actuation, drive, data[3] is not None,
                              c["commands"] is not None))


def _packed(exps, c, fit, scene, base, n_init, n_unknown) -> tuple:
    """The experiments as padded arrays (`_pack`), checked before anything is compiled: each
    one's first sample against the model (`check_starts`, `check_scene_start`), the columns
    that drive the model over the whole record (`check_plausible`), the samples held out
    (`held_out`) and the residuals left against the unknowns. `scene`: (own, scene_obj, drive,
    actuation) as `resolve_scene` decided them.

    **Returns:**

    ((ts, X, W, tau, th, paths, start_fits), mask, held, n_res): held None or (the weights
    with the held-out samples, held (E, m), their description); n_res the residuals of weight
    > 0.
    """
    own, scene_obj, drive, actuation = scene
    noise = c["noise"]
    ts, X, W, tau, th, mask, paths, start_fits = _pack(exps, float(noise[0]),
                                                       float(noise[1]), drive, actuation,
                                                       own=own)
    # Can each experiment's first sample start the model? (In the channels that are fitted: a
    # channel of infinite noise is not.)
    fitted = tuple(math.isfinite(float(v)) for v in noise)
    if own:
        check_starts(exps, drive, base, start_fits, fitted)
    else:
        check_scene_start(exps, scene_obj, [fit_start(e.ts, e.X)[0] for e in exps], fitted)
    # then the units and robot of the columns that drive the model, over the whole record
    where = "from the data" if own else getattr(scene_obj, "name", c["scene"])
    check_plausible(exps, base, where, angles=th is not None, torques=tau is not None)
    held = held_out(fit.validation, ts, mask, [e.name for e in exps], n_init)
    if held is not None:
        W_all = W
        mask = mask & ~held[0]
        W = W * mask[..., None]
        held = (W_all, *held)
    n_res = int(np.count_nonzero(W))  # weight 0 (infinite noise, held out): no information
    if n_res <= n_unknown:
        raise DataError(f"{n_res} residuals cannot determine {n_unknown} unknowns")
    return (ts, X, W, tau, th, paths, start_fits), mask, held, n_res


def _problem(base, cmd, unknowns, data, c, fit, options, mdl, solver, extra, exps) -> _Problem:
    """The `_Problem`: `unknowns` (names, lo, hi, log), `data` (`_packed`'s arrays), `extra`
    (n_init, meas, scene_obj, drive, the scene's label)."""
    names, lo, hi, lg = unknowns
    ts, X, W, tau, th, paths, start_fits = data
    n_init, meas, scene_obj, drive, label = extra
    return _Problem(
        evaluation=evaluation(names, base, mdl, scene_obj, options, solver, ts.shape[1]),
        base=base, commands=cmd, lo=jnp.asarray(lo), hi=jnp.asarray(hi), ts=jnp.asarray(ts),
        X=jnp.asarray(X), w=jnp.asarray(W), tau=None if tau is None else jnp.asarray(tau),
        th=None if th is None else jnp.asarray(th), log=tuple(lg), scene=label,
        loss=jnp.asarray(LOSSES.index(fit.loss)),
        loss_scale=jnp.asarray(float(fit.loss_scale), dtype=jnp.float64),
        n_init=n_init, init_scale=jnp.asarray(INIT_SCALE[:n_init]) if n_init else None,
        meas=meas, drive=drive,
        paths=None if paths is None else jnp.asarray(paths),
        starts=None if start_fits is None else jnp.asarray(start_fits),
        experiment_names=tuple(e.name for e in exps), program_dir=c["program_dir"],
    )


def evaluation(names, base, model, scene, options, solver, m: int) -> Evaluation:
    """The `Evaluation` of the poses an identification fits: the unknowns `names` of `base`,
    `model` on `scene` (None: each experiment's own), with `options`' tolerances and step
    budget and `solver`, forward mode (the fit's Jacobian is `jacfwd`), for runs of `m` sample
    times.

    **Returns:**

    The `Evaluation` (no metrics), its options prepared once; their trajectory None: each run
    takes its scene's path (`Evaluation.poses`).
    """
    rtol, atol = options.tolerances(model)
    # The sample times are the program's inputs: the input table's panels follow from their
    # count alone (`input_panels` of an unknown horizon).
    prepared = SceneOptions(solver=solver, rtol=rtol, atol=atol,
                            max_steps=int(options.max_steps), adjoint=diffrax.ForwardMode(),
                            panels=input_panels(None, None, m)).prepared(model)
    prepared = dataclasses.replace(prepared, trajectory=None)
    return Evaluation(names=tuple(names), metrics=(),
                      equal_links=equal_links(base, names, local=False), samples=(),
                      ctx=SceneContext(scene, model, prepared, None))


def driven_by(own: bool, n_exps: int, actuation: str, drive: str, torques: bool,
              commands: bool) -> str:
    """What drove the model, in words (`Identification.actuation`).

    **Arguments:**

    - `own`: each experiment is its own scene (no named scene).
    - `n_exps`: the number of experiments.
    - `actuation`: "measured" or "commanded" (as `resolve_scene` decided).
    - `drive`: the scene's drive, "motion" or "torque".
    - `torques`: the measured torques drive the model.
    - `commands`: a commands model was named.

    **Returns:**

    The text.
    """
    whose = ("each experiment's own" if n_exps > 1 else "the experiment's own") if own \
        else "the"
    if actuation == "measured":
        text = f"{whose} measured actuated angles th_1..th_3"
    elif drive == "torque" and torques:
        text = f"{whose} measured torques tau_1..tau_3"
    else:
        what = "commanded angles" if drive == "motion" else "inverse-dynamics torques"
        text = (f"the {what} of the given commands model, held fixed" if commands
                else f"the {what} of the nominal robot (params with fixed), held fixed")
    if own:
        text += (" along its own path, from the state its first samples give"
                 if n_exps == 1 else
                 " along their own paths, from the states their first samples give")
    return text
