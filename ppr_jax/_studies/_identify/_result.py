"""The result of an identification: estimates, covariance, identifiability, residual statistics."""

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
    INIT_NAMES,
    INIT_SCALE,
    INIT_UNITS,
    MEAS_NAMES,
    MEAS_SCALE,
    MEAS_UNITS,
    POOR_FIT_SCALE,
    _dp_dz,
    _params_at,
    _Problem,
    _residual_and_jacobian,
    _to_p,
    _to_z,
    noise_text,
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


def _preflight(prob, z, Jz) -> dict:
    """The identifiability of the unknowns at the start z, before any fit: `_identifiability` of
    the residual Jacobian Jz (N, len(z)) = dr/dz at z, with the residual scale s = 1 (the noise as
    stated: the data's own sampling and weights, nothing fitted yet). The nuisance unknowns
    (initial states, measurement parameters) are marginalised out as `_finish` does for the
    intervals: their directions are projected out of the parameters' Jacobian. Returns the
    `_identifiability` dict with "refused" (the combinations not identifiable from these
    data)."""
    P = len(prob.names)
    z = jnp.asarray(z)
    Jz = np.asarray(Jz)
    p = np.asarray(_to_p(prob, z))
    dpdz = np.asarray(_dp_dz(prob, z))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        J = Jz[:, :P] / np.maximum(dpdz, 1e-300)[None, :]
    J = np.where(np.isfinite(J), J, 0.0)
    Jn = Jz[:, P:]
    if Jn.shape[1]:
        Qi = _range_basis(Jn)
        J = J - Qi @ (Qi.T @ J)
    idf = _identifiability(prob.names, p, J, 1.0)
    idf["refused"] = [c for c in idf["combinations"]
                      if c["status"] == "not identifiable from these data"]
    return idf


def _refusal_message(idf, names) -> str:
    """Why `identify` refuses to fit: the combinations of the unknowns that the data cannot
    determine at the initial guess, with their relative std, what would make them identifiable
    and how to fit anyway."""
    parts = []
    for c in idf["refused"]:
        involved = [n for n, e in zip(names, c["exponents"])
                    if abs(e) > 0.1 * max(abs(x) for x in c["exponents"])]
        rel = c["relative_std"]
        what = (f"{c['expression']} (relative std "
                + (f"{rel * 100:.3g} %" if math.isfinite(rel) else "infinite: the residuals "
                   "do not depend on it") + ")")
        if len(involved) > 1:
            fix = (f"fix one of {', '.join(involved)} at a known value (leave it out of the "
                   f"unknowns and give fixed={{{involved[0]!r}: value}}; CLI --fix "
                   f"{involved[0]}=VALUE or --set {involved[0]}=VALUE)")
        else:
            fix = (f"fix {involved[0]} at a known value (leave it out of the unknowns; "
                   f"fixed={{{involved[0]!r}: value}}, CLI --set {involved[0]}=VALUE)")
        parts.append(f"{what}; to make it identifiable, {fix}, or fit data that excite it "
                     f"(longer or more experiments, less noise)")
    msg = ("preflight: at the initial guess, with the data's sampling and the stated noise, "
           "these combinations of the unknowns are not identifiable from these data (relative "
           "std >= 100 %): " + "; ".join(parts))
    if {"t", "K_theta"} <= set(names):
        msg += ("; note: t and K_theta act through the joint stiffness K = 2 E I rho K_theta / L "
                "with I = w t^3/12, i.e. through E w t^3 K_theta (the strip mass adds a little "
                "t alone): fit t with K_theta from the PRB table, or K_theta with t measured")
    return msg + ("; to fit anyway (the result's identifiability and quality then report it), "
                  "pass force=True (CLI --force)")


#: a start whose cost exceeds the best by more than this many s^2 ended elsewhere (the 95 %
#: point of chi^2 with one degree of freedom: a likelihood-ratio test of the two minima)
DISTINCT_MINIMUM = 3.84


def _starts_summary(hist, s2) -> dict:
    """How the starts of a multi-start fit ended: how many reached the best minimum (cost
    within `DISTINCT_MINIMUM` s^2 of it), and whether the given start (start 0) did."""
    runs = hist["starts"]
    costs = [r["cost"] for r in runs]
    best = min(c for c in costs if c is not None)
    reached = [c is not None and c - best <= DISTINCT_MINIMUM * s2 for c in costs]
    out = {"n": len(runs), "reached_best": int(sum(reached)), "best_start": hist["best_start"],
           "given_start_reached_best": bool(reached[0]),
           "failed": int(sum(c is None for c in costs))}
    notes = []
    if not reached[0]:
        c0 = costs[0]
        notes.append("the given start ended in another minimum"
                     + ("" if c0 is None else f" (cost {c0:.4g} against {best:.4g})")
                     + f"; the result is start {hist['best_start']}'s")
    if out["reached_best"] == 1 and len(runs) > 1:
        notes.append("only one start reached the best minimum: more starts may find a lower one")
    out["note"] = "; ".join(notes)
    return out


