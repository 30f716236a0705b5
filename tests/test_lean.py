"""The lean solve (`ppr_jax/_lean.py`) against diffrax's `diffeqsolve` with the same solver and
controller, an independent implementation of the same algorithm: a forced Van der Pol
oscillator at three tolerances (the same steps, accepted and rejected, and the same solution to
rounding; Tsit5 and Dopri8, with Dopri8's interpolant against diffrax's own), a budget that
runs out (the status code and the rows not reached), forward-mode derivatives in a parameter
and the initial state, a batch under `vmap`, and which solves take the lean loop; its reverse
mode (`lean_vjp`) against forward mode and against diffrax's own backward pass on the same
steps."""

import functools

import diffrax
import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ppr_jax._lean import (
    SEGMENT,
    _clip_to_steps,
    lean_applies,
    lean_solve,
    lean_vjp,
    method_of,
    ulps_below,
)
from ppr_jax._simulate import RecordedGrid

TS = jnp.linspace(0.0, 10.0, 101)
Y0 = jnp.array([1.5, 0.0])


def _vf(t, y, mu):
    return jnp.stack([y[1], mu * (1 - y[0] ** 2) * y[1] - y[0] + jnp.sin(3 * t)])


def _diffrax(y0, mu, rtol, max_steps=100_000, adjoint=None, solver=diffrax.Tsit5, **ctrl):
    c = diffrax.PIDController(rtol=rtol, atol=rtol * 1e-2, **ctrl)
    kw = {} if adjoint is None else {"adjoint": adjoint}
    sol = diffrax.diffeqsolve(diffrax.ODETerm(lambda t, y, a: _vf(t, y, mu)), solver(),
                              TS[0], TS[-1], None, y0, saveat=diffrax.SaveAt(ts=TS),
                              stepsize_controller=c, max_steps=max_steps, throw=False, **kw)
    return sol.ys, sol.ts, sol.result, sol.stats


def _lean(y0, mu, rtol, max_steps=100_000, solver=diffrax.Tsit5, **ctrl):
    c = diffrax.PIDController(rtol=rtol, atol=rtol * 1e-2, **ctrl)
    return lean_solve(lambda t, y: _vf(t, y, mu), y0, TS, c, max_steps,
                      method=method_of(solver))


@pytest.mark.parametrize("solver, rtol", [(diffrax.Tsit5, 1e-6), (diffrax.Tsit5, 1e-8),
                                          (diffrax.Tsit5, 1e-10), (diffrax.Dopri8, 1e-8),
                                          (diffrax.Dopri8, 1e-11)])
def test_same_steps_and_solution_as_diffeqsolve(solver, rtol):
    run = functools.partial(jax.jit, static_argnums=(2, 3))
    ys_d, ts_d, res_d, st_d = run(lambda y, mu, r, n: _diffrax(y, mu, r, n, solver=solver))(
        Y0, 2.0, rtol, 100_000)
    ys_l, ts_l, res_l, st_l = run(lambda y, mu, r, n: _lean(y, mu, r, n, solver=solver))(
        Y0, 2.0, rtol, 100_000)
    # the same structure: reverse mode swaps one for the other (`_simulate._solve_recorded`)
    assert jax.tree_util.tree_structure(st_l) == jax.tree_util.tree_structure(st_d)
    for key in st_d:
        assert int(st_l[key]) == int(st_d[key]), key
    assert int(st_l["num_rejected_steps"]) > 10  # the controller's rejections are exercised
    np.testing.assert_array_equal(np.asarray(ts_l), np.asarray(ts_d))
    np.testing.assert_allclose(ys_l, ys_d, rtol=0, atol=1e-12)
    assert res_l == res_d == diffrax.RESULTS.successful


def _stiff(t, y, lam):
    return -lam * (y - jnp.stack([jnp.cos(t), jnp.sin(t)]))


