"""Tracker data that ppr_jax did not make: an L2 servo circle simulated by the independent
NumPy/scipy formulation (`scipy_l2`), for the known-truth identification checks (sim-to-sim
recovery): the test suite's small version and `benchmarks/identify_known_truth.py`.

The robot (`truth`) differs from the model that computed the motors' commands (`nominal`): the
commands are L1's inverse kinematics of eq 55 for `nominal`, as a controller computes them from
its own model, and the robot follows them exactly (ideal servos), so the file's actuated angles
are the commands. What the data share with the library: the parameters, the commanded angles
(evaluated by the library's L1 inverse kinematics on a 1 ms grid and splined, an input like the
scene's torques) and the initial state (the library's quasi-static state under those angles,
checked against this formulation in `tests/test_initial_state.py`: no ringing to 3e-11 m).
Everything the fit could get wrong (equations of motion, loop closures, the start's balance
under foreign commands, the actuation default) is computed independently.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

import ppr_jax as pj

from . import scipy_l2


def servo_data(truth: pj.RobotParams, nominal: pj.RobotParams, *, t_end: float = 2.0,
               rate: float = 100.0, rtol: float = 1e-11, atol: float = 1e-13, times=None,
               path=None):
    """Noise-free tracker samples of the L2 robot `truth` under the commands of `nominal`, at
    `rate` Hz over [0, t_end], or at the increasing `times` (s, >= 0) when given. `path`: the
    commanded pose path t -> (3,) (default the circle of eq 55; any path of `ppr_jax`: a
    `Line`, `Fourier`, `Waypoints`), whose L1 inverse kinematics for `nominal` gives the
    commands; the start is L2's quasi-static state under them at t = 0 with the path as the
    pose guess.

    **Returns:** (ts (n,) s, X (n, 3) pose (m, m, rad), th (n, 3) actuated angles (rad))."""
    path = pj.Circle() if path is None else path
    angles = pj.InverseKinematicsAngles(pj.Reduced(), pj.Robot(nominal), path)
    grid = np.arange(-0.02, t_end + 0.02, 1e-3)
    ths = np.asarray(jax.jit(jax.vmap(angles))(jnp.asarray(grid)))
    spline = scipy_l2.AnglesSpline(grid, ths)
    z0, zd0 = pj.quasi_static_state(pj.Double1R(), pj.Robot(truth), path, 0.0,
                                    pj.MotionDriven(angles))
    m = scipy_l2.L2Model(truth, None, angles=spline)
    if times is None:
        ts = np.arange(int(round(t_end * rate)) + 1) / rate
    else:
        ts = np.asarray(times, dtype=np.float64)
        t_end = float(ts[-1])
    sol = scipy_l2.simulate(m, m.state_from_library(np.asarray(z0), np.asarray(zd0)), ts,
                            "DOP853", rtol, atol)
    if sol.status != 0:
        raise RuntimeError(f"scipy integration failed: {sol.message}")
    return ts, sol.y[9:12].T.copy(), sol.y[0:9:3].T - float(truth.sigma) * float(
        pj.derived(truth).delta1)


def noisy(ts, X, th, noise_pos: float, noise_phi: float, noise_th: float, seed: int,
          name: str = "independent"):
    """An `Experiment` of the samples with Gaussian noise (seeded) on x, y (m), phi (rad) and
    the actuated angles (rad)."""
    rng = np.random.default_rng(seed)
    Xn = X.copy()
    Xn[:, :2] += noise_pos * rng.standard_normal((len(ts), 2))
    Xn[:, 2] += noise_phi * rng.standard_normal(len(ts))
    thn = th + noise_th * rng.standard_normal(th.shape) if noise_th else th
    return pj.experiment(ts, Xn, th=thn, name=f"{name} seed {seed}")
