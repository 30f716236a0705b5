"""The L2 robot (`double1r`, MODEL.md sections 3-5) rebuilt in MuJoCo, and its `paper-circle` run.

The MJCF (`mjcf`) reproduces the library's L2 mechanics body by body (`ppr_jax/_models/double1r.py`
`chain_bodies`, `masses`, `ppr_jax/_geometry.py` `deflections`), with every number taken from
`ppr_jax.Robot` (`ppr_jax/_prb.py` `derived`), so that the two differ only in their numerics:

- chain i is a kinematic tree rooted at A_i: the drive link (hinge about z at A_i, motor actuator
  giving the torque tau_i), the pseudo-link (hinge at B_i), the connecting link (hinge at D_i);
  the platform is a separate body on (slide x, slide y, hinge phi) from the world origin, so its
  first three joint coordinates are the pose X = (x, y, phi) itself;
- body frames: the drive link's x axis is its centre line (hinge coordinate = the actuated angle
  th_a, as in the library's z); the pseudo-link's x axis is the chain vector B->D (angle th_i2);
  the connecting link's x axis is D->E (angle th_i3). B_i lies at r1 e(sigma delta1) in the drive
  link's frame, D_i at (r2, 0), E_i at (r3, 0); delta1 = delta3 = 0 on the centre lines (the
  default `joint_geometry`), nonzero for `strip` (MODEL.md 3a), which this file handles too;
- masses and central inertias as `AbstractDouble1R.masses`: drive link m1 with I1 + J_rotor
  (COM at l1/2 on its centre line), pseudo-link m2 with I2 = m2 r2^2/12 (COM at r2/2), connecting
  link m3 with I3 (COM at l3/2 back from E_i along its centre line), platform m4 with I4 at
  (x, y). The motion is planar (every hinge about z, slides in x and y), so only the z moment of
  inertia enters; the other two principal moments are set equal to it, which any planar motion
  ignores and which satisfies MuJoCo's triangle inequality;
- springs: the hinge coordinate at B_i is q_B = th_i2 - th_a, so the library's deflection
  d_i1 = (th_i2 - th_i1) - sigma (psi0 - delta1) = q_B - sigma psi0: stiffness K, springref
  sigma psi0. At D_i, q_D = th_i3 - th_i2 and d_i2 = q_D - sigma (psi0 - delta3): springref
  sigma (psi0 - delta3). MuJoCo's joint spring energy K/2 (q - springref)^2 is then the library's
  U = K/2 sum d^2 exactly (the library wraps d to (-pi, pi], immaterial at these deflections);
- damping: `c_spring` as joint damping on the B and D hinges (the library's -c_s Jd^T Jd z' is a
  viscous torque on each relative angle), `c_act` on the A hinges; both 0 by default, as in the
  library;
- gravity off: the library's gravity acts normal to the plane and does no work (`_dynamics.py`);
  no geoms, contacts disabled;
- loop closure: a `connect` equality per chain between a site at E_i on the connecting link and
  one at E_i on the platform (the site form, so both anchors are the sites themselves, not
  positions recomputed at the model's reference configuration). The library closes its chains
  exactly (6 DOF in independent coordinates); MuJoCo's equality is soft: its impedance is set to
  MuJoCo's maximum, solimp d = 0.9999 (dmin = dmax, so independent of the violation), and its
  time constant to 2 dt (the smallest MuJoCo accepts with its `refsafe` rule). Measured on 1 s
  of `paper-circle` at dt = 1e-3 with exact stage torques: the platform's error from the
  softness is proportional to 1 - d (1e-3 gives 10 times, 1e-2 100 times the error of 1e-4) and
  smallest at 2 dt (0.5 dt with `refsafe` off, or 4 dt, give 4-5 times more); it falls as dt^2
  with the time constant, 6e-10 m at dt = 1e-3. The connect's third (z) row is identically zero
  in this planar model and carries no force.

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

#: MuJoCo's largest constraint impedance (mjMAXIMP): the stiffest the equality can be made
IMPEDANCE = 0.9999
#: the equality's time constant in time steps (MuJoCo's `refsafe` minimum)
TIMECONST_STEPS = 2.0
#: platform joint directions beta_i (MODEL.md section 2)
BETA = np.array([7 * np.pi / 6, -np.pi / 6, np.pi / 2])
#: the scene's circle (eq 55): centre (m) and radius (m) of e_r
CENTER = np.array([0.45, 0.15 * np.sqrt(3.0)])
RADIUS = 0.1


def _f(x) -> str:
    """A float written exactly (17 significant digits round-trip a float64)."""
    return f"{float(x):.17g}"


def _v(*xs) -> str:
    return " ".join(_f(x) for x in xs)


def quantities(params: pj.RobotParams) -> dict:
    """The library's numbers the MJCF uses (floats, SI units), from `ppr_jax.Robot(params)`."""
    robot = pj.Robot(params)
    names = ("a", "l1", "l3", "r1", "r2", "r3", "delta1", "delta3", "psi0", "K", "m1", "I1",
             "m2", "I2", "m3", "I3", "m4", "I4", "rho_E", "J_rotor", "c_spring", "c_act")
    q = {n: float(np.asarray(getattr(robot, n))) for n in names}
    q["sigma"] = int(robot.sigma)
    a = q["a"]
    q["A"] = np.array([[0.0, 0.0], [a, 0.0], [a / 2, np.sqrt(3.0) * a / 2]])
    return q


