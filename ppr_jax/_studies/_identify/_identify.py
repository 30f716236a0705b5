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
- ``FitOptions.initial_state``: ``"scene"`` (default) starts each experiment from the scene's
  quasi-static state at t = 0; ``"pose"`` adds each experiment's initial platform pose (x0, y0,
  phi0) to the unknowns, ``"pose-velocity"`` also its initial platform velocity, as offsets from
  that state (the platform coordinates z[:3] of every model; the actuated angles stay where the
  actuation puts them, the chains' other coordinates where the quasi-static state does). They
  are nuisance parameters: the parameters' covariance is marginal over them (their Jacobian
  columns projected out), and they are reported per experiment in
  `Identification.initial_state`. Use it when a recording starts in motion or off equilibrium.

Method, and why:
- Residuals: simulated minus measured pose at the sample times, each channel divided by its
  stated noise (`noise=(position m, phi rad)`), so x, y and phi weigh alike and the residual
  variance is about 1 when the noise is as stated. An infinite noise leaves its channel out
  (weight 0); residuals of weight 0 (that channel, padding, held-out samples) are not counted
  in N. The simulation saves at the sample times directly (no interpolation error).
- Unknowns are reparametrised for their bounds (default `PARAM_RANGES`): p = exp(log lo +
  (log hi - log lo) sigmoid(z)) for lo > 0 (relative steps, so t ~ 5e-4 and E ~ 7e10 are both
  O(1) in z), p = lo + (hi - lo) sigmoid(z) otherwise. Bounds are never crossed.
- Experiments are padded to a common length and simulated in one program, as a batch's
  members (`map_members`: on a CPU one after another, each on the lean loop), so several
  experiments cost one compilation.
- Jacobian: forward mode through diffrax (`diffrax.ForwardMode`), one compiled function
  returning residuals and Jacobian together (one jvp per unknown), the unknowns' directions in
  slices on the host's cores (`forward_jacobian`). The default solver
  is a Levenberg-Marquardt loop on the host around that one compiled function: the same
  compilation then serves the covariance and any further fit on data of the same shapes.
  ``FitOptions(solver="optimistix-lm")`` / ``"optimistix-gn"`` run
  `optimistix.LevenbergMarquardt` / `optimistix.GaussNewton` instead; they compile their own
  loop (L2, 0.5 s experiment: about 115 s against 31 s for the compiled Jacobian, and 0.4 s
  per step against 0.12 s, because `jax.linearize` re-runs the solve for each tangent).
