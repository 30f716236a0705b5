"""Scenes of MODEL.md section 6: `paper-circle`, `servo-circle` and `modes`.

Each scene computes only what it needs: a torque-driven scene integrates an ODE; a motion-driven
L0/L1 scene is forward kinematics plus inverse dynamics (no ODE); `modes` is a static solve and an
eigenproblem. Scene cores are jit-compiled once per (model, shapes) and vmap over parameter batches
(`RobotParams` with a leading axis); failures name the batch members that failed.
"""

from __future__ import annotations

import time
from typing import Callable, Optional

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._actuation import InverseDynamicsTorque, InverseKinematicsAngles, MotionDriven, TorqueDriven
from ._checks import (
    PPRError,
    RESIDUAL_TOL, RESULTS, check_number, check_result, failure_reasons, first_failure, is_traced,
)
from ._custom_types import Array
from ._dynamics import inverse_dynamics
from ._kinematics import det3, fold_flags
from ._metrics import outputs
from ._models import Reduced, get_model
from ._modes import modes as _modes
from ._params import RobotParams, params_invalid
from ._robot import Robot
from ._simulate import Solution, _simulate_core, default_controller, get_solver
from ._statics import _quasi_static_state, kinematic_state
from ._tabulated import input_too_coarse, scene_input, scene_panels
from ._trajectory import Circle, derivatives

SCENES = ("paper-circle", "servo-circle", "modes")
#: strip thickness of each scene (m): the paper's simulation uses 0.3 mm, its experiment 0.5 mm
SCENE_THICKNESS = {"paper-circle": 0.3e-3, "servo-circle": 0.5e-3, "modes": 0.3e-3}
#: default solver per model level (docs/which_model.md)
DEFAULT_SOLVER = {"rigid": "tsit5", "reduced": "tsit5", "double1r": "tsit5", "beam": "dopri8"}


def scene_params(scene: str, **overrides) -> RobotParams:
    """Default parameters of a scene (the strip thickness differs) with overrides applied."""
    if scene not in SCENES:
        raise PPRError(f"unknown scene {scene!r}; allowed: {', '.join(SCENES)}")
    kw = {"t": SCENE_THICKNESS[scene]}
    kw.update(overrides)
    return RobotParams().replace(**kw)


