"""The implicit integration path (issue 31): the stage root finder, the PI controller and
Kvaerno5 on a stiff problem, through the same solver machinery as the scenes (`get_solver`,
`default_controller`)."""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

import ppr_jax as pj
from ppr_jax._scenes._solver_choice import choose_solver
from ppr_jax._simulate import StageChord, default_controller, get_solver
from tests.helpers import suite_program_dir


class _Recorder(diffrax.PIDController):
    """A PID controller that reports, for every attempted step, whether the solver's error
    estimate was infinite (a failed stage solve) and whether the step was kept."""

    def adapt_step_size(self, t0, t1, y0, y1_candidate, args, y_error, error_order, state):
        out = super().adapt_step_size(t0, t1, y0, y1_candidate, args, y_error, error_order,
                                      state)
        failed = jnp.any(jnp.stack([jnp.any(~jnp.isfinite(e))
                                    for e in jax.tree_util.tree_leaves(y_error)]))
        jax.debug.callback(_LOG.append_step, failed, out[0], ordered=True)
        return out


class _Log:
    def __init__(self):
        self.steps = []

    def append_step(self, failed, kept):
        self.steps.append((bool(failed), bool(kept)))


_LOG = _Log()


def _solve(vf, y0, t1, solver, controller, dt0=None, ts=None):
    return diffrax.diffeqsolve(
        diffrax.ODETerm(vf), solver, 0.0, t1, dt0, y0,
        saveat=diffrax.SaveAt(ts=ts) if ts is not None else diffrax.SaveAt(t1=True),
        stepsize_controller=controller, max_steps=100_000,
    )


@pytest.mark.parametrize("name, max_steps",
                         [("kvaerno5", 300), ("kvaerno5-kept", 300), ("ros34pw2", 400)])
def test_stiff_forced_oscillator_matches_the_closed_form(name, max_steps):
    """x'' = -w^2 (x - sin t), w = 2 pi 300 Hz, started on the forced response
    x = w^2 / (w^2 - 1) sin t (no free vibration), through `get_solver` and
    `default_controller`: the stiff path takes steps set by the slow forcing, far beyond the
    explicit stability limit (about 3 / w = 1.6 ms; Tsit5 needs about 2,000 steps here),
    rejects few, and matches the closed form at the output times (dense output between
    steps)."""
    w = 2 * np.pi * 300.0
    a = w**2 / (w**2 - 1)

    def vf(t, y, args):
        x, v = y
        return v, -(w**2) * (x - jnp.sin(t))

    ts = jnp.linspace(0.0, 1.0, 101)
    solver = get_solver(name)
    sol = _solve(vf, (jnp.asarray(0.0), jnp.asarray(a)), 1.0, solver,
                 default_controller(solver, 1e-6, 1e-9), ts=ts)
    steps, rejected = int(sol.stats["num_steps"]), int(sol.stats["num_rejected_steps"])
    np.testing.assert_allclose(sol.ys[0], a * np.sin(ts), atol=2e-6)
    # the velocity (about 1 m/s) is held to rtol 1e-6 per step
    np.testing.assert_allclose(sol.ys[1], a * np.cos(ts), atol=2e-5)
    assert steps < max_steps, steps
    assert rejected <= 0.15 * steps, (steps, rejected)


def test_stage_root_finder_iterates_on_while_the_chord_converges():
    """A chord iteration that contracts by about 0.05 per iterate from a first correction 1e6
    tolerances long: diffrax 0.7.2's VeryChord (and optimistix 0.1.0's Chord) report
    divergence after the second iterate here; StageChord converges to the root."""

    def fn(y, args):
        return y - 0.05 * jnp.sin(y) - 1000.0

    rf = StageChord(rtol=1e-8, atol=1e-8, norm=optx.max_norm, max_steps=20)
    sol = optx.root_find(fn, rf, jnp.asarray(0.0), max_steps=20, throw=False)
    assert sol.result == optx.RESULTS.successful
    assert abs(float(fn(sol.value, None))) < 1e-6  # kappa (atol + rtol |y|) = 1e-7
    assert int(sol.stats["num_steps"]) > 2


def test_stage_root_finder_reports_a_stalled_iteration():
    """arctan(y) = 1.5 from y = 0 with the Jacobian frozen there: the chord crawls (rate near 1)
    and cannot converge in the iterations allowed, which must be reported, not returned as
    a root."""

    def fn(y, args):
        return jnp.arctan(y) - 1.5

    rf = StageChord(rtol=1e-8, atol=1e-8, norm=optx.max_norm, max_steps=10)
    sol = optx.root_find(fn, rf, jnp.asarray(0.0), max_steps=10, throw=False)
    assert sol.result != optx.RESULTS.successful


