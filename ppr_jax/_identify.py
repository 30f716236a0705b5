"""Identification of robot parameters from measured platform trajectories (MODEL.md section 7).

`identify(experiments, unknowns=("t", "K_theta"), model="double1r")` fits any subset of the
float leaves of `RobotParams` to measured poses by least squares through the simulation, and
reports how well the data determine them: the Gauss-Newton covariance, 95 % intervals,
correlations, the identifiable combinations (a singular-value analysis of the relative
sensitivities) and the residuals against the stated noise.

The experiment (what the motors did) is a scene:
- ``servo-circle``: the actuated angles drive the model (motion-driven), its response simulated
  from its quasi-static state at t = 0 under those angles (`quasi_static_state`);
- ``paper-circle``: torque-driven by the measured torques (columns tau_1..tau_3, cubic Hermite
  interpolation) or, without them, by L1's inverse-dynamics torques of eq 55 for the commands'
  parameters (held fixed), from the nominal pose at t = 0.
Sample times are those of the trajectory (t = 0 at the start of the motion).

Which angles drive a servo-circle model (`actuation`, MODEL.md section 7):
- ``"auto"`` (default): the measured angles when every experiment holds th_1..th_3, else the
  commands. Measured angles are what the motors did; commands recomputed from a guess are not.
- ``"commanded"``: L1's inverse kinematics of eq 55 for the parameters of the model that
  computed the commands, `commands` (a `RobotParams`; default the nominal robot, `params` with
  `fixed` applied), held fixed whatever the unknowns: the motors received those commands
  whatever the robot really is. Never the unknowns' initial values: a geometric unknown (gamma,
  rho, r, theta_c, a link length) would then change the commands it is fitted against.
- ``"measured"``: the measured actuated angles th_1..th_3 drive the
  model instead of the commands, through a C2 not-a-knot cubic spline of the samples
  (`spline_pieces`; C2 because its second derivative is the prescribed acceleration). Use it
  when the servos do not follow their commands exactly: the commands then leave a tracking
  error the fit would misread as stiffness. Encoders are far finer than a tracker, so the
  spline interpolates (no smoothing); it is fourth-order accurate (1e-9 rad at 100 Hz on the
  paper's circle).
- ``initial_state``: ``"scene"`` (default) starts each experiment from the scene's quasi-static
  state at t = 0; ``"pose"`` adds each experiment's initial platform pose (x0, y0, phi0) to the
  unknowns, ``"pose-velocity"`` also its initial platform velocity, as offsets from that state
  (the platform coordinates z[:3] of every model; the actuated angles stay where the actuation
  puts them, the chains' other coordinates where the quasi-static state does). They are nuisance
  parameters: the parameters' covariance is marginal over them (their Jacobian columns projected
  out), and they are reported per experiment in `Identification.initial_state`. Use it when a
  recording starts in motion or off equilibrium.

Method, and why:
- Residuals: simulated minus measured pose at the sample times, each channel divided by its
  stated noise (`noise=(position m, phi rad)`), so x, y and phi weigh alike and the residual
  variance is about 1 when the noise is as stated. The simulation saves at the sample times
  directly (no interpolation error).
- Unknowns are reparametrised for their bounds (default `PARAM_RANGES`): p = exp(log lo +
  (log hi - log lo) sigmoid(z)) for lo > 0 (relative steps, so t ~ 5e-4 and E ~ 7e10 are both
  O(1) in z), p = lo + (hi - lo) sigmoid(z) otherwise. Bounds are never crossed.
- Experiments are padded to a common length and simulated in one vmapped call, so several
  experiments cost one compilation.
- Jacobian: forward mode through diffrax (`jax.jacfwd`, `diffrax.ForwardMode`), one compiled
  function returning residuals and Jacobian together (one jvp per unknown). The default solver
  is a Levenberg-Marquardt loop on the host around that one compiled function: the same
  compilation then serves the covariance and any further fit on data of the same shapes.
  ``solver="optimistix-lm"`` / ``"optimistix-gn"`` run `optimistix.LevenbergMarquardt` /
  `optimistix.GaussNewton` instead; they compile their own loop (L2, 0.5 s experiment: about 115 s
  against 31 s for the compiled Jacobian, and 0.4 s per step against 0.12 s, because
  `jax.linearize` re-runs the solve for each tangent).
- Robust losses ``huber`` and ``cauchy`` transform each residual r into sign(r) sqrt(2 rho(r))
  (as scipy's `least_squares`), with `loss_scale` in noise units (default 3): least squares on
  the transformed residuals minimises the robust cost.
- Covariance: s^2 (J^T J)^-1 with J the Jacobian with respect to the physical parameters and
  s^2 = sum r^2 / (N - P) estimated from the (weighted) residuals; intervals use Student's t.
"""

from __future__ import annotations

import math
import time
from typing import Optional, Sequence, Union

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._actuation import MotionDriven, TorqueDriven
from ._checks import RESULTS, PPRError
from ._custom_types import Array
from ._data import DataError, Experiment
from ._models import get_model
from ._params import PARAM_RANGES, RobotParams
from ._prb import derived
from ._robot import Robot
from ._scenes import SceneOptions, get_scene, input_panels_at, scene_params
from ._simulate import get_solver
from ._trajectory import Interpolated, PiecewiseCubic, spline_pieces

LOSSES = ("linear", "huber", "cauchy")
#: largest step of the Levenberg-Marquardt loop in the reparametrised unknowns z
MAX_STEP_Z = 1.0
SOLVERS = ("lm", "optimistix-lm", "optimistix-gn")
#: what drives a servo-circle model: the measured angles when the data hold them (auto), the
#: scene's commands for the parameters of the model that computed them, or the measured angles
ACTUATIONS = ("auto", "commanded", "measured")
#: what of each experiment's initial state is estimated (number of unknowns per experiment):
#: nothing (the scene's quasi-static state), the platform pose (x0, y0, phi0), or the pose and
#: the platform velocity
INITIAL_STATES = {"scene": 0, "pose": 3, "pose-velocity": 6}
#: the scale of the initial-state unknowns in the fit (m, m, rad, m/s, m/s, rad/s): the size of
#: offset a unit step in z makes, so that the trust region of MAX_STEP_Z means 1 mm, 10 mrad
INIT_SCALE = (1e-3, 1e-3, 1e-2, 1e-2, 1e-2, 1e-1)
INIT_NAMES = ("x0", "y0", "phi0", "xd0", "yd0", "phid0")
INIT_UNITS = ("m", "m", "rad", "m/s", "m/s", "rad/s")
ID_SCENES = ("servo-circle", "paper-circle")
#: residual scale s (1 = noise as stated) above which a fit does not explain the data: its
#: intervals then measure the misfit, and it is reported as a poor fit, never as converged
POOR_FIT_SCALE = 3.0
#: default noise weights: tracker position (m) and platform angle (rad), Optotrak-like
DEFAULT_NOISE = (1e-4, 1e-3)


class IdentificationError(PPRError):
    """An identification that cannot run as asked (unknown names, bounds, a failed simulation)."""


# ---------------------------------------------------------------------------------------------
# The problem: everything the compiled residual needs, as one pytree
# ---------------------------------------------------------------------------------------------


