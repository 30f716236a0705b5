"""Sensitivities d(metric)/d(parameter) of the paper's metrics to every float parameter.

The metrics are traced functions of the parameters (an `_evaluation.Evaluation` of the
catalogue's scene metrics and the first locked natural frequency), differentiated in forward
mode (`jax.jvp` with `diffrax.ForwardMode()`: one tangent per parameter, carried on the solve,
the parameters in slices, one a CPU core, `_jacobian.forward_jacobian`) or reverse mode
(`jax.jacrev` with diffrax's `RecursiveCheckpointAdjoint`: one forward pass, one backward pass
per metric). Normalised sensitivities are (p / m) dm/dp: the relative change of the metric per
relative change of the parameter.

Max / min over time: the metrics radial_error_max/min, end_rotation_diff_max and torque_peak are
the exact max (min) over the output samples, so their derivative is the derivative at the
arg-max sample (a subgradient, exact while that sample does not change under the perturbation);
no smoothing is applied.

Base frequency: the lowest eigenvalue of the locked linearisation (`ppr_jax.modes`). `eigh`'s
derivative divides by eigenvalue gaps, and the symmetric robot has repeated eigenvalues, so it
is NaN there. The derivative used here is the Rayleigh quotient's: with the mass-normalised mode
shapes held fixed (`stop_gradient`), lambda_k = v_k^T K v_k / v_k^T M v_k has the exact first
derivative of a simple eigenvalue (Hellmann-Feynman); for a repeated lowest eigenvalue the
average over its cluster (relative gap below `CLUSTER_RTOL`) is reported, whose derivative is
well defined (the trace over the cluster's subspace).

PRB parameters: `gamma`, `rho` and `K_theta` default to the fitted table's values at theta_c
(`RobotParams` leaves them None). They are made explicit leaves at those values, so their
sensitivities exist; dm/dtheta_c then holds the PRB parameters fixed.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Callable, Optional, Sequence

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import PPRError
from .._models import get_model
from .._names import (  # the table's rows, SI units
    PATH_SENSITIVITY_METRICS as PATH_SENSITIVITY_METRICS,
    SENSITIVITY_METRICS as SENSITIVITY_METRICS,
)
from .._params import RobotParams
from .._prb import derived
from .._programs import cached_program
from .._scenes import SceneOptions, check_scene_commands, get_scene
from ._catalogue import (
    CLUSTER_RTOL as CLUSTER_RTOL,
    SceneContext,
    allowed_metrics as allowed_metrics,
    base_frequency as base_frequency,
    default_metrics as default_metrics,
    locked_stiffness as locked_stiffness,
    tracking_metrics,
)
from ._evaluation import Evaluation, equal_links
from ._jacobian import derivatives_along, forward_jacobian, jacobian_with_values
from ._sweep import FLOAT_PARAMS


def explicit_params(params: RobotParams) -> RobotParams:
    """`params` with gamma, rho and K_theta set to the values in use (the PRB table's where
    they are None), so that every float parameter is a leaf to differentiate."""
    dv = derived(params)
    return params.replace(gamma=float(dv.gamma), rho=float(dv.rho), K_theta=float(dv.K_theta))


@dataclasses.dataclass
class Sensitivity:
    """A sensitivity table. `metrics` (names, k), `parameters` (names, p); `values` {metric:
    value} at the nominal parameters (units in the name); `param_values` {name: value} (SI);
    `jacobian` (k, p) numpy array dm/dp (metric unit per parameter unit); `normalized` (k, p)
    (p / m) dm/dp (dimensionless; NaN where m == 0); `mode` 'fwd' or 'rev'; `timing` {compile_s,
    run_s} (s) of the derivative's one program (which gives the values too; the first run of a
    program compiled in this process carries its first execution's own costs: a torque-driven
    L2 `PathScene` over 0.5 s, 19 parameters, ran 218 ms forward and 126 ms reverse first,
    20 and 29 ms after, and the first run of the same program on new inputs 45 and 27 ms:
    time repeated calls, as `benchmarks/` does); `info` the
    settings; `evaluate(x)` the compiled metrics (k,) at parameter values x (p,) in `parameters`
    order (for checks such as finite differences; NaN where the solve fails), a program of its
    own compiled on the first call."""

    metrics: list
    parameters: list
    values: dict
    param_values: dict
    jacobian: np.ndarray
    normalized: np.ndarray
    mode: str
    timing: dict
    info: dict
    evaluate: Optional[Callable] = dataclasses.field(default=None, repr=False)

    def rows(self) -> list:
        """One dict per (metric, parameter): the tidy form the CLI writes."""
        out = []
        for i, m in enumerate(self.metrics):
            for j, p in enumerate(self.parameters):
                out.append({"metric": m, "parameter": p, "metric_value": self.values[m],
                            "parameter_value": self.param_values[p],
                            "derivative": float(self.jacobian[i, j]),
                            "normalized": float(self.normalized[i, j])})
        return out


def metric_function(scene="paper-circle", params: Optional[RobotParams] = None, *,
                    model="double1r", torque_model=None, frequency_model="double1r",
                    parameters: Optional[Sequence[str]] = None,
                    options: Optional[SceneOptions] = None,
                    metrics: Optional[Sequence[str]] = None, **option_fields):
    """(f, x0, names): `f(x, adjoint)` -> (k,) the `metrics` (default `default_metrics` of
    the scene's path) at parameter values x (p,) (the `parameters`, default every float
    parameter, in `names` order), x0 the nominal values. Traceable and differentiable;
    `adjoint` is diffrax's (ForwardMode for forward mode). `scene`: a registered name or an
    `AbstractScene`; `options` and `option_fields` (`SceneOptions`' fields as keywords) as
    `sweep`'s."""
    return _metric_function(scene, params, model=model, torque_model=torque_model,
                            frequency_model=frequency_model, parameters=parameters,
                            options=options, metrics=metrics, **option_fields)[:3]


def _metric_function(scene, params, *, model, torque_model, frequency_model, parameters,
                     options, metrics, **option_fields):
    """`metric_function`, and the metrics, the scene and the prepared options it decided."""
    scene_ = get_scene(scene, torque_model)
    base = explicit_params(scene_.default_params() if params is None else params)
    if np.ndim(base.a) != 0:
        raise PPRError("sensitivities are computed for one robot, not a batch")
    names = list(FLOAT_PARAMS if parameters is None else parameters)
    for n in names:
        if n not in FLOAT_PARAMS:
            raise PPRError(f"unknown parameter {n!r}; allowed: {', '.join(FLOAT_PARAMS)}")
    model_ = get_model(model)
    opts = (SceneOptions() if options is None else options).updated(**option_fields).check()
    options = opts.prepared(model_, scene_.trajectory())
    traj = options.trajectory
    check_scene_commands(scene_, base, traj, opts.t_end)
    metrics = tuple(default_metrics(traj) if metrics is None else metrics)
    allowed = allowed_metrics(traj, "sensitivity")
    for m in metrics:
        if m not in allowed:
            raise PPRError(f"unknown metric {m!r} for the scene's path; allowed: "
                           f"{', '.join(allowed)}")
    x0 = jnp.array([float(getattr(base, n)) for n in names])
    follows = scene_.follows_its_input(model_)
    tracking = tracking_metrics(metrics)
    if follows and tracking:
        raise PPRError(
            f"{', '.join(tracking)} of model {model_.name!r} in {scene_.name!r} measure the "
            f"integrator's error, not the robot: {follows}. Ask for the response of another "
            f"model (model='double1r' or 'beam', the paper's question; or a scene driven by "
            f"another model's input, torque_model='rigid' for L1 under the rigid model's "
            f"torques), or leave these metrics out")
    fmodel = get_model(frequency_model)
    # the nominal robot's structural choice, as its single run makes it (`equal_links`)
    equal = equal_links(base, names, local=True)
    ev = Evaluation(names=tuple(names), metrics=metrics, equal_links=equal, samples=(),
                    ctx=SceneContext(scene_, model_, options, fmodel))

    def f(x, adjoint=None):
        return ev.values(x, base, adjoint=adjoint)

    return f, x0, names, metrics, scene_, options, (base, ev)


@eqx.filter_jit
def _values(x, base, ev):
    return ev.values(x, base)


def _metrics_at(x, base, ev, adjoint):
    return ev.values(x, base, adjoint=adjoint)


@eqx.filter_jit
def _jacobian_fwd(x, V, base, ev):
    # along the rows of V (the identity's, a slice of them a core: `forward_jacobian`)
    return derivatives_along(_metrics_at, x, V, base, ev, diffrax.ForwardMode())


@eqx.filter_jit
def _jacobian_rev(x, base, ev, adjoint):
    return jacobian_with_values(_metrics_at, x, base, ev, adjoint)


def sensitivity(scene="paper-circle", params: Optional[RobotParams] = None, *,
                mode: str = "fwd", model="double1r", torque_model=None,
                frequency_model="double1r", parameters: Optional[Sequence[str]] = None,
                metrics: Optional[Sequence[str]] = None, options: Optional[SceneOptions] = None,
                t_end: Optional[float] = None, n_out: Optional[int] = None, solver=None,
                rtol: Optional[float] = None, atol: Optional[float] = None,
                max_steps: Optional[int] = None, checkpoints: Optional[int] = None,
                program_dir: Optional[str] = None) -> Sensitivity:
    """d(metric)/d(parameter) of `metrics` of `scene` to `parameters`, at `params`.

    **Arguments:**

    - `scene`: a registered name (default `paper-circle`) or an `AbstractScene` (a `PathScene`
      on your own path).
    - `params`: one `RobotParams`; None (default): the scene's.
    - `mode`: 'fwd' (default): `jax.jvp` with `diffrax.ForwardMode()` along every
      parameter's direction, the directions in slices, one a core (`forward_jacobian`; cost
      grows with the number of parameters); 'rev': `jax.jacrev` with
      `diffrax.RecursiveCheckpointAdjoint(checkpoints)` (cost grows with the number of
      metrics).
    - `model`: the simulated model; the default is L2 (`double1r`) under L1's torques (the
      paper's question).
    - `torque_model`: for a registered torque-driven scene, the model whose inverse dynamics
      gives the torques; None: the scene's default.
    - `frequency_model`: the model whose base frequency is reported (locked actuators, home
      pose; L1 has no mode); default `double1r`.
    - `parameters`: names of float parameters of `RobotParams`; None (default): every one.
    - `metrics`: None (default): `SENSITIVITY_METRICS` on a circle, `PATH_SENSITIVITY_METRICS`
      on any other path (`allowed_metrics` lists them all).
    - `options`: a `SceneOptions`; `t_end`, `n_out`, `solver`, `rtol`, `atol`, `max_steps`:
      its fields also as keywords (replacing the options' where not None), as `sweep`.
    - `checkpoints`: the checkpoints of mode 'rev'; None (default): the solve's own
      reverse pass where it runs Tsit5 under the default controller (a state kept every 16
      accepted steps, each segment replayed and transposed), diffrax's default elsewhere; a
      number: diffrax's `RecursiveCheckpointAdjoint` with that many.
    - `program_dir`: a directory of stored programs (as `run_scene`'s; the command line's): the
      metrics' and their derivatives' programs are exported there once and loaded by later
      processes, which skip tracing them; None (default): compiled in this process (and kept
      for later calls of the same setting).

    **Returns:**

    A `Sensitivity`: the values, the Jacobian (k, p) dm/dp and its normalized form (p / m)
    dm/dp, timings and settings.

    **Raises:**

    `PPRError` for a `mode` other than 'fwd' or 'rev', metrics not finite at these parameters
    (failed solve), or the tracking error of a model that follows its own input
    (`follows_its_input`: L0 or L1 under its own torques, L1 in servo-circle): it is the
    integrator's error.
    """
    if mode not in ("fwd", "rev"):
        raise PPRError(f"mode must be 'fwd' or 'rev', got {mode!r}")
    f, x0, names, metrics, scene_, opts, (base, ev) = _metric_function(
        scene, params, model=model, torque_model=torque_model, frequency_model=frequency_model,
        parameters=parameters, options=options, metrics=metrics, t_end=t_end, n_out=n_out,
        solver=solver, rtol=rtol, atol=atol, max_steps=max_steps)
    label = f"sensitivity-{scene_.name}-{get_model(model).name}"
    # compiled (or loaded) ahead of time, then run once: the derivative is not run a second time
    # just to time it
    clock = {}

    def compiled_run(fn, args):
        t2 = time.perf_counter()
        jac = cached_program(fn, args, (0, 0), program_dir, f"{label}-{mode}")
        t3 = time.perf_counter()
        out = jax.block_until_ready(jac(*args))
        clock.update(compile_s=t3 - t2, run_s=time.perf_counter() - t3)
        return out

    if mode == "fwd":
        J, v = forward_jacobian(_jacobian_fwd, x0, base, ev, run=compiled_run)
    else:
        J, v = compiled_run(_jacobian_rev, (x0, base, ev, diffrax.RecursiveCheckpointAdjoint(
            checkpoints=checkpoints)))
    J, v = np.asarray(J), np.asarray(v)
    run = clock["run_s"]

    def evaluate(x):
        # compiled on first use (finite differences, checks): the table needs no values program
        value = cached_program(_values, (x0, base, ev), 0, program_dir, f"{label}-values")
        return np.asarray(value(jnp.asarray(x, dtype=jnp.float64), base, ev))

    if not np.all(np.isfinite(v)):
        bad = [m for m, x in zip(metrics, v) if not np.isfinite(x)]
        raise PPRError(f"the metrics {bad} are not finite at these parameters (failed solve?)")
    x = np.asarray(x0)
    with np.errstate(divide="ignore", invalid="ignore"):
        norm = J * x[None, :] / v[:, None]
    norm = np.where(v[:, None] == 0, np.nan, norm)
    return Sensitivity(
        metrics=list(metrics), parameters=names,
        values={m: float(a) for m, a in zip(metrics, v)},
        param_values={n: float(a) for n, a in zip(names, x)}, jacobian=J, normalized=norm,
        mode=mode,
        timing={"compile_s": clock["compile_s"], "run_s": run},
        info=dict(scene=scene_.name, model=get_model(model).name,
                  input_model=scene_.input_model.name,
                  frequency_model=get_model(frequency_model).name, t_end=float(opts.t_end),
                  n_out=int(opts.n_out), rtol=float(opts.rtol), atol=float(opts.atol),
                  checkpoints=checkpoints),
        evaluate=evaluate,
    )
