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
from .._models import get_model
from .._modes import reduced_eigh
from .._names import SENSITIVITY_METRICS as SENSITIVITY_METRICS  # the table's rows, SI units
from .._params import RobotParams
from .._prb import derived
from .._robot import Robot
from .._scenes import (
    ATOL,
    MAX_STEPS,
    N_OUT,
    RTOL,
    T_END,
    SceneOptions,
    check_scene_args,
    get_scene,
    scene_params,
)
from .._statics import assemble, static_equilibrium
from ._sweep import FLOAT_PARAMS, _plain, traced_metrics

#: eigenvalues within this relative distance of the lowest are one (repeated) cluster
CLUSTER_RTOL = 1e-6
#: the metrics that measure how far the platform leaves the nominal circle
TRACKING_METRICS = ("radial_error_max_m", "radial_error_min_m")


def explicit_params(params: RobotParams) -> RobotParams:
    """`params` with gamma, rho and K_theta set to the values in use (the PRB table's where
    they are None), so that every float parameter is a leaf to differentiate."""
    dv = derived(params)
    return params.replace(gamma=float(dv.gamma), rho=float(dv.rho), K_theta=float(dv.K_theta))


def base_frequency(model, robot: Robot, X=None):
    """The lowest natural frequency (Hz, signed: negative = unstable) of `model` about its static
    equilibrium near X (default home) with the actuators locked, differentiable (module
    docstring: Rayleigh quotient with the mode shapes held fixed; repeated lowest eigenvalues
    averaged). Raises for a model without free coordinates when locked (L0, L1)."""
    X = home_pose(robot) if X is None else X
    # No host callback in the differentiated program: a failed equilibrium gives NaN.
    z_eq, free, failed = static_equilibrium(model, robot, model.coords_from_pose(robot, X),
                                            locked=True, wrench=jnp.zeros(3), check=False,
                                            return_failed=True)
    if not free:
        raise PPRError(f"model {model.name!r} has no vibration mode with locked actuators; "
                       f"use double1r (or beam) for the base frequency")
    n = model.n_dof
    known = tuple(i for i in range(n) if i not in free)
    f = jnp.array(free)
    zk = z_eq[jnp.array(known)] if known else None

    def Q(zf):
        z = assemble(n, free, zf, known, zk)
        return generalized_force(eom_terms(model, robot, z, jnp.zeros(n)), jnp.zeros(3),
                                 jnp.zeros(3))[f]

    K = -jax.jacfwd(Q)(z_eq[f])
    K = (K + K.T) / 2
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
    run_s, value_run_s} (s) of the derivative and of the plain metric evaluation; `info` the
    settings; `evaluate(x)` the compiled metrics (k,) at parameter values x (p,) in `parameters`
    order (for checks such as finite differences; NaN where the solve fails)."""

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


def metric_function(scene: str = "paper-circle", params: Optional[RobotParams] = None, *,
                    model="double1r", torque_model="reduced", frequency_model="double1r",
                    parameters: Optional[Sequence[str]] = None, t_end: float = T_END,
                    n_out: int = N_OUT, solver=None, rtol: float = RTOL, atol: float = ATOL,
                    max_steps: int = MAX_STEPS, metrics: Sequence[str] = SENSITIVITY_METRICS):
    """(f, x0, names): `f(x, adjoint)` -> (k,) the `metrics` at parameter values x (p,) (the
    `parameters`, default every float parameter, in `names` order), x0 the nominal values.
    Traceable and differentiable; `adjoint` is diffrax's (ForwardMode for forward mode)."""
    base = explicit_params(scene_params(scene) if params is None else params)
    if np.ndim(base.a) != 0:
        raise PPRError("sensitivities are computed for one robot, not a batch")
    names = list(FLOAT_PARAMS if parameters is None else parameters)
    for n in names:
        if n not in FLOAT_PARAMS:
            raise PPRError(f"unknown parameter {n!r}; allowed: {', '.join(FLOAT_PARAMS)}")
    for m in metrics:
        if m not in SENSITIVITY_METRICS:
            raise PPRError(f"unknown metric {m!r}; allowed: {', '.join(SENSITIVITY_METRICS)}")
    x0 = jnp.array([float(getattr(base, n)) for n in names])
    model_, tmodel = get_model(model), get_model(torque_model)
    scene_ = get_scene(scene, tmodel)
    follows = scene_.follows_its_input(model_)
    tracking = [m for m in metrics if m in TRACKING_METRICS]
    if follows and tracking:
        raise PPRError(
            f"{', '.join(tracking)} of model {model_.name!r} in {scene!r} measure the "
            f"integrator's error, not the robot: {follows}. Ask for the response of another "
            f"model (model='double1r' or 'beam', the paper's question; or "
            f"torque_model='rigid' for L1 under the rigid model's torques), or leave these "
            f"metrics out")
    fmodel = get_model(frequency_model)
    # The structural choice of the nominal robot, as its single run makes it: with l1 == l3 the
    # closed-form inverse kinematics, whose one Newton step carries the implicit-function
    # derivative in l1 or l3 alone (ppr_jax._robot).
    equal = float(base.l1) == float(base.l3)
    options = SceneOptions(t_end=t_end, n_out=n_out, solver=solver, rtol=rtol, atol=atol,
                           max_steps=max_steps).prepared(model_, scene_.trajectory())
    scene_metrics_needed = [m for m in metrics if m != "base_frequency_hz"]

    def f(x, adjoint=None):
        p = eqx.tree_at(lambda q: [getattr(q, n) for n in names], base, list(x))
        robot = Robot(p, equal_links=equal)
        out = {}
        if scene_metrics_needed:
            opts = options if adjoint is None else eqx.tree_at(
                lambda o: o.adjoint, options, adjoint)
            res = scene_.run(model_, robot, opts)
            out.update(traced_metrics(res, opts.trajectory))
            # A failed solve must not pass as a number: NaN through every metric.
            bad = res.result != RESULTS.successful
            out = {k: jnp.where(bad, jnp.nan, v) for k, v in out.items()}
        if "base_frequency_hz" in metrics:
            out["base_frequency_hz"] = base_frequency(fmodel, robot)
        return jnp.stack([out[m] for m in metrics])

    return f, x0, names