class _Problem(eqx.Module):
    base: RobotParams  # the parameters with the unknowns at their initial values
    commands: RobotParams  # the parameters of the model that computed the commands (fixed)
    lo: Array  # (P,) bounds of the unknowns
    hi: Array
    ts: Array  # (E, m) simulation times per experiment (padded)
    X: Array  # (E, m, 3) measured pose (padded)
    w: Array  # (E, m, 3) weights 1/noise, 0 on padding
    tau: Optional[Array]  # (E, m, 3) measured torques or None
    th: Optional[Array]  # (E, m - 1, 4, 3) spline pieces of the measured actuated angles or None
    rtol: Array
    atol: Array
    names: tuple = eqx.field(static=True)
    log: tuple = eqx.field(static=True)  # per unknown: bounds in log space
    model: object = eqx.field(static=True)
    scene: str = eqx.field(static=True)
    equal_links: bool = eqx.field(static=True)
    solver: object = eqx.field(static=True)
    max_steps: int = eqx.field(static=True)
    loss: Array  # index into LOSSES: traced, so that changing the loss reuses the compilation
    loss_scale: Array
    #: unknowns of each experiment's initial state (0, 3 or 6: INITIAL_STATES), after the
    #: parameters in z, as offsets in units of `init_scale` (m, m, rad, m/s, m/s, rad/s)
    n_init: int = eqx.field(static=True, default=0)
    init_scale: Optional[Array] = None


def _to_p(prob: _Problem, z):
    s = jax.nn.sigmoid(z[:len(prob.names)])
    out = []
    for i, lg in enumerate(prob.log):
        lo, hi = prob.lo[i], prob.hi[i]
        out.append(jnp.exp(jnp.log(lo) + s[i] * (jnp.log(hi) - jnp.log(lo))) if lg
                   else lo + s[i] * (hi - lo))
    return jnp.stack(out)


def _to_z(prob_log, lo, hi, p):
    p, lo, hi = (np.asarray(v, dtype=np.float64) for v in (p, lo, hi))
    lg = np.asarray(prob_log)
    s = np.where(lg, (np.log(p) - np.log(lo)) / (np.log(hi) - np.log(lo)), (p - lo) / (hi - lo))
    return np.log(s) - np.log1p(-s)


def _dp_dz(prob: _Problem, z):
    """Diagonal of dp/dz (the reparametrisation is elementwise) of the parameters."""
    z = z[:len(prob.names)]
    s = jax.nn.sigmoid(z)
    p = _to_p(prob, z)
    ds = s * (1 - s)
    lg = jnp.asarray(prob.log)
    return jnp.where(lg, p * (jnp.log(prob.hi) - jnp.log(prob.lo)) * ds, (prob.hi - prob.lo) * ds)


def _params_at(prob: _Problem, p):
    return eqx.tree_at(lambda q: tuple(getattr(q, n) for n in prob.names), prob.base,
                       tuple(p[i] for i in range(len(prob.names))))


def _offsets(prob: _Problem, z):
    """(E, 6) offsets of each experiment's initial platform pose and velocity (zeros where not
    estimated) from the unknowns z."""
    E = prob.ts.shape[0]
    d = jnp.zeros((E, 6))
    if prob.n_init:
        P = len(prob.names)
        d = d.at[:, :prob.n_init].set(z[P:].reshape(E, prob.n_init) * prob.init_scale)
    return d


def _pose_one(prob: _Problem, params, base_robot, ts, tau, th, d0):
    """Simulated pose (m, 3) of one experiment at times ts (ts[0] = 0, the scene's start) and
    whether its scene succeeded: the scene's own run (`AbstractScene.run`), driven by the
    measured angles or torques, or by the scene's commands for the commands' robot."""
    model = prob.model
    scene = get_scene(prob.scene)
    traj = scene.trajectory()
    # The panel count is a shape: decided from the (traced) times as the scenes decide it.
    options = SceneOptions(solver=prob.solver, rtol=prob.rtol, atol=prob.atol,
                           max_steps=prob.max_steps, adjoint=diffrax.ForwardMode(),
                           panels=input_panels_at(traj, ts)).prepared(model, traj)
    if th is not None:
        # the angles the motors followed: a C2 spline through the samples
        act = MotionDriven(PiecewiseCubic(ts, th))
    elif tau is not None:
        act = TorqueDriven(Interpolated(ts, tau))
    else:
        # the commands, fixed, from the commands' parameters
        act = scene.commands(model, base_robot, traj, ts, options.panels).actuation
    robot = Robot(params, equal_links=prob.equal_links)
    res = scene.run(model, robot, options, act, ts=ts, initial_offset=d0)
    return res.X, res.result == RESULTS.successful


def _robust(r, loss, c):
    """sign(r) sqrt(2 rho(r)) for the loss with index `loss` in LOSSES (all three are computed
    and one selected: cheap, and the loss stays a traced value)."""
    a = jnp.abs(r)
    # Huber: rho = r^2/2 inside c, c (|r| - c/2) outside (max(...) keeps sqrt's argument safe)
    huber = jnp.where(a <= c, r, jnp.sign(r) * jnp.sqrt(jnp.maximum(2 * c * a - c * c, c * c)))
    cauchy = jnp.sign(r) * c * jnp.sqrt(jnp.log1p((r / c) ** 2))
    return jnp.select([loss == 0, loss == 1], [r, huber], cauchy)


def _weighted_residuals(prob: _Problem, p, d0):
    """(E, m, 3) weighted residuals (simulated - measured) / noise, raw (before the loss), and
    the success flag of every experiment's simulation; d0 (E, 6) initial-state offsets."""
    params = _params_at(prob, p)
    base_robot = Robot(jax.lax.stop_gradient(prob.commands))
    tau, th = prob.tau, prob.th
    X, ok = jax.vmap(
        lambda ts, tau, th, d0: _pose_one(prob, params, base_robot, ts, tau, th, d0),
        in_axes=(0, None if tau is None else 0, None if th is None else 0, 0),
    )(prob.ts, tau, th, d0)
    # Padding rows have weight 0; a failed simulation may be NaN there, keep it out of sums.
    r = jnp.where(prob.w > 0, (X - prob.X) * prob.w, 0.0)
    return r, X, jnp.all(ok)


def _residual_vector(prob: _Problem, z):
    r, X, ok = _weighted_residuals(prob, _to_p(prob, z), _offsets(prob, z))
    return _robust(r.reshape(-1), prob.loss, prob.loss_scale), (ok, X)


@eqx.filter_jit
def _residual_and_jacobian(prob: _Problem, z):
    """(r (N,), J (N, P) = dr/dz, simulations ok, simulated pose (E, m, 3)) in one compiled
    forward-mode pass: the fit, the covariance and the fitted trajectory share it."""
    def fn(z):
        r, aux = _residual_vector(prob, z)
        return r, (r, aux)

    J, (r, (ok, X)) = jax.jacfwd(fn, has_aux=True)(z)
    return r, J, ok, X


# ---------------------------------------------------------------------------------------------
# Result
# ---------------------------------------------------------------------------------------------