def test_a_rejected_first_step():
    """The loop's first step also computes the start's derivative (its stage 0); a first step
    that the controller rejects keeps it for the next try. The first step (0.01 s) is 20 times
    past the problem's explicit stability limit here: rejected (a budget of one step accepts
    none), and the steps and solution are still diffrax's, in value and in forward mode."""
    ts = jnp.linspace(0.0, 0.5, 11)
    y0 = jnp.array([2.0, -1.0])
    c = diffrax.PIDController(rtol=1e-8, atol=1e-10)

    def lean(lam, max_steps=100_000):
        return lean_solve(lambda t, y: _stiff(t, y, lam), y0, ts, c, max_steps)

    def ref(lam):
        sol = diffrax.diffeqsolve(diffrax.ODETerm(lambda t, y, a: _stiff(t, y, lam)),
                                  diffrax.Tsit5(), ts[0], ts[-1], None, y0,
                                  saveat=diffrax.SaveAt(ts=ts), stepsize_controller=c,
                                  max_steps=100_000, throw=False,
                                  adjoint=diffrax.ForwardMode())
        return sol.ys, sol.stats

    assert int(jax.jit(lean, static_argnums=1)(2000.0, 1)[3]["num_accepted_steps"]) == 0
    ys_l, _, _, st_l = jax.jit(lean)(2000.0)
    ys_d, st_d = jax.jit(ref)(2000.0)
    for key in ("num_steps", "num_accepted_steps", "num_rejected_steps"):
        assert int(st_l[key]) == int(st_d[key]), key
    np.testing.assert_allclose(ys_l, ys_d, rtol=0, atol=1e-12)
    t_l = jax.jit(lambda lam: jax.jvp(lambda x: lean(x)[0], (lam,), (1.0,))[1])(2000.0)
    t_d = jax.jit(lambda lam: jax.jvp(lambda x: ref(x)[0], (lam,), (1.0,))[1])(2000.0)
    np.testing.assert_allclose(t_l, t_d, rtol=0, atol=1e-9 * float(jnp.abs(t_d).max()))


def test_clipping_threshold_equals_diffraxs():
    """t1 lowered by 100 ulp on the bits equals diffrax's 100 steps of `prevbefore`, over the
    magnitudes and signs a horizon can have."""
    rng = np.random.default_rng(3)
    mags = 10.0 ** rng.uniform(-290, 300, 500)
    xs = jnp.asarray(np.concatenate([mags, -mags, [7.54, 1.0, 0.5, 2.0 ** 40, -4.0]]))

    def steps(x):
        for _ in range(100):
            x = eqxi.prevbefore(x)
        return x

    np.testing.assert_array_equal(jax.jit(jax.vmap(steps))(xs),
                                  jax.jit(jax.vmap(lambda x: ulps_below(x, 100)))(xs))


def test_an_i_controller_with_other_settings():
    """The controller decides the steps (its own `adapt_step_size`): another integral gain,
    safety factor and factor bounds give diffrax's steps too."""
    kw = dict(icoeff=0.7, safety=0.8, factormin=0.3, factormax=4.0)
    ys_d, _, _, st_d = _diffrax(Y0, 2.0, 1e-8, **kw)
    ys_l, _, _, st_l = _lean(Y0, 2.0, 1e-8, **kw)
    assert int(st_l["num_steps"]) == int(st_d["num_steps"]) != int(_lean(Y0, 2.0, 1e-8)[3][
        "num_steps"])
    assert int(st_l["num_rejected_steps"]) == int(st_d["num_rejected_steps"])
    np.testing.assert_allclose(ys_l, ys_d, rtol=0, atol=1e-12)


def test_a_budget_that_runs_out():
    ys_d, ts_d, res_d, st_d = _diffrax(Y0, 2.0, 1e-8, max_steps=40)
    ys_l, ts_l, res_l, st_l = _lean(Y0, 2.0, 1e-8, max_steps=40)
    assert res_l == res_d == diffrax.RESULTS.max_steps_reached
    assert int(st_l["num_steps"]) == int(st_d["num_steps"]) == 40
    reached = np.isfinite(np.asarray(ts_d))
    assert 0 < reached.sum() < TS.shape[0]
    np.testing.assert_array_equal(np.isfinite(np.asarray(ts_l)), reached)
    assert np.all(np.isinf(np.asarray(ys_l)[~reached]))
    np.testing.assert_allclose(np.asarray(ys_l)[reached], np.asarray(ys_d)[reached], atol=1e-12)


