"""Identification (MODEL.md section 7): recovery of known parameters from synthetic L2 data,
intervals that shrink with the noise, the covariance against a finite-difference Jacobian, the
identifiability report for t and K_theta, and the errors of bad requests.

The data come from the public scene `servo_circle` (an independent path from the identification's
own simulation, which holds the motor commands fixed and saves at the sample times). Experiments
are short (0.6 s at 100 Hz) so that one module compiles one simulation and one Jacobian; every
fit of the module reuses that compiled Jacobian (same unknowns, same data shapes)."""

import math

import numpy as np
import pytest

import ppr_jax as pj

T_END, N = 0.6, 61
#: the paper's experiment the module's data come from (pose-only files name it)
SC = "servo-circle"
# m, rad: a twentieth of an Optotrak's noise, so that a 0.6 s run determines the stiffness to a
# few per cent (the elastic deflections of the servo circle are small at t = 0.5 mm)
NOISE = (5e-6, 5e-5)


@pytest.fixture(scope="module")
def truth():
    p = pj.scene_params("servo-circle")  # t = 0.5 mm
    dv = pj.derived(p)
    return p.replace(K_theta=float(dv.K_theta))


@pytest.fixture(scope="module")
def clean(truth):
    """Noise-free L2 response of the servo-circle scene at 100 Hz (the public scene)."""
    res = pj.servo_circle(truth, model="double1r", t_end=T_END, n_out=N)
    return np.asarray(res.ts), np.asarray(res.X)


def _noisy(clean, scale, seed):
    ts, X = clean
    rng = np.random.default_rng(seed)
    Xn = X.copy()
    Xn[:, :2] += scale * NOISE[0] * rng.standard_normal((len(ts), 2))
    Xn[:, 2] += scale * NOISE[1] * rng.standard_normal(len(ts))
    return pj.experiment(ts, Xn, name=f"noise x{scale}")


@pytest.fixture(scope="module")
def fits(truth, clean):
    """t and K_theta with L2 from a start 10 % and 20 % off, at the stated noise and at a
    tenth of it (the second fit reuses the compiled Jacobian). The pair is not identifiable
    (only t^3 K_theta is): the preflight would refuse it, and these fits are forced on purpose,
    to check what the result reports about it."""
    start = {"t": 0.9 * float(truth.t), "K_theta": 1.2 * float(truth.K_theta)}
    out = {}
    for scale in (1.0, 0.1):
        out[scale] = pj.identify(_noisy(clean, scale, seed=1), ("t", "K_theta"), scene=SC,
                                 model="double1r", initial=start,
                                 noise=(scale * NOISE[0], scale * NOISE[1]),
                                 fit_options=pj.FitOptions(force=True))
    return out


def test_recovers_truth_within_intervals(truth, fits):
    for fit in fits.values():
        assert fit.history["stop"] == "converged"
        for i, name in enumerate(fit.names):
            lo, hi = fit.ci95[i]
            assert lo <= float(getattr(truth, name)) <= hi, (name, fit.table())
    # At the stated noise the residual scale estimate is about 1 and the RMS is the noise. (At a
    # tenth of it, 0.5 um, s rises to about 1.8: the simulation's own error at rtol = 1e-8,
    # which differs between the scene and the fit's runs at other parameters, shows.)
    fit = fits[1.0]
    assert 0.8 < math.sqrt(fit.sigma2) < 1.2
    rs = fit.residual_stats["experiments"][0]
    assert 0.8 * fit.noise[0] < rs["rms_x_m"] < 1.2 * fit.noise[0]
    assert 0.8 * fit.noise[1] < rs["rms_phi_rad"] < 1.2 * fit.noise[1]


def test_stiffness_combination_identified_not_each_parameter(truth, fits):
    """t and K_theta act through E w t^3 K_theta: the report must name t^3 K_theta as the
    determined combination, recover its true value within its 95 % interval, and flag the
    other direction."""
    fit = fits[1.0]
    idf = fit.identifiability
    c0, c1 = idf["combinations"]
    e = dict(zip(fit.names, c0["exponents"]))
    assert abs(e["t"] / e["K_theta"] - 3.0) < 0.05, c0
    true_value = float(truth.t) ** e["t"] * float(truth.K_theta) ** e["K_theta"]
    rel = c0["relative_std"]
    assert abs(math.log(c0["value"] / true_value)) < 1.96 * rel + 1e-12, (c0, true_value)
    assert c0["status"] == "identifiable"
    assert c1["relative_std"] > 20 * c0["relative_std"]
    assert idf["condition_number"] > 20
    assert "t^3" in c0["expression"] or "t^3.0" in c0["expression"]
    assert "E w t^3 K_theta" in idf["note"]
    # t and K_theta estimates are strongly negatively correlated
    assert fit.correlation[0, 1] < -0.9