def _validation(X, Xm, W, held, exps, s_fit, what) -> dict:
    """The fitted model's residuals on the held-out samples `held` (E, m) with the full weights
    W (E, m, 3): their scale s_val (RMS of the weighted residuals: 1 = noise as stated) against
    the fit's. The model generalises when s_val <= `GENERALISES_FACTOR` max(s_fit, 1): with
    noise alone both are about 1 (s_val of n samples spreads by 1/sqrt(2 n))."""
    d = X - Xm
    wv = (d * W)[held[..., None] & (W > 0)]  # a channel of infinite noise does not count
    s_val = float(np.sqrt(np.mean(wv ** 2)))
    rows = []
    for k, e in enumerate(exps):
        m = held[k]
        if m.any():
            rows.append({"name": e.name, "n": int(m.sum()),
                         "rms_position_m": float(np.sqrt(np.mean(np.sum(d[k][m, :2] ** 2, -1)
                                                                 / 2))),
                         "rms_phi_rad": float(np.sqrt(np.mean(d[k][m, 2] ** 2)))})
    return {"held_out": what, "samples": int(held.sum()), "residual_scale": s_val,
            "train_residual_scale": s_fit,
            "generalises": bool(s_val <= GENERALISES_FACTOR * max(s_fit, 1.0)),
            "experiments": rows}


#: a validation residual scale above this many times the fit's (or 1) is a model that does not
#: generalise to the held-out samples
GENERALISES_FACTOR = 2.0


def _finish(prob, zrj, p0, hist, exps, mask, noise, drive="", held=None) -> Identification:
    """The `Identification` of the fit `zrj` = (z, r, J, X). `held`: None, or (W, held (E, m),
    description) of the held-out samples (`_validation`)."""
    from scipy import stats

    z, r, Jz, X = zrj
    z = jnp.asarray(z)
    P, E = len(prob.names), len(exps)
    p = np.asarray(_to_p(prob, z))
    dpdz = np.asarray(_dp_dz(prob, z))
    # At a bound the reparametrisation is flat (dp/dz -> 0): the chain rule loses the
    # physical Jacobian there, so such unknowns are reported and their columns kept finite.
    bound = at_bound(prob, z)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        J = Jz[:, :P] / np.maximum(dpdz, 1e-300)[None, :]  # d r / d p (physical)
    J = np.where(np.isfinite(J), J, 0.0)
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
    raw = np.where(np.asarray(prob.w) > 0, (X - np.asarray(prob.X)) * np.asarray(prob.w), 0.0)
    rs = []
    for k, e in enumerate(exps):
        m = mask[k]
        if not m.any():  # held out whole (validation by experiment): `validation` has its RMS
            rs.append({"name": e.name, "n": 0, "held_out": True, "rms_x_m": None,
                       "rms_y_m": None, "rms_phi_rad": None, "max_abs_position_m": None,
                       "max_abs_phi_rad": None})
            continue
        d = (X[k] - np.asarray(prob.X)[k])[m]
        rs.append({"name": e.name, "n": int(m.sum()),
                   "rms_x_m": float(np.sqrt(np.mean(d[:, 0] ** 2))),
                   "rms_y_m": float(np.sqrt(np.mean(d[:, 1] ** 2))),
                   "rms_phi_rad": float(np.sqrt(np.mean(d[:, 2] ** 2))),
                   "max_abs_position_m": float(np.max(np.hypot(d[:, 0], d[:, 1]))),
                   "max_abs_phi_rad": float(np.max(np.abs(d[:, 2])))})
    wr = raw[np.asarray(prob.w) > 0]  # the weighted residuals, before the loss
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
        validation=validation, held_out=None if held is None else held[1],
        measurement=measurement,
    )


def _range_basis(A, rtol=1e-12):
    """Orthonormal basis (n, k) of the column space of A (n, q), columns scaled first."""
    nrm = np.linalg.norm(A, axis=0)
    A = A / np.where(nrm > 0, nrm, 1.0)[None, :]
    U, sv, _ = np.linalg.svd(A, full_matrices=False)
    return U[:, sv > rtol * max(float(sv[0]) if sv.size else 0.0, 1e-300)]


def _marginal_std(Jo, Jn, s2):
    """Standard deviations of the unknowns of the columns Jn, marginal over those of Jo (their
    directions projected out), with residual variance s2."""
    Qp = _range_basis(Jo) if Jo.shape[1] else np.zeros((Jn.shape[0], 0))
    Jne = Jn - Qp @ (Qp.T @ Jn)
    nrm = np.linalg.norm(Jne, axis=0)
    nrm = np.where(nrm > 0, nrm, 1.0)
    A = (Jne / nrm).T @ (Jne / nrm)
    Ci = np.linalg.pinv(A) / np.outer(nrm, nrm) * s2
    return np.sqrt(np.maximum(np.diag(Ci), 0.0))


def _measurement_report(prob, z, Jo, Jm, s2):
    """The measurement nuisance parameters (bias of x, y, phi; delay) with standard deviations
    marginal over the parameters and initial states."""
    k = len(prob.meas)
    values = np.asarray(z)[-k:] * np.asarray([MEAS_SCALE[i] for i in prob.meas])
    sd = _marginal_std(Jo, Jm, s2)
    return {"estimated": [MEAS_NAMES[i] for i in prob.meas],
            "values": {MEAS_NAMES[i]: {"estimate": float(values[j]), "std": float(sd[j]),
                                       "unit": MEAS_UNITS[i]}
                       for j, i in enumerate(prob.meas)},
            "note": "the tracker's offsets of x, y, phi and its delay against the actuation "
                    "(shared by every experiment); std marginal over the parameters and the "
                    "initial states"}


def _initial_state_report(prob, z, X, Jr, Ji, s2, exps):
    """Per experiment: the estimated initial platform pose (absolute: the fitted pose at t = 0)
    and the velocity offset from the scene's quasi-static initial velocity, with standard
    deviations marginal over the parameters (their directions projected out)."""
    sd = _marginal_std(Jr, Ji, s2)
    k = prob.n_init
    P = len(prob.names)
    d = np.asarray(z)[P:P + len(exps) * k].reshape(len(exps), k) * np.asarray(INIT_SCALE[:k])
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