def test_forward_mode_matches_diffrax():
    def lean_out(p):
        return _lean(p[:2], p[2], 1e-9)[0]

    def diffrax_out(p):
        return _diffrax(p[:2], p[2], 1e-9, adjoint=diffrax.ForwardMode())[0]

    p = jnp.array([1.5, 0.0, 2.0])
    J_l = jax.jit(jax.jacfwd(lean_out))(p)
    J_d = jax.jit(jax.jacfwd(diffrax_out))(p)
    scale = np.abs(np.asarray(J_d)).max()
    assert scale > 1.0
    np.testing.assert_allclose(J_l, J_d, rtol=0, atol=1e-9 * scale)
    # and central differences of the solve itself, in mu
    h = 1e-6
    fd = (lean_out(p.at[2].add(h)) - lean_out(p.at[2].add(-h))) / (2 * h)
    np.testing.assert_allclose(J_l[..., 2], fd, rtol=0, atol=1e-4 * np.abs(fd).max())


def test_a_batch_equals_its_members():
    mus = jnp.array([0.5, 2.0, 4.0])
    batch = jax.jit(jax.vmap(lambda mu: _lean(Y0, mu, 1e-8)))(mus)
    for i, mu in enumerate(mus):
        one = _lean(Y0, mu, 1e-8)
        np.testing.assert_allclose(batch[0][i], one[0], rtol=1e-12, atol=1e-12)
        assert int(batch[3]["num_steps"][i]) == int(one[3]["num_steps"])


def test_dopri8s_interpolant_is_diffraxs():
    """The loop evaluates Dopri8's dense output as a sum of weighted rows (no dot, which would
    keep the loop from compiling as one kernel): diffrax's interpolant to rounding, on a step
    of random increments, at its ends and inside."""
    rng = np.random.default_rng(5)
    k = jnp.asarray(rng.normal(size=(14, 5)))
    y0 = jnp.asarray(rng.normal(size=5))
    t0, t1 = 0.3, 0.3 + 2e-3
    ts = jnp.asarray(np.concatenate([[t0, t1], t0 + (t1 - t0) * rng.uniform(size=20)]))
    method = method_of(diffrax.Dopri8)
    ours = jax.vmap(lambda t: method.interpolate(t0, t1, y0, y0, k, t))(ts)
    dense = diffrax.Dopri8.interpolation_cls(t0=t0, t1=t1, y0=y0, y1=y0, k=k)
    theirs = jax.vmap(dense.evaluate)(ts)
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-14 * float(jnp.abs(theirs).max()))
    # a step of zero length: y0, as diffrax's `linear_rescale` gives it
    np.testing.assert_array_equal(method.interpolate(t0, t0, y0, y0, k, t0), y0)


def test_which_solves_take_it():
    pid = diffrax.PIDController(rtol=1e-8, atol=1e-10)
    none = diffrax.NoProgressMeter()
    assert lean_applies(diffrax.Tsit5(), pid, None, False, none, None)
    assert lean_applies(diffrax.Dopri8(), pid, None, False, none, None)
    assert not lean_applies(diffrax.Dopri5(), pid, None, False, none, None)
    assert not lean_applies(diffrax.Tsit5(), diffrax.PIDController(rtol=1e-8, atol=1e-10,
                                                                   pcoeff=0.2, icoeff=0.4),
                            None, False, none, None)
    assert lean_applies(diffrax.Tsit5(), diffrax.ClipStepSizeController(
        pid, step_ts=jnp.array([0.5])), None, False, none, None)
    assert not lean_applies(diffrax.Tsit5(), diffrax.ClipStepSizeController(
        pid, jump_ts=jnp.array([0.5])), None, False, none, None)
    assert not lean_applies(diffrax.Tsit5(), diffrax.ClipStepSizeController(
        pid, step_ts=jnp.array([0.5]), store_rejected_steps=4), None, False, none, None)
    assert not lean_applies(diffrax.Tsit5(), diffrax.ClipStepSizeController(
        diffrax.PIDController(rtol=1e-8, atol=1e-10, pcoeff=0.2, icoeff=0.4),
        step_ts=jnp.array([0.5])), None, False, none, None)
    assert not lean_applies(diffrax.Tsit5(), pid, 1e-3, False, none, None)
    assert not lean_applies(diffrax.Tsit5(), pid, None, True, none, None)
    assert not lean_applies(diffrax.Tsit5(), pid, None, False, diffrax.TextProgressMeter(),
                            None)
    assert not lean_applies(diffrax.Tsit5(), pid, None, False, none, diffrax.SaveAt(t1=True))
    assert not lean_applies(diffrax.Tsit5(), diffrax.PIDController(rtol=1e-8, atol=1e-10,
                                                                   dtmax=0.1),
                            None, False, none, None)