class Identification(eqx.Module):
    """The result of `identify` (SI units; P unknowns, E experiments).

    names (P,) unknowns; estimate, initial, std (P,); ci95 (P, 2) 95 % confidence intervals
    (Student t on the Gauss-Newton standard errors); ci95_log (P, 2) the same for log p,
    p exp(+-q std/p), positive (the better reading when std/p is not small); covariance, correlation (P, P); params the
    fitted `RobotParams`; sigma2 the estimated variance of the weighted residuals (about 1 when
    the noise is as stated: s^2 = sum r^2/(N - P)); jacobian (N, P) d(weighted residual)/d(p)
    at the estimate; residuals (N,) weighted residuals (after the loss) at the estimate;
    fitted (E, m, 3) and measured (E, m, 3) poses, ts (E, m) their times, mask (E, m) real
    samples (padding False); identifiability (dict: singular values of the relative
    sensitivities, condition number, the combinations the data determine and those they do
    not); residual_stats (dict: RMS per experiment and channel in m / rad against the stated
    noise); history (dict: iterations, cost, convergence, compile_s, run_s)."""

    names: tuple
    estimate: Array
    initial: Array
    std: Array
    ci95: Array
    ci95_log: Array
    covariance: Array
    correlation: Array
    params: RobotParams
    sigma2: float
    jacobian: Array
    residuals: Array
    fitted: Array
    measured: Array
    ts: Array
    mask: Array
    identifiability: dict
    residual_stats: dict
    history: dict
    model: str
    scene: str
    experiment_names: tuple
    noise: tuple
    problem: _Problem
    initial_state: Optional[dict] = None
    z: Optional[Array] = None
    #: what drove the model: "measured angles", or the commands (or torques) and for which
    #: parameters they were computed
    actuation: str = ""
    #: whether the fit can be trusted: {"ok", "residual_scale", "explains_data", "at_bound",
    #: "problems" (list of sentences)}
    quality: Optional[dict] = None

    def residuals_at(self, values) -> np.ndarray:
        """Weighted residuals (N,) (after the loss) at parameter values (P,) (physical units,
        order of `names`), the initial state (when estimated) held at its estimate, through the
        fit's compiled function: for checks such as a finite-difference Jacobian, or a profile
        of the cost."""
        prob = self.problem
        z = _to_z(prob.log, np.asarray(prob.lo), np.asarray(prob.hi), values)
        z = np.concatenate([z, np.asarray(self.z)[len(self.names):]])
        return np.asarray(_residual_and_jacobian(prob, jnp.asarray(z))[0])

    def profile(self, name: str, *, level: float = 0.95, n_max: int = 8,
                max_iter: int = 20) -> dict:
        """Profile-likelihood interval of the unknown `name`: walk it away from the estimate in
        both directions (steps of half its linearised standard error, in log p for a
        log-bounded unknown), re-fitting every other unknown at each step (warm-started, the
        fit's own compiled function), until the cost rises by the likelihood-ratio threshold
        (S - S_min) / s^2 = F(level; 1, N - P) (the square of Student's t: the linearised interval
        when the model is linear in the unknowns). The end points are interpolated in the
        signed root of the rise. A side that reaches a bound, or `n_max` steps, without the
        rise is open (None): the data do not bound the unknown on that side. An end reached
        only because another unknown ran into its bound while compensating (t against
        K_theta) names that unknown in `limited_by_bounds_of`: the interval is then the
        bounds' doing, not the data's.

        Where the model is nonlinear in the unknowns over the interval (the stiffness through
        t^3 when t is poorly determined) the profile interval is the one to quote: it is
        invariant under reparametrisation and does not assume a quadratic cost.

        Returns a dict: name, estimate, level, threshold, values and delta (the walked points,
        sorted, delta = (S - S_min) / s^2), ci (low, high) with None for an open side, open
        (the open sides: 'low', 'high'), limited_by_bounds_of, linearised (ci95 for
        comparison), evaluations, run_s."""
        from scipy import stats

        if name not in self.names:
            raise IdentificationError(f"{name!r} is not an unknown of this fit "
                                      f"({', '.join(self.names)})")
        prob = self.problem
        i = self.names.index(name)
        lo, hi = float(prob.lo[i]), float(prob.hi[i])
        lg = prob.log[i]
        p_hat = float(self.estimate[i])
        n_all = self.z.shape[0]
        dof = max(int(self.mask.sum()) * 3 - n_all, 1)
        q = float(stats.f.ppf(level, 1, dof))
        s2 = float(self.sigma2)
        s_min = float(self.residuals @ self.residuals)
        std = float(self.std[i])
        if lg:
            span = math.log(hi / lo)
            h = min(0.5 * std / p_hat, span / 8) if math.isfinite(std) else span / 8
            h = max(h, 1e-6)
            at = lambda k: p_hat * math.exp(k * h)  # noqa: E731
        else:
            span = hi - lo
            h = min(0.5 * std, span / 8) if math.isfinite(std) else span / 8
            h = max(h, 1e-9 * span)
            at = lambda k: p_hat + k * h  # noqa: E731
        free = np.ones(n_all, bool)
        free[i] = False
        t0 = time.perf_counter()
        pts = [(p_hat, 0.0)]
        ends, open_, limited = [None, None], [], []
        n_eval = [0]
        to_x = (lambda v: math.log(v)) if lg else (lambda v: v)  # noqa: E731
        from_x = (lambda x: math.exp(x)) if lg else (lambda x: x)  # noqa: E731

        def rise(v, z):
            """(S(v) - S_min) / s^2 with the other unknowns re-fitted from z, and their z."""
            z = np.array(z, dtype=np.float64)
            z[i] = _to_z((lg,), [lo], [hi], [v])[0]
            if free.any():
                (z, r, _, _), hist = _levenberg_marquardt(prob, z, max_iter, 1e-8, 1e-10, 1e-2,
                                                          free=free)
                n_eval[0] += hist["evaluations"]
            else:  # a single unknown: nothing to re-fit
                r, _, ok, _ = _residual_and_jacobian(prob, jnp.asarray(z))
                _check_ok(ok, z, prob)
                r = np.asarray(r)
                n_eval[0] += 1
            return (float(r @ r) - s_min) / s2, z

        for side, sgn in ((0, -1), (1, 1)):
            prev = (p_hat, 0.0, np.asarray(self.z))
            for k in range(1, n_max + 1):
                v = at(sgn * k)
                if not (lo < v < hi):
                    break
                try:
                    d, z = rise(v, prev[2])
                except IdentificationError:
                    break  # the simulation fails out there: the walk ends
                pts.append((v, d))
                if d > q:
                    # A steep wall (another unknown reaching its bound) is bisected until the
                    # crossing step is short enough for the interpolation below.
                    cur = (v, d, z)
                    for _ in range(8):
                        if cur[1] <= 3 * q:
                            break
                        vm = from_x((to_x(prev[0]) + to_x(cur[0])) / 2)
                        try:
                            dm, zm = rise(vm, prev[2])
                        except IdentificationError:
                            break
                        pts.append((vm, dm))
                        if dm > q:
                            cur = (vm, dm, zm)
                        else:
                            prev = (vm, dm, zm)
                    # the signed root of the rise is nearly linear in the parameter
                    a0, a1 = math.sqrt(max(prev[1], 0.0)), math.sqrt(cur[1])
                    f = (math.sqrt(q) - a0) / (a1 - a0)
                    x0, x1 = to_x(prev[0]), to_x(cur[0])
                    ends[side] = from_x(x0 + f * (x1 - x0))
                    sz = 1 / (1 + np.exp(-cur[2][:len(self.names)]))
                    limited += [n for j, n in enumerate(self.names)
                                if j != i and not (1e-3 < sz[j] < 1 - 1e-3) and n not in limited]
                    break
                prev = (v, d, z)
            if ends[side] is None:
                open_.append(("low", "high")[side])
        n_eval = n_eval[0]
        pts.sort()
        return {"name": name, "estimate": p_hat, "level": level, "threshold": q,
                "values": [v for v, _ in pts], "delta": [d for _, d in pts],
                "ci": ends, "open": open_, "limited_by_bounds_of": limited,
                "linearised": [float(self.ci95[i, 0]), float(self.ci95[i, 1])],
                "evaluations": n_eval, "run_s": time.perf_counter() - t0}

    def table(self) -> str:
        """A text table of the estimates with their intervals."""
        lines = [f"{'name':>10s} {'estimate':>13s} {'std':>11s} {'95% low':>13s} "
                 f"{'95% high':>13s} {'rel.std':>8s} {'initial':>13s}"]
        for i, n in enumerate(self.names):
            e, s = float(self.estimate[i]), float(self.std[i])
            lines.append(f"{n:>10s} {e:13.6g} {s:11.3g} {float(self.ci95[i, 0]):13.6g} "
                         f"{float(self.ci95[i, 1]):13.6g} {abs(s / e) * 100:7.3g}% "
                         f"{float(self.initial[i]):13.6g}")
        idf = self.identifiability
        lines.append(f"model {self.model}, scene {self.scene}, {len(self.experiment_names)} "
                     f"experiment(s), N = {self.residuals.shape[0]} residuals, s = "
                     f"{math.sqrt(self.sigma2):.4g} (1 = noise as stated), condition number "
                     f"{idf['condition_number']:.3g}")
        if self.actuation:
            lines.append(f"  driven by: {self.actuation}")
        for msg in (self.quality or {}).get("problems", []):
            lines.append(f"  WARNING: {msg}")
        for c in idf["combinations"]:
            lines.append(f"  {c['expression']}: relative std {c['relative_std'] * 100:.3g}% "
                         f"({c['status']})")
        if idf.get("note"):
            lines.append(f"  note: {idf['note']}")
        if self.initial_state:
            for en, row in self.initial_state["experiments"].items():
                parts = [(f"{k} = {v['estimate']:.6g}" if "estimate" in v else
                          f"{k} {v['offset']:+.4g}") + f" +- {v['std']:.2g} {v['unit']}"
                         for k, v in row.items()]
                lines.append(f"  initial state of {en}: " + ", ".join(parts))
        for e in self.residual_stats["experiments"]:
            lines.append(f"  {e['name']}: RMS x {e['rms_x_m'] * 1e3:.4g} mm, y "
                         f"{e['rms_y_m'] * 1e3:.4g} mm, phi {e['rms_phi_rad'] * 1e3:.4g} mrad "
                         f"(noise {self.noise[0] * 1e3:.3g} mm, {self.noise[1] * 1e3:.3g} mrad)")
        return "\n".join(lines)

    def figures(self, out_dir: str) -> list:
        """Write fit_trajectory.png and fit_residuals.png to `out_dir` (matplotlib, Agg);
        returns their paths."""
        from ._identify_plots import identification_figures

        return identification_figures(self, out_dir)

    def to_dict(self) -> dict:
        """JSON-ready summary (estimates, intervals, correlations, identifiability, residuals);
        an infinite or undefined value (a parameter the data do not see) is None."""
        return _json_safe({
            "model": self.model,
            "scene": self.scene,
            "actuation": self.actuation,
            "experiments": list(self.experiment_names),
            "noise": {"position_m": self.noise[0], "phi_rad": self.noise[1]},
            "unknowns": {
                n: {"estimate": float(self.estimate[i]), "std": float(self.std[i]),
                    "ci95": [float(self.ci95[i, 0]), float(self.ci95[i, 1])],
                    "ci95_log": [float(self.ci95_log[i, 0]), float(self.ci95_log[i, 1])],
                    "initial": float(self.initial[i])}
                for i, n in enumerate(self.names)
            },
            "correlation": np.asarray(self.correlation).tolist(),
            "covariance": np.asarray(self.covariance).tolist(),
            "sigma2": float(self.sigma2),
            "identifiability": self.identifiability,
            "residual_stats": self.residual_stats,
            "initial_state": self.initial_state,
            "quality": self.quality,
            "history": self.history,
        })


