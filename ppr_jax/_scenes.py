"""Scenes of MODEL.md section 6: `paper-circle`, `servo-circle` and `modes`.

Each scene computes only what it needs: a torque-driven scene integrates an ODE; a motion-driven
L0/L1 scene is forward kinematics plus inverse dynamics (no ODE); `modes` is a static solve and an
eigenproblem. Scene cores are jit-compiled once per (model, shapes) and vmap over parameter batches
(`RobotParams` with a leading axis); failures name the batch members that failed.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Optional

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._beam import Beam
from ._actuation import InverseDynamicsTorque, InverseKinematicsAngles, MotionDriven, TorqueDriven
from ._checks import raise_if
from ._double1r import Double1R
from ._dynamics import inverse_dynamics
from ._ik import _fk
from ._linalg import solve
from ._metrics import metrics, outputs
from ._model import AbstractModel
from ._modes import modes as _modes
from ._params import RobotParams
from ._prb import derived
from ._reduced import Reduced
from ._rigid import Rigid
from ._simulate import Solution, _simulate_core, check_result, get_solver
from ._statics import quasi_static_state
from ._trajectory import Circle, derivatives

MODELS = {"rigid": Rigid, "reduced": Reduced, "double1r": Double1R, "beam": Beam}
SCENES = ("paper-circle", "servo-circle", "modes")
#: strip thickness of each scene (m): the paper's simulation uses 0.3 mm, its experiment 0.5 mm
SCENE_THICKNESS = {"paper-circle": 0.3e-3, "servo-circle": 0.5e-3, "modes": 0.3e-3}
#: default solver per model level (see README, "Solvers")
DEFAULT_SOLVER = {"rigid": "tsit5", "reduced": "tsit5", "double1r": "tsit5", "beam": "tsit5"}


def get_model(model, n_elements: Optional[int] = None) -> AbstractModel:
    """A model from its name (rigid, reduced, double1r, beam) or an instance; `n_elements` is
    the number of beam elements per strip of `beam` (default 8)."""
    if isinstance(model, AbstractModel):
        return model
    if str(model) == "beam":
        n = 8 if n_elements is None else int(n_elements)
        if n < 1:
            raise ValueError(f"--elements (beam elements per strip) must be >= 1, got {n}")
        return Beam(n)
    try:
        return MODELS[str(model)]()
    except KeyError:
        raise ValueError(f"unknown model {model!r}; allowed: {', '.join(MODELS)}") from None


def scene_params(scene: str, **overrides) -> RobotParams:
    """Default parameters of a scene (the strip thickness differs) with overrides applied."""
    if scene not in SCENES:
        raise ValueError(f"unknown scene {scene!r}; allowed: {', '.join(SCENES)}")
    kw = {"t": SCENE_THICKNESS[scene]}
    kw.update(overrides)
    return RobotParams().replace(**kw)


@dataclasses.dataclass
class SceneResult:
    """A scene run: arrays are numpy; `metrics` holds the MODEL.md section 6 numbers (SI units
    unless the key says otherwise) and `timing` the compile and run wall times (s)."""

    scene: str
    model: str
    ts: np.ndarray
    X: np.ndarray
    X_nominal: np.ndarray
    tau: np.ndarray
    end_rot: np.ndarray
    metrics: dict
    timing: dict
    solver: dict
    params: RobotParams


# ---------------------------------------------------------------------------------------------
# Cores (jit-able, vmappable over params)
# ---------------------------------------------------------------------------------------------


def _paper_circle_core(model, torque_model, params, traj, ts, solver, controller, max_steps, throw):
    torque = InverseDynamicsTorque(torque_model, params, traj)
    z0, zd0 = quasi_static_state(model, params, traj, ts[0], motion_driven=False, torque=torque)
    sol = _simulate_core(
        model, params, TorqueDriven(torque), z0, zd0, ts, solver, controller, None, max_steps,
        jnp.zeros(3), throw, diffrax.NoProgressMeter(),
    )
    return sol, outputs(model, params, sol.z, sol.zdot)


def _kinematic_motion(model, params, angles, X0, ts):
    """L0/L1 motion-driven: X(t) by warm-started forward kinematics, X' and X'' from
    th_a(X) = th_a(t) differentiated once and twice, torques by inverse dynamics. No ODE."""
    dv = derived(params)

    def tha_of_X(X):
        return model.kinematics(params, dv, model.coords_from_pose(params, dv, X)).th_a

    def step(X, t):
        th, thd, thdd = derivatives(angles, t)
        X, res = _fk(model, params, th, X, 1e-13, 1e-13, 50)
        S = jax.jacfwd(tha_of_X)(X)
        Xd = solve(S, thd)
        conv = jax.jvp(lambda X: jax.jvp(tha_of_X, (X,), (Xd,))[1], (X,), (Xd,))[1]
        Xdd = solve(S, thdd - conv)
        tau, _ = inverse_dynamics(model, params, dv, X, Xd, Xdd)
        return X, (X, Xd, tau, res._value)

    _, (X, Xd, tau, codes) = jax.lax.scan(step, X0, ts)
    return X, Xd, tau, codes


def _servo_circle_core(model, params, traj, ts, solver, controller, max_steps, throw):
    angles = InverseKinematicsAngles(Reduced(), params, traj)
    if model.actuated_index is None:
        X, Xd, tau, codes = _kinematic_motion(model, params, angles, traj(ts[0]), ts)
        X = raise_if(X, jnp.any(codes != 0), "forward kinematics failed along the servo path")
        result = diffrax.RESULTS.where(
            jnp.any(codes != 0), diffrax.RESULTS.max_steps_reached, diffrax.RESULTS.successful
        )
        sol = Solution(
            ts=ts, z=X, zdot=Xd, tau=tau, result=result, num_steps=jnp.asarray(0),
            num_accepted=jnp.asarray(0), num_rejected=jnp.asarray(0),
        )
    else:
        act = MotionDriven(angles)
        z0, zd0 = quasi_static_state(model, params, traj, ts[0], motion_driven=True)
        sol = _simulate_core(
            model, params, act, z0, zd0, ts, solver, controller, None, max_steps, jnp.zeros(3),
            throw, diffrax.NoProgressMeter(),
        )
    return sol, outputs(model, params, sol.z, sol.zdot)


_paper_circle_jit = eqx.filter_jit(_paper_circle_core)
_servo_circle_jit = eqx.filter_jit(_servo_circle_core)
# Batched cores: vmapped over the parameters (argument 2 / 1), compiled once per shape.
_paper_circle_batch = eqx.filter_jit(
    eqx.filter_vmap(_paper_circle_core, in_axes=(None, None, 0) + (None,) * 6)
)
_servo_circle_batch = eqx.filter_jit(
    eqx.filter_vmap(_servo_circle_core, in_axes=(None, 0) + (None,) * 6)
)


def _batched(params: RobotParams) -> bool:
    return jnp.ndim(params.a) == 1


def _run_timed(fn, *args):
    """(result, compile_s, run_s): ahead-of-time compile, then one timed run."""
    t0 = time.perf_counter()
    compiled = fn.lower(*args).compile()
    t1 = time.perf_counter()
    out = compiled(*args)
    jax.block_until_ready(out)
    t2 = time.perf_counter()
    return out, t1 - t0, t2 - t1


def _run_scene(scene, core, core_batch, model, params, traj, pre, post, sname, rtol, atol):
    """Run a scene core on one robot (timed, -> SceneResult) or on a batch (-> (Solution,
    Outputs) with a leading axis, every member checked)."""
    if _batched(params):
        sol, out = core_batch(*pre, params, *post)
        check_result(sol.result, scene)
        return sol, out
    (sol, out), tc, tr = _run_timed(core, *pre, params, *post)
    check_result(sol.result, f"{scene} ({model.name})")
    return _scene_result(scene, model, params, traj, sol, out, tc, tr, sname, rtol, atol)


def _scene_result(scene, model, params, traj, sol, out, t_compile, t_run, solver_name, rtol, atol):
    X_nom = np.asarray(jax.vmap(traj)(sol.ts))
    m = metrics(out, X_nom, traj.center, traj.radius)
    m.update(
        num_steps=int(sol.num_steps), num_accepted=int(sol.num_accepted),
        num_rejected=int(sol.num_rejected), wall_time_s=t_run, compile_time_s=t_compile,
    )
    return SceneResult(
        scene=scene, model=model.name, ts=np.asarray(sol.ts), X=np.asarray(out.X),
        X_nominal=X_nom, tau=np.asarray(sol.tau), end_rot=np.asarray(out.end_rot), metrics=m,
        timing={"compile_s": t_compile, "run_s": t_run},
        solver={"name": solver_name, "rtol": rtol, "atol": atol}, params=params,
    )


def _common(model, params, scene, t_end, n_out, solver, rtol, atol):
    model = get_model(model)
    params = scene_params(scene) if params is None else params
    ts = jnp.linspace(0.0, t_end, n_out)
    solver_name = DEFAULT_SOLVER[model.name] if solver is None else solver
    controller = diffrax.PIDController(
        rtol=jnp.asarray(rtol, dtype=jnp.float64), atol=jnp.asarray(atol, dtype=jnp.float64)
    )
    return model, params, ts, solver_name, get_solver(solver_name), controller


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
):
    """Scene `paper-circle` (paper Fig 8-12): torques from `torque_model`'s inverse dynamics along
    eq 55 (default L1; `rigid` gives the paper's "simplified model" torques), `model` simulated
    torque-driven from the nominal pose and velocity at t = 0 (L2's internal coordinates at the
    quasi-static state). Default params: Table 1 with t = 0.3 mm.

    With batched `params` (leading axis) returns (Solution, Outputs) batched, after checking every
    member; otherwise a `SceneResult` with metrics and timings."""
    model, params, ts, sname, solver_, ctrl = _common(
        model, params, "paper-circle", t_end, n_out, solver, rtol, atol
    )
    traj = Circle() if trajectory is None else trajectory
    tm = get_model(torque_model)
    return _run_scene(
        "paper-circle", _paper_circle_jit, _paper_circle_batch, model, params, traj,
        (model, tm), (traj, ts, solver_, ctrl, max_steps, False), sname, rtol, atol,
    )


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
):
    """Scene `servo-circle` (paper Fig 17-18): the actuated angles follow L1's inverse kinematics
    of eq 55 exactly (motion-driven); the platform's response of `model`. L0/L1 need no ODE
    (forward kinematics + inverse dynamics). Default params: Table 1 with t = 0.5 mm."""
    model, params, ts, sname, solver_, ctrl = _common(
        model, params, "servo-circle", t_end, n_out, solver, rtol, atol
    )
    traj = Circle() if trajectory is None else trajectory
    if model.actuated_index is None:
        sname = "none (kinematics + inverse dynamics)"
    return _run_scene(
        "servo-circle", _servo_circle_jit, _servo_circle_batch, model, params, traj, (model,),
        (traj, ts, solver_, ctrl, max_steps, False), sname, rtol, atol,
    )


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