class SceneResult(eqx.Module):
    """The result of a scene: the same pytree for one robot or a batch (then every array has a
    leading batch axis), as `diffrax.diffeqsolve` always returns a `Solution`.

    ts (m,) output times (s); z, zdot (m, n) the model's coordinates and their rates; X (m, 3)
    platform pose (m, m, rad); X_nominal (m, 3) the nominal pose of eq 55; tau (m, 3) actuator
    torques (applied, or the reactions when motion-driven) (N m); end_rot (m, 2) rotations of
    chain 1's compliant-joint ends (rad); residual (m,) max loop-closure residual (m);
    kinetic, potential (m,) energy (J); result a `ppr_jax.RESULTS` code: diffrax's, or invalid
    parameters, no initial state, a loop-closure residual above 1e-9 m at an output time (a
    failure is raised by the scene functions when called outside a transformation with
    `throw=True`; `failures()` lists them per member); num_steps,
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

    def failures(self) -> dict:
        """{member index (None for one robot): reason} for every failed member (host-side)."""
        return failure_reasons(self.result, _failure_detail(self))


# ---------------------------------------------------------------------------------------------
# Cores: traceable, one robot; jitted once per (model, shapes) and vmapped for batches
# ---------------------------------------------------------------------------------------------


def _open_at(model, robot, z):
    """A chain is open at coordinates z (loop-closure residual above `RESIDUAL_TOL`)."""
    k = model.kinematics(robot, z)
    return ~(jnp.max(jnp.linalg.norm(model.loop_residual(robot, k), axis=-1)) <= RESIDUAL_TOL)


def _reference_open(ref_model, robot, traj, ts):
    """The nominal trajectory is out of reach at some output time for the model whose inverse
    kinematics drives the scene (`ref_model`, L0 or L1)."""

    def resid(t):
        k = ref_model.kinematics(robot, ref_model.coords_from_pose(robot, traj(t)))
        return jnp.max(jnp.linalg.norm(ref_model.loop_residual(robot, k), axis=-1))

    return ~(jnp.max(jax.vmap(resid)(ts)) <= RESIDUAL_TOL)


def _result(scene, model, robot, traj, sol: Solution, qs_failed=None, open0=None,
            ref_open=None, coarse=None) -> SceneResult:
    out = outputs(model, robot, sol.z, sol.zdot)
    # Every precondition as a status code (most fundamental cause first): invalid parameters
    # (in sol.result), no initial state, the solver's failure, a chain that does not close at
    # some output time (an L0/L1 pose out of reach integrates happily on an open chain).
    result = first_failure(
        (params_invalid(robot.params), RESULTS.invalid_parameter),
        (ref_open, RESULTS.trajectory_out_of_reach),
        (coarse, RESULTS.input_table_too_coarse),
        (qs_failed, RESULTS.initial_state_failed),
        (open0, RESULTS.loop_not_closed),
        sol.result,
        (~(jnp.max(out.residual) <= RESIDUAL_TOL), RESULTS.loop_not_closed),
    )
    return SceneResult(
        ts=sol.ts, z=sol.z, zdot=sol.zdot, X=out.X, X_nominal=jax.vmap(traj)(sol.ts),
        tau=sol.tau, end_rot=out.end_rot, residual=out.residual, kinetic=out.kinetic,
        potential=out.potential, result=result, num_steps=sol.num_steps,
        num_accepted=sol.num_accepted, num_rejected=sol.num_rejected, scene=scene,
        model=model.name,
    )


def _tabulated_input(fn, ts, panels):
    """(table, coarse, ref_open): the scene input `fn` (an `InverseDynamicsTorque` or
    `InverseKinematicsAngles`) tabulated, whether the table is too coarse, and whether the
    nominal path leaves the chains' reach at a node, from the table's own evaluations."""
    table, resid = scene_input(fn.with_residual, ts, panels, aux=True)
    return table, input_too_coarse(table), ~(jnp.max(resid) <= RESIDUAL_TOL)


def _paper_circle_core(model, torque_model, robot, traj, ts, solver, controller, max_steps,
                       adjoint, panels):
    torque, coarse, ref_open = _tabulated_input(
        InverseDynamicsTorque(torque_model, robot, traj), ts, panels)
    act = TorqueDriven(torque)
    z0, zd0, failed = _quasi_static_state(model, robot, traj, ts[0], act)
    open0 = _open_at(model, robot, z0)
    sol = _simulate_core(
        model, robot, act, z0, zd0, ts, solver, controller, None, max_steps,
        jnp.zeros(3), False, diffrax.NoProgressMeter(), adjoint,
        _any(failed, open0, ref_open, coarse, params_invalid(robot.params)),
    )
    return _result("paper-circle", model, robot, traj, sol, failed, open0, ref_open, coarse)


def _any(*flags):
    """Or of the flags that were checked (None: not checked)."""
    out = False
    for f in flags:
        if f is not None:
            out = out | f
    return out


def _kinematic_motion(model, robot, angles, X0, ts):
    """L0/L1 motion-driven: X(t) by warm-started forward kinematics, X' and X'' from
    th_a(X) = th_a(t) differentiated once and twice, torques by inverse dynamics. No ODE."""

    def step(X, t):
        X, Xd, Xdd, code, S = kinematic_state(model, robot, derivatives(angles, t), X)
        tau, _ = inverse_dynamics(model, robot, X, Xd, Xdd)
        return X, (X, Xd, tau, code, det3(S))

    _, (X, Xd, tau, codes, det) = jax.lax.scan(step, X0, ts)
    # A motion through a type-II singularity: the warm start folds back in its assembly mode
    # and every solve converges; det S along the solved poses shows it (`fold_flags`).
    return X, Xd, tau, codes, fold_flags(det, ts)


def _servo_circle_core(model, robot, traj, ts, solver, controller, max_steps, adjoint, panels):
    angles = InverseKinematicsAngles(Reduced(), robot, traj)
    if model.actuated_index is None:
        ref_open = _reference_open(Reduced(), robot, traj, ts)
        X, Xd, tau, codes, folds = _kinematic_motion(model, robot, angles, traj(ts[0]), ts)
        # A status code, not a callback: forward kinematics failing along the path is reported
        # like a solver failure (and the compiled program stays free of host callbacks).
        result = first_failure((jnp.any(folds), RESULTS.singular_path),
                               (jnp.any(codes != 0), RESULTS.kinematics_failed))
        zero = jnp.asarray(0)
        sol = Solution(
            ts=ts, z=X, zdot=Xd, tau=tau, result=result, num_steps=zero, num_accepted=zero,
            num_rejected=zero,
        )
    else:
        # th, th' and th'' at every stage: derivatives of the table's polynomials (`_tabulated`).
        angles_in, coarse, ref_open = _tabulated_input(angles, ts, panels)
        act = MotionDriven(angles_in)
        z0, zd0, failed = _quasi_static_state(model, robot, traj, ts[0], act)
        open0 = _open_at(model, robot, z0)
        sol = _simulate_core(
            model, robot, act, z0, zd0, ts, solver, controller, None, max_steps, jnp.zeros(3),
            False, diffrax.NoProgressMeter(), adjoint,
            _any(failed, open0, ref_open, coarse, params_invalid(robot.params)),
        )
        return _result("servo-circle", model, robot, traj, sol, failed, open0, ref_open, coarse)
    return _result("servo-circle", model, robot, traj, sol, ref_open=ref_open)


#: scene name -> (core, index of the robot among the core's arguments)
_CORES = {"paper-circle": (_paper_circle_core, 2), "servo-circle": (_servo_circle_core, 1)}
_JIT = {name: eqx.filter_jit(core) for name, (core, _) in _CORES.items()}


def _member_map(scene: str, args: tuple):
    """The core of `scene` over the batched robot `args[k]` (every other argument shared), as
    `_chunked_vmap`: traceable, for one device or inside each device's shard."""
    core, k = _CORES[scene]
    robot_dyn, robot_static = eqx.partition(args[k], eqx.is_array)

    def member(r):
        return core(*args[:k], eqx.combine(r, robot_static), *args[k + 1:])

    return _chunked_vmap(member, robot_dyn)