def _json_safe(x):
    if isinstance(x, dict):
        return {k: _json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_safe(v) for v in x]
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    return x


# ---------------------------------------------------------------------------------------------
# identify
# ---------------------------------------------------------------------------------------------


def _fill_prb(params: RobotParams, names) -> RobotParams:
    """Unknown PRB parameters that `params` leaves to the table become explicit leaves."""
    dv = derived(params)
    kw = {n: float(getattr(dv, n)) for n in ("gamma", "K_theta", "rho")
          if n in names and getattr(params, n) is None}
    return params.replace(**kw) if kw else params


def _pack(experiments: Sequence[Experiment], w_pos, w_phi, scene, actuation="commanded"):
    """Pad the experiments to one length: times start at 0 (a leading t = 0 sample of weight 0
    when the data start later) and continue past the end at the median step (weight 0).
    With measured actuation, also the spline pieces of each experiment's angles on its padded
    times (the spline's first piece continued back to 0, a linear continuation after the end)."""
    rows = []
    for e in experiments:
        ts = np.asarray(e.ts, dtype=np.float64)
        if ts[0] < 0:
            raise DataError(f"{e.name}: times must start at or after 0 (the start of the motion), "
                            f"got {ts[0]:g} s")
        lead = ts[0] > 0
        rows.append((ts, lead))
    m = max(len(ts) + int(lead) for ts, lead in rows)
    TS, XX, WW, TT, MASK = [], [], [], [], []
    has_tau = [e.tau is not None for e in experiments]
    use_tau = scene == "paper-circle" and all(has_tau)
    if scene == "paper-circle" and any(has_tau) and not all(has_tau):
        raise DataError("paper-circle: either every experiment gives torques tau_1..tau_3 or none")
    if actuation == "measured":
        lack = [e.name for e in experiments if e.th is None]
        if lack:
            raise DataError(f"actuation 'measured' needs the actuated angles th_1, th_2, th_3 in "
                            f"every experiment; missing in {', '.join(lack)}")
        short = [e.name for e in experiments if e.n < 4]
        if short:
            raise DataError(f"actuation 'measured' needs at least 4 samples of the angles (a "
                            f"cubic spline); too few in {', '.join(short)}")
    TH = []
    for e, (ts, lead) in zip(experiments, rows):
        X = np.asarray(e.X)
        mask = np.ones(len(ts), bool)
        tau = None if e.tau is None else np.asarray(e.tau)
        if lead:
            ts = np.concatenate([[0.0], ts])
            X = np.concatenate([X[:1], X])
            mask = np.concatenate([[False], mask])
            if tau is not None:
                tau = np.concatenate([tau[:1], tau])
        k = m - len(ts)
        if k:
            dt = float(np.median(np.diff(ts)))
            ts = np.concatenate([ts, ts[-1] + dt * np.arange(1, k + 1)])
            X = np.concatenate([X, np.repeat(X[-1:], k, 0)])
            mask = np.concatenate([mask, np.zeros(k, bool)])
            if tau is not None:
                tau = np.concatenate([tau, np.repeat(tau[-1:], k, 0)])
        if actuation == "measured":
            TH.append(spline_pieces(ts, e.ts, e.th))
        TS.append(ts)
        XX.append(X)
        MASK.append(mask)
        WW.append(mask[:, None] * np.array([1 / w_pos, 1 / w_pos, 1 / w_phi]))
        TT.append(tau)
    tau = np.stack(TT) if use_tau else None
    th = np.stack(TH) if TH else None
    return np.stack(TS), np.stack(XX), np.stack(WW), tau, th, np.stack(MASK)