@pytest.mark.slow
def test_a_scene_differentiates_in_both_modes():
    """L0 `paper-circle` (driven by L1's torques) over 0.2 s: reverse mode (whose forward pass
    is diffrax's solve, the primal the lean loop's) equals forward mode (through the lean
    loop), and the lean loop's metrics equal central differences of themselves in the links'
    density."""
    import ppr_jax as pj

    o = pj.SceneOptions(t_end=0.2, n_out=21)
    kw = dict(model="rigid", parameters=["rho_m", "l1"], options=o)
    fwd = pj.sensitivity("paper-circle", mode="fwd", **kw)
    rev = pj.sensitivity("paper-circle", mode="rev", **kw)
    scale = np.abs(fwd.jacobian).max(axis=1, keepdims=True)
    assert np.sum(scale > 0) >= 3, fwd.metrics
    scale = np.where(scale > 0, scale, 1.0)
    np.testing.assert_allclose(rev.jacobian / scale, fwd.jacobian / scale, rtol=0, atol=1e-7)
    x = np.array([fwd.param_values["rho_m"], fwd.param_values["l1"]])
    h = 1e-7 * x[0]
    fd = (np.asarray(fwd.evaluate(x + [h, 0.0]))
          - np.asarray(fwd.evaluate(x - [h, 0.0]))) / (2 * h)
    np.testing.assert_allclose(fwd.jacobian[:, 0] / scale[:, 0], fd / scale[:, 0], rtol=0,
                               atol=1e-4)


# reverse mode: the same oscillator with its parameters as a pytree (mu, forcing amplitude)
W = jnp.asarray(np.random.default_rng(7).normal(size=(TS.shape[0], 2)))


def _vf_d(d, t, y):
    return _vf(t, y, d["mu"]) + jnp.stack([0.0 * t, (d["a"] - 1.0) * jnp.sin(3 * t)])


def _loss_fwd(p, ts, rtol, max_steps=100_000, solver=diffrax.Tsit5):
    """sum(W * ys) through the lean loop, for forward mode."""
    d = {"mu": p[2], "a": p[3]}
    c = diffrax.PIDController(rtol=rtol, atol=rtol * 1e-2)
    ys = lean_solve(lambda t, y: _vf_d(d, t, y), p[:2], ts, c, max_steps,
                    method=method_of(solver))[0]
    return jnp.sum(jnp.where(jnp.isfinite(ys), W * ys, 0.0))


@functools.partial(jax.jit, static_argnums=(3, 4, 5))
def _rev(p, ts, g, rtol=1e-9, max_steps=100_000, solver=diffrax.Tsit5):
    d = {"mu": p[2], "a": p[3]}
    c = diffrax.PIDController(rtol=rtol, atol=rtol * 1e-2)
    method = method_of(solver)
    *_, tape = lean_solve(lambda t, y: _vf_d(d, t, y), p[:2], ts, c, max_steps, record=True,
                          method=method)
    gd, gy0, gts = lean_vjp(_vf_d, d, p[:2], ts, tape, g, method=method)
    return jnp.concatenate([gy0, jnp.stack([gd["mu"], gd["a"]])]), gts, tape


P = jnp.array([1.5, 0.0, 2.0, 1.3])


@pytest.mark.parametrize("rtol", [pytest.param(1e-9, marks=pytest.mark.slow), 1e-7])
def test_reverse_mode_equals_forward_mode(rtol):
    """Parameters, the initial state and the output times against `jax.jacfwd` through the
    loop (but the first: in forward mode it moves every step with it, on the recorded steps
    only the first step's start); at both
    tolerances the accepted steps are not a whole number of segments, once more than one
    segment."""
    g, gts, tape = _rev(P, TS, W, rtol)
    assert int(tape.accepted) % SEGMENT != 0 and int(tape.accepted) > SEGMENT
    g_f = jax.jacfwd(_loss_fwd)(P, TS, rtol)
    np.testing.assert_allclose(g, g_f, rtol=0, atol=1e-12 * np.abs(g_f).max())
    gts_f = jax.jacfwd(_loss_fwd, argnums=1)(P, TS, rtol)
    np.testing.assert_allclose(gts[1:], gts_f[1:], rtol=0,
                               atol=1e-12 * np.abs(gts_f).max())


