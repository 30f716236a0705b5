"""The L2 robot (`double1r`, MODEL.md sections 3-5) written as MJCF, MuJoCo's model format.

The MJCF (`to_mjcf`) reproduces the library's L2 mechanics body by body
(`ppr_jax/_models/double1r.py` `chain_bodies`, `masses`, `ppr_jax/_geometry.py`
`deflections`), with every number taken from `ppr_jax.Robot` (`ppr_jax/_prb.py` `derived`), so
that the two differ only in their numerics:

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

Initial state: every joint's `ref` (MuJoCo's qpos0, where a reset and the viewer start) and the
keyframe `assembled` hold the assembled state of `assembled_state`: the chains closed on the
platform at a pose (the home pose by default), the actuated angles that put the platform in
static equilibrium under the springs, and the motor torques (`ctrl`) that hold them there. The
body frames are written at those angles, so qpos keeps its meaning (the absolute angles above).

`to_mjcf` also draws each body (capsules along the links, the platform's triangle) for MuJoCo's
viewer: visual geoms only (no contact, no mass: every body's `inertial` is explicit, so MuJoCo
takes its mass and inertia from there, not from the geoms). `python -m mujoco.viewer
--mjcf=robot.xml` opens the identified or any other robot.
"""

from __future__ import annotations

import numpy as np

from ._errors import PPRError
from ._params import RobotParams
from ._robot import Robot

#: MuJoCo's largest constraint impedance (mjMAXIMP): the stiffest the equality can be made
IMPEDANCE = 0.9999
#: the equality's time constant in time steps (MuJoCo's `refsafe` minimum)
TIMECONST_STEPS = 2.0
#: platform joint directions beta_i (MODEL.md section 2)
BETA = np.array([7 * np.pi / 6, -np.pi / 6, np.pi / 2])


def _f(x) -> str:
    """A float written exactly (17 significant digits round-trip a float64)."""
    return f"{float(x):.17g}"


def _v(*xs) -> str:
    return " ".join(_f(x) for x in xs)


def quantities(params: RobotParams) -> dict:
    """The library's numbers the MJCF uses (floats, SI units), from `Robot(params)`."""
    robot = Robot(params)
    names = ("a", "l1", "l3", "r1", "r2", "r3", "delta1", "delta3", "psi0", "K", "m1", "I1",
             "m2", "I2", "m3", "I3", "m4", "I4", "rho_E", "J_rotor", "c_spring", "c_act")
    q = {n: float(np.asarray(getattr(robot, n))) for n in names}
    q["sigma"] = int(robot.sigma)
    a = q["a"]
    q["A"] = np.array([[0.0, 0.0], [a, 0.0], [a / 2, np.sqrt(3.0) * a / 2]])
    return q


def spring_refs(params: RobotParams) -> tuple[float, float]:
    """(springref of the B hinges, springref of the D hinges) (rad): the hinge angles at which
    the library's deflections d_i1, d_i2 vanish (module docstring)."""
    q = quantities(params)
    s = q["sigma"]
    return s * q["psi0"], s * (q["psi0"] - q["delta3"])


def _closure(q, X, th_a):
    """The MJCF's hinge coordinates (q_B, q_D) (3,) each of the chains closed on the platform at
    pose X with the drive links at th_a (3,): the two-link (r2, r3) solution from B_i to E_i on
    the elbow branch sigma (`_geometry.chain_closure_double1r`, in numpy), and its margin."""
    s = q["sigma"]
    t1 = th_a + s * q["delta1"]
    B = q["A"] + q["r1"] * np.stack([np.cos(t1), np.sin(t1)], -1)
    E = X[:2] + q["rho_E"] * np.stack([np.cos(BETA + X[2]), np.sin(BETA + X[2])], -1)
    d = E - B
    la, lb = q["r2"], q["r3"]
    c = (np.sum(d**2, -1) - la**2 - lb**2) / (2 * la * lb)
    delta = s * np.arccos(np.clip(c, -1.0, 1.0))
    t2 = np.arctan2(d[:, 1], d[:, 0]) - np.arctan2(lb * np.sin(delta), la + lb * np.cos(delta))
    q_b = t2 - th_a
    q_b = q_b - 2 * np.pi * np.round((q_b - s * q["psi0"]) / (2 * np.pi))
    return q_b, delta, 1 - np.abs(c)


