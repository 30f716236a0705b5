"""The L2 robot (`double1r`, MODEL.md sections 3-5) rebuilt in MuJoCo, and its `paper-circle` run.

The MJCF is the library's export, `ppr_jax.to_mjcf` (`ppr_jax/_mjcf.py`, whose docstring
describes it body by body); this file runs it.

`run` drives it with the library's `paper-circle` torques (L1 inverse dynamics along eq 55) from
the library's initial state, with RK4, and returns the platform pose at the library's output
times; its docstring says how the torques reach MuJoCo's steps and what that costs in accuracy.
`radial_error` is the scene's e_r.
"""

from __future__ import annotations

import time

import jax
import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402

import ppr_jax as pj  # noqa: E402

from . import library  # noqa: E402

#: the scene's circle (eq 55): centre (m) and radius (m) of e_r
CENTER = np.array([0.45, 0.15 * np.sqrt(3.0)])
RADIUS = 0.1


def mjcf(params: pj.RobotParams, *, dt: float = 1e-4) -> str:
    """The library's MJCF export (`ppr_jax.to_mjcf`) without the drawn geoms."""
    return pj.to_mjcf(params, dt=dt, visual=False)


def qpos_index(model: mujoco.MjModel) -> dict:
    """Addresses in qpos (= in qvel: hinges and slides only) of the named joints."""
    names = [f"{j}{i}" for i in range(3) for j in "ABD"] + ["x", "y", "phi"]
    return {n: int(model.joint(n).qposadr[0]) for n in names}


def library_initial_state(params: pj.RobotParams):
    """The library's L2 `paper-circle` initial state: (z0 (6,), zdot0 (6,), th (3, 3) chain
    angles, thdot (3, 3) their rates). z0, zdot0 as the scene starts (`library.initial_state`);
    the chain angles and rates follow from the library's own closure (`Double1R.kinematics`)
    and its derivative."""
    z0, zd0 = library.initial_state(params)
    return (z0, zd0, *chain_state(params, z0, zd0))


def chain_state(params: pj.RobotParams, z0, zd0):
    """Chain angles th (3, 3) and rates of the library's L2 state (z0, zd0)."""
    model, robot = pj.get_model("double1r"), pj.Robot(params)
    th, thd = jax.jvp(lambda z: model.kinematics(robot, z).th, (jnp.asarray(z0),),
                      (jnp.asarray(zd0),))
    return np.asarray(th), np.asarray(thd)


def mujoco_state(model, th, thd, z, zd):
    """(qpos, qvel) of the MJCF from the library's chain angles th (3, 3), rates thd, pose z[:3]
    and its rate: q_A = th_a (the centre-line angle, z[3:]), q_B = th_i2 - th_a,
    q_D = th_i3 - th_i2."""
    idx = qpos_index(model)
    qpos, qvel = np.zeros(model.nq), np.zeros(model.nv)
    for i in range(3):
        for vec, a, ang in ((qpos, z, th), (qvel, zd, thd)):
            vec[idx[f"A{i}"]] = a[3 + i]
            vec[idx[f"B{i}"]] = ang[i, 1] - a[3 + i]
            vec[idx[f"D{i}"]] = ang[i, 2] - ang[i, 1]
    for k, n in enumerate(("x", "y", "phi")):
        qpos[idx[n]], qvel[idx[n]] = z[k], zd[k]
    return qpos, qvel


def radial_error(X) -> np.ndarray:
    """The scene's radial error e_r = |(x, y) - c| - R (m), c = (0.45, 0.15 sqrt 3), R = 0.1."""
    X = np.asarray(X)
    return np.linalg.norm(X[..., :2] - CENTER, axis=-1) - RADIUS