- Robust losses ``huber`` and ``cauchy`` transform each residual r into sign(r) sqrt(2 rho(r))
  (as scipy's `least_squares`), with `FitOptions.loss_scale` in noise units (default 3): least
  squares on the transformed residuals minimises the robust cost.
- Covariance: s^2 (J^T J)^-1 with J the Jacobian with respect to the physical parameters and
  s^2 = sum r^2 / (N - P) estimated from the (weighted) residuals, N those of weight > 0;
  intervals use Student's t."""

from __future__ import annotations

from typing import Optional, Sequence, Union

from ..._data import Experiment
from ..._params import RobotParams
from ..._scenes import AbstractScene, SceneOptions, options_from
from ._options import FitOptions, deprecated_keywords
from ._problem import DEFAULT_NOISE
from ._result import Identification
from ._run import run
from ._setup import prepare


def identify(
    experiments: Union[Experiment, Sequence[Experiment]],
    unknowns: Sequence[str] = ("t",),
    *,
    model="double1r",
    scene: Union[None, str, AbstractScene] = None,
    actuation: str = "auto",
    params: Optional[RobotParams] = None,
    commands: Optional[RobotParams] = None,
    fixed: Optional[dict] = None,
    initial: Optional[dict] = None,
    bounds: Optional[dict] = None,
    noise: tuple = DEFAULT_NOISE,
    fit_options: Optional[FitOptions] = None,
    options: Optional[SceneOptions] = None,
    program_dir: Optional[str] = None,
    **deprecated,
) -> Identification:
    """Fit `unknowns` (names of `RobotParams` float leaves) to measured experiments.

    How the fit runs (solver, stops, loss, starts, initial state, nuisances, validation,
    force) is a `FitOptions`; how the simulation runs (solver, tolerances, step budget) a
    `SceneOptions`. Before fitting, a preflight checks the identifiability of the unknowns at
    the initial guess, from the data's own sampling and the stated noise (residual scale
    s = 1): the singular-value analysis of the relative sensitivities that the result reports
    (`Identification.identifiability`), on the residual Jacobian at the start (the first
    iteration's), with the nuisance unknowns marginalised out. A combination "not identifiable
    from these data" (relative std >= 1) is refused with an `IdentificationError` naming it and
    what would make it identifiable, unless `FitOptions(force=True)`; `history["preflight"]`
    keeps the verdict.

    **Arguments:**

    - `experiments`: one `Experiment` or several (fitted jointly; `load_csv`,
        `load_experiments`).
    - `unknowns`: the parameters to fit. Default `("t",)`: the strip thickness, with K_theta
        from the PRB table. t and K_theta act on the motion through the joint stiffness
        E w t^3 K_theta (only the strip mass separates them), so the preflight refuses the pair
        on the usual data (on 0.6 s of the servo circle t^3 K_theta has a relative std of 6 %,
        t^-1 K_theta^3 of 1e6 %); force it to see the combinations in the result.
    - `model`: "double1r" (L2, default), "reduced" (L1), "rigid" (L0) or a model instance
        (`get_model("beam", n_elements=...)` for the beam's element count).
    - `scene`: None (default): each experiment's own scene, driven by its own angles (or
        torques) along its own path from its own first samples (module docstring); or the
        paper's experiment the data come from, a registered name ("servo-circle",
        "paper-circle") or an `AbstractScene`, whose drive (`AbstractScene.drive`) says
        whether angles or torques drive it.
    - `actuation`: "auto" (default: the data's th_1..th_3 drive the model when every
        experiment holds them and no `commands` are named, else the commands), "commanded" (a
        named scene's commands, or torques, computed for `commands`) or "measured" (a
        motion-driven scene: the data's angles). Without a scene the data's own commands
        drive the model. `Identification.actuation` says which drove the fit.
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
    - `fit_options`: a `FitOptions` (default `FitOptions()`).
    - `options`: a `SceneOptions`: its `solver`, `rtol`, `atol` and `max_steps` are the
        simulation's (default the model's solver and tolerances, `AbstractModel.default_solver`,
        `default_rtol`, `default_atol`, and the scenes' step budget); the horizon and output
        times are the experiments' own.
    - `program_dir`: a directory of stored programs (as `run_scene`'s; the command line's):
        the fit's residual-and-Jacobian program is exported there once and loaded by later
        processes, which then skip its trace. None: compiled in this process. The results are
        the same either way.
    - `deprecated`: the keywords of earlier releases, for one release (a `DeprecationWarning`):
        the fields of `FitOptions` (not together with `fit_options`), `ode_solver`, `rtol`,
        `atol`, `max_steps` (the `SceneOptions` fields, not together with `options`) and
        `n_elements`.

    **Returns:**

    An `Identification`.

    **Raises:**

    `IdentificationError` for unknown or fixed names that are not leaves, a numeric option out
    of its range (`FitOptions`' ranges; rtol in [1e-14, 1e-2], atol in [1e-16, 1e-2],
    max_steps in [1, 1e9]; checked before anything is compiled), bounds outside the physical
    range, an initial value outside its bounds, a bad option (naming it and its allowed
    values), a simulation that fails at the initial values (naming the experiment and the
    cause), or a preflight refusal; its subclass `StartError`, before anything is compiled,
    for an experiment whose first sample cannot start the model (module docstring);
    `DataError` for unusable data (without a scene: data that hold neither angles nor
    torques); `TypeError` for a keyword `identify` never took.
    """
    fit, scene_keywords, n_elements = deprecated_keywords(fit_options, deprecated)
    options = options_from(options, "identify", True, **scene_keywords)
    call = dict(model=model, scene=scene, actuation=actuation, params=params,
                commands=commands, fixed=fixed, initial=initial, bounds=bounds, noise=noise,
                program_dir=program_dir)
    return run(prepare(experiments, unknowns, call, fit, options, n_elements), fit)