@pytest.mark.parametrize("make", [
    lambda: diffrax.Kvaerno5(
        root_finder=diffrax.with_stepsize_controller_tols(StageChord)(max_steps=3),
        root_find_max_steps=3),
    lambda: pj.KeptKvaerno5(root_find_max_steps=3),
], ids=["kvaerno5", "kvaerno5-kept"])
def test_a_failed_implicit_step_is_rejected_never_accepted(make):
    """diffrax #752 class: a step whose stage solve fails must be retried shorter, never kept.
    A stiff pendulum-like oscillator, x'' = -w^2 sin(x - sin t) (strongly nonlinear at the
    amplitudes a too-long first step reaches), with a first step of 0.5 s, at most 3
    iterations per stage: the first attempts fail their stage solves (KeptKvaerno5's with a
    fresh Jacobian too). Every such step must be rejected, and the run must still succeed and
    agree with Tsit5."""
    w = 2 * np.pi * 20.0

    def vf(t, y, args):
        x, v = y
        return v, -(w**2) * jnp.sin(x - jnp.sin(t)) - 5.0 * v

    y0 = (jnp.asarray(1.0), jnp.asarray(0.0))
    _LOG.steps = []
    ctrl = _Recorder(rtol=1e-6, atol=1e-9, pcoeff=0.2, icoeff=0.4)
    sol = _solve(vf, y0, 1.0, make(), ctrl, dt0=0.5)
    ref = _solve(vf, y0, 1.0, diffrax.Tsit5(), diffrax.PIDController(rtol=1e-10, atol=1e-12))
    failed = [kept for f, kept in _LOG.steps if f]
    assert len(failed) > 0, "the test must exercise a failed stage solve"
    assert not any(failed), "a step with a failed stage solve was accepted"
    assert sol.result == diffrax.RESULTS.successful
    np.testing.assert_allclose(sol.ys[0][-1], ref.ys[0][-1], atol=1e-4)


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_kvaerno5_rejects_few_steps_on_l2_servo_circle():
    """L2 `double1r` on `servo-circle`, t = 4 mm (modes up to 355 Hz) over 0.2 s, rtol 1e-6:
    with diffrax's own root finder and I controller half of Kvaerno5's steps were rejected
    (every one a failed stage solve); the library's path must reject at most 15 %."""
    p = pj.scene_params("servo-circle", t=4e-3)
    r = pj.servo_circle(p, model="double1r", solver="kvaerno5", rtol=1e-6, t_end=0.2, n_out=21)
    steps, rejected = int(r.num_steps), int(r.num_rejected)
    assert steps > 10, steps
    assert rejected <= 0.15 * steps, (steps, rejected)


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_auto_solver_follows_the_work_precision_measurements():
    """`solver="auto"` picks the solver that `benchmarks/implicit_l2.py` measured faster on the
    L2 servo-circle: Kvaerno5 at t = 4 mm for rtol 1e-3 to 1e-5 (31 against 154 ms at 1e-4),
    Tsit5 there at 1e-6 and 1e-8 (142 against 229 ms, 0.32 against 1.55 s), Tsit5 at 2 mm and
    1e-5 (44 against 89 ms) and at the paper's thicknesses; a scene run with "auto" is the run
    with the solver it names, step for step."""
    dbl = pj.Double1R()
    thick = pj.scene_params("servo-circle", t=4e-3)
    for t, rtol, want in [(4e-3, 1e-3, "kvaerno5"), (4e-3, 1e-4, "kvaerno5"),
                          (4e-3, 1e-5, "kvaerno5"), (4e-3, 1e-6, "tsit5"),
                          (4e-3, 1e-8, "tsit5"), (2e-3, 1e-5, "tsit5"), (0.5e-3, 1e-4, "tsit5"),
                          (0.3e-3, 1e-3, "tsit5")]:
        got, why = choose_solver(dbl, thick.replace(t=t), rtol, "tsit5")
        assert got == want, (t, rtol, why)
    # a batch is decided by its stiffest member
    batch = pj.stack_params([thick.replace(t=0.5e-3), thick])
    assert choose_solver(dbl, batch, 1e-4, "tsit5")[0] == "kvaerno5"
    auto = pj.servo_circle(thick, model="double1r", solver="auto", rtol=1e-4, t_end=0.2,
                           n_out=21)
    named = pj.servo_circle(thick, model="double1r", solver="kvaerno5", rtol=1e-4, t_end=0.2,
                            n_out=21)
    assert int(auto.num_steps) == int(named.num_steps) < 100
    np.testing.assert_array_equal(auto.X, named.X)