def test_preflight_refuses_t_with_K_theta_naming_the_combination(truth, clean, fits):
    """Before fitting, at the initial guess, the preflight finds that t and K_theta are not
    identifiable apart and refuses, naming the combination, its relative std, a fix and
    `force=True`. Checked independently of the singular-value analysis: the named
    combination's exponents must be orthogonal to those of the joint stiffness E w t^3 K_theta
    (3, 1) (what the data see), and moving the parameters along it must leave the residuals
    (the fit's own residual function, at the initial guess) almost unchanged, while the same
    step along the stiffness changes them. The forced fit (the module's `fits`, same data and
    start) runs and reports the refusal it overrode."""
    import re

    start = {"t": 0.9 * float(truth.t), "K_theta": 1.2 * float(truth.K_theta)}
    with pytest.raises(pj.IdentificationError) as info:
        pj.identify(_noisy(clean, 1.0, seed=1), ("t", "K_theta"), scene=SC, model="double1r",
                    initial=start, noise=NOISE)
    msg = str(info.value)
    m = re.search(r"(t\^(-?[\d.]+) \* K_theta\^(-?[\d.]+)) \(relative std ([\d.e+]+) %\)",
                  msg)
    assert m, msg
    e = np.array([float(m[2]), float(m[3])])
    assert abs(e @ np.array([3.0, 1.0])) < 0.05 * np.linalg.norm(e) * math.sqrt(10), e
    assert float(m[4]) >= 100
    assert "fixed={'t': value}" in msg and "force=True" in msg and "E w t^3 K_theta" in msg
    fit = fits[1.0]
    assert fit.history["preflight"]["forced"]
    assert fit.quality["preflight_not_identifiable"] == [m[1]]
    assert "preflight: not identifiable at the initial guess" in fit.table()
    # the named direction is flat in the data, the stiffness direction is not
    p0 = np.array([start["t"], start["K_theta"]])
    r0 = fit.residuals_at(p0)

    def change(direction):
        d = np.asarray(direction, dtype=np.float64)
        return np.linalg.norm(fit.residuals_at(p0 * np.exp(1e-3 * d / np.linalg.norm(d))) - r0)

    assert change(e) < 1e-2 * change([3.0, 1.0]), (change(e), change([3.0, 1.0]))


def test_intervals_shrink_with_noise(fits):
    a, b = fits[1.0], fits[0.1]
    ca = a.identifiability["combinations"][0]["relative_std"]
    cb = b.identifiability["combinations"][0]["relative_std"]
    # linear theory: 10 x less noise, 10 x narrower (the noise realisation is the same)
    assert 6 < ca / cb < 14, (ca, cb)
    assert np.all(np.diff(b.ci95, axis=1) < np.diff(a.ci95, axis=1))


def test_validation_holds_out_samples_and_flags_a_model_that_does_not_generalise(truth, clean):
    """Fit the first 70 % of a run, predict the last 30 %: on data the model explains, the
    held-out residual scale is the noise's (about 1, as the fit's). When the last 30 % of the
    data drift away (x offset by 20 noise std there, which no parameter of the model makes),
    the fit of the first 70 % is as good as before but its prediction is not, and the fit says
    so: a problem in `quality`, the stop reason, the table."""
    start = {"t": 0.9 * float(truth.t), "K_theta": 1.2 * float(truth.K_theta)}
    good = _noisy(clean, 1.0, seed=5)
    fit = pj.identify(good, ("t", "K_theta"), scene=SC, model="double1r", initial=start,
                      noise=NOISE, fit_options=pj.FitOptions(validation=0.3, force=True))
    v = fit.validation
    assert 17 <= v["samples"] <= 19 and int(fit.mask.sum()) == N - v["samples"]
    assert 0.7 < v["residual_scale"] < 1.4 and v["generalises"] and fit.quality["ok"], v
    ts, X = good.ts, np.array(good.X)
    X[ts > 0.7 * T_END, 0] += 20 * NOISE[0]
    drifted = pj.experiment(ts, X, name="drifted")
    fit2 = pj.identify(drifted, ("t", "K_theta"), scene=SC, model="double1r", initial=start,
                       noise=NOISE, fit_options=pj.FitOptions(validation=0.3, force=True))
    np.testing.assert_allclose(fit2.estimate, fit.estimate, rtol=1e-6)  # the same fitted part
    v2 = fit2.validation
    assert v2["residual_scale"] > 10 and not v2["generalises"], v2
    assert not fit2.quality["ok"] and fit2.history["stop"] == "does not generalise"
    assert "does NOT generalise" in fit2.table()
    assert fit2.to_dict()["validation"]["generalises"] is False
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        html = open(fit2.report(f"{d}/report.html", figures=fit2.figures(d)),
                    encoding="utf-8").read()
    assert "does not generalise" in html and "held out" in html.lower()
    for bad, match in [(1.5, "in \\(0, 1\\)"), (["nope"], "not one of the experiments"),
                       ([0], "every experiment")]:
        with pytest.raises(pj.IdentificationError, match=match):
            pj.identify(good, ("t", "K_theta"), scene=SC, model="double1r",
                        fit_options=pj.FitOptions(validation=bad))