def test_reverse_mode_equals_diffrax_on_the_recorded_steps():
    """diffrax's own backward pass of `diffeqsolve` on the steps the lean loop accepted
    (`RecordedGrid`, what reverse mode ran before): the same cotangents, the first output
    time's included."""
    g, gts, tape = _rev(P, TS, W)
    grid = jnp.where(jnp.isfinite(tape.grid), tape.grid, TS[-1])

    def loss(p, ts):
        d = {"mu": p[2], "a": p[3]}
        sol = diffrax.diffeqsolve(diffrax.ODETerm(lambda t, y, a: _vf_d(d, t, y)),
                                  diffrax.Tsit5(), ts[0], ts[-1], None, p[:2],
                                  saveat=diffrax.SaveAt(ts=ts),
                                  stepsize_controller=RecordedGrid(grid), max_steps=100_000)
        return jnp.sum(W * sol.ys)

    g_d, gts_d = jax.jit(jax.grad(loss, argnums=(0, 1)))(P, TS)
    np.testing.assert_allclose(g, g_d, rtol=0, atol=1e-12 * np.abs(g_d).max())
    np.testing.assert_allclose(gts, gts_d, rtol=0, atol=1e-12 * np.abs(gts_d).max())


def test_reverse_mode_of_dopri8_equals_forward_mode():
    """Dopri8 (the quasi-static L3's solver) in both modes through the lean loop: the
    parameters', the initial state's and the output times' cotangents are forward mode's."""
    g, gts, tape = _rev(P, TS, W, 1e-9, 100_000, diffrax.Dopri8)
    assert int(tape.accepted) > SEGMENT
    g_f = jax.jacfwd(_loss_fwd)(P, TS, 1e-9, 100_000, diffrax.Dopri8)
    np.testing.assert_allclose(g, g_f, rtol=0, atol=1e-12 * np.abs(g_f).max())
    gts_f = jax.jacfwd(_loss_fwd, argnums=1)(P, TS, 1e-9, 100_000, diffrax.Dopri8)
    # the output times' cotangents go through the interpolant's derivative in t: a polynomial of
    # degree 6 whose coefficients sum to hundreds in magnitude, over h, so the two modes'
    # orders of summation differ by more rounding than Tsit5's (3e-11 of the largest seen)
    np.testing.assert_allclose(gts[1:], gts_f[1:], rtol=0, atol=1e-10 * np.abs(gts_f).max())


def test_reverse_mode_of_a_solve_that_stops_short():
    """A budget that runs out: the rows not reached (inf) carry no cotangent, the rest are
    forward mode's."""
    g, _, tape = _rev(P, TS, W, 1e-9, 40)
    assert int(tape.accepted) < 40
    g_f = jax.jacfwd(_loss_fwd)(P, TS, 1e-9, 40)
    np.testing.assert_allclose(g, g_f, rtol=0, atol=1e-12 * np.abs(g_f).max())


def test_reverse_mode_maps_over_cotangents():
    """`jax.jacrev`'s use: cotangents batched under `vmap`, the forward pass's tape not."""
    gs = jnp.stack([W, -2.0 * W, W.at[:, 0].set(0.0)])
    batch = jax.vmap(lambda g: _rev(P, TS, g)[0])(gs)
    for i in range(3):
        np.testing.assert_allclose(batch[i], _rev(P, TS, gs[i])[0], rtol=1e-13, atol=1e-13)


