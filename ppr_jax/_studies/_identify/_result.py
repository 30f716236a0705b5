"""The result of an identification (`Identification`): estimates, covariance, identifiability,
residual statistics (computed in `_statistics`), with its table, report, figures and profile
intervals."""

from __future__ import annotations

import math
import time
from typing import Optional

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..._custom_types import Array
from ..._errors import IdentificationError
from ..._params import RobotParams
from ._fit import _check_ok, _levenberg_marquardt, at_bound
from ._problem import (
    INIT_SCALE,
    MEAS_SCALE,
    POOR_FIT_SCALE,
    _Problem,
    _residual_and_jacobian,
    _to_z,
    noise_text,
)
from ._statistics import (
    _covariance,
    _identifiability,
    _initial_state_report,
    _measurement_report,
    _physical_jacobian,
    _range_basis,
    _residual_stats,
    _starts_summary,
    _validation,
)


class Identification(eqx.Module):
    """The result of `identify` (SI units; P unknowns, E experiments).

    names (P,) unknowns; estimate, initial, std (P,); ci95 (P, 2) 95 % confidence intervals (Student
    t on the Gauss-Newton standard errors); ci95_log (P, 2) the same for log p, p exp(+-q std/p),
    positive (the better reading when std/p is not small); covariance, correlation (P, P); params
    the fitted `RobotParams`; sigma2 the estimated variance of the weighted residuals (about 1 when
    the noise is as stated: s^2 = sum r^2/(N - P)); jacobian (N, P) d(weighted residual)/d(p) at the
    estimate; residuals (N,) weighted residuals (after the loss) at the estimate; fitted (E, m, 3)
    and measured (E, m, 3) poses, ts (E, m) their times, mask (E, m) real samples (padding False);
    identifiability (dict: singular values of the relative sensitivities, condition number, the
    combinations the data determine and those they do not); residual_stats (dict: RMS per experiment
    and channel in m / rad against the stated noise; an experiment held out whole by `validation`
    has n = 0, held_out True and no RMS: `validation` has its prediction's); history (dict:
    iterations, cost, convergence, compile_s, run_s)."""

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
    #: the held-out samples' check (`identify(..., validation=...)`): {"held_out", "samples",
    #: "residual_scale", "train_residual_scale", "generalises", "experiments" (RMS per
    #: experiment)}; None without validation
    validation: Optional[dict] = None
    #: (E, m) the held-out samples (`validation`), None without validation
    held_out: Optional[Array] = None
    #: the measurement nuisance parameters (`identify(..., nuisance=...)`): {"estimated",
    #: "values" {name: {"estimate", "std", "unit"}}}; None when none was estimated
    measurement: Optional[dict] = None

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
        dof = max(int(np.count_nonzero(np.asarray(prob.w))) - n_all, 1)
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
                     f"experiment(s), N = {np.count_nonzero(np.asarray(self.problem.w))} "
                     f"residuals, s = "
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
            if e.get("held_out"):
                lines.append(f"  {e['name']}: held out of the fit (its prediction: validation)")
                continue
            lines.append(f"  {e['name']}: RMS x {e['rms_x_m'] * 1e3:.4g} mm, y "
                         f"{e['rms_y_m'] * 1e3:.4g} mm, phi {e['rms_phi_rad'] * 1e3:.4g} mrad "
                         f"(noise {noise_text(self.noise)})")
        q = self.quality or {}
        if q.get("escalated"):
            lines.append(f"  starts auto: {q['escalated']}: "
                         + self.history["escalation"]["note"])
        if q.get("preflight_not_identifiable"):
            lines.append("  preflight: not identifiable at the initial guess: "
                         + ", ".join(q["preflight_not_identifiable"])
                         + " (fitted anyway: force=True)")
        st = q.get("starts")
        if st:
            lines.append(f"  starts: {st['n']} (Latin hypercube), {st['reached_best']} reached the "
                         f"best minimum" + (f"; {st['note']}" if st["note"] else ""))
        if self.measurement:
            parts = [f"{n} {v['estimate']:+.4g} +- {v['std']:.2g} {v['unit']}"
                     for n, v in self.measurement["values"].items()]
            lines.append("  measurement: " + ", ".join(parts))
        v = self.validation
        if v:
            lines.append(f"  validation ({v['held_out']}, {v['samples']} samples): s = "
                         f"{v['residual_scale']:.4g} against {v['train_residual_scale']:.4g} "
                         f"on the fitted samples ("
                         + ("generalises" if v["generalises"] else "does NOT generalise") + ")")
        return "\n".join(lines)

    def report(self, path: str, *, figures=(), data_files=(), command=None,
               profiles=None) -> str:
        """Write one self-contained HTML report (`report.html`): the estimates with their
        linearised, log and (given `profiles`) profile intervals, correlations,
        identifiability, measurement model, initial states, residuals, validation, the PNG
        `figures` embedded, and the provenance: the `data_files` with their sha256, the versions
        of ppr_jax and its numerical dependencies, the `command`. Returns the path."""
        from ._report import write_report

        return write_report(self, path, figures=figures, data_files=data_files,
                            command=command, profiles=profiles)

    def figures(self, out_dir: str) -> list:
        """Write fit_trajectory.png and fit_residuals.png to `out_dir` (matplotlib, Agg);
        returns their paths."""
        from ._plots import identification_figures

        return identification_figures(self, out_dir)

    def to_dict(self) -> dict:
        """JSON-ready summary (estimates, intervals, correlations, identifiability, residuals);
        an infinite or undefined value (a parameter the data do not see) is None."""
        return _json_safe({
            "model": self.model,
            "scene": self.scene,
            "actuation": self.actuation,
            "experiments": list(self.experiment_names),
            "noise": {"position_m": self.noise[0], "phi_rad": self.noise[1],
                      # an infinite noise (None above): that channel was not fitted
                      "not_fitted": ["x", "y"] * (not math.isfinite(self.noise[0]))
                      + ["phi"] * (not math.isfinite(self.noise[1]))},
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
            "validation": self.validation,
            "measurement": self.measurement,
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


def _finish(prob, zrj, p0, hist, exps, mask, noise, drive="", held=None) -> Identification:
    """The `Identification` of the fit `zrj` = (z, r, J, X). `held`: None, or (W, held (E, m),
    description) of the held-out samples (`_validation`)."""
    z, r, Jz, X = zrj
    z = jnp.asarray(z)
    P, E = len(prob.names), len(exps)
    p, J = _physical_jacobian(prob, z, Jz)
    # At a bound the reparametrisation is flat (dp/dz -> 0): the chain rule loses the
    # physical Jacobian there, so such unknowns are reported and their columns kept finite.
    bound = at_bound(prob, z)
    # The residuals that carry information: padding, held-out samples and a channel of infinite
    # noise have weight 0 (exact zeros, no degree of freedom)
    N = int(np.count_nonzero(np.asarray(prob.w)))
    # the nuisance unknowns after the parameters: initial states, then measurement parameters
    scale = np.concatenate([np.tile(np.asarray(INIT_SCALE[:prob.n_init]), E),
                            np.asarray([MEAS_SCALE[i] for i in prob.meas])])
    Jn = np.asarray(Jz)[:, P:] / scale[None, :]
    Ji, Jm = Jn[:, :E * prob.n_init], Jn[:, E * prob.n_init:]
    dof = max(N - P - Jn.shape[1], 1)
    s2 = float(r @ r) / dof
    Jr = J * p[None, :]
    init = (_initial_state_report(prob, z, X, np.hstack([Jr, Jm]), Ji, s2, exps)
            if prob.n_init else None)
    measurement = (_measurement_report(prob, z, np.hstack([Jr, Ji]), Jm, s2)
                   if prob.meas else None)
    if Jn.shape[1]:
        # The initial state and the measurement parameters are nuisances: the parameters'
        # marginal covariance is that of their Jacobian with the nuisance directions projected
        # out (the Schur complement).
        Qi = _range_basis(Jn)
        J = J - Qi @ (Qi.T @ J)
    C, std, ci, ci_log, corr = _covariance(J, p, s2, dof)
    idf = _identifiability(prob.names, p, J, s2)
    idf["at_bound"] = bound
    if bound:
        idf["note"] = ((idf["note"] + "; ") if idf["note"] else "") + (
            f"{', '.join(bound)} ended at a bound: its interval is not meaningful (widen the "
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
    if bound:
        problems.append(f"{', '.join(bound)} at a bound")
    validation = None
    if held is not None:
        validation = _validation(np.asarray(X), np.asarray(prob.X), held[0], held[1], exps,
                                 s_fit, held[2])
        if not validation["generalises"]:
            problems.append(f"the model does not generalise: residual scale "
                            f"{validation['residual_scale']:.3g} on the held-out samples "
                            f"({validation['held_out']}) against {s_fit:.3g} on the fitted ones")
    hist = dict(hist)
    starts = _starts_summary(hist, s2) if "starts" in hist else None
    hist["optimizer_stop"] = hist.get("stop")
    if problems and hist.get("stop") == "converged":
        hist["stop"] = ("poor fit" if not s_fit <= POOR_FIT_SCALE else
                        "at bound" if bound else "does not generalise")
    quality = {"residual_scale": s_fit, "explains_data": bool(s_fit <= POOR_FIT_SCALE),
               "at_bound": bound, "ok": not problems,
               "generalises": None if validation is None else validation["generalises"],
               "starts": starts,
               # starts="auto": why the given start's fit called for more starts (None: it
               # did not, or the option was not "auto")
               "escalated": (hist.get("escalation") or {}).get("reason"),
               # the preflight's combinations not identifiable at the initial guess (fitted
               # anyway with force=True)
               "preflight_not_identifiable": (hist.get("preflight") or {}).get("refused", []),
               "problems": problems}
    stats_ = _residual_stats(X, prob, mask, exps)
    params = prob.evaluation.params(jnp.asarray(p), prob.base)
    return Identification(
        names=prob.names, estimate=p, initial=p0, std=std, ci95=ci, ci95_log=ci_log, covariance=C,
        correlation=corr, params=params, sigma2=s2, jacobian=J, residuals=r, fitted=X,
        measured=np.asarray(prob.X), ts=np.asarray(prob.ts), mask=mask, identifiability=idf,
        residual_stats=stats_, history=hist, model=prob.model.name, scene=prob.scene,
        experiment_names=tuple(e.name for e in exps), noise=noise, problem=prob,
        initial_state=init, z=np.asarray(z), actuation=drive, quality=quality,
        validation=validation, held_out=None if held is None else held[1],
        measurement=measurement,
    )
