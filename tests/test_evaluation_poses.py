"""`Evaluation.poses`, what identification fits: the platform poses of a scene's run at given
sample times, for a robot whose unknowns take the values x, against the scene's own public run
(`run_scene`) of that robot. L0 under the paper circle's torques, 0.1 s at 100 Hz: the reference
is the scene program of tests/test_programs.py (a hit of the suite's compilation cache), the
poses one small program."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

import ppr_jax as pj
from ppr_jax._studies._identify._setup import evaluation

T_END, N = 0.1, 11


def test_poses_at_sample_times_are_the_scenes_run():
    """At every other output time of `run_scene` (another count of sample times, so another
    input table), the poses of the robot with t at 0.8 times the base's equal the scene's run
    of that robot, their rates its differences; an initial-state offset moves the first pose
    by exactly its pose part, and the run succeeds."""
    base = pj.scene_params("paper-circle")
    t = 0.8 * float(base.t)
    ref = pj.run_scene("paper-circle", base.replace(t=t), model="rigid",
                       options=pj.SceneOptions(t_end=T_END, n_out=N))
    model, scene = pj.get_model("rigid"), pj.PaperCircle()
    ts = jnp.asarray(np.asarray(ref.ts)[::2])
    ev = evaluation(("t",), base, model, scene, pj.SceneOptions(), None, ts.shape[0])
    poses = eqx.filter_jit(lambda x, d0: ev.poses(x, base, ts, initial_offset=d0))
    X, V, code = poses(jnp.asarray([t]), jnp.zeros(6))
    assert int(code) == 0
    # (1e-14 here; the base robot's poses are 3 mm and 9 mrad away)
    np.testing.assert_allclose(np.asarray(X), np.asarray(ref.X)[::2], rtol=0, atol=1e-12)
    # the rates are the poses' derivatives (central differences of the reference, O(h^2):
    # 3e-6 of rates up to 0.13)
    Xr, h = np.asarray(ref.X), float(ref.ts[1] - ref.ts[0])
    np.testing.assert_allclose(np.asarray(V)[1:-1], (Xr[3::2] - Xr[1:-2:2]) / (2 * h),
                               rtol=0, atol=1e-5)
    d0 = jnp.asarray([1e-4, -2e-4, 3e-3, 0.0, 0.0, 0.0])
    X1, _, code1 = poses(jnp.asarray([t]), d0)
    assert int(code1) == 0
    np.testing.assert_allclose(np.asarray(X1[0] - X[0]), np.asarray(d0[:3]), rtol=0,
                               atol=1e-15)