def test_covariance_against_finite_difference_jacobian(fits):
    """Rebuild the Jacobian with respect to the physical parameters by central differences of
    the residuals (the fit's own residual function at points along each parameter) and
    recompute s^2 (J^T J)^-1 with numpy."""
    fit = fits[1.0]
    p_hat = np.asarray(fit.estimate)
    cols = []
    for i in range(len(p_hat)):
        h = 1e-4 * p_hat[i]
        dp = np.zeros_like(p_hat)
        dp[i] = h
        cols.append((fit.residuals_at(p_hat + dp) - fit.residuals_at(p_hat - dp)) / (2 * h))
    J_fd = np.column_stack(cols)
    r = fit.residuals_at(p_hat)
    # The same residuals from the plain program as from the fit's Jacobian program, to the
    # integration's rounding (the two programs round differently, and adaptive steps amplify
    # it; 1e-7 noise units is 5e-13 m).
    np.testing.assert_allclose(r, fit.residuals, rtol=1e-7, atol=1e-7)
    np.testing.assert_allclose(fit.jacobian, J_fd, rtol=2e-4, atol=1e-5 * np.abs(J_fd).max())
    s2 = r @ r / (r.size - 2)
    C_fd = s2 * np.linalg.inv(J_fd.T @ J_fd)
    # J^T J has a condition number of about 1e10 here (t against K_theta): the variance along
    # the direction the data do not determine amplifies the finite differences' error of ~1e-7
    # (their agreement there, 1 % at one estimate, a factor 4 at another 0.01 standard errors
    # away, says nothing about the library). So: the covariance is s^2 (J^T J)^-1 of the fit's
    # own (checked) Jacobian, and the determined combination t^3 K_theta has the finite
    # differences' variance to 0.1 %.
    J = np.asarray(fit.jacobian)
    np.testing.assert_allclose(fit.covariance, s2 * np.linalg.inv(J.T @ J), rtol=1e-5)
    np.testing.assert_allclose(np.sqrt(np.diag(fit.covariance)), fit.std, rtol=1e-12)
    c0 = fit.identifiability["combinations"][0]
    e = np.asarray(c0["exponents"])
    rel_fd = math.sqrt(e @ (C_fd / np.outer(p_hat, p_hat)) @ e)
    np.testing.assert_allclose(rel_fd, c0["relative_std"], rtol=1e-3)
    # the 95 % interval is estimate +- t_{0.975, N-P} std
    from scipy import stats

    q = stats.t.ppf(0.975, r.size - 2)
    np.testing.assert_allclose(fit.ci95, np.column_stack([p_hat - q * fit.std,
                                                          p_hat + q * fit.std]), rtol=1e-12)
    rel = fit.std / p_hat
    with np.errstate(over="ignore"):  # exp(q rel) = inf for the undetermined direction
        ref = np.column_stack([p_hat * np.exp(-q * rel), p_hat * np.exp(q * rel)])
    np.testing.assert_allclose(fit.ci95_log, ref, rtol=1e-12)
    assert np.all(fit.ci95_log >= 0)  # [0, inf] for the direction the data do not see


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_robust_loss_resists_outliers(truth, clean, fits):
    """Ten gross outliers (1 mm, 200 noise standard deviations) on x: the linear fit's residual
    scale blows up and its stiffness moves; Huber's and Cauchy's stay near the clean fit. The
    loss is a traced value: these fits reuse the module's compiled Jacobian."""
    exp = _noisy(clean, 1.0, seed=1)
    X = np.asarray(exp.X).copy()
    X[5:55:5, 0] += 1e-3
    bad = pj.experiment(exp.ts, X, name="outliers")
    ref = fits[1.0]
    start = {"t": float(ref.estimate[0]), "K_theta": float(ref.estimate[1])}

    def stiffness(fit):
        c = fit.identifiability["combinations"][0]
        return c["value"], c["relative_std"]

    k_ref, rel_ref = stiffness(ref)
    # (one start: the outliers make a poor fit, which "auto" would refit from more starts)
    lin = pj.identify(bad, ("t", "K_theta"), scene=SC, initial=start, noise=NOISE,
                      fit_options=pj.FitOptions(force=True, starts=1))
    assert math.sqrt(lin.sigma2) > 10  # the outliers dominate a linear fit
    err_lin = abs(math.log(stiffness(lin)[0] / k_ref))
    errs = {}
    for loss in ("huber", "cauchy"):
        # one start too: Huber's residual scale with the outliers is about 8, so "auto" refits
        # from 3 more starts (and compiles a vmapped screening for them), all of which
        # end at the given start's minimum (its cost the lowest, the estimate the same to the
        # last digit)
        rob = pj.identify(bad, ("t", "K_theta"), scene=SC, initial=start, noise=NOISE,
                          fit_options=pj.FitOptions(loss=loss, force=True, starts=1))
        errs[loss] = abs(math.log(stiffness(rob)[0] / k_ref))
    print(f"stiffness error: linear {err_lin:.3g}, {errs} (relative std {rel_ref:.3g})")
    # Cauchy's influence vanishes for gross outliers; Huber's is bounded (each outlier still
    # pulls with loss_scale noise units), so it lands between
    assert errs["cauchy"] < 2 * rel_ref
    assert errs["cauchy"] < errs["huber"] < err_lin


# A servo that does not follow its commands (a smooth 2 mrad wobble on top of them) and a robot
# released off its quasi-static state: the measured angles must drive the model, and the
# initial state must be estimated, for the data to be explained.
D0 = np.array([3e-4, -2e-4, 2e-3, 1e-3, -1e-3, 1e-2])  # m, m, rad, m/s, m/s, rad/s