def identify(
    experiments: Union[Experiment, Sequence[Experiment]],
    unknowns: Sequence[str] = ("t", "K_theta"),
    *,
    model="double1r",
    scene: str = "servo-circle",
    actuation: str = "auto",
    initial_state: str = "scene",
    params: Optional[RobotParams] = None,
    commands: Optional[RobotParams] = None,
    fixed: Optional[dict] = None,
    initial: Optional[dict] = None,
    bounds: Optional[dict] = None,
    noise: tuple = DEFAULT_NOISE,
    loss: str = "linear",
    loss_scale: float = 3.0,
    solver: str = "lm",
    max_iter: int = 50,
    xtol: float = 1e-8,
    ftol: float = 1e-10,
    stat_tol: float = 1e-2,
    ode_solver=None,
    rtol: float = 1e-8,
    atol: float = 1e-10,
    max_steps: int = 100_000,
    n_elements: Optional[int] = None,
) -> Identification:
    """Fit `unknowns` (names of `RobotParams` float leaves) to measured experiments.

    experiments: one `Experiment` or several (fitted jointly; `load_csv`, `load_experiments`).
    model: "double1r" (L2, default), "reduced" (L1), "rigid" (L0) or a model instance.
    scene: the experiment's actuation, "servo-circle" (default) or "paper-circle" (module
    docstring). actuation: "auto" (default: the data's th_1..th_3 drive the model when every
    experiment holds them and no `commands` are named, else the commands), "commanded" (the scene's commands, or torques,
    computed for `commands`, the parameters of the model that computed them: default the
    nominal robot `params` with `fixed`, never the unknowns' initial values) or "measured"
    (servo-circle: the data's angles). `Identification.actuation` says which drove the fit.
    initial_state: "scene" (default), "pose" or "pose-velocity": what of each experiment's initial
    state is estimated (module docstring). params: the robot (default `scene_params(scene)`), `fixed` ({name: value})
    overrides applied to it; `initial` ({name: value}) start values of unknowns (default: the
    robot's); `bounds` ({name: (lo, hi)}) default `PARAM_RANGES`. noise: (position m, phi rad),
    the residual weights (their scale is estimated from the fit; the report compares the RMS of
    the residuals to them). loss: "linear", "huber" or "cauchy" with `loss_scale` in noise units.
    solver: "lm" (host Levenberg-Marquardt on the compiled Jacobian), "optimistix-lm",
    "optimistix-gn". xtol, ftol: stop when the step in z or the relative cost change is below
    them; "lm" also stops when an accepted step is shorter than `stat_tol` standard errors
    (measured with the information matrix J^T J / s^2, so that steps along undetermined
    directions do not count). ode_solver, rtol, atol, max_steps: the simulation's (default tsit5, 1e-8, 1e-10).

    Returns an `Identification`. Raises `IdentificationError` for unknown or fixed names that
    are not leaves, bounds outside the physical range, an initial value outside its bounds or a
    simulation that fails at the initial values; `DataError` for unusable data."""
    exps = [experiments] if isinstance(experiments, Experiment) else list(experiments)
    if not exps:
        raise DataError("no experiment given")
    for e in exps:
        if not isinstance(e, Experiment):
            raise DataError(f"experiments must be Experiment objects (load_csv), got "
                            f"{type(e).__name__}")
    if scene not in ID_SCENES:
        raise IdentificationError(f"unknown scene {scene!r}; allowed: {', '.join(ID_SCENES)}")
    if actuation not in ACTUATIONS:
        raise IdentificationError(f"unknown actuation {actuation!r}; allowed: "
                                  f"{', '.join(ACTUATIONS)}")
    if actuation == "auto":
        # named commands are asked for; otherwise what the files hold
        has_th = all(e.th is not None for e in exps)
        measured = commands is None and scene == "servo-circle" and has_th
        actuation = "measured" if measured else "commanded"
    if actuation == "measured" and scene != "servo-circle":
        raise IdentificationError("actuation 'measured' (the measured angles drive the model) "
                                  "applies to the motion-driven servo-circle scene; "
                                  "paper-circle is torque-driven (it uses measured torques "
                                  "tau_1..tau_3 when the data give them)")
    if initial_state not in INITIAL_STATES:
        raise IdentificationError(f"unknown initial_state {initial_state!r}; allowed: "
                                  f"{', '.join(INITIAL_STATES)}")
    n_init = INITIAL_STATES[initial_state]
    if loss not in LOSSES:
        raise IdentificationError(f"unknown loss {loss!r}; allowed: {', '.join(LOSSES)}")
    if solver not in SOLVERS:
        raise IdentificationError(f"unknown solver {solver!r}; allowed: {', '.join(SOLVERS)}")
    names = tuple(unknowns)
    if not names:
        raise IdentificationError("no unknown given; choose among " + ", ".join(PARAM_RANGES))
    for n in names:
        if n not in PARAM_RANGES:
            raise IdentificationError(f"unknown {n!r} is not a float parameter; allowed: "
                                      f"{', '.join(PARAM_RANGES)}")
    if len(set(names)) != len(names):
        raise IdentificationError(f"an unknown is repeated: {list(names)}")
    fixed = dict(fixed or {})
    clash = set(fixed) & set(names)
    if clash:
        raise IdentificationError(f"parameter(s) {sorted(clash)} are both unknown and fixed")
    if len(noise) != 2 or not all(float(v) > 0 for v in noise):
        raise IdentificationError(f"noise must be (position m, phi rad), both > 0, got {noise}")
    stray = set(initial or {}) - set(names)
    if stray:
        raise IdentificationError(f"initial values given for {sorted(stray)}, which are not "
                                  f"unknowns (to hold a parameter at a value, use fixed=)")
    mdl = get_model(model, n_elements)
    if n_init and scene == "servo-circle" and mdl.actuated_index is None:
        raise IdentificationError(f"initial_state={initial_state!r}: the {mdl.name} model has no "
                                  f"free initial state in the motion-driven servo-circle scene "
                                  f"(its pose follows from the angles); use initial_state='scene'")
    base = scene_params(scene) if params is None else params
    try:
        base = base.replace(**fixed) if fixed else base
        nominal = base
        base = base.replace(**{k: float(v) for k, v in (initial or {}).items()})
    except ValueError as err:
        raise IdentificationError(str(err)) from None
    base = _fill_prb(base, names)
    bounds = dict(bounds or {})
    lo, hi, lg = [], [], []
    for n in names:
        plo, phi_, unit, _ = PARAM_RANGES[n]
        b = bounds.pop(n, (plo, phi_))
        b_lo, b_hi = float(b[0]), float(b[1])
        if not (plo <= b_lo < b_hi <= phi_):
            raise IdentificationError(f"bounds of {n!r} must satisfy {plo:g} <= lo < hi <= "
                                      f"{phi_:g} {unit}, got ({b_lo:g}, {b_hi:g})")
        v = float(getattr(base, n))
        if not (b_lo < v < b_hi):
            raise IdentificationError(f"initial value of {n!r} = {v:g} {unit} is not strictly "
                                      f"inside its bounds ({b_lo:g}, {b_hi:g}); give initial="
                                      f"{{{n!r}: value}}")
        lo.append(b_lo)
        hi.append(b_hi)
        lg.append(b_lo > 0)
    if bounds:
        raise IdentificationError(f"bounds given for parameters that are not unknowns: "
                                  f"{sorted(bounds)}")
    ts, X, W, tau, th, mask = _pack(exps, float(noise[0]), float(noise[1]), scene, actuation)
    n_res = int(mask.sum()) * 3
    n_unknown = len(names) + n_init * len(exps)
    if n_res <= n_unknown:
        raise DataError(f"{n_res} residuals cannot determine {n_unknown} unknowns")
    from ._robot import _equal_links

    eq = _equal_links(base) and "l1" not in names and "l3" not in names
    ode = get_solver("tsit5" if ode_solver is None else ode_solver)
    if commands is not None and not isinstance(commands, RobotParams):
        raise IdentificationError(f"commands must be the RobotParams of the model that computed "
                                  f"the commands, got {type(commands).__name__}")
    if commands is not None and actuation == "measured":
        raise IdentificationError("commands= names the model that computed the commands; with "
                                  "actuation='measured' the measured angles drive the model")
    cmd = nominal if commands is None else commands
    if actuation == "measured":
        drive = "the measured actuated angles th_1..th_3"
    elif scene == "paper-circle" and all(e.tau is not None for e in exps):
        drive = "the measured torques tau_1..tau_3"
    else:
        what = "commanded angles" if scene == "servo-circle" else "inverse-dynamics torques"
        drive = (f"the {what} of the nominal robot (params with fixed), held fixed"
                 if commands is None else f"the {what} of the given commands model, held fixed")
    prob = _Problem(
        base=base, commands=cmd, lo=jnp.asarray(lo), hi=jnp.asarray(hi), ts=jnp.asarray(ts),
        X=jnp.asarray(X), w=jnp.asarray(W), tau=None if tau is None else jnp.asarray(tau),
        th=None if th is None else jnp.asarray(th),
        rtol=jnp.asarray(rtol, dtype=jnp.float64), atol=jnp.asarray(atol, dtype=jnp.float64),
        names=names, log=tuple(lg), model=mdl, scene=scene, equal_links=eq, solver=ode,
        max_steps=int(max_steps), loss=jnp.asarray(LOSSES.index(loss)),
        loss_scale=jnp.asarray(float(loss_scale), dtype=jnp.float64),
        n_init=n_init, init_scale=jnp.asarray(INIT_SCALE[:n_init]) if n_init else None,
    )
    p0 = np.array([float(getattr(base, n)) for n in names])
    z0 = np.concatenate([_to_z(lg, lo, hi, p0), np.zeros(n_init * len(exps))])
    if n_init:
        z0 = _initial_state_guess(prob, z0, mask)
    if solver == "lm":
        z, hist = _levenberg_marquardt(prob, z0, max_iter, xtol, ftol, stat_tol)
    else:
        z, hist = _optimistix(prob, z0, solver, max_iter, xtol, ftol)
    return _finish(prob, z, p0, hist, exps, mask, tuple(float(v) for v in noise), drive)


