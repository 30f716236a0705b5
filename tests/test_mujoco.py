"""The MuJoCo rebuild of L2 (`benchmarks/contenders/mujoco_l2.py`) is the library's L2.

Two independent implementations of the same mechanics: MuJoCo's recursive rigid-body dynamics
with soft loop-closure equalities against the library's projected equations in independent
coordinates. The MJCF's masses are checked against MODEL.md section 1 computed by hand, its
spring rest angles against section 4 (psi0 = theta_c/2), its energies against the library's at a
closed state (which checks every mass, inertia, centre of mass and spring at once), and a short
`paper-circle` window against the library's L2 run.
"""

import jax
import numpy as np
import pytest

pytest.importorskip("mujoco")
import mujoco  # noqa: E402

import ppr_jax as pj  # noqa: E402
from benchmarks.contenders import mujoco_l2

GEOMETRIES = ["centerline", "strip"]


def _model(params, dt=1e-4):
    return mujoco.MjModel.from_xml_string(mujoco_l2.mjcf(params, dt=dt))


@pytest.mark.parametrize("geometry", GEOMETRIES)
def test_mass_and_spring_rest_angles(geometry):
    p = pj.scene_params("paper-circle", joint_geometry=geometry)
    m = _model(p)
    # MODEL.md section 1 by hand: three links of each kind, one strip per chain, the platform.
    link = p.rho_m * p.l1 * p.b_r * p.t_r
    strip = p.rho_m * p.w * p.t * p.r * p.theta_c
    plate = p.rho_m * np.sqrt(3.0) / 4 * p.h**2 * p.t_p
    np.testing.assert_allclose(mujoco.mj_getTotalmass(m), 3 * (2 * link + strip) + plate,
                               rtol=1e-14)
    robot = pj.Robot(p)
    psi0 = p.theta_c / 2  # MODEL.md section 3: the rest turn at each pivot
    ref_b = p.sigma * psi0
    ref_d = p.sigma * (psi0 - float(robot.delta3))  # section 3a; delta3 = 0 on the centre lines
    idx = mujoco_l2.qpos_index(m)
    for i in range(3):
        for joint, ref in ((f"B{i}", ref_b), (f"D{i}", ref_d)):
            j = m.joint(joint).id
            np.testing.assert_allclose(m.qpos_spring[idx[joint]], ref, rtol=0, atol=1e-15)
            np.testing.assert_allclose(m.jnt_stiffness[j], float(robot.K), rtol=1e-14)
        assert m.jnt_stiffness[m.joint(f"A{i}").id] == 0.0
    if geometry == "centerline":
        assert float(robot.delta3) == 0.0


@pytest.mark.parametrize("geometry", GEOMETRIES)
def test_energies_equal_the_library(geometry):
    """At a closed state off the quasi-static manifold (actuated angles and rates perturbed),
    MuJoCo's kinetic and spring energies are the library's."""
    p = pj.scene_params("paper-circle", joint_geometry=geometry, J_rotor=1e-4)
    robot, model = pj.Robot(p), pj.get_model("double1r")
    z = model.coords_from_pose(robot, jax.numpy.array([0.47, 0.27, 0.03]))
    z = z + jax.numpy.array([0.0, 0.0, 0.0, 0.02, -0.01, 0.015])
    zd = jax.numpy.array([0.05, -0.08, 0.3, 0.4, -0.2, 0.1])
    th, thd = jax.jvp(lambda z: model.kinematics(robot, z).th, (z,), (zd,))
    T, U = pj.energy(model, robot, z, zd)
    m = _model(p)
    m.opt.enableflags |= int(mujoco.mjtEnableBit.mjENBL_ENERGY)
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:] = mujoco_l2.mujoco_state(m, np.asarray(th), np.asarray(thd),
                                                  np.asarray(z), np.asarray(zd))
    mujoco.mj_forward(m, d)
    for i in range(3):  # the state is closed: both E_i sites coincide
        np.testing.assert_allclose(d.site(f"E{i}_chain").xpos, d.site(f"E{i}_platform").xpos,
                                   rtol=0, atol=1e-14)
    np.testing.assert_allclose(d.energy[0], float(U), rtol=1e-12)
    np.testing.assert_allclose(d.energy[1], float(T), rtol=1e-12)


