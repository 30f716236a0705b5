"""What a scene returns, and how its failures are told."""

from __future__ import annotations

from typing import Optional

import equinox as eqx
import numpy as np

from .._custom_types import Array
from .._errors import (
    RESIDUAL_TOL,
    RESULTS,
    check_result,
    failure_reasons,
    is_traced,
    result_code,
)
from .._kinematics import path_singular
from .._models import Reduced, Rigid
from .._names import SOLVER_NAMES, STIFF_SOLVER_NAMES
from .._params import PARAM_RANGES, member_params
from .._robot import Robot


class SceneResult(eqx.Module):
    """The result of a scene: the same pytree for one robot or a batch (then every array has a
    leading batch axis), as `diffrax.diffeqsolve` always returns a `Solution`.

    ts (m,) output times (s); z, zdot (m, n) the model's coordinates and their rates; X (m, 3)
    platform pose (m, m, rad); X_nominal (m, 3) the scene's nominal pose (eq 55 for the circle
    scenes); tau (m, 3) actuator torques (applied, or the reactions when motion-driven) (N m);
    end_rot (m, 2) rotations of chain 1's compliant-joint ends (rad); residual (m,) max
    loop-closure residual (m); kinetic, potential (m,) energy (J); result a `ppr_jax.RESULTS`
    code: diffrax's, or invalid parameters, no initial state, a loop-closure residual above
    1e-9 m at an output time (a failure is raised by the scene functions when called outside a
    transformation with `throw=True`; `failures()` lists them per member); num_steps,
    num_accepted, num_rejected solver statistics (0 for a scene that needs no ODE). `scene` and
    `model` (static) name what ran. Metrics, timings and printing: `ppr_jax.run_scene`."""

    ts: Array
    z: Array
    zdot: Array
    X: Array
    X_nominal: Array
    tau: Array
    end_rot: Array
    residual: Array
    kinetic: Array
    potential: Array
    result: RESULTS
    num_steps: Array
    num_accepted: Array
    num_rejected: Array
    scene: str = eqx.field(static=True)
    model: str = eqx.field(static=True)

    @property
    def ok(self) -> np.ndarray:
        """True where the member succeeded (host-side; bool, or (batch,) bool)."""
        return np.asarray(self.result == RESULTS.successful)

    def failures(self, params=None) -> dict:
        """{member index (None for one robot): reason} for every failed member (host-side).
        With the `RobotParams` that ran, an invalid-parameter failure names the parameters."""
        return failure_reasons(self.result, failure_detail(self, params))


def result_template(scene: str, model: str) -> SceneResult:
    """A `SceneResult` with the tree structure of a scene's result (zeros as leaves): how a
    stored program's flat outputs are put back together (`_programs.py`)."""
    z = np.zeros(())
    return SceneResult(
        ts=z, z=z, zdot=z, X=z, X_nominal=z, tau=z, end_rot=z, residual=z, kinetic=z,
        potential=z, result=RESULTS.successful, num_steps=z, num_accepted=z, num_rejected=z,
        scene=scene, model=model,
    )


def _bad_params(params, i) -> str:
    out = []
    for name, (lo, hi, unit, _) in PARAM_RANGES.items():
        v = getattr(params, name, None)
        if v is None:
            continue
        v = np.asarray(v)
        v = v if i is None else v[i]
        if not (np.isfinite(v) and lo <= v <= hi):
            out.append(f"{name} = {float(v):.6g} {unit} not in [{lo:g}, {hi:g}]".replace(" ]", "]"))
    return "; ".join(out)


_path_singular_jit = eqx.filter_jit(path_singular)


def _singular_time(params, i, ts, X_nominal) -> str:
    """Where the nominal path `X_nominal` (at times `ts`) of member i meets a type-II
    singularity of L1 or L0 (the models whose inverse kinematics or dynamics give the scenes'
    inputs), or "" if not between two output times."""
    if params is None:
        return ""
    robot = Robot(params if i is None else member_params(params, i))
    for name, model in (("L1", Reduced()), ("L0", Rigid())):
        flags = np.asarray(_path_singular_jit(model, robot, np.asarray(X_nominal)))
        bad = np.flatnonzero(flags & np.isfinite(ts))
        if bad.size:
            k = bad[0]
            when = f"at t = {ts[k]:.4g} s" if k == 0 else (
                f"between t = {ts[k - 1]:.4g} and {ts[k]:.4g} s")
            return (f"the nominal path meets {name}'s ({model.name}) type-II singularity {when}, "
                    f"near x, y, phi = " + ", ".join(f"{v:.4g}" for v in X_nominal[k]))
    return ""


def failure_detail(res: SceneResult, params=None):
    """detail(i): host-side particulars of failed member i (None for one robot), told only where
    they describe the failure: the parameters out of range (given `params`), how far and when the
    loop opened, where the solver stopped, or when the nominal path meets a type-II singularity
    (given `params`)."""
    # read on the host only when a member failed: a successful call asks nothing
    # (`failure_reasons` calls `detail` for failed members alone)
    host = {}

    def read():
        if host:
            return host
        # the codes as host integers, compared in numpy (no XLA program per comparison)
        codes = np.asarray(result_code(res.result))

        def is_(*names):
            return np.isin(codes, [int(result_code(getattr(RESULTS, n))) for n in names
                                   if hasattr(RESULTS, n)])

        host.update(
            invalid=is_("invalid_parameter"),
            singular=is_("singular_path"),
            # how far and when the loop is open: for a chain that opened, and for a path out
            # of reach
            open_loop=is_("loop_not_closed", "trajectory_out_of_reach"),
            # the solver's own failures: diffrax fills the output times after one with inf
            stopped=is_("max_steps_reached", "max_steps_rejected", "singular", "breakdown",
                        "nonlinear_divergence", "nonlinear_max_steps_reached",
                        "dt_min_reached", "nonfinite"),
            resid=np.asarray(res.residual), ts=np.asarray(res.ts),
            X_nominal=np.asarray(res.X_nominal))
        return host

    def detail(i):
        h = read()
        pick = (lambda a: a) if i is None else (lambda a: a[i])
        r, t = pick(h["resid"]), pick(h["ts"])
        if pick(h["invalid"]):
            return _bad_params(params, i) if params is not None else ""
        if pick(h["singular"]):
            return _singular_time(params, i, t, pick(h["X_nominal"]))
        if pick(h["open_loop"]):
            bad = np.flatnonzero(~(r <= RESIDUAL_TOL) & np.isfinite(t))
            if bad.size == 0:
                return ""
            k = bad[0]
            return (f"loop-closure residual {r[k]:.3g} m at t = {t[k]:.4g} s, largest "
                    f"{np.nanmax(r):.3g} m")
        if pick(h["stopped"]):
            done = np.flatnonzero(np.isfinite(t))
            if done.size and done.size < t.size:
                return f"the last output time reached is t = {t[done[-1]]:.4g} s"
            if done.size == 0:
                return "no output time was reached"
        return ""

    return detail


def finish(res: SceneResult, throw: bool = True, params=None,
           solver_name: Optional[str] = None) -> SceneResult:
    """`res`, raising `SimulationError` for failed members when `throw` and concrete.
    `solver_name` (the prepared scene's) keeps a step failure from advising the implicit solver
    that already ran."""
    if throw and not is_traced(res.result):
        name = (solver_name or "").split(" ")[0]
        stiff = (True if name in STIFF_SOLVER_NAMES else False if name in SOLVER_NAMES
                 else None)
        check_result(res.result, f"{res.scene} ({res.model})", failure_detail(res, params), res,
                     stiff=stiff)
    return res