def _initial_state_guess(prob, z0, mask):
    """Start the initial-state unknowns where the data put them: the pose offset as the first
    measured sample minus the simulated one, the velocity offset as the same difference of the
    first two samples' finite difference. A released robot oscillates at 10 to 100 Hz, so the
    cost is far from convex in the initial state; from zero offsets the fit can end in a local
    minimum."""
    _, _, ok, X = _residual_and_jacobian(prob, jnp.asarray(z0))
    _check_ok(ok, z0, prob)
    X, Xm, ts = np.asarray(X), np.asarray(prob.X), np.asarray(prob.ts)
    P, k = len(prob.names), prob.n_init
    d = np.zeros((X.shape[0], 6))
    for j in range(X.shape[0]):
        i = np.flatnonzero(mask[j])
        d[j, :3] = Xm[j, i[0]] - X[j, i[0]]
        dt = ts[j, i[1]] - ts[j, i[0]]
        d[j, 3:] = ((Xm[j, i[1]] - Xm[j, i[0]]) - (X[j, i[1]] - X[j, i[0]])) / dt
    z0 = np.array(z0, dtype=np.float64)
    z0[P:] = (d[:, :k] / np.asarray(INIT_SCALE[:k])).reshape(-1)
    return z0


def _check_ok(ok, z, prob):
    if not bool(ok):
        p = np.asarray(_to_p(prob, jnp.asarray(z)))
        at = ", ".join(f"{n} = {v:.6g}" for n, v in zip(prob.names, p))
        raise IdentificationError(f"the {prob.model.name} simulation of the {prob.scene} scene "
                                  f"failed at {at} (solver failure or step limit; loosen "
                                  f"tolerances or raise max_steps)")


def _levenberg_marquardt(prob, z0, max_iter, xtol, ftol, stat_tol, free=None):
    """Levenberg-Marquardt (Marquardt's diagonal scaling, Nielsen's damping update) on the host,
    around the one compiled residual-and-Jacobian function. Each trial point costs one call.
    `free` (bool, like z) the unknowns that move (default all; a profile holds one fixed and
    reuses the same compiled function)."""
    t0 = time.perf_counter()
    r, J, ok, X = _residual_and_jacobian(prob, jnp.asarray(z0))
    r, J = np.asarray(r), np.asarray(J)
    compile_s = time.perf_counter() - t0
    _check_ok(ok, z0, prob)
    t1 = time.perf_counter()
    z = np.array(z0, dtype=np.float64)
    sel = np.arange(z.size) if free is None else np.flatnonzero(free)
    cost = float(r @ r)
    A = J.T @ J
    lam = 1e-3  # dimensionless: the damping term is lam * diag(J^T J) (Marquardt's scaling)
    nu = 2.0
    costs = [cost]
    n_eval, it, reason = 1, 0, "max_iter"
    for it in range(1, max_iter + 1):
        Jf = J[:, sel]
        g = Jf.T @ r
        A = Jf.T @ Jf
        if not np.max(np.diag(A)) > 0:
            # e.g. t with a kinematic model (L0/L1 motion-driven): nothing to fit
            reason = "the residuals do not depend on the unknowns"
            break
        D = np.maximum(np.diag(A), 1e-12 * max(float(np.max(np.diag(A))), 1e-300))
        try:
            dz = -np.linalg.solve(A + lam * np.diag(D), g)
        except np.linalg.LinAlgError:
            lam *= nu
            nu *= 2
            continue
        # A trust region in z (unit steps: a factor of about 10 in a log-bounded parameter):
        # along a direction the data barely see (t against K_theta) the Gauss-Newton step is
        # huge and would run the estimate into its bounds.
        big = float(np.max(np.abs(dz)))
        if big > MAX_STEP_Z:
            dz = dz * (MAX_STEP_Z / big)
        z_new = z.copy()
        z_new[sel] += dz
        r_new, J_new, ok_new, X_new = _residual_and_jacobian(prob, jnp.asarray(z_new))
        n_eval += 1
        r_new = np.asarray(r_new)
        cost_new = float(r_new @ r_new) if bool(ok_new) else np.inf
        pred = float(dz @ (lam * D * dz - g))  # predicted reduction of the cost (>= 0)
        if np.isfinite(cost_new) and cost_new < cost:
            rho_gain = (cost - cost_new) / max(pred, 1e-300)
            rel = (cost - cost_new) / max(cost, 1e-300)
            z, r, J, X, cost = z_new, r_new, np.asarray(J_new), X_new, cost_new
            costs.append(cost)
            lam *= max(1 / 3, 1 - (2 * rho_gain - 1) ** 3)
            nu = 2.0
            # Statistical stop: a step below `stat_tol` standard errors of every unknown moves
            # the estimate by nothing the data can tell (noise-dominated residuals make
            # Gauss-Newton converge only linearly, so the plain tests would take many steps).
            # The step's length in standard errors is measured with the information matrix
            # (sqrt(dz' J'J dz / s^2)): steps along directions the data do not determine (t
            # against K_theta) are free and must not count, steps along determined ones must.
            # The noise scale is the smaller of the stated one (1 in weighted units) and the
            # residuals' estimate: far from the optimum the misfit inflates the latter, which
            # would make every step look negligible.
            Jf = J[:, sel]
            A = Jf.T @ Jf
            s2 = min(cost / max(r.size - sel.size, 1), 1.0)
            step_se = math.sqrt(max(float(dz @ A @ dz), 0.0) / max(s2, 1e-300))
            if (np.max(np.abs(dz)) < xtol * (1 + np.max(np.abs(z))) or rel < ftol
                    or step_se < stat_tol):
                reason = "converged"
                break
        else:
            lam *= nu
            nu *= 2
            if np.max(np.abs(dz)) < xtol * (1 + np.max(np.abs(z))):
                reason = "converged"  # no smaller cost within a negligible step
                break
    hist = {"solver": "lm (host loop, compiled residual+Jacobian)", "iterations": it,
            "evaluations": n_eval, "cost": costs, "stop": reason, "compile_s": compile_s,
            "run_s": time.perf_counter() - t1}
    return (z, r, J, np.asarray(X)), hist