def run(scene_params: pj.RobotParams, *, dt: float, t_end: float = 7.54, n_out: int = 755,
        repeats: int = 3, inputs: str = "midpoint", initial_state=None) -> dict:
    """L2 `paper-circle` in MuJoCo: RK4 at a fixed step near dt (s), torque-driven by the
    library's torques from the library's initial state; the pose at the library's output times
    t_k = t_end k/(n_out - 1).

    Steps: each output interval is split into n_sub = round(interval/dt) equal steps, so the
    step used is interval/n_sub (dt itself when it divides the interval) and every output time
    is a step boundary.

    Torques (`inputs`), precomputed on the host once either way:
    - "midpoint" (default): MuJoCo holds `ctrl` constant over a step (all four RK4 stages see
      it), so each step gets tau at its midpoint. The rollout runs in C (`mujoco.rollout`, one
      call per output interval on the calling thread, reusing its output buffer; the state at
      the interval's end starts the next), as fast as MuJoCo runs this model. The hold makes the
      run second order in dt whatever the integrator: a held input shifts the position by
      tau' dt^3/12 per step, which adds up to O(dt^2) (measured on the full scene: platform
      position 1.6e-8 m from the library's at dt = 1e-3, 1.6e-10 m at 1e-4, 1.6e-12 m at 1e-5;
      7 times the error of "stages" at the same step).
    - "stages": the torque at each RK4 stage's own time (t, t + dt/2, t + dt: a half-step
      table), set by MuJoCo's control callback, which every stage calls; this is RK4 as the
      library's solvers see the input. The callback is Python, so the loop is `mj_step` in
      Python: 1.2-1.4 times the time per step of "midpoint", 7 times more accurate (2.2e-9 m at
      dt = 1e-3, 2.2e-11 m at 1e-4). Remaining error: the soft loop closure (second order too,
      through the time constant 2 dt).

    Initial state: the library's, (z0, zdot0) in its L2 coordinates (x, y, phi, th_a1..3) and
    their rates; by default computed here as the scene computes it (`library_initial_state`);
    `initial_state` passes one already at hand (a library run's first state) instead.

    Timing: a warm-up of one output interval, then the minimum of `repeats` full runs
    (`time.perf_counter`).

    Returns {"t" (n_out,), "X" (n_out, 3) platform pose (m, m, rad), "run_s", "setup_s" (MJCF
    compilation, initial state and torques), "n_steps", "dt" (the step used), "includes",
    "constraint_residual_max_m" (largest loop-closure violation at the output times)}.
    """
    if inputs not in ("midpoint", "stages"):
        raise ValueError(f"inputs must be 'midpoint' or 'stages', got {inputs!r}")
    t0 = time.perf_counter()
    interval = t_end / (n_out - 1)
    n_sub = max(int(round(interval / dt)), 1)
    h = interval / n_sub
    n_steps = n_sub * (n_out - 1)
    model = mujoco.MjModel.from_xml_string(mjcf(scene_params, dt=h))
    data = mujoco.MjData(model)
    if initial_state is None:
        z0, zd0, th, thd = library_initial_state(scene_params)
    else:
        z0, zd0 = (np.asarray(v, dtype=np.float64) for v in initial_state)
        th, thd = chain_state(scene_params, z0, zd0)
    qpos, qvel = mujoco_state(model, th, thd, z0, zd0)
    if inputs == "midpoint":
        tau = library.scene_torques(scene_params, (np.arange(n_steps) + 0.5) * h)
        tau = tau.reshape(n_out - 1, n_sub, 3)
    else:
        half = library.scene_torques(scene_params, np.arange(2 * n_steps + 1) * (h / 2))
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    nstate = mujoco.mj_stateSize(model, spec)
    data.qpos[:], data.qvel[:], data.time = qpos, qvel, 0.0
    mujoco.mj_forward(model, data)
    s0 = np.empty(nstate)
    mujoco.mj_getState(model, data, s0, spec)
    idx = qpos_index(model)
    ix = 1 + np.array([idx["x"], idx["y"], idx["phi"]])  # state = (time, qpos, ...)
    out = np.empty((n_out, nstate))
    setup_s = time.perf_counter() - t0

    if inputs == "midpoint":
        buf = np.empty((1, n_sub, nstate))
        sens = np.empty((1, n_sub, model.nsensordata))
        ctrl_spec = int(mujoco.mjtState.mjSTATE_CTRL)
        pool = mj_rollout.Rollout(nthread=0)

        def go(n_int):
            out[0] = s0
            for j in range(n_int):
                # skip_checks: the arrays are already what the C call wants (C-contiguous
                # float64, batch of one), so it goes straight to the C rollout
                pool.rollout([model], [data], out[j][None], tau[j][None], control_spec=ctrl_spec,
                             skip_checks=True, nstep=n_sub, state=buf, sensordata=sens,
                             chunk_size=1)
                out[j + 1] = buf[0, -1]
    else:
        def control(m, d):
            d.ctrl[:] = half[int(round(d.time * (2 / h)))]

        def go(n_int):
            out[0] = s0
            mujoco.mj_setState(model, data, s0, spec)
            step = mujoco.mj_step
            for j in range(n_int):
                for _ in range(n_sub):
                    step(model, data)
                mujoco.mj_getState(model, data, out[j + 1], spec)

        mujoco.set_mjcb_control(control)
    try:
        go(1)  # warm-up
        runs = []
        for _ in range(max(int(repeats), 1)):
            t1 = time.perf_counter()
            go(n_out - 1)
            runs.append(time.perf_counter() - t1)
    finally:
        if inputs == "midpoint":
            pool.close()
        else:
            mujoco.set_mjcb_control(None)
    resid = 0.0
    for j in range(n_out):
        mujoco.mj_setState(model, data, out[j], spec)
        mujoco.mj_kinematics(model, data)
        for i in range(3):
            resid = max(resid, float(np.linalg.norm(
                data.site(f"E{i}_chain").xpos - data.site(f"E{i}_platform").xpos)))
    includes = (
        "rollout only (MuJoCo's C rollout, RK4, one call per output interval); torques "
        "precomputed at step midpoints, model compiled, initial state set"
        if inputs == "midpoint" else
        "mj_step loop in Python with RK4 and a Python control callback at every stage reading "
        "precomputed torques; model compiled, initial state set"
    )
    return {
        "t": out[:, 0].copy(), "X": out[:, ix].copy(), "run_s": min(runs), "setup_s": setup_s,
        "n_steps": n_steps, "dt": h, "constraint_residual_max_m": resid, "inputs": inputs,
        "includes": includes,
    }