def test_reverse_mode_without_the_output_times():
    """`times=False` (output times not differentiated): the same cotangents of the rest."""
    d = {"mu": P[2], "a": P[3]}
    c = diffrax.PIDController(rtol=1e-9, atol=1e-11)
    *_, tape = lean_solve(lambda t, y: _vf_d(d, t, y), P[:2], TS, c, 100_000, record=True)
    gd, gy0, gts = jax.jit(lambda g: lean_vjp(_vf_d, d, P[:2], TS, tape, g, times=False))(W)
    assert gts is None
    g = jnp.concatenate([gy0, jnp.stack([gd["mu"], gd["a"]])])
    ref = _rev(P, TS, W)[0]
    np.testing.assert_allclose(g, ref, rtol=0, atol=1e-12 * np.abs(ref).max())


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_a_scenes_stages_compile_as_one_kernel():
    """Under the library's XLA settings (`_devices.loop_flags`, which the suite sets too) the
    Runge-Kutta stages of L1's and L2's scene programs are a loop that XLA compiles as one
    kernel (a call marked `xla_cpu_small_call`); a stage loop grown past `SMALL_LOOP_BYTES`
    would lose that, and this test says so."""
    import os

    import equinox as eqx

    from ppr_jax._devices import loop_flags
    from ppr_jax._scenes._options import SceneOptions
    from ppr_jax._scenes._run import prepare, scene_program

    if not loop_flags() or loop_flags()[0] not in os.environ.get("XLA_FLAGS", ""):
        pytest.skip("the small-loop threshold is not set in this process")
    for model in ("reduced", "double1r"):
        c = prepare("paper-circle", None, model, SceneOptions(t_end=0.05, n_out=6))
        dyn, static = eqx.partition(c.args, eqx.is_array)
        text = jax.jit(lambda d: scene_program(*eqx.combine(d, static))).lower(dyn).compile(
        ).as_text()
        small = [line for line in text.splitlines()
                 if " call(" in line and "xla_cpu_small_call" in line]
        assert small, model


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_the_quasi_static_l3s_loop_of_steps_compiles_as_one_kernel():
    """The quasi-static L3 at its default N = 8 runs Dopri8 on the lean loop, and under the
    library's threshold XLA compiles its whole loop of steps as one kernel. A dot in it (a
    product that XLA hands to its matrix library: Dopri8's interpolant or the mass matrix as
    einsums, `_lean.Method.interpolate`, `_dynamics._eom_terms`) or a loop grown past
    `SMALL_LOOP_BYTES` keeps it out, and the run is 2-3 times slower."""
    import os
    import re

    import equinox as eqx

    import ppr_jax as pj
    from ppr_jax._devices import loop_flags
    from ppr_jax._scenes._options import SceneOptions
    from ppr_jax._scenes._run import prepare, scene_program

    if not loop_flags() or loop_flags()[0] not in os.environ.get("XLA_FLAGS", ""):
        pytest.skip("the small-loop threshold is not set in this process")
    c = prepare("paper-circle", None, pj.QuasiStaticBeam(8), SceneOptions(t_end=0.05, n_out=6))
    dyn, static = eqx.partition(c.args, eqx.is_array)
    text = jax.jit(lambda d: scene_program(*eqx.combine(d, static))).lower(dyn).compile(
    ).as_text()
    steps = [line for line in text.splitlines()
             if " call(" in line and "xla_cpu_small_call" in line
             and re.search(r'jit\(simulate_core\)/while"', line)]
    assert steps


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_the_quasi_static_l3_on_the_lean_loop_equals_diffeqsolve():
    """The quasi-static L3 (N = 4, `paper-circle`, 1 s) on the lean loop (Dopri8) against the
    same scene on `diffeqsolve` (a subclass of Dopri8, which the lean loop does not take): the
    same trajectory to 1e-10 m and rad, and the step counts within 1 % (the error estimate's sums
    round differently, and over thousands of steps a decision near the tolerance may flip: the
    whole 7.54 s scene took 3,466 steps against 3,464, 1.9e-12 m apart)."""
    import ppr_jax as pj

    class NotLean(diffrax.Dopri8):
        pass

    model = pj.QuasiStaticBeam(4)
    o = pj.SceneOptions(t_end=1.0, n_out=101)
    lean = pj.solve_scene("paper-circle", model=model, options=o)
    ref = pj.solve_scene("paper-circle", model=model,
                         options=pj.SceneOptions(t_end=1.0, n_out=101, solver=NotLean()))
    pid, none = diffrax.PIDController(rtol=1e-8, atol=1e-10), diffrax.NoProgressMeter()
    assert model.default_solver == "dopri8"
    assert not lean_applies(NotLean(), pid, None, False, none, None)
    assert abs(int(lean.num_steps) - int(ref.num_steps)) <= 0.01 * int(ref.num_steps)
    np.testing.assert_allclose(np.asarray(lean.X), np.asarray(ref.X), rtol=0, atol=1e-10)