@pytest.fixture(scope="module")
def lagging(truth):
    """Noisy L2 data of the lagging servo released off equilibrium, simulated directly with
    `pj.simulate` (not the identification's program), and the true initial pose."""
    import equinox as eqx
    import jax.numpy as jnp

    robot = pj.Robot(truth)
    cmd = pj.InverseKinematicsAngles(pj.Reduced(), robot, pj.Circle())

    class Actual(eqx.Module):
        def __call__(self, t):
            return cmd(t) + 2e-3 * jnp.sin(2 * jnp.pi * 3.0 * t) * jnp.array([1.0, -0.5, 0.7])

    act = pj.MotionDriven(Actual())
    L2 = pj.Double1R()
    z0, zd0 = pj.quasi_static_state(L2, robot, pj.Circle(), 0.0, act)
    z0, zd0 = z0.at[:3].add(D0[:3]), zd0.at[:3].add(D0[3:])
    ts = np.linspace(0.0, T_END, N)
    sol = pj.simulate(L2, robot, act, z0, zd0, jnp.asarray(ts))
    X, th = np.asarray(sol.z[:, :3]), np.asarray(sol.z[:, 3:6])
    rng = np.random.default_rng(3)
    Xn = X.copy()
    Xn[:, :2] += NOISE[0] * rng.standard_normal((N, 2))
    Xn[:, 2] += NOISE[1] * rng.standard_normal(N)
    return pj.experiment(ts, Xn, th=th, name="lagging servo"), X[0]


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_measured_angles_and_initial_state(truth, lagging, fits):
    """With the measured angles as actuation and the initial pose and velocity estimated, the
    fit explains the data to the noise, recovers t^3 K_theta and the release offsets within
    their intervals; with the commands and the scene's initial state it cannot (s >> 1)."""
    exp, X0 = lagging
    start = {"t": 0.9 * float(truth.t), "K_theta": 1.2 * float(truth.K_theta)}
    fit = pj.identify(exp, ("t", "K_theta"), scene=SC, model="double1r", initial=start, noise=NOISE,
                      actuation="measured",
                      fit_options=pj.FitOptions(initial_state="pose-velocity", force=True))
    assert fit.history["stop"] == "converged"
    assert 0.7 < math.sqrt(fit.sigma2) < 1.3, fit.table()
    c = fit.identifiability["combinations"][0]
    assert c["expression"] == "t^3.00 * K_theta^1.00"
    e_t, e_k = c["exponents"]
    true_c = float(truth.t) ** e_t * float(truth.K_theta) ** e_k
    assert abs(math.log(c["value"] / true_c)) < 2.5 * c["relative_std"], (c, true_c)
    row = fit.initial_state["experiments"]["lagging servo"]
    for i, name in enumerate(("x0", "y0", "phi0", "xd0", "yd0", "phid0")):
        v = row[name]
        assert v["std"] > 0
        assert abs(v["offset"] - D0[i]) < 3 * v["std"], (name, v, D0[i])
        if i < 3:
            assert abs(v["estimate"] - X0[i]) < 3 * v["std"], (name, v, X0[i])
    assert "initial state of lagging servo" in fit.table()
    # the commanded angles and the scene's initial state (reuses the compiled fit of `fits`)
    bad = pj.identify(exp, ("t", "K_theta"), scene=SC, model="double1r", initial=start, noise=NOISE,
                      actuation="commanded", fit_options=pj.FitOptions(force=True, starts=1))
    assert math.sqrt(bad.sigma2) > 20 * math.sqrt(fit.sigma2)
    # which is reported as a poor fit, never as converged or identifiable
    assert fit.quality["ok"] and bad.history["stop"] == "poor fit", bad.history
    assert not bad.quality["explains_data"] and "does not explain" in bad.table()
    assert all(c["status"] == "not trustworthy (poor fit)"
               for c in bad.identifiability["combinations"])
    # and by default the file's angles drive the model (the same as the first fit)
    assert "measured" in pj.identify(exp, ("t", "K_theta"), scene=SC, model="double1r",
                                     initial=start, noise=NOISE,
                                     fit_options=pj.FitOptions(initial_state="pose-velocity",
                                                               max_iter=1, starts=1,
                                                               force=True)).actuation
    # max_iter=0: no step, the statistics at the initial values (a fit only lowers the cost)
    at_start = pj.identify(exp, ("t", "K_theta"), scene=SC, model="double1r", initial=start,
                           noise=NOISE, fit_options=pj.FitOptions(
                               initial_state="pose-velocity", max_iter=0, force=True))
    assert at_start.history["iterations"] == 0, at_start.history
    assert "no step" in at_start.history["stop"]
    # (to the round trip through the fit's log coordinates)
    np.testing.assert_allclose(at_start.estimate, [start["t"], start["K_theta"]], rtol=1e-14)
    assert at_start.sigma2 > fit.sigma2


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_profile_likelihood(truth, clean, fits):
    """One determined unknown (K_theta, t fixed at the truth): the profile-likelihood interval
    has the linearised one's width to 3 % (a wrong Jacobian changes the linearised width), its
    ends lie within 10 % of the width of the linearised ends (the response's curvature in
    K_theta over the +-12 % interval shifts both ends up by 5-7 % of the width on these data)
    and it holds the truth."""
    exp = _noisy(clean, 1.0, seed=1)
    fit = pj.identify(exp, ("K_theta",), scene=SC, model="double1r",
                      initial={"K_theta": 1.2 * float(truth.K_theta)}, noise=NOISE)
    # one unknown the data determine: the preflight does not refuse it
    pre = fit.history["preflight"]
    assert pre["refused"] == [] and not pre["forced"]
    assert pre["combinations"][0]["status"] == "identifiable", pre
    assert fit.quality["preflight_not_identifiable"] == []
    pr = fit.profile("K_theta")
    lo, hi = pr["ci"]
    llo, lhi = pr["linearised"]
    assert pr["open"] == [] and pr["limited_by_bounds_of"] == []
    assert abs((hi - lo) / (lhi - llo) - 1) < 0.03, pr
    assert abs(lo - llo) < 0.1 * (lhi - llo) and abs(hi - lhi) < 0.1 * (lhi - llo), pr
    assert lo < float(truth.K_theta) < hi
    # the walked points: a rise that grows both ways from zero at the estimate
    d = np.asarray(pr["delta"])
    k = int(np.argmin(np.abs(np.asarray(pr["values"]) - pr["estimate"])))
    assert d[k] == 0.0 and np.all(np.diff(d[:k + 1]) < 0) and np.all(np.diff(d[k:]) > 0)

    with pytest.raises(pj.PPRError, match="not an unknown of this fit"):
        fit.profile("E")
    # (the two-unknown profiles are checked through the CLI, test_cli_synth_then_identify)