# Batched cores: mapped over the robot only, compiled once per (model, batch size).
_BATCH = {
    name: eqx.filter_jit(lambda *args, _name=name: _member_map(_name, args)) for name in _CORES
}


def _batched(params: RobotParams) -> bool:
    return jnp.ndim(params.a) == 1


_SHARDED: dict = {}

#: members vectorised together on one device at most: a larger local batch runs as a loop over
#: chunks of this size (`_chunked_vmap`)
MEMBER_CHUNK = 64


def _chunked_vmap(f, xs):
    """`jax.vmap(f)(xs)` in sequential chunks of at most `MEMBER_CHUNK` members
    (`jax.lax.map` with `batch_size`): the same values, but a chunk's members wait only for the
    slowest of their chunk and its temporaries stay in cache."""
    n = jax.tree_util.tree_leaves(xs)[0].shape[0]
    if n <= MEMBER_CHUNK:
        return jax.vmap(f)(xs)
    return jax.lax.map(f, xs, batch_size=MEMBER_CHUNK)


def _sharded_batch(scene: str, devices: tuple):
    """The batched core of `scene` split over `devices` along the batch (compiled once per
    scene and device set): `shard_map` over a 1-D mesh, a local (chunked) vmap on each device, so that
    adaptive steps never synchronise across devices (`_devices.py`). Only the robot is split;
    every other argument is replicated."""
    key = (scene, devices)
    if key in _SHARDED:
        return _SHARDED[key]
    from jax.sharding import Mesh, PartitionSpec as P

    k = _CORES[scene][1]
    mesh = Mesh(np.asarray(devices), ("batch",))

    @eqx.filter_jit
    def fn(*args):
        robot_dyn, robot_static = eqx.partition(args[k], eqx.is_array)
        rest_dyn, rest_static = eqx.partition(args[:k] + (None,) + args[k + 1:], eqx.is_array)

        def local(robot_dyn, rest_dyn):
            rest = eqx.combine(rest_dyn, rest_static)
            robot = eqx.combine(robot_dyn, robot_static)
            return _member_map(scene, rest[:k] + (robot,) + rest[k + 1:])

        # check_vma=False: diffrax's loops carry values that are replicated at entry and vary
        # per device after one step, which the varying-axes check rejects; each device's body
        # is a plain local vmap, with no collective to get wrong.
        return jax.shard_map(local, mesh=mesh, in_specs=(P("batch"), P()),
                             out_specs=P("batch"), check_vma=False)(robot_dyn, rest_dyn)

    _SHARDED[key] = fn
    return fn


def batch_devices(batch: int) -> tuple:
    """The local devices a batch of `batch` robots is split over: all of them when there are
    several and they divide the batch, else none (one device)."""
    devices = jax.local_devices()
    if len(devices) > 1 and batch % len(devices) == 0:
        return tuple(devices)
    return ()


