"""Paths and command logs (`ppr_jax._paths`): `Line` against its closed-form quintic, `Waypoints`
against scipy's `CubicSpline`, `Fourier` against the hand-written series, the CSV loaders against
the spline of the SI samples, every refused input with its line and cause, the inverse kinematics
along a path, and derivatives with respect to the samples against finite differences."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.interpolate import CubicSpline

import ppr_jax as pj
from ppr_jax import DataError

CENTER = np.array([0.45, 0.26, 0.0])


def _d3(path, ts):
    """(X, X', X'') (m, 3) each at times ts, by `derivatives` under vmap."""
    return jax.vmap(lambda t: pj.derivatives(path, t))(jnp.asarray(ts, dtype=jnp.float64))


def _figure_eight(n=41, T=2.0):
    """A figure-eight around the workspace centre, within 40 mm and 0.04 rad (SI)."""
    ts = np.linspace(0.0, T, n)
    w = 2 * np.pi / T
    X = CENTER + np.column_stack([0.04 * np.sin(w * ts), 0.02 * np.sin(2 * w * ts),
                                  0.04 * np.sin(w * ts) * np.cos(w * ts)])
    return ts, X


# ---------------------------------------------------------------------------------------------
# Line


def test_line_matches_the_closed_form_quintic():
    start = np.array([0.42, 0.25, -0.02])
    end = np.array([0.48, 0.28, 0.03])
    T = 1.3
    path = pj.Line(start, end, T)
    ts = np.array([-0.4, 0.0, 0.1, 0.37, 0.65, 1.0, 1.29, T, 1.8])
    X, Xd, Xdd = (np.asarray(v) for v in _d3(path, ts))
    u = np.clip(ts / T, 0, 1)[:, None]
    inside = ((ts > 0) & (ts < T))[:, None]
    s = 10 * u**3 - 15 * u**4 + 6 * u**5
    sd = np.where(inside, 30 * u**2 * (1 - u) ** 2 / T, 0.0)
    sdd = np.where(inside, 60 * u * (1 - u) * (1 - 2 * u) / T**2, 0.0)
    D = end - start
    np.testing.assert_allclose(X, start + s * D, rtol=0, atol=1e-15)
    np.testing.assert_allclose(Xd, sd * D, rtol=0, atol=1e-15)
    np.testing.assert_allclose(Xdd, sdd * D, rtol=0, atol=1e-14)
    # rest to rest: the end poses exactly, no velocity or acceleration at the ends
    np.testing.assert_array_equal(X[1], start)
    np.testing.assert_array_equal(X[-2], end)
    assert np.all(Xd[[0, 1, -2, -1]] == 0) and np.max(np.abs(Xdd[[0, 1, -2, -1]])) < 1e-16


def test_line_refuses_bad_arguments():
    with pytest.raises(DataError, match="duration must be positive"):
        pj.Line(CENTER, CENTER, 0.0)
    with pytest.raises(DataError, match=r"poses \(3,\)"):
        pj.Line(CENTER[:2], CENTER, 1.0)


# ---------------------------------------------------------------------------------------------
# Waypoints


@pytest.fixture(scope="module")
def uneven():
    rng = np.random.default_rng(3)
    ts = np.cumsum(rng.uniform(0.03, 0.3, 15)) - 0.2
    P = CENTER + rng.normal(scale=[0.02, 0.02, 0.02], size=(15, 3))
    return ts, P


@pytest.mark.parametrize("bc", ["clamped", "natural"])
def test_waypoints_match_scipy_cubic_spline(uneven, bc):
    ts, P = uneven
    path = pj.Waypoints(ts, P, bc)
    ref = CubicSpline(ts, P, bc_type=bc, axis=0)
    tt = np.concatenate([ts, np.linspace(ts[0], ts[-1], 97)])
    got = [np.asarray(v) for v in _d3(path, tt)]
    for d in range(3):
        want = ref(tt, d)
        err = np.max(np.abs(got[d] - want)) / np.max(np.abs(want))
        assert err < 1e-12, (bc, d, err)
    if bc == "clamped":
        assert np.max(np.abs(got[1][[0, len(ts) - 1]])) < 1e-13  # at rest at the ends
    else:
        assert np.max(np.abs(got[2][[0, len(ts) - 1]])) < 1e-10  # no acceleration at the ends


@pytest.mark.parametrize("bc", ["clamped", "natural"])
def test_waypoints_are_c2_at_the_knots(uneven, bc):
    ts, P = uneven
    path = pj.Waypoints(ts, P, bc)
    knots = ts[1:-1]
    right = _d3(path, knots)  # the piece starting at the knot
    left = _d3(path, np.nextafter(knots, -np.inf))  # the piece ending there
    for d, tol in ((0, 1e-13), (1, 1e-11), (2, 1e-9)):
        scale = np.max(np.abs(right[d]))
        assert np.max(np.abs(left[d] - right[d])) <= tol * scale, d
    # and the third derivative does jump: the knots are really knots
    third = jax.vmap(jax.jacfwd(lambda t: pj.derivatives(path, t)[2]))
    assert np.max(np.abs(third(jnp.asarray(knots)) - third(jnp.asarray(
        np.nextafter(knots, -np.inf))))) > 1e-3


def test_waypoints_continue_outside_the_samples(uneven):
    ts, P = uneven
    clamped = pj.Waypoints(ts, P, "clamped")
    X, Xd, Xdd = (np.asarray(v) for v in _d3(clamped, [ts[0] - 1.0, ts[-1] + 1.0]))
    np.testing.assert_allclose(X, P[[0, -1]], rtol=0, atol=1e-15)
    assert np.all(Xd == 0) and np.all(Xdd == 0)
    natural = pj.Waypoints(ts, P, "natural")
    ref = CubicSpline(ts, P, bc_type="natural", axis=0)
    X, Xd, _ = _d3(natural, [ts[-1] + 0.5])
    np.testing.assert_allclose(X[0], P[-1] + 0.5 * ref(ts[-1], 1), rtol=1e-12)
    np.testing.assert_allclose(Xd[0], ref(ts[-1], 1), rtol=1e-12)


def test_waypoints_refuse_bad_arrays():
    ts, X = _figure_eight(8)
    bad = X.copy()
    bad[3, 1] = np.nan
    with pytest.raises(DataError, match=r"Waypoints: sample 4: NaN or infinite"):
        pj.Waypoints(ts, bad)
    t2 = ts.copy()
    t2[5] = t2[4]
    with pytest.raises(DataError, match=r"sample 6 \(t = .*\): the same time as sample 5"):
        pj.Waypoints(t2, X)
    with pytest.raises(DataError, match="unknown boundary condition"):
        pj.Waypoints(ts, X, "periodic")
    with pytest.raises(DataError, match="must be concrete"):
        jax.jit(lambda t: pj.Waypoints(t, X)(0.1))(jnp.asarray(ts))


def test_waypoints_gradient_wrt_samples_matches_finite_differences(uneven):
    ts, P = uneven
    t = 0.5 * (ts[4] + ts[5]) + 0.01
    w = jnp.asarray(np.random.default_rng(1).normal(size=9))

    def f(P):
        X, Xd, Xdd = pj.derivatives(pj.Waypoints(ts, P), t)
        return jnp.sum(w * jnp.tanh(jnp.concatenate([10 * X, Xd, 0.1 * Xdd])))

    f = jax.jit(f)  # the spline built from traced samples
    P = jnp.asarray(P)
    g_rev = jax.grad(f)(P)
    g_fwd = jax.jacfwd(f)(P)
    eps = 1e-6
    fd = np.zeros(P.shape)
    for i in range(P.shape[0]):
        for j in range(3):
            e = jnp.zeros(P.shape).at[i, j].set(eps)
            fd[i, j] = (f(P + e) - f(P - e)) / (2 * eps)
    scale = np.max(np.abs(fd))
    assert scale > 1e-3 and np.count_nonzero(np.abs(fd) > 1e-6 * scale) > 20  # not local
    np.testing.assert_allclose(g_rev, fd, rtol=0, atol=1e-7 * scale)
    np.testing.assert_allclose(g_fwd, fd, rtol=0, atol=1e-7 * scale)


# ---------------------------------------------------------------------------------------------
# Fourier


def test_fourier_matches_the_series_and_its_derivatives():
    rng = np.random.default_rng(2)
    mean = CENTER
    A = rng.normal(scale=0.01, size=(3, 3))
    B = rng.normal(scale=0.01, size=(3, 3))
    w = 1.7
    path = pj.Fourier(mean, A, B, w)
    ts = np.array([0.0, 0.3, 1.1, 2.9, -0.7])
    X, Xd, Xdd = _d3(path, ts)
    x, xd, xdd = np.tile(mean, (len(ts), 1)), np.zeros((len(ts), 3)), np.zeros((len(ts), 3))
    for k in (1, 2, 3):
        c, s = np.cos(k * w * ts)[:, None], np.sin(k * w * ts)[:, None]
        x = x + A[k - 1] * c + B[k - 1] * s
        xd = xd + k * w * (-A[k - 1] * s + B[k - 1] * c)
        xdd = xdd - (k * w) ** 2 * (A[k - 1] * c + B[k - 1] * s)
    np.testing.assert_allclose(X, x, rtol=0, atol=1e-15)
    np.testing.assert_allclose(Xd, xd, rtol=0, atol=1e-14)
    np.testing.assert_allclose(Xdd, xdd, rtol=0, atol=1e-13)
    # periodic, and K = 0 is the constant mean
    np.testing.assert_allclose(path(0.4 + 2 * np.pi / w), path(0.4), rtol=0, atol=1e-15)
    np.testing.assert_array_equal(pj.Fourier(mean, np.zeros((0, 3)), np.zeros((0, 3)), w)(1.0),
                                  mean)


def test_fourier_refuses_bad_shapes():
    with pytest.raises(DataError, match=r"cos and sin \(K, 3\)"):
        pj.Fourier(CENTER, np.zeros((2, 3)), np.zeros((3, 3)), 1.0)
    with pytest.raises(DataError, match="omega must be positive"):
        pj.Fourier(CENTER, np.zeros((1, 3)), np.zeros((1, 3)), -1.0)


# ---------------------------------------------------------------------------------------------
# every path under jit and vmap, and along the robot's inverse kinematics


def _paths():
    ts, X = _figure_eight()
    return {
        "line": pj.Line(CENTER + [-0.03, -0.02, -0.03], CENTER + [0.04, 0.03, 0.04], 1.5),
        "waypoints": pj.Waypoints(ts, X),
        "fourier": pj.Fourier(CENTER, [[0.03, 0.0, 0.0], [0.0, 0.01, 0.0]],
                              [[0.0, 0.03, 0.04], [0.0, 0.0, 0.0]], 2.0),
    }


@pytest.mark.parametrize("name", ["line", "waypoints", "fourier"])
def test_paths_under_jit_and_vmap(name):
    path = _paths()[name]
    tt = np.linspace(-0.1, 2.1, 23)
    jitted = jax.jit(jax.vmap(lambda t: pj.derivatives(path, t)))(jnp.asarray(tt))
    for i, t in enumerate(tt):
        eager = pj.derivatives(path, float(t))
        for a, b in zip(jitted, eager):
            np.testing.assert_allclose(a[i], b, rtol=1e-14, atol=1e-15)
    # a path is a pytree of arrays: it crosses jit as an argument
    call = jax.jit(lambda p, t: p(t))
    np.testing.assert_allclose(call(path, 0.7), path(0.7), rtol=1e-14)


@pytest.mark.parametrize("name", ["line", "waypoints"])
def test_inverse_kinematics_along_a_non_circular_path(robot, name):
    path = _paths()[name]
    tt = jnp.asarray([0.0, 0.35, 0.8, 1.2, 1.5])
    X = jax.vmap(path)(tt)
    assert np.max(np.abs(np.asarray(X) - CENTER)) <= 0.05
    res = pj.inverse_kinematics(robot, X)
    assert np.all(np.asarray(res.margin) > 0) and np.all(np.asarray(res.singularity) > 0.05)
    # the round trip through a second formulation, with no program to compile: forward
    # kinematics by scipy's root finder on the NumPy L1's closed-form inverse kinematics
    # (benchmarks/contenders/scipy_l2.py), from the workspace centre, gives the poses back
    import scipy.optimize

    from benchmarks.contenders import scipy_l2

    model = scipy_l2.L2Model(robot.params, None)
    th = np.asarray(res.th_a)
    for i in range(X.shape[0]):
        sol = scipy.optimize.root(lambda x: model.l1_angles(x) - th[i], CENTER, tol=1e-14)
        assert np.abs(model.l1_angles(sol.x) - th[i]).max() < 1e-13, sol.message
        np.testing.assert_allclose(sol.x, X[i], rtol=0, atol=1e-11)
    # the actuated angles along the path, with their rates, through derivatives
    angles = pj.InverseKinematicsAngles(pj.Reduced(), robot, path)
    th, thd, thdd = pj.derivatives(angles, 0.8)
    np.testing.assert_allclose(th, res.th_a[2], rtol=0, atol=1e-10)
    assert np.all(np.isfinite(thd)) and np.all(np.isfinite(thdd))
    _, Xd, _ = pj.derivatives(path, 0.8)
    np.testing.assert_allclose(thd, res.S[2] @ Xd, rtol=1e-8, atol=1e-12)


# ---------------------------------------------------------------------------------------------
# CSV files


def _write(path, header, rows, comments=()):
    with open(path, "w") as f:
        for c in comments:
            f.write(f"# {c}\n")
        f.write(header + "\n")
        for r in rows:
            f.write(",".join(r if isinstance(r, str) else f"{v:.17g}" for v in r) + "\n")
    return str(path)


def _pose_rows_mm_deg(ts, X):
    return np.column_stack([ts, X[:, 0] * 1e3, X[:, 1] * 1e3, np.degrees(X[:, 2])])


def test_load_path_in_mm_and_deg_is_the_spline_of_the_si_samples(tmp_path):
    ts, X = _figure_eight(51)
    f = _write(tmp_path / "eight.csv", "time,x,y,phi", _pose_rows_mm_deg(ts, X),
               comments=["figure eight", "units: time=s, length=mm, angle=deg"])
    path = pj.load_path(f, bc="clamped")
    assert isinstance(path, pj.Waypoints) and path.name == "eight.csv" and path.bc == "clamped"
    ref = CubicSpline(ts, X, bc_type="clamped", axis=0)
    tt = np.linspace(0, ts[-1], 37)
    got = _d3(path, tt)
    for d in range(3):
        want = ref(tt, d)
        assert np.max(np.abs(got[d] - want)) <= 1e-12 * np.max(np.abs(want)), d
    # the same file with units in the column names, natural ends
    g = _write(tmp_path / "eight2.csv", "t[s],x[mm],y[mm],phi[deg]", _pose_rows_mm_deg(ts, X))
    nat = pj.load_path(g, bc="natural")
    ref = CubicSpline(ts, X, bc_type="natural", axis=0)
    np.testing.assert_allclose(jax.vmap(nat)(jnp.asarray(tt)), ref(tt), rtol=1e-12, atol=1e-15)


def test_load_commands_angles_and_torques(tmp_path):
    ts = np.linspace(0, 1, 21)
    th = np.column_stack([0.5 + 0.1 * np.sin(3 * ts), 2.6 + 0.05 * ts, -1.6 + 0.02 * ts**2])
    f = _write(tmp_path / "angles.csv", "time,th_1[deg],th_2[deg],th_3[deg]",
               np.column_stack([ts, np.degrees(th)]))
    log = pj.load_commands(f, bc="clamped")
    assert log.kind == "angles" and log.name == "angles.csv"
    np.testing.assert_allclose(jax.vmap(log)(jnp.asarray(ts)), th, rtol=1e-13)
    act = log.actuation()
    assert isinstance(act, pj.MotionDriven) and act.prescribes_angles
    ref = CubicSpline(ts, th, bc_type="clamped", axis=0)
    a, ad, add = act.angles_at(0.43)
    for d, got in enumerate((a, ad, add)):
        np.testing.assert_allclose(got, ref(0.43, d), rtol=1e-11, atol=1e-13)
    servo = log.actuation(Kp=20.0, Kd=0.5)
    assert isinstance(servo, pj.PDServo)
    np.testing.assert_allclose(servo.torque_at(0.43, a - 0.01, ad), 20.0 * 0.01, rtol=1e-12)

    tau = np.column_stack([0.1 * np.cos(ts), -0.2 * ts, 0.05 + 0 * ts])
    g = _write(tmp_path / "torques.csv", "time,tau_1[Nmm],tau_2[Nmm],tau_3[Nmm]",
               np.column_stack([ts, tau * 1e3]))
    tlog = pj.load_commands(g, bc="clamped")
    act = tlog.actuation()
    assert tlog.kind == "torque" and isinstance(act, pj.TorqueDriven)
    np.testing.assert_allclose(act.torque_at(0.43, None, None),
                               CubicSpline(ts, tau, bc_type="clamped", axis=0)(0.43), rtol=1e-12)
    with pytest.raises(DataError, match="servo gains apply to an angle log"):
        tlog.actuation(Kp=1.0, Kd=0.1)
    # a file with both: kind picks
    h = _write(tmp_path / "both.csv", "time,th_1,th_2,th_3,tau_1,tau_2,tau_3",
               np.column_stack([ts, th, tau]))
    with pytest.raises(DataError, match="both.csv: the file holds both.*kind="):
        pj.load_commands(h)
    assert pj.load_commands(h, kind="torque").kind == "torque"


def test_loaders_choose_the_ends_the_file_calls_for(tmp_path):
    """`bc="auto"`, the loaders' default: a file that starts and ends moving (the figure eight,
    sin(w t) at t = 0) is splined with natural ends, as scipy's natural spline; a move that
    starts and ends at rest (a quintic ramp; one column constant) with clamped ends, as
    scipy's clamped spline; a torque log likewise by its rate. An unknown `bc` is refused
    before the file is read, naming the allowed values."""
    ts, X = _figure_eight(51)
    f = _write(tmp_path / "eight.csv", "time,x[mm],y[mm],phi[deg]", _pose_rows_mm_deg(ts, X))
    nat = pj.load_path(f)
    assert nat.bc == "natural" and pj.end_condition(ts, X) == "natural"
    tt = np.linspace(0, ts[-1], 29)
    np.testing.assert_allclose(jax.vmap(nat)(jnp.asarray(tt)),
                               CubicSpline(ts, X, bc_type="natural", axis=0)(tt),
                               rtol=1e-12, atol=1e-15)
    s = ts / ts[-1]
    ramp = CENTER + np.column_stack([0.03 * (10 * s**3 - 15 * s**4 + 6 * s**5),
                                     0.0 * s, 0.02 * (10 * s**3 - 15 * s**4 + 6 * s**5)])
    g = _write(tmp_path / "ramp.csv", "time,x[mm],y[mm],phi[deg]", _pose_rows_mm_deg(ts, ramp))
    clamped = pj.load_path(g)
    assert clamped.bc == "clamped" and pj.end_condition(ts, ramp) == "clamped"
    np.testing.assert_allclose(jax.vmap(clamped)(jnp.asarray(tt)),
                               CubicSpline(ts, ramp, bc_type="clamped", axis=0)(tt),
                               rtol=1e-12, atol=1e-15)
    # a torque log cut out of a motion (its rate at both ends) and one that holds still there
    tau = np.column_stack([0.1 * np.cos(3 * ts), 0 * ts, 0 * ts])
    h = _write(tmp_path / "tau.csv", "time,tau_1,tau_2,tau_3", np.column_stack([ts, tau]))
    assert pj.load_commands(h).spline.bc == "natural"
    assert pj.load_commands(h, bc="clamped").spline.bc == "clamped"
    assert pj.end_condition(ts, 0 * tau) == "clamped"  # nothing moves: at rest
    for loader in (pj.load_path, pj.load_commands):
        with pytest.raises(DataError, match=r"missing.csv: unknown boundary condition "
                                            r"bc='free'; allowed: auto, clamped, natural"):
            loader(str(tmp_path / "missing.csv"), bc="free")


def test_check_same_rate(tmp_path):
    ts, X = _figure_eight(51)  # 25 Hz
    poses = pj.load_path(_write(tmp_path / "poses.csv", "time,x[mm],y[mm],phi[deg]",
                                _pose_rows_mm_deg(ts, X)))
    t2 = np.linspace(0, 2, 101)  # 50 Hz
    tau = _write(tmp_path / "tau.csv", "time,tau_1,tau_2,tau_3",
                 np.column_stack([t2, 0 * t2, 0 * t2, 0 * t2]))
    same = _write(tmp_path / "tau25.csv", "time,tau_1,tau_2,tau_3",
                  np.column_stack([ts, 0 * ts, 0 * ts, 0 * ts]))
    assert pj.check_same_rate(poses, pj.load_commands(same)) == pytest.approx(0.04)
    with pytest.raises(DataError, match=r"poses.csv is sampled at 25 Hz .* but tau.csv at 50 Hz"):
        pj.check_same_rate(poses, pj.load_commands(tau))


# Each refused input: (file name, header, rows as a function of the good rows, loader options,
# the expected message). The good file: a comment line and the header, so sample i (0-based)
# is on line i + 3.
_GOOD_TS, _GOOD_X = _figure_eight(41)
_GOOD = _pose_rows_mm_deg(_GOOD_TS, _GOOD_X)


def _edit(i, j, value):
    def f(rows):
        rows = rows.copy()
        rows[i, j] = value
        return rows
    return f


def _angles(rows):
    """An angle log (rad) with the pose file's times."""
    one = np.ones_like(rows[:, 0])
    return np.column_stack([rows[:, 0], 0.5 + 0.1 * rows[:, 1] / 1e3, 2.6 * one, -1.6 * one])


BAD = {
    "duplicated time": ("path", _edit(10, 0, _GOOD[9, 0]),
                        r"bad.csv: line 13 \(t = 0\.45 s\): the same time as line 12"),
    "decreasing time": ("path", _edit(10, 0, 0.1),
                        r"bad.csv: line 13 \(t = 0\.1 s\): an earlier time than line 12 "
                        r"\(t = 0\.45 s\); times must be strictly increasing"),
    "gap": ("path", lambda r: np.delete(r, np.s_[20:35], axis=0),
            r"bad.csv: line 23 \(t = 1\.75 s\): gap of 0\.8 s after line 22 \(t = 0\.95 s\), "
            r"more than 10 times the median time step 0\.05 s"),
    "nan": ("path", _edit(7, 2, np.nan), r"bad.csv: line 10: NaN, empty or infinite"),
    "inf": ("path", _edit(30, 3, np.inf), r"bad.csv: line 33: NaN, empty or infinite"),
    "too few samples": ("path", lambda r: r[:3],
                        r"bad.csv: too few samples: 3; a C2 cubic spline.* at least 4"),
    "pose far outside the workspace": (
        "path", _edit(17, 1, 450e3),
        r"bad.csv: line 20 \(t = 0\.85 s\): the platform position is 450 m from the base "
        r"origin.*millimetres read as metres"),
    "rotation beyond pi/2": (
        "path", _edit(5, 3, 120.0),
        r"bad.csv: line 8 \(t = 0\.25 s\): platform rotation \|phi\| reaches 2\.094 rad"),
    "a stray pose": (
        "path", _edit(17, 1, _GOOD[17, 1] + 500.0),
        r"bad.csv: line 20 \(t = 0\.85 s\): a stray pose, 50\d\.?\d* mm off the line between "
        r"its neighbours \(lines 19 and 21\)"),
    "a stray rotation": (
        "path", _edit(30, 3, _GOOD[30, 3] + 20.0),
        r"bad.csv: line 33 \(t = 1\.5 s\): a stray pose, 0\.3\d* rad off"),
    "angles in degrees read as radians": (
        "angles", lambda r: _edit(12, 2, 150.0)(_angles(r)),
        r"bad.csv: line 15 \(t = 0\.6 s\): actuated angle 150 rad, beyond two turns: probably "
        r"degrees read as radians"),
    "wrapped angle": (
        "angles", lambda r: _edit(np.s_[25:], 3, -3.1)(_edit(np.s_[:25], 3, 3.1)(_angles(r))),
        r"bad.csv: line 28 \(t = 1\.25 s\): an actuated angle jumps by 6\.2 rad from line 27: "
        r"wrapped at \+-pi\? unwrap it"),
    "commands without angles or torques": (
        "commands-none", lambda r: r, r"bad.csv: a command log needs columns th_1, th_2, th_3"),
}


@pytest.mark.parametrize("cause", list(BAD))
def test_bad_files_raise_data_error_naming_line_and_cause(tmp_path, cause):
    kind, rows, message = BAD[cause]
    header = {"path": "time,x[mm],y[mm],phi[deg]", "angles": "time,th_1,th_2,th_3",
              "commands-none": "time,x[mm],y[mm],phi[deg]"}[kind]
    f = _write(tmp_path / "bad.csv", header, rows(_GOOD), comments=["a log"])
    load = pj.load_path if kind == "path" else pj.load_commands
    with pytest.raises(DataError, match=message):
        load(f)


def test_gap_check_can_be_turned_off_for_uneven_waypoints(tmp_path):
    rows = np.delete(_GOOD, np.s_[20:35], axis=0)
    f = _write(tmp_path / "uneven.csv", "time,x[mm],y[mm],phi[deg]", rows)
    path = pj.load_path(f, max_gap=None)
    np.testing.assert_allclose(path(rows[22, 0]), _GOOD_X[37], rtol=1e-13)


def test_loaders_keep_the_reader_s_checks(tmp_path):
    f = _write(tmp_path / "cols.csv", "time,x,y", _GOOD[:, :3])
    with pytest.raises(DataError, match=r"cols.csv: missing column\(s\) phi"):
        pj.load_path(f)
    g = _write(tmp_path / "cmd.csv", "time,th_1,th_2", _GOOD[:, :3])
    with pytest.raises(DataError, match="th_1, th_2, th_3 come as a set of three"):
        pj.load_commands(g)
    with pytest.raises(DataError, match="no such file"):
        pj.load_commands(str(tmp_path / "missing.csv"))
    assert math.isclose(pj.load_path(_write(tmp_path / "ok.csv", "time,x[mm],y[mm],phi[deg]",
                                            _GOOD)).ts[-1], 2.0)


def test_a_command_log_drives_a_scene_of_ones_own(tmp_path, robot):
    """Angles of L1's inverse kinematics along a `Line`, written as a controller's log and loaded
    back, drive a scene (motion-driven L1): the platform follows the line."""
    line = pj.Line([0.42, 0.25, -0.02], [0.48, 0.28, 0.03], 1.0)
    tt = np.linspace(0.0, 1.0, 201)
    th = np.asarray(pj.inverse_kinematics(robot, jax.vmap(line)(jnp.asarray(tt))).th_a)
    log = pj.load_commands(_write(tmp_path / "log.csv", "time,th_1[deg],th_2[deg],th_3[deg]",
                                  np.column_stack([tt, np.degrees(th)])))

    scene = pj.PathScene(line, drive="motion", command_log=log, name="log")
    res = pj.solve_scene(scene, model="reduced", options=pj.SceneOptions(t_end=1.0, n_out=13))
    assert res.ok
    err = np.abs(np.asarray(res.X) - np.asarray(jax.vmap(line)(res.ts))).max()
    assert err < 1e-8, err  # output times between the log's samples: the spline's error
    assert np.abs(np.asarray(res.X[-1] - res.X[0])).max() > 0.02


# ---------------------------------------------------------------------------------------------
# Scenes on a path read from a file


def _eight_file(tmp_path, hz=20):
    """The figure eight sampled at `hz` over 2 s, written in mm and deg."""
    ts, X = _figure_eight(int(round(2.0 * hz)) + 1)
    return _write(tmp_path / f"eight_{hz}.csv", "time,x[mm],y[mm],phi[deg]",
                  _pose_rows_mm_deg(ts, X))


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_torque_driven_scene_on_a_loaded_spline_runs_at_defaults(tmp_path):
    """A `PathScene` on a non-circular path read with `load_path` (a C2 spline through 20 Hz
    samples, clamped: its torques have a kink at every knot), torque-driven, runs at the scene
    defaults (L1, 7.54 s, 755 outputs): the input table has panel boundaries at the knots and
    the integrator steps to them. L1 driven by its own inverse-dynamics torques follows the
    path during the move (open loop, so the gap is the integration's and the table's: 2e-8 m
    over the 2 s of samples, 7e-7 m when the integrator stepped across the knots); in the
    hold after it the open-loop gap grows by about e^(1.5 t) (4e-6 m at 7.54 s)."""
    path = pj.load_path(_eight_file(tmp_path), bc="clamped")
    rep = pj.run_scene(pj.PathScene(path, drive="torque"))
    r = rep.result
    assert r.ok and r.X.shape == (755, 3)
    move = np.asarray(r.ts) <= 2.0
    gap = float(np.abs(np.asarray(r.X) - np.asarray(r.X_nominal))[move].max())
    assert gap < 1e-7, gap
    assert float(np.abs(np.asarray(r.X_nominal[40]) - np.asarray(r.X_nominal[0])).max()) > 0.01


@pytest.mark.slow
def test_torque_driven_spline_scene_matches_the_scipy_l2(tmp_path):
    """L2 (`double1r`) torque-driven along the loaded figure eight (natural ends) over 0.4 s at
    default tolerances, against the independent scipy L2 (benchmarks/contenders/scipy_l2.py:
    absolute coordinates and Lagrange multipliers) driven by the exact inverse-dynamics torques
    (not the library's table) from the library's initial state: the platform paths agree to
    the integration error. Slow: L2 compiles in 20-30 s."""
    from benchmarks.contenders import library, scipy_l2

    path = pj.load_path(_eight_file(tmp_path), bc="natural")
    params = pj.scene_params("paper-circle")
    r = pj.run_scene(
        pj.PathScene(path, drive="torque"),
        params,
        model="double1r",
        options=pj.SceneOptions(t_end=0.4, n_out=41),
    ).result
    fn = library.scene_torque_fn(params, path)
    exact = jax.jit(lambda t: fn(t))
    out = scipy_l2.run(params, method="DOP853", rtol=1e-11, atol=1e-13, t_end=0.4, n_out=41,
                       repeats=1, z0=r.z[0], zdot0=r.zdot[0],
                       torque=lambda t: np.asarray(exact(jnp.asarray(t, dtype=jnp.float64))))
    assert out["status"] == 0
    pos = np.linalg.norm(out["X"][:, :2] - np.asarray(r.X)[:, :2], axis=1)
    assert pos.max() < 1e-8, pos.max()
    assert np.abs(out["X"][:, 2] - np.asarray(r.X)[:, 2]).max() < 1e-7
    # the robot left the path (L2 is not the torques' L1), so the agreement is not trivial
    assert np.abs(np.asarray(r.X) - np.asarray(r.X_nominal)).max() > 1e-5


def test_a_path_too_long_for_its_input_table_is_refused_before_compiling(tmp_path,
                                                                          monkeypatch):
    """A path whose input table would hold a panel per sample beyond `MAX_BREAKS` (a file of
    1e6 samples asked XLA for 54 GB after 97 s of compiling) is refused while tracing, naming
    its samples and the limit (here with the limit lowered to 10, on 21 samples)."""
    import ppr_jax._tabulated as tab

    monkeypatch.setattr(tab, "MAX_BREAKS", 10)
    ts = np.linspace(0.0, 0.2, 21)
    s = ts / 0.2
    X = np.stack([0.45 + 0.01 * s, 0.26 + 0.0 * s, 0.0 * s], axis=1)
    f = tmp_path / "long.csv"
    f.write_text("time[s],x[m],y[m],phi[rad]\n" + "".join(
        ",".join(repr(float(v)) for v in (t, *x)) + "\n" for t, x in zip(ts, X)))
    scene = pj.PathScene(pj.load_path(str(f)), drive="torque")
    with pytest.raises(pj.PPRError, match="21 samples.*at most 10 samples"):
        pj.solve_scene(scene, model="rigid", options=pj.SceneOptions(t_end=0.2, n_out=3))


def test_not_a_knot_spline_is_scipys():
    """`Waypoints(bc="not-a-knot")` against scipy's `CubicSpline` (its default ends) on uneven
    samples: values and second derivatives up to the ends, and outside them the end pieces
    continued (the quasi-static start's stencil reads them)."""
    from scipy.interpolate import CubicSpline

    ts = np.sort(np.random.default_rng(3).uniform(0.0, 2.0, 12))
    ys = np.stack([np.sin(ts), np.cos(2 * ts), ts**3], axis=1)
    w = pj.Waypoints(ts, ys, bc="not-a-knot")
    cs = CubicSpline(ts, ys, bc_type="not-a-knot", extrapolate=True)
    tt = np.concatenate([np.linspace(ts[0], ts[-1], 200), [ts[0] - 0.01, ts[-1] + 0.01]])
    got = np.asarray(jax.vmap(w)(jnp.asarray(tt)))
    np.testing.assert_allclose(got, cs(tt), rtol=0, atol=1e-13)
    acc = np.asarray(jax.vmap(lambda t: pj.derivatives(w, t)[2])(jnp.asarray(tt)))
    np.testing.assert_allclose(acc, cs(tt, 2), rtol=0, atol=1e-10)
    with pytest.raises(pj.DataError, match="samples"):
        pj.Waypoints(ts[:2], ys[:2], bc="not-a-knot")


def test_command_log_header_declares_its_spline(tmp_path):
    """A log whose header says `# spline: not-a-knot` (what `compensate` writes) is splined so
    under bc="auto"; an unknown spline name is refused naming the file."""
    ts = np.linspace(0.0, 1.0, 21)
    rows = "\n".join(f"{t:.17g},{np.sin(t):.17g},{np.cos(t):.17g},{t:.17g}" for t in ts)
    good = tmp_path / "a.csv"
    good.write_text(f"# spline: not-a-knot\ntime,th_1,th_2,th_3\n{rows}\n")
    assert pj.load_commands(str(good)).spline.bc == "not-a-knot"
    assert pj.load_commands(str(good), bc="natural").spline.bc == "natural"
    bad = tmp_path / "b.csv"
    bad.write_text(f"# spline: akima\ntime,th_1,th_2,th_3\n{rows}\n")
    with pytest.raises(pj.DataError, match="b.csv.*akima"):
        pj.load_commands(str(bad))
