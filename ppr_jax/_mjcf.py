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


def to_mjcf(params: RobotParams, *, dt: float = 1e-4, visual: bool = True) -> str:
    """The L2 robot of `params` as an MJCF document (module docstring).

    **Arguments:**

    - `params`: the robot (`RobotParams`, one robot: SI units).
    - `dt`: MuJoCo's time step (s), RK4; the loop closures' time constant is 2 dt.
    - `visual`: draw the links and the platform (geoms without contact or mass).

    **Returns:** the MJCF text; `mujoco.MjModel.from_xml_string` loads it. Joints A_i (actuated,
    motor `tau_i`), B_i and D_i (the joint's two pivots, springs K at the library's rest
    angles), the platform on slides x, y and hinge phi. The constraint solver is Newton: with
    equality constraints only its problem is quadratic and one Newton iteration solves it
    exactly; tolerance 1e-15 leaves nothing to the iteration.
    """
    if np.ndim(params.t) != 0:
        raise PPRError("to_mjcf writes one robot: params has a batch axis (unstack_params)")
    q = quantities(params)
    s = q["sigma"]
    ref_b, ref_d = spring_refs(params)
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
    <body name="drive{i}" pos="{_v(ax, ay, 0)}">
      <joint name="A{i}" type="hinge" axis="0 0 1" damping="{_f(q['c_act'])}"/>
      <inertial pos="{_v(q['l1'] / 2, 0, 0)}" mass="{_f(q['m1'])}"
                diaginertia="{_v(izz1, izz1, izz1)}"/>
      {geom(f"drive{i}", bx, by)}
      <body name="pseudo{i}" pos="{_v(bx, by, 0)}">
        <joint name="B{i}" type="hinge" axis="0 0 1" stiffness="{_f(q['K'])}"
               springref="{_f(ref_b)}" damping="{_f(q['c_spring'])}"/>
        <inertial pos="{_v(q['r2'] / 2, 0, 0)}" mass="{_f(q['m2'])}"
                  diaginertia="{_v(q['I2'], q['I2'], q['I2'])}"/>
        {geom(f"pseudo{i}", q['r2'], 0)}
        <body name="connecting{i}" pos="{_v(q['r2'], 0, 0)}">
          <joint name="D{i}" type="hinge" axis="0 0 1" stiffness="{_f(q['K'])}"
                 springref="{_f(ref_d)}" damping="{_f(q['c_spring'])}"/>
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