def _forced_pendulum(t, y, args):
    x, v = y
    return v, -4.0 * jnp.sin(x) - 0.3 * v + jnp.cos(3.0 * t)


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_ros34pw2_is_third_order_with_a_fresh_and_a_lagged_jacobian():
    """ROS34PW2 on a forced, damped pendulum (nonlinear and non-autonomous) with constant steps,
    against Dopri8 at rtol 1e-13: the error falls as h^3 with a Jacobian evaluated at every step
    (a Rosenbrock method) and with one kept over 4 steps (a W-method keeps its order with any
    Jacobian). A wrong coefficient, a missing f_t term or a Jacobian misused in the stages
    drops the order."""
    y0 = (jnp.asarray(0.5), jnp.asarray(0.0))
    ref = _solve(_forced_pendulum, y0, 2.0, diffrax.Dopri8(),
                 diffrax.PIDController(rtol=1e-13, atol=1e-13)).ys[0][-1]
    for every in (1, 4):
        errs = []
        for n in (20, 40, 80):
            sol = _solve(_forced_pendulum, y0, 2.0, pj.Ros34PW2(jacobian_every=every),
                         diffrax.ConstantStepSize(), dt0=2.0 / n)
            errs.append(abs(float(sol.ys[0][-1] - ref)))
        orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
        assert np.all((orders > 2.8) & (orders < 3.3)), (every, errs, orders)


def test_ros34pw2_rejects_an_invalid_jacobian_age():
    with np.testing.assert_raises(ValueError):
        pj.Ros34PW2(jacobian_every=0)


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_kept_kvaerno5_is_fifth_order_with_a_fresh_and_a_kept_jacobian():
    """KeptKvaerno5 on the forced, damped pendulum with constant steps, against Dopri8 at rtol
    1e-13: the error falls as h^5 whether the Jacobian is fresh at every step or kept over 8
    (the Newton iteration converges the stages whatever matrix drives it; only its speed
    depends on the Jacobian), and it is diffrax's Kvaerno5 (the same tableau, written apart)
    to within the stages' convergence. A wrong coefficient, a stage derivative taken from the
    wrong stage or a kept matrix misused drops the order or moves the result."""
    y0 = (jnp.asarray(0.5), jnp.asarray(0.0))
    ref = _solve(_forced_pendulum, y0, 2.0, diffrax.Dopri8(),
                 diffrax.PIDController(rtol=1e-13, atol=1e-13)).ys[0][-1]
    tight = diffrax.VeryChord(rtol=1e-13, atol=1e-13)
    for every in (1, 8):
        errs = []
        for n in (10, 20, 40):
            solver = pj.KeptKvaerno5(root_finder=tight, jacobian_every=every,
                                     refresh_rate=0.99)
            sol = _solve(_forced_pendulum, y0, 2.0, solver, diffrax.ConstantStepSize(),
                         dt0=2.0 / n)
            errs.append(abs(float(sol.ys[0][-1] - ref)))
        orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
        assert np.all((orders > 4.6) & (orders < 5.6)), (every, errs, orders)
    kv = _solve(_forced_pendulum, y0, 2.0, get_solver(diffrax.Kvaerno5(root_finder=tight)),
                diffrax.ConstantStepSize(), dt0=0.1)
    kept = _solve(_forced_pendulum, y0, 2.0, pj.KeptKvaerno5(root_finder=tight),
                  diffrax.ConstantStepSize(), dt0=0.1)
    np.testing.assert_allclose(kept.ys[0][-1], kv.ys[0][-1], rtol=0, atol=1e-11)


def test_kept_kvaerno5_differentiates_in_forward_mode():
    """d x(1) / d b of the stiff forced oscillator x'' = -w^2 (x - b sin t) (w = 2 pi 30 Hz,
    started on its forced response x = b w^2 / (w^2 - 1) sin t) through KeptKvaerno5 (its
    Newton loops and kept Jacobian inside diffrax's forward-mode adjoint), against the closed
    form w^2 / (w^2 - 1) sin 1."""
    w = 2 * np.pi * 30.0
    a = w**2 / (w**2 - 1)

    def x1(b):
        def vf(t, y, args):
            x, v = y
            return v, -(w**2) * (x - b * jnp.sin(t))

        solver = pj.KeptKvaerno5()
        sol = diffrax.diffeqsolve(
            diffrax.ODETerm(vf), solver, 0.0, 1.0, None, (jnp.asarray(0.0), a * b),
            stepsize_controller=default_controller(solver, 1e-8, 1e-10),
            adjoint=diffrax.ForwardMode())
        return sol.ys[0][-1]

    b = jnp.asarray(1.5)
    np.testing.assert_allclose(x1(b), a * b * np.sin(1.0), rtol=1e-6)
    np.testing.assert_allclose(jax.jacfwd(x1)(b), a * np.sin(1.0), rtol=1e-5)