def _optimistix(prob, z0, solver, max_iter, xtol, ftol):
    import optimistix as optx

    fn = lambda z, _: _residual_vector(prob, z)[0]  # noqa: E731
    s = (optx.LevenbergMarquardt(rtol=xtol, atol=xtol) if solver == "optimistix-lm"
         else optx.GaussNewton(rtol=xtol, atol=xtol))
    run = eqx.filter_jit(lambda z0: optx.least_squares(fn, s, z0, max_steps=max_iter,
                                                       throw=False,
                                                       options={"jac": "fwd"}))
    t0 = time.perf_counter()
    sol = run(jnp.asarray(z0))
    z = np.asarray(sol.value)
    first = time.perf_counter() - t0
    t1 = time.perf_counter()
    r, J, ok, X = _residual_and_jacobian(prob, jnp.asarray(z))
    _check_ok(ok, z, prob)
    hist = {"solver": f"{solver} (optimistix)", "iterations": int(sol.stats["num_steps"]),
            "stop": "converged" if sol.result == optx.RESULTS.successful else str(sol.result),
            "compile_and_run_s": first, "covariance_compile_s": time.perf_counter() - t1,
            "cost": [float(np.asarray(r) @ np.asarray(r))]}
    return (z, np.asarray(r), np.asarray(J), np.asarray(X)), hist


def _combination(names, v):
    """Name the combination prod p_i^e_i whose log is v . log p, with exponents normalised so
    that the smallest significant one is +-1 (t^3 K_theta^1 for the bending stiffness)."""
    v = np.asarray(v, dtype=np.float64)
    big = np.abs(v) > 0.1 * np.max(np.abs(v))
    c = np.min(np.abs(v[big]))
    e = v / c
    if e[np.argmax(np.abs(e))] < 0:
        e = -e
    parts = [f"{n}^{x:.2f}" for n, x, b in zip(names, e, big) if b]
    return " * ".join(parts), e, c


def _identifiability(names, p, J, s2):
    """SVD of the relative sensitivities J diag(p): each right singular vector v is a
    combination sum v_i log p_i whose standard deviation is s / sigma."""
    Jr = J * p[None, :]
    U, sv, Vt = np.linalg.svd(Jr, full_matrices=False)
    s = math.sqrt(s2)
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
    combos = []
    for k in range(len(sv)):
        expr, e, c = _combination(names, Vt[k])
        rel = s / sv[k] / c if sv[k] > 0 else float("inf")  # std of sum e_i log p_i
        status = ("identifiable" if rel < 0.1 else "poorly identifiable" if rel < 1.0
                  else "not identifiable from these data")
        combos.append({"expression": expr, "exponents": [float(x) for x in e],
                       "value": float(np.prod(p ** e)), "relative_std": float(rel),
                       "singular_value": float(sv[k]), "status": status})
    note = None
    if len(names) > 1 and combos[-1]["status"] != "identifiable":
        note = (f"the data determine {combos[0]['expression']} (relative std "
                f"{combos[0]['relative_std'] * 100:.2g}%) but not each parameter apart: along "
                f"{combos[-1]['expression']} the relative std is "
                f"{combos[-1]['relative_std'] * 100:.2g}%")
        if {"t", "K_theta"} <= set(names):
            note += ("; t and K_theta act through the joint stiffness K = 2 E I rho K_theta / L "
                     "with I = w t^3/12, i.e. through E w t^3 K_theta (the strip mass adds a "
                     "little t alone); fix one of them (e.g. --fix t=...) to identify the other")
    return {"singular_values": [float(v) for v in sv], "condition_number": cond,
            "combinations": combos, "note": note}


def _finish(prob, zrj, p0, hist, exps, mask, noise, drive="") -> Identification:
    from scipy import stats

    z, r, Jz, X = zrj
    z = jnp.asarray(z)
    P, E = len(prob.names), len(exps)
    p = np.asarray(_to_p(prob, z))
    dpdz = np.asarray(_dp_dz(prob, z))
    sz = np.asarray(jax.nn.sigmoid(z[:P]))
    # At a bound the reparametrisation is flat (dp/dz -> 0): the chain rule loses the
    # physical Jacobian there, so such unknowns are reported and their columns kept finite.
    at_bound = [n for n, v in zip(prob.names, sz * (1 - sz)) if v < 1e-9]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        J = Jz[:, :P] / np.maximum(dpdz, 1e-300)[None, :]  # d r / d p (physical)
    J = np.where(np.isfinite(J), J, 0.0)
    N = int(mask.sum()) * 3  # padding rows are exact zeros
    scale = np.tile(np.asarray(INIT_SCALE[:prob.n_init]), E)
    Ji = Jz[:, P:] / scale[None, :] if prob.n_init else np.zeros((Jz.shape[0], 0))
    dof = max(N - P - Ji.shape[1], 1)
    s2 = float(r @ r) / dof
    init = _initial_state_report(prob, z, X, J * p[None, :], Ji, s2, exps) if prob.n_init else None
    if prob.n_init:
        # The initial state is a nuisance: the parameters' marginal covariance is that of their
        # Jacobian with the initial-state directions projected out (the Schur complement).
        Qi = _range_basis(Ji)
        J = J - Qi @ (Qi.T @ J)
    # Relative (scaled) normal equations: better conditioned than J^T J in SI units.
    Jr = J * p[None, :]
    U, sv, Vt = np.linalg.svd(Jr, full_matrices=False)
    null = ~(sv > sv[0] * 1e-14) | ~(sv > 0)
    inv = np.zeros_like(sv)
    inv[~null] = 1.0 / sv[~null] ** 2
    Cr = (Vt.T * inv) @ Vt * s2
    # Directions the data do not see at all have infinite variance (not the zero of a
    # pseudo-inverse): every parameter with a component along them is undetermined.
    unseen = np.any(np.abs(Vt[null]) > 1e-8, axis=0) if null.any() else np.zeros(P, bool)
    Cr = np.where(unseen[:, None] | unseen[None, :], np.inf, Cr)
    C = Cr * np.outer(p, p)
    std = np.sqrt(np.diag(C))
    q = float(stats.t.ppf(0.975, dof))
    ci = np.column_stack([p - q * std, p + q * std])
    # The same interval for log p (first order: std(log p) = std / p): positive, and the better
    # reading when std / p is not small (a linear interval of t can reach below 0).
    with np.errstate(over="ignore", invalid="ignore"):
        rel = std / np.abs(p)
        ci_log = np.column_stack([p * np.exp(-q * rel), p * np.exp(q * rel)])
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = np.where(np.isfinite(np.outer(std, std)), C / np.outer(std, std), np.nan)
    idf = _identifiability(prob.names, p, J, s2)
    idf["at_bound"] = at_bound
    if at_bound:
        idf["note"] = ((idf["note"] + "; ") if idf["note"] else "") + (
            f"{', '.join(at_bound)} ended at a bound: its interval is not meaningful (widen the "
            f"bounds, or fix it)")
    # A fit that does not explain the data is neither converged nor identifying anything: its
    # intervals measure the misfit, not the noise (a start 30x off once ended at s = 7,166 with
    # a "converged", "identifiable" 0.2 % interval).
    s_fit = math.sqrt(s2)
    problems = []
    if not s_fit <= POOR_FIT_SCALE:
        problems.append(f"the model does not explain the data: residual scale s = {s_fit:.3g} "
                        f"(> {POOR_FIT_SCALE:g}; 1 = noise as stated)")
        for c in idf["combinations"]:
            c["status"] = "not trustworthy (poor fit)"
    if at_bound:
        problems.append(f"{', '.join(at_bound)} at a bound")
    hist = dict(hist)
    hist["optimizer_stop"] = hist.get("stop")
    if problems and hist.get("stop") == "converged":
        hist["stop"] = "poor fit" if not s_fit <= POOR_FIT_SCALE else "at bound"
    quality = {"residual_scale": s_fit, "explains_data": bool(s_fit <= POOR_FIT_SCALE),
               "at_bound": at_bound, "ok": not problems,
               "problems": problems}
    raw = np.where(np.asarray(prob.w) > 0, (X - np.asarray(prob.X)) * np.asarray(prob.w), 0.0)
    rs = []
    for k, e in enumerate(exps):
        m = mask[k]
        d = (X[k] - np.asarray(prob.X)[k])[m]
        rs.append({"name": e.name, "n": int(m.sum()),
                   "rms_x_m": float(np.sqrt(np.mean(d[:, 0] ** 2))),
                   "rms_y_m": float(np.sqrt(np.mean(d[:, 1] ** 2))),
                   "rms_phi_rad": float(np.sqrt(np.mean(d[:, 2] ** 2))),
                   "max_abs_position_m": float(np.max(np.hypot(d[:, 0], d[:, 1]))),
                   "max_abs_phi_rad": float(np.max(np.abs(d[:, 2])))})
    wr = raw[mask]  # (n_real, 3) weighted, before the loss
    stats_ = {"experiments": rs,
              "rms_weighted": float(np.sqrt(np.mean(wr ** 2))),
              "note": "RMS of simulated minus measured pose; with the noise as stated and a "
                      "model that fits, RMS x, y ~ noise position and RMS phi ~ noise phi"}
    params = _params_at(prob, jnp.asarray(p))
    return Identification(
        names=prob.names, estimate=p, initial=p0, std=std, ci95=ci, ci95_log=ci_log, covariance=C,
        correlation=corr, params=params, sigma2=s2, jacobian=J, residuals=r, fitted=X,
        measured=np.asarray(prob.X), ts=np.asarray(prob.ts), mask=mask, identifiability=idf,
        residual_stats=stats_, history=hist, model=prob.model.name, scene=prob.scene,
        experiment_names=tuple(e.name for e in exps), noise=noise, problem=prob,
        initial_state=init, z=np.asarray(z), actuation=drive, quality=quality,
    )