def assembled_state(params: RobotParams, pose=None) -> dict:
    """The robot held still at `pose` (x m, y m, phi rad; default the home pose, the base
    centroid): the actuated angles th_a at which the platform is in static equilibrium under the
    springs alone, and the motor torques tau that hold the drive links there (N m), in numpy.

    With the platform free of loads, equilibrium is dU/dX = 0 at the fixed pose, with U the
    springs' energy K/2 sum (q - springref)^2 over the chains closed by `_closure`; three
    equations in th_a, solved by Newton's method with central differences from the rigid rest
    shape pointed at E_i; tau = dU/dth_a. Returns {"qpos" (12,) in the MJCF's joint order,
    "ctrl" (3,), "pose", "th_a", "residual_N": the platform's largest unbalanced force or moment
    (N, N m)}. Raises `PPRError` when the pose is out of reach or Newton's method does not
    converge."""
    q = quantities(params)
    ref_b, ref_d = spring_refs(params)
    a = q["a"]
    X = (np.array([a / 2, np.sqrt(3.0) * a / 6, 0.0]) if pose is None
         else np.asarray(pose, dtype=np.float64).reshape(3))

    def energy(X, th_a):
        q_b, q_d, margin = _closure(q, X, th_a)
        return 0.5 * q["K"] * float(np.sum((q_b - ref_b) ** 2 + (q_d - ref_d) ** 2)), margin

    def grad(f, x, h):
        return np.array([(f(x + h * e) - f(x - h * e)) / (2 * h) for e in np.eye(len(x))])

    def platform_force(th_a):
        return grad(lambda Y: energy(Y, th_a)[0], X, 1e-6)

    # start: each chain at its rest shape, turned to point at E_i
    s = q["sigma"]
    t1 = s * q["delta1"]
    v = (q["r1"] * np.array([np.cos(t1), np.sin(t1)])
         + q["r2"] * np.array([np.cos(ref_b), np.sin(ref_b)])
         + q["r3"] * np.array([np.cos(ref_b + ref_d), np.sin(ref_b + ref_d)]))
    E = X[:2] + q["rho_E"] * np.stack([np.cos(BETA + X[2]), np.sin(BETA + X[2])], -1)
    th_a = np.arctan2(E[:, 1] - q["A"][:, 1], E[:, 0] - q["A"][:, 0]) - np.arctan2(v[1], v[0])
    scale = q["K"] / max(a, 1e-300)  # N: a force the springs make over the robot's size
    for _ in range(30):
        f = platform_force(th_a)
        J = np.stack([(platform_force(th_a + 1e-6 * e) - platform_force(th_a - 1e-6 * e))
                      / 2e-6 for e in np.eye(3)], -1)
        try:
            step = np.linalg.solve(J, -f)
        except np.linalg.LinAlgError:
            break
        th_a = th_a + np.clip(step, -0.1, 0.1)
        if np.max(np.abs(step)) < 1e-12:
            break
    U, margin = energy(X, th_a)
    f = platform_force(th_a)
    residual = float(np.max(np.abs(f)))
    if not (np.all(margin > 0) and np.isfinite(U) and residual < 1e-6 * scale):
        raise PPRError(
            f"to_mjcf: no assembled state at the pose (x, y, phi) = ({X[0]:.6g} m, "
            f"{X[1]:.6g} m, {X[2]:.6g} rad): "
            + ("the pose is out of the chains' reach" if not np.all(margin > 0) else
               f"the platform's equilibrium was not found (unbalanced {residual:.3g} N)")
            + "; give a pose inside the workspace (pose=)")
    tau = grad(lambda t: energy(X, t)[0], th_a, 1e-6)
    q_b, q_d, _ = _closure(q, X, th_a)
    qpos = np.concatenate([np.stack([th_a, q_b, q_d], -1).reshape(-1), X])
    return {"qpos": qpos, "ctrl": tau, "pose": X, "th_a": th_a, "residual_N": residual}