def test_bad_requests_raise_clear_errors(truth, clean):
    exp = _noisy(clean, 1.0, seed=0)
    with pytest.raises(pj.PPRError, match="unknown 'colour' is not a float parameter"):
        pj.identify(exp, ("colour",), scene=SC)
    with pytest.raises(pj.PPRError, match=r"both unknown and fixed"):
        pj.identify(exp, ("t",), scene=SC, fixed={"t": 5e-4})
    with pytest.raises(pj.PPRError, match=r"bounds of 't' must satisfy"):
        pj.identify(exp, ("t",), scene=SC, bounds={"t": (1e-3, 1e-4)})
    with pytest.raises(pj.PPRError,
                       match=r"initial value of 't' = 0.0005 m is not strictly inside"):
        pj.identify(exp, ("t",), scene=SC, bounds={"t": (1e-4, 4e-4)})
    with pytest.raises(pj.PPRError, match=r"initial values given for \['E'\]"):
        pj.identify(exp, ("t",), scene=SC, initial={"E": 70e9})
    with pytest.raises(pj.PPRError, match="unknown loss"):
        pj.identify(exp, ("t",), scene=SC, fit_options=pj.FitOptions(loss="l1"))
    with pytest.raises(pj.PPRError, match="unknown scene"):
        pj.identify(exp, ("t",), scene="modes")
    with pytest.raises(pj.DataError, match="no experiment"):
        pj.identify([], ("t",))
    with pytest.raises(pj.PPRError, match="unknown actuation"):
        pj.identify(exp, ("t",), scene=SC, actuation="encoder")
    with pytest.raises(pj.DataError, match=r"needs the actuated angles th_1, th_2, th_3"):
        pj.identify(exp, ("t",), scene=SC, actuation="measured")
    with pytest.raises(pj.PPRError, match="applies to a motion-driven scene; paper-circle is"):
        pj.identify(exp, ("t",), actuation="measured", scene="paper-circle")
    with pytest.raises(pj.PPRError, match="unknown initial_state"):
        pj.identify(exp, ("t",), scene=SC, fit_options=pj.FitOptions(initial_state="all"))
    with pytest.raises(pj.PPRError, match="no free initial state"):
        pj.identify(exp, ("t",), scene=SC, model="reduced",
                    fit_options=pj.FitOptions(initial_state="pose"))
    # argument types: named, not a raw TypeError
    for bad in (1e-4, ("a", "b"), (1e-4,), (1e-4, float("nan"))):
        with pytest.raises(pj.IdentificationError, match=r"noise must be \(position m, phi rad"):
            pj.identify(exp, ("t",), scene=SC, noise=bad)


def _still_experiment(n=20):
    """A platform at rest, n samples at 100 Hz: enough for every check made before compiling."""
    return pj.experiment(0.01 * np.arange(n), np.tile([0.55, 0.26, 0.0], (n, 1)), name="still")