def test_kept_kvaerno5_rejects_invalid_settings():
    for kw in (dict(jacobian_every=0), dict(root_find_max_steps=1), dict(refresh_rate=1.0)):
        with pytest.raises(ValueError):
            pj.KeptKvaerno5(**kw)


def test_full_l3_defaults_to_a_stiff_solver():
    """The full L3 (`Beam`, the model with fast coordinates) runs on KeptKvaerno5 at rtol 1e-4,
    atol 1e-6 by default and under "auto" (without the stiffness estimate: its default is for
    stiff problems already); the quasi-static L3 and L2 keep their explicit defaults and the
    scenes' tolerances; tolerances given are kept."""
    from ppr_jax._scenes._options import SceneOptions, default_solver

    assert pj.Beam(4).fast_index == tuple(range(6, 15))
    assert pj.QuasiStaticBeam(4).fast_index == pj.Double1R().fast_index == ()
    assert default_solver(pj.Beam(4)) == "kvaerno5-kept"
    assert default_solver(pj.QuasiStaticBeam(4)) == "dopri8"
    assert default_solver(pj.Double1R()) == "tsit5"
    full = SceneOptions().prepared(pj.Beam(4))
    assert isinstance(full.solver, pj.KeptKvaerno5)
    assert (float(full.rtol), float(full.atol)) == (1e-4, 1e-6)
    qs = SceneOptions().prepared(pj.QuasiStaticBeam(4))
    assert (float(qs.rtol), float(qs.atol)) == (1e-8, 1e-10)
    given = SceneOptions(rtol=1e-6).prepared(pj.Beam(4))
    assert (float(given.rtol), float(given.atol)) == (1e-6, 1e-6)
    name, why = choose_solver(pj.Beam(4), pj.scene_params("paper-circle"), 1e-4, "kvaerno5-kept")
    assert name == "kvaerno5-kept" and "stiff" in why


@pytest.fixture(scope="module")
def quasi_static_l3_start():
    """The quasi-static L3 (N = 4) over the first 50 ms of paper-circle, Tsit5 at rtol 1e-10."""
    return pj.paper_circle(pj.scene_params("paper-circle"), model=pj.QuasiStaticBeam(4),
                           solver="tsit5", rtol=1e-10, atol=1e-12, t_end=0.05, n_out=11)


@pytest.mark.parametrize("name, max_steps", [
    # all in the second tier (75-170 s each on the 2-core machine); the default tier keeps the
    # kept Kvaerno5's order (test_kept_kvaerno5_*) and the full L3 on its defaults (test_cli)
    pytest.param("kvaerno5", 200, marks=pytest.mark.slow),
    pytest.param("kvaerno5-kept", 200, marks=pytest.mark.slow),
    pytest.param("ros34pw2", 300, marks=pytest.mark.slow)])
def test_full_l3_on_the_stiff_path_matches_the_quasi_static_l3(quasi_static_l3_start, name,
                                                               max_steps):
    """The full L3 (N = 4, strip modes up to 1e5 rad/s, undamped) on a stiff solver over the
    first 50 ms of paper-circle, against the quasi-static L3 (the strips' static shape at
    every instant): a second formulation that shares only the strip's potential. The strips'
    inertia (0.8 g against 234 g per link) moves the platform by 3.5e-7 m here (the same at
    rtol 1e-4 and 1e-6, by both solvers: it is the physics, not the solver); a wrong
    Jacobian, a missed stage or a start that rings would show far above that. The steps are
    the robot's, not the strips' (an explicit solver is held to microseconds by the strip
    modes): measured Kvaerno5 103 steps (12 rejected), Ros34PW2 135 (25 rejected: it keeps
    its Jacobian over 10 steps; a fresh one every step rejects about 10 %).

    `kvaerno5-kept` at these settings is the command line's full L3 on its defaults
    (`test_cli`): it runs through the suite's program store, so that the command line loads
    this program, or this test the command line's."""
    store = suite_program_dir() if name == "kvaerno5-kept" else None
    full = pj.run_scene(
        "paper-circle",
        pj.scene_params("paper-circle"),
        model=pj.Beam(4),
        program_dir=store,
        options=pj.SceneOptions(solver=name, rtol=1e-4, atol=1e-6, t_end=0.05, n_out=11),
    ).result
    qs = quasi_static_l3_start
    d = np.max(np.hypot(*(np.asarray(full.X)[:, :2] - np.asarray(qs.X)[:, :2]).T))
    assert 1e-8 < d < 1e-6, d
    assert int(full.num_steps) < max_steps, int(full.num_steps)
    assert int(full.num_rejected) <= 0.3 * int(full.num_steps)