_JIT_CACHE: dict = {}


def sensitivity(scene: str = "paper-circle", params: Optional[RobotParams] = None, *,
                mode: str = "fwd", model="double1r", torque_model="reduced",
                frequency_model="double1r", parameters: Optional[Sequence[str]] = None,
                metrics: Sequence[str] = SENSITIVITY_METRICS, t_end: float = T_END,
                n_out: int = N_OUT, solver=None, rtol: float = RTOL, atol: float = ATOL,
                max_steps: int = MAX_STEPS, checkpoints: Optional[int] = None) -> Sensitivity:
    """d(metric)/d(parameter) of `metrics` (`SENSITIVITY_METRICS`) of `scene` to `parameters`
    (default every float parameter of `RobotParams`), at `params` (default the scene's).

    mode 'fwd': `jax.jacfwd` with `diffrax.ForwardMode()` (cost grows with the number of
    parameters); 'rev': `jax.jacrev` with `diffrax.RecursiveCheckpointAdjoint(checkpoints)`
    (cost grows with the number of metrics; `checkpoints` None = diffrax's default, about
    log(steps) memory). The base frequency is that of `frequency_model` (locked actuators,
    home pose; L1 has no mode). Scene settings as `paper_circle`; the default `model` is L2
    under L1's torques (the paper's question). The radial error of a model that follows its own
    input (`follows_its_input`: L0 or L1 under its own torques, L1 in servo-circle) is refused
    with a `PPRError`: it is the integrator's error. Returns `Sensitivity`."""
    if mode not in ("fwd", "rev"):
        raise PPRError(f"mode must be 'fwd' or 'rev', got {mode!r}")
    check_scene_args(t_end, n_out, rtol, atol, max_steps)
    f, x0, names = metric_function(
        scene, params, model=model, torque_model=torque_model, frequency_model=frequency_model,
        parameters=parameters, t_end=t_end, n_out=n_out, solver=solver, rtol=rtol, atol=atol,
        max_steps=max_steps, metrics=metrics)
    base = explicit_params(scene_params(scene) if params is None else params)
    key = (scene, get_model(model), get_model(torque_model), get_model(frequency_model),
           tuple(names), tuple(metrics), float(t_end), int(n_out), str(solver), float(rtol),
           float(atol), int(max_steps), mode, checkpoints,
           tuple((fl.name, _plain(getattr(base, fl.name))) for fl in dataclasses.fields(base)))
    try:
        cached = _JIT_CACHE.get(key)
    except TypeError:  # an unhashable model or solver: no reuse
        key, cached = None, None
    if cached is None:
        if mode == "fwd":
            jac = jax.jit(jax.jacfwd(lambda x: f(x, diffrax.ForwardMode())))
        else:
            adj = diffrax.RecursiveCheckpointAdjoint(checkpoints=checkpoints)
            jac = jax.jit(jax.jacrev(lambda x: f(x, adj)))
        cached = (jax.jit(f), jac)
        if key is not None:
            _JIT_CACHE[key] = cached
    value, jac = cached
    t0 = time.perf_counter()
    v = np.asarray(value(x0))
    t1 = time.perf_counter()
    v = np.asarray(value(x0))
    value_run = time.perf_counter() - t1
    value_compile = max(t1 - t0 - value_run, 0.0)
    t2 = time.perf_counter()
    J = np.asarray(jac(x0))
    t3 = time.perf_counter()
    J = np.asarray(jac(x0))
    run = time.perf_counter() - t3
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
        timing={"compile_s": max(t3 - t2 - run, 0.0), "run_s": run, "value_run_s": value_run,
                "value_compile_s": value_compile},
        info=dict(scene=scene, model=get_model(model).name,
                  torque_model=get_model(torque_model).name,
                  frequency_model=get_model(frequency_model).name, t_end=t_end, n_out=n_out,
                  rtol=rtol, atol=atol, checkpoints=checkpoints),
        evaluate=lambda x: np.asarray(value(jnp.asarray(x, dtype=jnp.float64))),
    )