@pytest.mark.parametrize("kw, match", [
    (dict(options=pj.SceneOptions(rtol=float("nan"))),
     r"rtol must be finite: nan is not finite \(allowed range \[1e-14, 0.01\]\)"),
    (dict(options=pj.SceneOptions(rtol=0.5)),
     r"rtol = 0.5 is out of its allowed range \[1e-14, 0.01\]"),
    (dict(options=pj.SceneOptions(atol=-1e-9)),
     r"atol = -1e-09 is out of its allowed range \[1e-16, 0.01\]"),
    (dict(options=pj.SceneOptions(max_steps=0)),
     r"max_steps = 0 is out of its allowed range \[1, 1e\+09\]"),
    (dict(options=pj.SceneOptions(max_steps=2.5)), r"max_steps must be an integer"),
    (dict(loss_scale=0.0), r"loss_scale = 0.0 is out of its allowed range \(0, 1e\+06\] "
                           r"noise units"),
    (dict(loss_scale=float("inf")), r"loss_scale must be finite"),
    (dict(max_iter=-1), r"max_iter = -1 is out of its allowed range \[0, 100000\]"),
    (dict(max_iter=0, solver="optimistix-gn"), r"max_iter = 0 \(no step.*needs solver='lm'"),
    (dict(xtol="1e-8"), r"xtol must be a number"),
    (dict(ftol=-1.0), r"ftol = -1.0 is out of its allowed range \[0, 1\]"),
    (dict(stat_tol=float("nan")), r"stat_tol must be finite"),
    (dict(seed=-1), r"seed = -1 is out of its allowed range"),
])
def test_solver_arguments_checked_before_compiling(kw, match, monkeypatch):
    """identify's numeric options are checked before anything is compiled (a NaN rtol ran the
    whole fit, 107 s, and then advised loosening tolerances; a zero loss scale was blamed on the
    data): one IdentificationError naming the argument and its allowed range. The compiled
    residual is replaced by a tripwire: no check may reach it."""
    from ppr_jax._studies._identify import _run

    def tripwire(*a, **k):
        raise AssertionError("compiled before the arguments were checked")

    monkeypatch.setattr(_run, "_residual_and_jacobian", tripwire)
    kw = dict(kw)
    options = kw.pop("options", None)
    with pytest.raises(pj.IdentificationError, match=match):
        pj.identify(_still_experiment(), ("t",), options=options,
                    fit_options=pj.FitOptions(**kw))


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_cli_synth_then_identify(tmp_path, truth, capsys):
    """`ppr-jax synth` writes a tracker file that `ppr-jax identify` reads back and fits; the
    outputs exist and the JSON holds the estimates with intervals. Same shapes and options as
    the module's fits, so both commands reuse the compiled functions."""
    import json
    import os

    from ppr_jax._cli import main

    path = str(tmp_path / "exp.csv")
    K = float(truth.K_theta)
    assert main(["synth", "--scene", "servo-circle", "--model", "double1r", "--t-end",
                 str(T_END), "--rate", "100", "--noise-pos", str(NOISE[0]), "--noise-phi",
                 str(NOISE[1]), "--seed", "3", "--set", f"K_theta={K}", "--out", path]) == 0
    exp = pj.load_csv(path)
    assert exp.n == N and exp.th is not None and exp.tau is not None
    out = str(tmp_path / "fit")
    args = ["identify", "--data", path, "--scene", "servo-circle", "--model", "double1r",
            "--unknown", "t",
            "--unknown", "K_theta", "--initial", f"t={0.9 * float(truth.t)}",
            "--noise-pos", str(NOISE[0]), "--noise-phi", str(NOISE[1]),
            "--actuation", "commanded",  # the module's compiled fit (no angles packed)
            # the default step limit, given: a static option, another value would compile
            # the fit again
            "--max-steps", "200000", "--profile", "--out", out]
    # the pair is refused by the preflight: exit 2, the combination named, nothing written
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("ppr-jax: error: preflight") and "t^-1.00 * K_theta^3.00" in err
    assert "--force" in err and not os.path.exists(out)
    rc = main(args + ["--force"])  # --force reaches identify: the fit runs
    assert rc == 0
    assert "driven by the commanded angles of the nominal robot" in capsys.readouterr().err
    # t and K_theta both unknown: K_theta's profile is open on both sides (t compensates), t's
    # ends only where K_theta meets a bound, and the profile says so
    prof = {p["name"]: p for p in json.load(open(f"{out}/profiles.json"))}
    assert prof["K_theta"]["ci"] == [None, None] and prof["K_theta"]["open"] == ["low", "high"]
    assert prof["t"]["open"] == [] and prof["t"]["limited_by_bounds_of"] == ["K_theta"]
    assert "profile 95% interval of t" in open(f"{out}/estimates.txt").read()
    summary = json.load(open(f"{out}/estimates.json"))
    c0 = summary["identifiability"]["combinations"][0]
    e = dict(zip(["t", "K_theta"], c0["exponents"]))
    true_c = float(truth.t) ** e["t"] * K ** e["K_theta"]
    assert abs(math.log(c0["value"] / true_c)) < 1.96 * c0["relative_std"]
    for name in ("t", "K_theta"):
        lo, hi = summary["unknowns"][name]["ci95"]
        assert lo <= float(getattr(truth, name)) <= hi
    assert summary["quality"]["preflight_not_identifiable"] == ["t^-1.00 * K_theta^3.00"]
    for f in ("estimates.txt", "fitted.csv", "fit_trajectory.png", "fit_residuals.png",
              "profiles.png"):
        assert os.path.getsize(f"{out}/{f}") > 0
    lines = open(f"{out}/fitted.csv").read().splitlines()
    assert lines[0].startswith("experiment,time,x_measured") and len(lines) == N + 1
    # the identified robot, read back: the parameter file holds the estimates exactly, and its
    # MJCF (when MuJoCo is installed) carries the identified strip's spring stiffness
    # the report: one file, figures inside, the data file named with its sha256, the command
    import hashlib

    report = open(f"{out}/report.html", encoding="utf-8").read()
    assert hashlib.sha256(open(path, "rb").read()).hexdigest() in report
    assert report.count("data:image/png;base64,") == 3 and "95 % (profile)" in report
    assert "ppr-jax identify --data" in report and "jax=" in report
    # the fit was forced past the preflight: the robot files say so themselves
    assert "# WARNING: forced past the preflight" in open(f"{out}/identified.toml").read()
    assert "WARNING: forced past the preflight" in open(f"{out}/identified_l2.xml").read()
    back = pj.load_params(f"{out}/identified.toml")
    for name in ("t", "K_theta"):
        assert float(getattr(back, name)) == summary["unknowns"][name]["estimate"]
    try:
        import mujoco
    except ImportError:
        return
    m = mujoco.MjModel.from_xml_path(f"{out}/identified_l2.xml")
    np.testing.assert_allclose(m.jnt_stiffness[m.joint("B0").id], float(pj.Robot(back).K),
                               rtol=1e-15)