def test_paper_circle_window_matches_library():
    """0.5 s of `paper-circle` (torques, initial state and output times the scene's): MuJoCo's
    RK4 at dt = 1e-4 s against the library's L2 at rtol 1e-10. Measured: platform position
    1e-10 m apart, e_r statistics 1e-11 m; the bound is 1e-7 m (1e-4 mm)."""
    p = pj.scene_params("paper-circle")
    t_end, n_out = 0.5, 51
    lib = pj.paper_circle(p, model="double1r", t_end=t_end, n_out=n_out, rtol=1e-10,
                          atol=1e-12)
    # The scene's own initial state (computing it again, as `run` does by default with the same
    # library function, would only add a compilation to this test).
    mj = mujoco_l2.run(p, dt=1e-4, t_end=t_end, n_out=n_out, repeats=1,
                       initial_state=(lib.z[0], lib.zdot[0]))
    X_lib = np.asarray(lib.X)
    np.testing.assert_allclose(mj["t"], np.asarray(lib.ts), rtol=0, atol=1e-12)
    assert mj["n_steps"] == 5000
    pos = np.linalg.norm(mj["X"][:, :2] - X_lib[:, :2], axis=-1).max()
    assert pos < 1e-7, pos
    assert np.abs(mj["X"][:, 2] - X_lib[:, 2]).max() < 1e-7
    e_mj, e_lib = mujoco_l2.radial_error(mj["X"]), mujoco_l2.radial_error(X_lib)
    for stat in (np.max, np.min, np.mean):
        assert abs(stat(e_mj) - stat(e_lib)) < 1e-7, stat.__name__
    # the window shows the model's own error (not a trivially small signal)
    assert e_lib.min() < -1e-5
    assert mj["constraint_residual_max_m"] < 1e-9


def test_export_draws_weightless_geoms_and_refuses_a_batch():
    """`to_mjcf` as users get it: the drawn links and platform (12 capsules, no contact) change
    no mass, centre of mass or inertia of any body; a batch of robots is refused by name."""
    p = pj.RobotParams()
    drawn = mujoco.MjModel.from_xml_string(pj.to_mjcf(p))
    bare = mujoco.MjModel.from_xml_string(pj.to_mjcf(p, visual=False))
    assert drawn.ngeom == 12 and bare.ngeom == 0
    assert not drawn.geom_contype.any() and not drawn.geom_conaffinity.any()
    for field in ("body_mass", "body_ipos", "body_inertia"):
        np.testing.assert_array_equal(getattr(drawn, field), getattr(bare, field))
    with pytest.raises(pj.PPRError, match="one robot"):
        pj.to_mjcf(pj.stack_params([p, p]))


@pytest.mark.parametrize("geometry, pose", [("centerline", None),
                                            ("strip", (0.52, 0.30, 0.04))])
def test_export_starts_assembled(geometry, pose):
    """`to_mjcf` runs as written: its initial configuration (qpos0, what MuJoCo resets to and
    its viewer starts from) and its keyframe `assembled` close every loop and are a static
    equilibrium under the keyframe's motor torques, checked by MuJoCo's own dynamics (qacc 0);
    300 steps from the keyframe stay finite, warning-free and on the pose. Before, every joint
    started at 0 with the loops 0.5 m open, and MuJoCo reported the simulation unstable at its
    first step."""
    p = pj.scene_params("paper-circle", joint_geometry=geometry)
    m = mujoco.MjModel.from_xml_string(pj.to_mjcf(p, pose=pose))
    assert m.nkey == 1 and m.key(0).name == "assembled"
    np.testing.assert_array_equal(m.qpos0, m.key_qpos[0])
    assert not m.key_qvel[0].any()
    idx = mujoco_l2.qpos_index(m)
    X0 = np.array([m.qpos0[idx[n]] for n in ("x", "y", "phi")])
    if pose is None:  # the home pose, the base centroid
        np.testing.assert_allclose(X0, [p.a / 2, np.sqrt(3.0) * p.a / 6, 0.0], atol=1e-15)
    else:
        np.testing.assert_allclose(X0, pose, atol=1e-15)
        assert np.abs(m.key_ctrl[0]).max() > 1e-3  # off the centre, the motors hold it
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, 0)
    mujoco.mj_forward(m, d)
    for i in range(3):
        np.testing.assert_allclose(d.site(f"E{i}_chain").xpos, d.site(f"E{i}_platform").xpos,
                                   rtol=0, atol=1e-12)
    # Equilibrium: the unbalanced generalized force M qacc against the springs' torques. MuJoCo's
    # soft equalities deliver only their impedance (0.9999) of the constraint force: measured
    # 5e-5 and 9e-5 of the spring torques here; zero motor torques off the centre leave 0.8.
    def unbalanced():
        mujoco.mj_forward(m, d)
        f = np.zeros(m.nv)
        mujoco.mj_mulM(m, d, f, d.qacc)
        return np.abs(f).max() / np.abs(d.qfrc_passive).max()

    assert unbalanced() < 3e-4
    if pose is not None:
        d.ctrl[:] = 0.0
        assert unbalanced() > 0.1
        mujoco.mj_resetDataKeyframe(m, d, 0)
    for _ in range(300):
        mujoco.mj_step(m, d)
    assert np.isfinite(d.qpos).all() and np.isfinite(d.qvel).all()
    assert not any(w.number for w in d.warning)
    X = np.array([d.qpos[idx[n]] for n in ("x", "y", "phi")])
    np.testing.assert_allclose(X, X0, rtol=0, atol=1e-8)
    assert np.abs(d.qvel).max() < 1e-5


def test_export_refuses_a_pose_out_of_reach():
    with pytest.raises(pj.PPRError, match=r"no assembled state at the pose .*out of the "
                                          r"chains' reach"):
        pj.to_mjcf(pj.RobotParams(), pose=(2.0, 2.0, 0.0))