_DERIVATIVE_LOOPS = """
import json
import ppr_jax as pj
pj.configure_cpu(1, derivatives=True)  # before the first computation
from tests.helpers import sensitivity_small_calls
print(json.dumps(sensitivity_small_calls()))
"""


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_a_sensitivitys_loops_compile_as_one_kernel_with_derivatives_set():
    """With `configure_cpu(derivatives=True)` (a fresh process) the solver's loop of steps of a
    forward-mode sensitivity of every float parameter (19 tangents) is a loop that XLA compiles
    as one kernel, and so is reverse mode's transposed replay of a segment's recorded steps.
    Under a threshold of 256 KiB neither was: a step of the forward derivative was about 300
    kernels (docs/performance.md)."""
    import json
    import os
    import subprocess
    import sys

    from ppr_jax._devices import loop_flags

    if not loop_flags():
        pytest.skip("no small-loop threshold on this jaxlib")
    # the suite's XLA settings without its threshold (kept as a user's own otherwise), which
    # the child then sets itself; any other backend option stays
    threshold = loop_flags()[0].partition("=")[2]
    flags = [f.replace(threshold, "").replace("=,", "=").rstrip(",")
             for f in os.environ.get("XLA_FLAGS", "").split()]
    empty = "--xla_backend_extra_options="
    env = dict(os.environ, XLA_FLAGS=" ".join(f for f in flags if f != empty))
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))  # `tests` importable
    proc = subprocess.run([sys.executable, "-c", _DERIVATIVE_LOOPS], capture_output=True,
                          text=True, timeout=900, env=env, cwd=root)
    assert proc.returncode == 0, proc.stderr[-3000:]
    _assert_one_kernel_loops(json.loads(proc.stdout.strip().splitlines()[-1]))


def _assert_one_kernel_loops(out):
    """Forward mode's loop of steps itself is one kernel, not only loops inside its body;
    reverse mode's replay of a segment's recorded steps, transposed (`_lean.lean_vjp`), too."""
    import re

    steps = re.compile(r"jvp\(jit\(simulate_core\)\)+/while$")
    assert any(steps.search(n) for n in out["fwd"]), out["fwd"]
    replay = re.compile(r"transpose\(jvp\(jit\(simulate_core\)\)\)+/while/body/"
                        r"transpose\(jvp\(\)\)/while$")
    assert any(replay.search(n) for n in out["rev"]), out["rev"]


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_a_sensitivitys_loops_compile_as_one_kernel_at_the_imports_threshold():
    """Under the import's threshold (`SMALL_LOOP_BYTES`, which the suite sets too) the loop of
    steps of a forward-mode sensitivity's slice of 10 tangents (19 parameters on two cores,
    `_jacobian.forward_jacobian`) and reverse mode's transposed replay compile as one kernel
    each. At 256 KiB neither was, and before each linearisation residual had its own
    `materialize` (`_dynamics._jvp_residuals_once`) not even one tangent's loop was."""
    import os

    from ppr_jax._devices import loop_flags
    from tests.helpers import sensitivity_small_calls

    if not loop_flags() or loop_flags()[0] not in os.environ.get("XLA_FLAGS", ""):
        pytest.skip("the small-loop threshold is not set in this process")
    _assert_one_kernel_loops(sensitivity_small_calls(rows=10))


_KNOTS = np.sort(np.random.default_rng(0).uniform(-1.0, 11.0, 40))
_UP = np.nextafter(_KNOTS, np.inf)
#: step times with the cases diffrax's clipping handles: outside (t0, t1), on t0 and t1, on
#: output times, repeated, one and two ulp apart, denser than the steps, one alone
STEP_TIMES = {
    "random": _KNOTS,
    "ends and outputs": np.concatenate([[0.0, 10.0], np.asarray(TS[3::7]), _KNOTS]),
    "repeated": np.concatenate([_KNOTS, _KNOTS[:5], _KNOTS[:5]]),
    "ulps apart": np.concatenate([_KNOTS, _UP, np.nextafter(_UP, np.inf)]),
    "dense": np.linspace(0.0, 10.0, 2001),
    "one": np.array([3.3]),
}


_PADDED = 2048


@eqx.filter_jit
def _clipped_pair(c, solver, rtol):
    """(diffeqsolve's, the lean loop's) (ys, ts, result, stats) under `c`, and the spread of
    diffeqsolve's own ys when rtol moves by 1e-13 (relative) either way."""
    def dfx(cc):
        sol = diffrax.diffeqsolve(diffrax.ODETerm(lambda t, y, a: _vf(t, y, 2.0)), solver(),
                                  TS[0], TS[-1], None, Y0, saveat=diffrax.SaveAt(ts=TS),
                                  stepsize_controller=cc, max_steps=100_000, throw=False)
        return sol.ys, sol.ts, sol.result, sol.stats

    def moved(eps):
        pid = diffrax.PIDController(rtol=rtol * (1 + eps), atol=rtol * 1e-2)
        return dfx(eqx.tree_at(lambda x: x.controller, c, pid))[0]

    ref = dfx(c)
    spread = jnp.maximum(jnp.max(jnp.abs(moved(1e-13) - ref[0])),
                         jnp.max(jnp.abs(moved(-1e-13) - ref[0])))
    lean = lean_solve(lambda t, y: _vf(t, y, 2.0), Y0, TS, c, 100_000,
                      method=method_of(solver))
    return ref, lean, spread