def check_scene_args(t_end, n_out, rtol, atol, max_steps) -> None:
    """Validate a scene's arguments before anything is compiled (`PPRError` naming the argument
    and its allowed range). The tolerance bounds: below 1e-14 the error control chases round-off;
    above 1e-2 the result is not worth a number."""
    if not is_traced(t_end):
        check_number("t_end", t_end, 0.0, 1e5, "s", open_lo=True)
    check_number("n_out", n_out, 2, 10_000_000, integer=True)
    check_number("max_steps", max_steps, 1, 10**9, integer=True)
    if not is_traced(rtol):
        check_number("rtol", rtol, 1e-14, 1e-2)
    if not is_traced(atol):
        check_number("atol", atol, 1e-16, 1e-2)


class SceneCall(eqx.Module):
    """A scene ready to run: `fn(*args)` is the compiled (and, for a batch, vmapped) core."""

    fn: Callable
    args: tuple
    scene: str = eqx.field(static=True)
    batched: bool = eqx.field(static=True)
    solver_name: str = eqx.field(static=True)
    #: devices a batch is split over (0: not split)
    devices: int = eqx.field(static=True, default=0)


def _prepare(scene, params, model, torque_model, trajectory, t_end, n_out, solver, rtol, atol,
             max_steps, adjoint=None) -> SceneCall:
    check_scene_args(t_end, n_out, rtol, atol, max_steps)
    model = get_model(model)
    params = scene_params(scene) if params is None else params
    traj = Circle() if trajectory is None else trajectory
    ts = jnp.linspace(0.0, t_end, n_out)
    solver = DEFAULT_SOLVER[model.name] if solver is None else solver
    solver_name = str(solver) if isinstance(solver, str) else type(solver).__name__
    if scene == "servo-circle" and model.actuated_index is None:
        solver_name = "none (kinematics + inverse dynamics)"
    solver = get_solver(solver)
    controller = default_controller(solver, rtol, atol)
    # Built here, outside any trace when params are concrete: the derived quantities once and
    # the structural choices (equal links, elbow) static, so a batch is branch-free.
    robot = Robot(params)
    pre = (model, get_model(torque_model)) if scene == "paper-circle" else (model,)
    adjoint = diffrax.RecursiveCheckpointAdjoint() if adjoint is None else adjoint
    panels = input_panels(traj, t_end, n_out)
    post = (traj, ts, solver, controller, max_steps, adjoint, panels)
    batched = _batched(params)
    fn = (_BATCH if batched else _JIT)[scene]
    devices = batch_devices(int(jnp.shape(params.a)[0])) if batched else ()
    if devices:
        fn = _sharded_batch(scene, devices)
    return SceneCall(fn=fn, args=(*pre, robot, *post), scene=scene, batched=batched,
                     solver_name=solver_name, devices=len(devices))


def result_template(call: SceneCall) -> SceneResult:
    """A `SceneResult` with the tree structure of `call`'s result (zeros as leaves): how a
    stored program's flat outputs are put back together (`_programs.py`)."""
    z = np.zeros(())
    return SceneResult(
        ts=z, z=z, zdot=z, X=z, X_nominal=z, tau=z, end_rot=z, residual=z, kinetic=z,
        potential=z, result=RESULTS.successful, num_steps=z, num_accepted=z, num_rejected=z,
        scene=call.scene, model=call.args[0].name,
    )


def input_panels(traj, t_end, n_out: int) -> int:
    """Panels of the scene's input table (`_tabulated.scene_panels`). The count is a shape, so it
    is decided before tracing: more panels for a longer horizon where t_end and the trajectory's
    speed (`omega`) are concrete, the minimum otherwise (the scene then reports a table too
    coarse for its horizon as `RESULTS.input_table_too_coarse`)."""
    omega = getattr(traj, "omega", None)
    known = not (is_traced(t_end) or omega is None or is_traced(omega) or np.ndim(omega) != 0)
    return scene_panels(n_out, float(t_end) * float(omega) if known else None)


def input_panels_at(traj, ts) -> int:
    """`input_panels` for output times `ts` (traced or not)."""
    t_end = ts[-1] if is_traced(ts) else float(np.asarray(ts)[-1])
    return input_panels(traj, t_end, ts.shape[0])