def to_mjcf(params: RobotParams, *, dt: float = 1e-4, visual: bool = True, pose=None) -> str:
    """The L2 robot of `params` as an MJCF document (module docstring).

    **Arguments:**

    - `params`: the robot (`RobotParams`, one robot: SI units).
    - `dt`: MuJoCo's time step (s), RK4; the loop closures' time constant is 2 dt.
    - `visual`: draw the links and the platform (geoms without contact or mass).
    - `pose`: (x m, y m, phi rad) of the assembled state (default the home pose, the base
      centroid; `assembled_state`).

    **Returns:** the MJCF text; `mujoco.MjModel.from_xml_string` loads it. Joints A_i (actuated,
    motor `tau_i`), B_i and D_i (the joint's two pivots, springs K at the library's rest
    angles), the platform on slides x, y and hinge phi. The constraint solver is Newton: with
    equality constraints only its problem is quadratic and one Newton iteration solves it
    exactly; tolerance 1e-15 leaves nothing to the iteration.

    The model's initial configuration (qpos0, each joint's `ref`: MuJoCo's reset and viewer
    start there) and its keyframe `assembled` (qpos, zero qvel, ctrl) are the assembled state:
    the chains closed on the platform at `pose`, in static equilibrium with the motor torques
    `ctrl` that hold it. Without them every joint started at 0, the loops open by some 0.5 m, and
    MuJoCo reported the simulation unstable at its first step.
    """
    if np.ndim(params.t) != 0:
        raise PPRError("to_mjcf writes one robot: params has a batch axis (unstack_params)")
    q = quantities(params)
    s = q["sigma"]
    ref_b, ref_d = spring_refs(params)
    st = assembled_state(params, pose)
    q0 = st["qpos"].reshape(-1)
    izz1 = q["I1"] + q["J_rotor"]
    bx, by = q["r1"] * np.cos(s * q["delta1"]), q["r1"] * np.sin(s * q["delta1"])
    cx = q["r3"] - q["l3"] / 2 * np.cos(s * q["delta3"])
    cy = -q["l3"] / 2 * np.sin(s * q["delta3"])
    tc = TIMECONST_STEPS * dt
    radius = 0.5 * float(np.asarray(params.b_r))

    def geom(name, x, y):
        # a capsule from the body's origin to (x, y): drawn, never in contact, weightless
        return (f'<geom name="{name}" type="capsule" fromto="{_v(0, 0, 0, x, y, 0)}" '
                f'size="{_f(radius)}" contype="0" conaffinity="0" group="1"/>' if visual else "")

    chains, eqs, acts, sites = [], [], [], []
    for i in range(3):
        ax, ay = q["A"][i]
        chains.append(f"""
    <body name="drive{i}" pos="{_v(ax, ay, 0)}" euler="{_v(0, 0, q0[3 * i])}">
      <joint name="A{i}" type="hinge" axis="0 0 1" damping="{_f(q['c_act'])}"
             ref="{_f(q0[3 * i])}"/>
      <inertial pos="{_v(q['l1'] / 2, 0, 0)}" mass="{_f(q['m1'])}"
                diaginertia="{_v(izz1, izz1, izz1)}"/>
      {geom(f"drive{i}", bx, by)}
      <body name="pseudo{i}" pos="{_v(bx, by, 0)}" euler="{_v(0, 0, q0[3 * i + 1])}">
        <joint name="B{i}" type="hinge" axis="0 0 1" stiffness="{_f(q['K'])}"
               springref="{_f(ref_b)}" damping="{_f(q['c_spring'])}"
               ref="{_f(q0[3 * i + 1])}"/>
        <inertial pos="{_v(q['r2'] / 2, 0, 0)}" mass="{_f(q['m2'])}"
                  diaginertia="{_v(q['I2'], q['I2'], q['I2'])}"/>
        {geom(f"pseudo{i}", q['r2'], 0)}
        <body name="connecting{i}" pos="{_v(q['r2'], 0, 0)}" euler="{_v(0, 0, q0[3 * i + 2])}">
          <joint name="D{i}" type="hinge" axis="0 0 1" stiffness="{_f(q['K'])}"
                 springref="{_f(ref_d)}" damping="{_f(q['c_spring'])}"
                 ref="{_f(q0[3 * i + 2])}"/>
          <inertial pos="{_v(cx, cy, 0)}" mass="{_f(q['m3'])}"
                    diaginertia="{_v(q['I3'], q['I3'], q['I3'])}"/>
          {geom(f"connecting{i}", q['r3'], 0)}
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
    if visual:
        E = [(q["rho_E"] * np.cos(b), q["rho_E"] * np.sin(b)) for b in BETA]
        sites += [f'      <geom name="platform{i}" type="capsule" fromto="'
                  f'{_v(*E[i], 0, *E[(i + 1) % 3], 0)}" size="{_f(radius)}" contype="0" '
                  f'conaffinity="0" group="1"/>' for i in range(3)]
    nl = "\n"
    return f"""<mujoco model="ppr_jax L2 double1r">
  <compiler angle="radian" autolimits="true" inertiafromgeom="false"/>
  <option timestep="{_f(dt)}" integrator="RK4" gravity="0 0 0" solver="Newton"
          tolerance="1e-15" iterations="20" ls_iterations="50">
    <flag contact="disable" island="disable"/>
  </option>
  <worldbody>{''.join(chains)}
    <body name="platform" pos="{_v(q0[9], q0[10], 0)}" euler="{_v(0, 0, q0[11])}">
      <joint name="x" type="slide" axis="1 0 0" ref="{_f(q0[9])}"/>
      <joint name="y" type="slide" axis="0 1 0" ref="{_f(q0[10])}"/>
      <joint name="phi" type="hinge" axis="0 0 1" ref="{_f(q0[11])}"/>
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
  <keyframe>
    <key name="assembled" qpos="{_v(*q0)}" qvel="{_v(*np.zeros(12))}" ctrl="{_v(*st['ctrl'])}"/>
  </keyframe>
</mujoco>
"""