@pytest.mark.parametrize("case", list(STEP_TIMES))
@pytest.mark.parametrize("solver, rtol", [(diffrax.Tsit5, 1e-6), (diffrax.Tsit5, 1e-9),
                                          (diffrax.Dopri8, 1e-9)])
def test_steps_clipped_to_given_times_as_diffeqsolve_clips_them(case, solver, rtol):
    """A `ClipStepSizeController` with `step_ts`: the same steps as `diffeqsolve`'s (the same
    accepted steps; the rejected ones to one), and the same solution. Clipped steps make the
    step sequence sensitive to rounding (a step that ends just past a step time leaves a
    sliver, one that ends just before it does not): diffeqsolve's own solution moves by up to
    1e-8 when rtol moves by 1e-13, where without step times it moves by 5e-14. The solutions
    are compared within ten times that spread (and 1e-12)."""
    # one shape for every case, so that one program per solver serves them: the padding lies
    # past t1, where no step goes
    st = STEP_TIMES[case]
    st = np.concatenate([st, np.full(_PADDED - st.shape[0], 1e3)])
    pid = diffrax.PIDController(rtol=jnp.asarray(rtol), atol=jnp.asarray(rtol * 1e-2))
    c = diffrax.ClipStepSizeController(pid, step_ts=jnp.asarray(st))
    (ys_d, ts_d, res_d, st_d), (ys_l, ts_l, res_l, st_l), spread = _clipped_pair(
        c, solver, jnp.asarray(rtol))
    assert int(st_l["num_accepted_steps"]) == int(st_d["num_accepted_steps"])
    # a step whose error ratio is 1 to rounding is kept by one and rejected by the other (seen
    # once: Dopri8 at 1e-9 with step times on the output times, 150 steps)
    assert abs(int(st_l["num_rejected_steps"]) - int(st_d["num_rejected_steps"])) <= 1
    np.testing.assert_array_equal(np.asarray(ts_l), np.asarray(ts_d))
    np.testing.assert_allclose(ys_l, ys_d, rtol=0, atol=10 * float(spread) + 1e-12)
    assert res_l == res_d == diffrax.RESULTS.successful
    # the step times are stepped to: more steps than without them where they are dense
    if case == "dense":
        assert int(st_l["num_accepted_steps"]) >= 2000


def test_the_clipping_of_a_step_is_diffraxs():
    """`_clip_to_steps` against `ClipStepSizeController.adapt_step_size`'s own clipping (its
    `_bump_next_t0`, `_find_idx_with_hint`, `_clip_t`) at step starts on, one and two ulp
    before and after the step times, between them and outside, from every index hint that
    the loop can hold: the same next t1 and index, exactly."""
    clip = pytest.importorskip("diffrax._step_size_controller.clip")
    st = jnp.asarray(np.sort(STEP_TIMES["ulps apart"].tolist() + _KNOTS[:3].tolist()))
    base = np.concatenate([np.asarray(st), [-2.0, 12.0, 0.3, 5.0]])
    starts = np.unique(np.concatenate([base, np.nextafter(base, np.inf),
                                       np.nextafter(base, -np.inf)]))

    @jax.jit
    def both(nt0, nt1, i):
        ours = _clip_to_steps(nt0, nt1, st, i)
        bumped, _ = clip._bump_next_t0(nt0, st)
        j = clip._find_idx_with_hint(bumped, st, i)
        return ours, (clip._clip_t(nt1, j, st, False), j)

    for nt0 in starts:
        # the hint: the index the previous step left (the first step time above an earlier
        # start), anywhere at or below the right one
        right = int(np.searchsorted(np.asarray(st), nt0, side="right"))
        for hint in {0, max(right - 2, 0), right, min(right + 1, st.shape[0])}:
            for nt1 in (nt0 + 1e-3, nt0 + 5.0):
                (a, i), (b, j) = both(nt0, nt1, hint)
                assert float(a) == float(b) and int(i) == int(j), (nt0, hint, nt1)