def _failure_detail(res: SceneResult):
    """Host-side particulars of a failed member: when its loop opened, how far."""
    resid = np.asarray(res.residual)
    ts = np.asarray(res.ts)

    def detail(i):
        r = resid if i is None else resid[i]
        t = ts if i is None else ts[i]
        bad = np.flatnonzero(~(r <= RESIDUAL_TOL))
        if bad.size == 0:
            return ""
        k = bad[0]
        return (f"loop-closure residual {r[k]:.3g} m at t = {t[k]:.4g} s, largest "
                f"{np.nanmax(r):.3g} m")

    return detail


def _finish(res: SceneResult, throw: bool = True) -> SceneResult:
    if throw and not is_traced(res.result):
        check_result(res.result, f"{res.scene} ({res.model})", _failure_detail(res), res)
    return res


def paper_circle(
    params: Optional[RobotParams] = None,
    *,
    model="reduced",
    torque_model="reduced",
    trajectory: Optional[Circle] = None,
    t_end: float = 7.54,
    n_out: int = 755,
    solver=None,
    rtol: float = 1e-8,
    atol: float = 1e-10,
    max_steps: int = 200_000,
    throw: bool = True,
    adjoint: Optional[diffrax.AbstractAdjoint] = None,
) -> SceneResult:
    """Scene `paper-circle` (paper Fig 8-12): torques from `torque_model`'s inverse dynamics along
    eq 55 (default L1; `rigid` gives the paper's "simplified model" torques), `model` simulated
    torque-driven from the nominal pose and velocity at t = 0 (L2's internal coordinates at the
    quasi-static state). Default params: Table 1 with t = 0.3 mm.

    Returns a `SceneResult`, with a leading axis for batched `params` (`stack_params`): one
    compiled vmapped call. A failed member raises `SimulationError` naming it; with
    `throw=False`, or under a JAX transformation, check `result` instead (as diffrax's `throw`).
    `adjoint`: diffrax's default (reverse mode, `jax.grad`) or `diffrax.ForwardMode()` for
    `jax.jvp` / `jax.jacfwd` through the scene. Metrics and timings: `run_scene`."""
    c = _prepare("paper-circle", params, model, torque_model, trajectory, t_end, n_out, solver,
                 rtol, atol, max_steps, adjoint)
    return _finish(c.fn(*c.args), throw)


def servo_circle(
    params: Optional[RobotParams] = None,
    *,
    model="double1r",
    trajectory: Optional[Circle] = None,
    t_end: float = 7.54,
    n_out: int = 755,
    solver=None,
    rtol: float = 1e-8,
    atol: float = 1e-10,
    max_steps: int = 200_000,
    throw: bool = True,
    adjoint: Optional[diffrax.AbstractAdjoint] = None,
) -> SceneResult:
    """Scene `servo-circle` (paper Fig 17-18): the actuated angles follow L1's inverse kinematics
    of eq 55 exactly (motion-driven); the platform's response of `model`. L0/L1 need no ODE
    (forward kinematics + inverse dynamics). Default params: Table 1 with t = 0.5 mm.
    Returns a `SceneResult` (batched like `paper_circle`); `throw` and `adjoint` as there."""
    c = _prepare("servo-circle", params, model, "reduced", trajectory, t_end, n_out, solver,
                 rtol, atol, max_steps, adjoint)
    return _finish(c.fn(*c.args), throw)


def modes_scene(
    params: Optional[RobotParams] = None,
    *,
    model="double1r",
    actuators: str = "locked",
    X=None,
) -> dict:
    """Scene `modes`: natural frequencies (Hz, signed: negative = unstable) about the static
    equilibrium near pose X (default home), actuators locked or free."""
    model = get_model(model)
    params = scene_params("modes") if params is None else params
    t0 = time.perf_counter()
    r = _modes(model, params, X, actuators=actuators)
    jax.block_until_ready(r)
    wall = time.perf_counter() - t0
    free = len(r.free)
    return {
        "scene": "modes",
        "model": model.name,
        "actuators": actuators,
        "n_free_coordinates": free,
        "frequencies_hz": [float(f) for f in np.asarray(r.freq_hz)],
        "unstable_growth_rates_per_s": [float(g) for g in np.asarray(r.growth_rate) if g > 0],
        "eigenvalues_rad2_per_s2": [float(v) for v in np.asarray(r.eigvals)],
        "equilibrium_z": [float(v) for v in np.asarray(r.z_eq)],
        "note": (
            "no free coordinate: with locked actuators the pose of this model follows from the "
            "actuated angles (a kinematic model has no vibration modes)"
            if free == 0 else
            "negative frequency = unstable mode (negative stiffness), magnitude sqrt(|lambda|)/2pi"
        ),
        "wall_time_s": wall,
    }
