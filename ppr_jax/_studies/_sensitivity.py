"""Sensitivities d(metric)/d(parameter) of the paper's metrics to every float parameter.

The metrics are traced functions of the parameters (`_sweep.traced_metrics` of a scene,
plus the first locked natural frequency), differentiated in forward mode (`jax.jacfwd` with
`diffrax.ForwardMode()`: one tangent per parameter, all in one vmapped pass) or reverse mode
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

from .._dynamics import eom_terms, generalized_force
from .._errors import RESULTS, PPRError
from .._geometry import home_pose
from .._metrics import path_metrics
from .._models import get_model
from .._modes import reduced_eigh
from .._names import (  # the table's rows, SI units
    PATH_SENSITIVITY_METRICS as PATH_SENSITIVITY_METRICS,
    SENSITIVITY_METRICS as SENSITIVITY_METRICS,
)
from .._params import RobotParams
from .._prb import derived
from .._programs import cached_program
from .._robot import Robot
from .._scenes import SceneOptions, check_scene_commands, get_scene
from .._statics import assemble, static_equilibrium
from ._jacobian import jacobian_with_values
from ._sweep import FLOAT_PARAMS, sweep_metrics, traced_metrics

#: eigenvalues within this relative distance of the lowest are one (repeated) cluster
CLUSTER_RTOL = 1e-6


def default_metrics(trajectory) -> tuple:
    """The sensitivity table's default metrics along `trajectory`: `SENSITIVITY_METRICS` on a
    circle, `PATH_SENSITIVITY_METRICS` on any other path."""
    return (SENSITIVITY_METRICS if "radial_error_max_m" in path_metrics(trajectory)
            else PATH_SENSITIVITY_METRICS)


def allowed_metrics(trajectory) -> tuple:
    """Every metric a sensitivity may ask for along `trajectory`."""
    return sweep_metrics(trajectory) + ("base_frequency_hz",)


def explicit_params(params: RobotParams) -> RobotParams:
    """`params` with gamma, rho and K_theta set to the values in use (the PRB table's where
    they are None), so that every float parameter is a leaf to differentiate."""
    dv = derived(params)
    return params.replace(gamma=float(dv.gamma), rho=float(dv.rho), K_theta=float(dv.K_theta))


def locked_stiffness(model, robot: Robot, X=None):
    """The stiffness of `model` about its static equilibrium near the pose X (default home)
    with the actuators locked, in its free coordinates, differentiable (no host callback: a
    failed equilibrium is returned as a flag).

    **Arguments:**

    - `model`: a model with free coordinates when locked (L2, L3); `robot`: a `Robot`.
    - `X`: the pose (3,) (m, m, rad) near which the equilibrium is found.

    **Returns:** `(z_eq, free, K, failed)`: the equilibrium (n,), the free coordinates' indices,
    K = -dQ/dz_free (symmetrised), Q the generalised force at rest, and whether Newton failed.

    **Raises:** `PPRError` for a model without free coordinates when locked (L0, L1).
    """
    X = home_pose(robot) if X is None else X
    z_eq, free, failed = static_equilibrium(model, robot, model.coords_from_pose(robot, X),
                                            locked=True, wrench=jnp.zeros(3), check=False,
                                            return_failed=True)
    if not free:
        raise PPRError(f"model {model.name!r} has no free coordinate with locked actuators; "
                       f"use double1r (or beam) for the base frequency or the compliance")
    n = model.n_dof
    known = tuple(i for i in range(n) if i not in free)
    f = jnp.array(free)
    zk = z_eq[jnp.array(known)] if known else None

    def Q(zf):
        z = assemble(n, free, zf, known, zk)
        return generalized_force(eom_terms(model, robot, z, jnp.zeros(n)), jnp.zeros(3),
                                 jnp.zeros(3))[f]

    K = -jax.jacfwd(Q)(z_eq[f])
    return z_eq, free, (K + K.T) / 2, failed


def base_frequency(model, robot: Robot, X=None):
    """The lowest natural frequency (Hz, signed: negative = unstable) of `model` about its static
    equilibrium near X (default home) with the actuators locked, differentiable (module
    docstring: Rayleigh quotient with the mode shapes held fixed; repeated lowest eigenvalues
    averaged). Raises for a model without free coordinates when locked (L0, L1)."""
    z_eq, free, K, failed = locked_stiffness(model, robot, X)
    n = model.n_dof
    f = jnp.array(free)
    M = eom_terms(model, robot, z_eq, jnp.zeros(n)).M[f][:, f]
    # Mode shapes from a non-differentiated eigenproblem: eigh's derivative is NaN at repeated
    # eigenvalues. The Rayleigh quotients below carry the exact first derivative.
    Ms, Ks = jax.lax.stop_gradient(M), jax.lax.stop_gradient(K)
    lam0, _, shapes = reduced_eigh(Ms, Ks)  # shapes M-orthonormal
    lam = jnp.einsum("ik,ij,jk->k", shapes, K, shapes) / jnp.einsum("ik,ij,jk->k", shapes, M,
                                                                    shapes)
    w = (jnp.abs(lam0 - lam0[0]) <= CLUSTER_RTOL * jnp.abs(lam0[0])).astype(lam.dtype)
    lam1 = jnp.sum(w * lam) / jnp.sum(w)
    f = jnp.sign(lam1) * jnp.sqrt(jnp.abs(lam1)) / (2 * jnp.pi)
    return jnp.where(failed, jnp.nan, f)


@dataclasses.dataclass
class Sensitivity:
    """A sensitivity table. `metrics` (names, k), `parameters` (names, p); `values` {metric:
    value} at the nominal parameters (units in the name); `param_values` {name: value} (SI);
    `jacobian` (k, p) numpy array dm/dp (metric unit per parameter unit); `normalized` (k, p)
    (p / m) dm/dp (dimensionless; NaN where m == 0); `mode` 'fwd' or 'rev'; `timing` {compile_s,
    run_s} (s) of the derivative's one program (which gives the values too); `info` the
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
    allowed = allowed_metrics(traj)
    for m in metrics:
        if m not in allowed:
            raise PPRError(f"unknown metric {m!r} for the scene's path; allowed: "
                           f"{', '.join(allowed)}")
    x0 = jnp.array([float(getattr(base, n)) for n in names])
    follows = scene_.follows_its_input(model_)
    tracking = [m for m in metrics if m in path_metrics(traj)]
    if follows and tracking:
        raise PPRError(
            f"{', '.join(tracking)} of model {model_.name!r} in {scene_.name!r} measure the "
            f"integrator's error, not the robot: {follows}. Ask for the response of another "
            f"model (model='double1r' or 'beam', the paper's question; or a scene driven by "
            f"another model's input, torque_model='rigid' for L1 under the rigid model's "
            f"torques), or leave these metrics out")
    fmodel = get_model(frequency_model)
    # The structural choice of the nominal robot, as its single run makes it: with l1 == l3 the
    # closed-form inverse kinematics, whose one Newton step carries the implicit-function
    # derivative in l1 or l3 alone (ppr_jax._robot).
    equal = float(base.l1) == float(base.l3)
    setting = _Setting(base=base, names=tuple(names), metrics=metrics, scene=scene_,
                       model=model_, frequency_model=fmodel, options=options, equal=equal)

    def f(x, adjoint=None):
        return _metrics_at(x, setting, adjoint)

    return f, x0, names, metrics, scene_, options, setting