def test_cli_user_errors_exit_2(tmp_path, capsys):
    import os

    from ppr_jax._cli import main

    bad = tmp_path / "bad.csv"
    bad.write_text("time,x,y\n0,0.5,0.2\n")
    assert main(["identify", "--data", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "missing column(s) phi" in err[0]
    assert main(["identify", "--data", str(tmp_path / "none.csv")]) == 2
    assert "no such file" in capsys.readouterr().err
    assert main(["synth", "--rate", "0", "--out", str(tmp_path / "s.csv")]) == 2
    assert "rate and t_end must be > 0" in capsys.readouterr().err
    # the options of validation, several starts and the measurement model reach `identify`
    # and are checked there, before anything is compiled
    good = tmp_path / "good.csv"
    good.write_text("time,x,y,phi\n" + "".join(f"{0.01 * k},0.55,0.26,0.0\n"
                                                for k in range(20)))
    for extra, msg in [(["--validation", "1.5"], "validation: a fraction"),
                       (["--validation", "nope"], "not one of the experiments"),
                       (["--rtol", "nan"], "rtol must be finite: nan is not finite (allowed "
                                           "range [1e-14, 0.01])"),
                       (["--loss-scale", "0"], "loss_scale = 0.0 is out of its allowed range "
                                               "(0, 1e+06] noise units"),
                       (["--max-steps", "0"], "max_steps = 0 is out of its allowed range"),
                       (["--starts", "0"], "starts must be 'auto' or an integer in [1, 1000]"),
                       (["--starts", "many"], "starts must be 'auto' or an integer")]:
        assert main(["identify", "--data", str(good), "--scene", SC, "--out",
                     str(tmp_path / "o"), *extra]) == 2
        err = [ln for ln in capsys.readouterr().err.splitlines() if "error" in ln.lower()]
        assert len(err) == 1 and err[0].startswith("ppr-jax: error: ") and msg in err[0], extra
    assert not os.path.exists(tmp_path / "o")  # a refused run writes nothing
    with pytest.raises(SystemExit):  # argparse: bias or delay only
        main(["identify", "--data", str(good), "--nuisance", "offset"])


def test_cli_out_checked_before_fitting(tmp_path, capsys):
    """--out is checked before the data are read or anything is fitted: a directory that
    cannot be written (or a file in its way) fails at once, one line naming it, instead of
    losing the fit afterwards. Nothing is created for a run that does not start. As root the
    permission bits do not bind, so /proc (where nobody creates files) stands in for the
    read-only directory."""
    import os

    from ppr_jax._cli import main

    data = str(tmp_path / "none.csv")  # never read: the --out check comes first
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    cases = [(str(ro / "fit"), "its parent"), (str(ro), "the directory is not writable")]
    try:
        probe = ro / "probe"
        probe.write_text("")  # root: the bits do not bind
        probe.unlink()
        cases = []
    except PermissionError:
        pass
    if os.path.isdir("/proc/self"):
        cases.append(("/proc/ppr-jax-out", "its parent '/proc' is not writable"))
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    cases.append((str(blocker / "fit"), "is a file, not a directory"))
    assert len(cases) >= 2
    for out, msg in cases:
        assert main(["identify", "--data", data, "--out", out]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"ppr-jax: error: --out {out!r}") \
            and msg in err[0], (out, err)
        assert not os.path.exists(out)
    ro.chmod(0o755)


def test_identified_robot_files_marked_when_the_fit_is_poor_or_forced(tmp_path):
    """identified.toml and identified_l2.xml say in themselves where they come from, and carry a
    WARNING line when the fit cannot be trusted (quality problems: a poor fit, an unknown at a
    bound, no generalisation) or was forced past the preflight; a good fit's files carry none.
    The files stay readable: load_params reads the parameters back exactly, the MJCF is valid
    XML (MuJoCo loads it where installed). Built from a stand-in result: nothing is fitted."""
    import types
    import xml.etree.ElementTree as ET

    from ppr_jax._cli._identify import _write_robot

    params = pj.scene_params("servo-circle").replace(t=4.87e-4)
    base = dict(names=("t", "K_theta"), model="double1r", experiment_names=("run0",),
                params=params)
    good = types.SimpleNamespace(**base, quality={
        "residual_scale": 0.98, "problems": [], "preflight_not_identifiable": []})
    poor = types.SimpleNamespace(**base, quality={
        "residual_scale": 20.3, "problems": [
            "the model does not explain the data: residual scale s = 20.3 (> 3; 1 = noise as "
            "stated)", "K_theta at a bound"],
        "preflight_not_identifiable": ["t^-1.00 * K_theta^3.00"]})
    for fit, marked in ((good, False), (poor, True)):
        d = tmp_path / ("poor" if marked else "good")
        d.mkdir()
        toml, xml = _write_robot(str(d), fit)
        texts = [open(toml).read(), open(xml).read()]
        for text in texts:
            assert "identified by ppr-jax identify: t, K_theta fitted with the double1r model " \
                   "to run0" in text
            assert ("WARNING" in text) == marked and ("fit quality: ok" in text) != marked
            if marked:
                assert "WARNING: this fit cannot be trusted: the model does not explain the " \
                       "data" in text and "K_theta at a bound" in text
                assert "WARNING: forced past the preflight" in text
                assert "t^-1.00 * K_theta^3.00" in text
        assert float(pj.load_params(toml).t) == 4.87e-4
        assert ET.parse(xml).getroot().tag == "mujoco"
        try:
            import mujoco
        except ImportError:
            continue
        mujoco.MjModel.from_xml_path(xml)
    with pytest.raises(pj.PPRError, match="comments need a .toml file"):
        pj.save_params(params, str(tmp_path / "robot.json"), comments=["no comments in JSON"])


def test_recovers_truth_from_data_of_an_independent_formulation(truth):
    """Sim-to-sim recovery on data ppr_jax did not make: the independent scipy L2
    (benchmarks/contenders/known_truth.py) simulates a robot whose K_theta is 15 % above the
    module's, under commands a controller computed from its own nominal model (gamma = 0.81,
    not the robot's); the fit names that model (`commands=`) and recovers t^3 K_theta within
    its 95 % interval. The same data fitted with the commands recomputed from the robot's own
    parameters (what the default did before) cannot be explained (s about 20: residuals of
    0.1 mm against 5 um of noise) and say so: the check can fail. Same shapes and unknowns as
    the module's fits: the compiled Jacobian is reused."""
    from benchmarks.contenders import known_truth

    robot = truth.replace(K_theta=1.15 * float(truth.K_theta))
    nominal = truth.replace(gamma=0.81)
    ts, X, _ = known_truth.servo_data(robot, nominal, t_end=T_END, rate=(N - 1) / T_END)
    rng = np.random.default_rng(7)
    X[:, :2] += NOISE[0] * rng.standard_normal((N, 2))
    X[:, 2] += NOISE[1] * rng.standard_normal(N)
    exp = pj.experiment(ts, X, name="independent")  # no angles in the file: commanded
    start = {"t": 0.9 * float(truth.t), "K_theta": 1.2 * float(truth.K_theta)}
    kw = dict(model="double1r", scene=SC, initial=start, noise=NOISE)

    def miss(fit):
        c0 = fit.identifiability["combinations"][0]
        e = dict(zip(fit.names, c0["exponents"]))
        true_value = float(robot.t) ** e["t"] * float(robot.K_theta) ** e["K_theta"]
        return abs(math.log(c0["value"] / true_value)) / c0["relative_std"]

    fit = pj.identify(exp, ("t", "K_theta"), commands=nominal,
                      fit_options=pj.FitOptions(force=True), **kw)
    assert "commanded angles of the given commands model" in fit.actuation
    assert fit.history["stop"] == "converged"
    assert miss(fit) < 1.96, (miss(fit), fit.table())
    assert 0.8 < math.sqrt(fit.sigma2) < 1.25
    # commands of the robot's own gamma (one start: a poor fit on purpose)
    wrong = pj.identify(exp, ("t", "K_theta"), fit_options=pj.FitOptions(starts=1, force=True),
                        **kw)
    assert "nominal robot" in wrong.actuation
    assert math.sqrt(wrong.sigma2) > 5, wrong.table()
    assert wrong.history["stop"] == "poor fit" and not wrong.quality["ok"]


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_tracker_bias_and_delay_estimated_as_nuisance(truth):
    """A tracker whose frame is offset by (0.3 mm, -0.2 mm, 2 mrad) and whose samples lag the
    actuation by 4 ms: samples of the independent scipy L2 (benchmarks/contenders) at t - 4 ms,
    stamped t. With the measurement model estimated (`nuisance=("bias", "delay")`) the fit
    explains the data to the noise and recovers the bias, the delay and t^3 K_theta within
    3 standard deviations each; without it the same data cannot be explained (s >> 1). The
    fit without nuisances has the module's shapes (the compiled Jacobian is reused)."""
    from benchmarks.contenders import known_truth

    robot = truth.replace(K_theta=1.15 * float(truth.K_theta))
    nominal = truth.replace(gamma=0.81)
    bias, delay = np.array([3e-4, -2e-4, 2e-3]), 4e-3
    stamps = np.arange(1, N) / ((N - 1) / T_END)  # the first stamp would need t < 0
    _, X, _ = known_truth.servo_data(robot, nominal, times=stamps - delay)
    rng = np.random.default_rng(11)
    X = X + bias[None, :]
    X[:, :2] += NOISE[0] * rng.standard_normal((N - 1, 2))
    X[:, 2] += NOISE[1] * rng.standard_normal(N - 1)
    exp = pj.experiment(stamps, X, name="biased, late")
    start = {"t": 0.9 * float(truth.t), "K_theta": 1.2 * float(truth.K_theta)}
    kw = dict(model="double1r", scene=SC, initial=start, noise=NOISE, commands=nominal)
    # a poor fit on purpose
    plain = pj.identify(exp, ("t", "K_theta"), fit_options=pj.FitOptions(starts=1, force=True),
                        **kw)
    assert math.sqrt(plain.sigma2) > 5 and not plain.quality["ok"], plain.table()
    fit = pj.identify(exp, ("t", "K_theta"),
                      fit_options=pj.FitOptions(nuisance=("bias", "delay"), force=True), **kw)
    assert 0.75 < math.sqrt(fit.sigma2) < 1.3, fit.table()
    got = fit.measurement["values"]
    for name, true in zip(("bias_x", "bias_y", "bias_phi", "delay"), (*bias, delay)):
        assert abs(got[name]["estimate"] - true) < 3 * got[name]["std"], (name, fit.table())
    assert got["delay"]["std"] < 0.5e-3  # the delay is determined, not merely bounded
    c0 = fit.identifiability["combinations"][0]
    e = dict(zip(fit.names, c0["exponents"]))
    true_c = float(robot.t) ** e["t"] * float(robot.K_theta) ** e["K_theta"]
    assert abs(math.log(c0["value"] / true_c)) < 3 * c0["relative_std"], fit.table()
    assert "measurement: bias_x" in fit.table() and fit.to_dict()["measurement"]
    with pytest.raises(pj.IdentificationError, match="unknown nuisance"):
        pj.identify(exp, ("t",), fit_options=pj.FitOptions(nuisance=("offset",)))


@pytest.mark.slow
def test_default_call_fits_t_and_is_not_refused(truth, clean):
    """The default call on the servo circle (L2, unknowns t alone with K_theta from the PRB table):
    the preflight finds t identifiable on the module's data, the fit is not refused, does not
    escalate, and holds the truth (the data's K_theta is the table's). One more compilation:
    slow."""
    fit = pj.identify(_noisy(clean, 1.0, seed=2), scene=SC,
                      initial={"t": 0.9 * float(truth.t)}, noise=NOISE)
    assert fit.names == ("t",)
    pre = fit.history["preflight"]
    assert pre["refused"] == [] and pre["combinations"][0]["status"] == "identifiable", pre
    assert fit.history["escalation"] is None and fit.quality["ok"], fit.table()
    lo, hi = fit.ci95[0]
    assert lo <= float(truth.t) <= hi, fit.table()