def spring_refs(params: pj.RobotParams) -> tuple[float, float]:
    """(springref of the B hinges, springref of the D hinges) (rad): the hinge angles at which
    the library's deflections d_i1, d_i2 vanish (module docstring)."""
    q = quantities(params)
    s = q["sigma"]
    return s * q["psi0"], s * (q["psi0"] - q["delta3"])


def mjcf(params: pj.RobotParams, *, dt: float = 1e-4) -> str:
    """MJCF of the L2 robot for `params` (module docstring), RK4 with time step dt (s).

    The constraint solver is Newton: with equality constraints only its problem is quadratic and
    one Newton iteration solves it exactly; tolerance 1e-15 leaves nothing to the iteration."""
    q = quantities(params)
    s = q["sigma"]
    ref_b, ref_d = spring_refs(params)
    izz1 = q["I1"] + q["J_rotor"]
    bx, by = q["r1"] * np.cos(s * q["delta1"]), q["r1"] * np.sin(s * q["delta1"])
    cx = q["r3"] - q["l3"] / 2 * np.cos(s * q["delta3"])
    cy = -q["l3"] / 2 * np.sin(s * q["delta3"])
    tc = TIMECONST_STEPS * dt
    chains, eqs, acts, sites = [], [], [], []
    for i in range(3):
        ax, ay = q["A"][i]
        chains.append(f"""
    <body name="drive{i}" pos="{_v(ax, ay, 0)}">
      <joint name="A{i}" type="hinge" axis="0 0 1" damping="{_f(q['c_act'])}"/>
      <inertial pos="{_v(q['l1'] / 2, 0, 0)}" mass="{_f(q['m1'])}"
                diaginertia="{_v(izz1, izz1, izz1)}"/>
      <body name="pseudo{i}" pos="{_v(bx, by, 0)}">
        <joint name="B{i}" type="hinge" axis="0 0 1" stiffness="{_f(q['K'])}"
               springref="{_f(ref_b)}" damping="{_f(q['c_spring'])}"/>
        <inertial pos="{_v(q['r2'] / 2, 0, 0)}" mass="{_f(q['m2'])}"
                  diaginertia="{_v(q['I2'], q['I2'], q['I2'])}"/>
        <body name="connecting{i}" pos="{_v(q['r2'], 0, 0)}">
          <joint name="D{i}" type="hinge" axis="0 0 1" stiffness="{_f(q['K'])}"
                 springref="{_f(ref_d)}" damping="{_f(q['c_spring'])}"/>
          <inertial pos="{_v(cx, cy, 0)}" mass="{_f(q['m3'])}"
                    diaginertia="{_v(q['I3'], q['I3'], q['I3'])}"/>
          <site name="E{i}_chain" pos="{_v(q['r3'], 0, 0)}"/>
        </body>
      </body>
    </body>""")
        sites.append(
            f'      <site name="E{i}_platform" pos="'
            f'{_v(q["rho_E"] * np.cos(BETA[i]), q["rho_E"] * np.sin(BETA[i]), 0)}"/>'
        )
        eqs.append(f'    <connect name="close{i}" site1="E{i}_chain" site2="E{i}_platform" '
                   f'solref="{_v(tc, 1.0)}" solimp="{_v(IMPEDANCE, IMPEDANCE, 0.001, 0.5, 2)}"/>')
        acts.append(f'    <motor name="tau{i}" joint="A{i}" gear="1"/>')
    m4, I4 = q["m4"], q["I4"]
    nl = "\n"
    return f"""<mujoco model="ppr_jax L2 double1r">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{_f(dt)}" integrator="RK4" gravity="0 0 0" solver="Newton"
          tolerance="1e-15" iterations="20" ls_iterations="50">
    <flag contact="disable" island="disable"/>
  </option>
  <worldbody>{''.join(chains)}
    <body name="platform">
      <joint name="x" type="slide" axis="1 0 0"/>
      <joint name="y" type="slide" axis="0 1 0"/>
      <joint name="phi" type="hinge" axis="0 0 1"/>
      <inertial pos="0 0 0" mass="{_f(m4)}" diaginertia="{_v(I4, I4, I4)}"/>
{nl.join(sites)}
    </body>
  </worldbody>
  <equality>
{nl.join(eqs)}
  </equality>
  <actuator>
{nl.join(acts)}
  </actuator>
</mujoco>
"""


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