class _Setting(eqx.Module):
    """Everything the metrics depend on besides the parameters varied: the nominal robot's
    parameters (arrays: inputs of the compiled programs, so that a stored program serves any
    nominal robot) and the structural choices (static: they key it)."""

    base: RobotParams
    names: tuple = eqx.field(static=True)
    metrics: tuple = eqx.field(static=True)
    scene: object
    model: object = eqx.field(static=True)
    frequency_model: object = eqx.field(static=True)
    options: SceneOptions
    equal: bool = eqx.field(static=True)


def _metrics_at(x, setting: _Setting, adjoint=None):
    """The metrics (k,) at parameter values x (p,) (`metric_function`'s f)."""
    p = eqx.tree_at(lambda q: [getattr(q, n) for n in setting.names], setting.base, list(x))
    robot = Robot(p, equal_links=setting.equal)
    out = {}
    needed = [m for m in setting.metrics if m != "base_frequency_hz"]
    if needed:
        opts = setting.options if adjoint is None else eqx.tree_at(
            lambda o: o.adjoint, setting.options, adjoint)
        res = setting.scene.run(setting.model, robot, opts)
        out.update(traced_metrics(res, opts.trajectory, needed))
        # A failed solve must not pass as a number: NaN through every metric.
        bad = res.result != RESULTS.successful
        out = {k: jnp.where(bad, jnp.nan, v) for k, v in out.items()}
    if "base_frequency_hz" in setting.metrics:
        out["base_frequency_hz"] = base_frequency(setting.frequency_model, robot)
    return jnp.stack([out[m] for m in setting.metrics])