def _range_basis(A, rtol=1e-12):
    """Orthonormal basis (n, k) of the column space of A (n, q), columns scaled first."""
    nrm = np.linalg.norm(A, axis=0)
    A = A / np.where(nrm > 0, nrm, 1.0)[None, :]
    U, sv, _ = np.linalg.svd(A, full_matrices=False)
    return U[:, sv > rtol * max(float(sv[0]) if sv.size else 0.0, 1e-300)]


def _initial_state_report(prob, z, X, Jr, Ji, s2, exps):
    """Per experiment: the estimated initial platform pose (absolute: the fitted pose at t = 0)
    and the velocity offset from the scene's quasi-static initial velocity, with standard
    deviations marginal over the parameters (their directions projected out)."""
    Qp = _range_basis(Jr)
    Jie = Ji - Qp @ (Qp.T @ Ji)
    nrm = np.linalg.norm(Jie, axis=0)
    nrm = np.where(nrm > 0, nrm, 1.0)
    A = (Jie / nrm).T @ (Jie / nrm)
    Ci = np.linalg.pinv(A) / np.outer(nrm, nrm) * s2
    sd = np.sqrt(np.maximum(np.diag(Ci), 0.0))
    k = prob.n_init
    d = np.asarray(z)[len(prob.names):].reshape(len(exps), k) * np.asarray(INIT_SCALE[:k])
    out = {}
    for j, e in enumerate(exps):
        row = {}
        for i in range(k):
            name, unit = INIT_NAMES[i], INIT_UNITS[i]
            if i < 3:
                row[name] = {"estimate": float(X[j, 0, i]), "offset": float(d[j, i]),
                             "std": float(sd[j * k + i]), "unit": unit}
            else:
                row[name] = {"offset": float(d[j, i]), "std": float(sd[j * k + i]),
                             "unit": unit}
        out[e.name] = row
    return {"estimated": list(INIT_NAMES[:k]), "experiments": out,
            "note": "x0, y0, phi0: the fitted platform pose at t = 0 and its offset from the "
                    "scene's quasi-static initial state; xd0, yd0, phid0: offsets from the "
                    "scene's initial platform velocity; std marginal over the parameters"}


# ---------------------------------------------------------------------------------------------
# Synthetic experiments
# ---------------------------------------------------------------------------------------------


@eqx.filter_jit
def _actuated_angles(model, robot, z):
    return jax.vmap(lambda z: model.kinematics(robot, z).th_a)(z)


def check_synth_args(noise_pos, noise_phi, rate, t_end) -> None:
    """`synthesize`'s numbers, checked before anything is compiled (`DataError` naming them)."""
    for what, v in (("noise_pos", noise_pos), ("noise_phi", noise_phi), ("rate", rate),
                    ("t_end", t_end)):
        if not math.isfinite(v):  # a NaN noise wrote a file of NaN poses
            raise DataError(f"{what} must be finite: {v!r} is not finite")
    if not (rate > 0 and t_end > 0):
        raise DataError(f"rate and t_end must be > 0, got rate={rate}, t_end={t_end}")
    if noise_pos < 0 or noise_phi < 0:
        raise DataError(f"noise must be >= 0, got noise_pos={noise_pos}, noise_phi={noise_phi}")


def synthesize(
    scene: str = "servo-circle",
    model="double1r",
    params: Optional[RobotParams] = None,
    *,
    noise_pos: float = 0.1e-3,
    noise_phi: float = 1e-3,
    rate: float = 100.0,
    t_end: float = 7.54,
    seed: int = 0,
    name: str = "synthetic",
    n_elements: Optional[int] = None,
    **scene_kw,
) -> Experiment:
    """A tracker-like `Experiment` from a scene: the simulated pose sampled at `rate` (Hz) from
    t = 0 to `t_end` (s, rounded down to whole samples), with independent Gaussian noise of
    standard deviation `noise_pos` (m) on x and y and `noise_phi` (rad) on phi, seeded
    (`numpy.random.default_rng(seed)`). The actuated angles (noise-free: encoders are far finer
    than a tracker) and the torques (applied, or the reactions of a motion-driven scene) are
    included. `params` defaults to `scene_params(scene)`; `scene_kw` go to the scene function."""
    from ._scenes import paper_circle, servo_circle

    if scene not in ID_SCENES:
        raise DataError(f"unknown scene {scene!r}; allowed: {', '.join(ID_SCENES)}")
    check_synth_args(noise_pos, noise_phi, rate, t_end)
    n = int(math.floor(t_end * rate + 1e-9)) + 1
    if n < 2:
        raise DataError(f"t_end = {t_end} s at {rate} Hz gives fewer than 2 samples")
    mdl = get_model(model, n_elements)
    params = scene_params(scene) if params is None else params
    fn = servo_circle if scene == "servo-circle" else paper_circle
    res = fn(params, model=mdl, t_end=(n - 1) / rate, n_out=n, **scene_kw)
    th = np.asarray(_actuated_angles(mdl, Robot(params), res.z))
    rng = np.random.default_rng(seed)
    X = np.asarray(res.X).copy()
    X[:, :2] += noise_pos * rng.standard_normal((n, 2))
    X[:, 2] += noise_phi * rng.standard_normal(n)
    return Experiment(ts=np.asarray(res.ts), X=X, th=th, tau=np.asarray(res.tau), name=name)