@eqx.filter_jit
def _values(x, setting):
    return _metrics_at(x, setting)


@eqx.filter_jit
def _jacobian_fwd(x, setting):
    return jacobian_with_values(_metrics_at, "fwd", x, setting, diffrax.ForwardMode())


@eqx.filter_jit
def _jacobian_rev(x, setting, adjoint):
    return jacobian_with_values(_metrics_at, "rev", x, setting, adjoint)


def sensitivity(scene="paper-circle", params: Optional[RobotParams] = None, *,
                mode: str = "fwd", model="double1r", torque_model=None,
                frequency_model="double1r", parameters: Optional[Sequence[str]] = None,
                metrics: Optional[Sequence[str]] = None, options: Optional[SceneOptions] = None,
                t_end: Optional[float] = None, n_out: Optional[int] = None, solver=None,
                rtol: Optional[float] = None, atol: Optional[float] = None,
                max_steps: Optional[int] = None, checkpoints: Optional[int] = None,
                program_dir: Optional[str] = None) -> Sensitivity:
    """d(metric)/d(parameter) of `metrics` of `scene` to `parameters` (default every float
    parameter of `RobotParams`), at `params` (default the scene's).

    `scene`: a registered name or an `AbstractScene` (a `PathScene` on your own path).
    `metrics`: default `SENSITIVITY_METRICS` on a circle, `PATH_SENSITIVITY_METRICS` on any
    other path (`allowed_metrics` lists them all). mode 'fwd': `jax.jacfwd` with
    `diffrax.ForwardMode()` (cost grows with the number of parameters); 'rev': `jax.jacrev`
    with `diffrax.RecursiveCheckpointAdjoint(checkpoints)` (cost grows with the number of
    metrics; `checkpoints` None = diffrax's default, about log(steps) memory). The base
    frequency is that of `frequency_model` (locked actuators, home pose; L1 has no mode).
    `options`: a `SceneOptions`, its fields also as keywords (replacing the options' where not
    None), as `sweep`; the default `model` is L2 under L1's torques (the paper's question).
    The tracking error of a model that follows its own input (`follows_its_input`: L0 or L1
    under its own torques, L1 in servo-circle) is refused with a `PPRError`: it is the
    integrator's error. `program_dir`: a directory of stored programs (as `run_scene`'s; the
    command line's): the metrics' and their derivatives' programs are exported there once and
    loaded by later processes, which skip tracing them; None: compiled in this process (and
    kept for later calls of the same setting). Returns `Sensitivity`."""
    if mode not in ("fwd", "rev"):
        raise PPRError(f"mode must be 'fwd' or 'rev', got {mode!r}")
    f, x0, names, metrics, scene_, opts, setting = _metric_function(
        scene, params, model=model, torque_model=torque_model, frequency_model=frequency_model,
        parameters=parameters, options=options, metrics=metrics, t_end=t_end, n_out=n_out,
        solver=solver, rtol=rtol, atol=atol, max_steps=max_steps)
    if mode == "fwd":
        jac_fn, jac_args = _jacobian_fwd, (x0, setting)
    else:
        jac_fn = _jacobian_rev
        jac_args = (x0, setting, diffrax.RecursiveCheckpointAdjoint(checkpoints=checkpoints))
    label = f"sensitivity-{scene_.name}-{get_model(model).name}"
    # compiled (or loaded) ahead of time, then run once: the derivative is not run a second time
    # just to time it
    t2 = time.perf_counter()
    jac = cached_program(jac_fn, jac_args, (0, 0), program_dir, f"{label}-{mode}")
    t3 = time.perf_counter()
    J, v = (np.asarray(a) for a in jax.block_until_ready(jac(*jac_args)))
    run = time.perf_counter() - t3

    def evaluate(x):
        # compiled on first use (finite differences, checks): the table needs no values program
        value = cached_program(_values, (x0, setting), 0, program_dir, f"{label}-values")
        return np.asarray(value(jnp.asarray(x, dtype=jnp.float64), setting))

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
        timing={"compile_s": t3 - t2, "run_s": run},
        info=dict(scene=scene_.name, model=get_model(model).name,
                  input_model=scene_.input_model.name,
                  frequency_model=get_model(frequency_model).name, t_end=float(opts.t_end),
                  n_out=int(opts.n_out), rtol=float(opts.rtol), atol=float(opts.atol),
                  checkpoints=checkpoints),
        evaluate=evaluate,
    )
