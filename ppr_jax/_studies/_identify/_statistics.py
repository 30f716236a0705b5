"""The statistics of an identification: the physical Jacobian, the Gauss-Newton covariance and
intervals, the identifiable combinations (before the fit: the preflight), the nuisance unknowns'
marginal standard deviations, the residuals against the stated noise, the starts' and the
held-out samples' verdicts."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from ._problem import (
    INIT_NAMES,
    INIT_SCALE,
    INIT_UNITS,
    MEAS_NAMES,
    MEAS_SCALE,
    MEAS_UNITS,
    _dp_dz,
    _to_p,
)


def _physical_jacobian(prob, z, Jz):
    """(p, J): the unknowns p (P,) at z and the Jacobian J (N, P) of the residuals with respect
    to them (physical units) from Jz = dr/dz (N, len(z)); where the reparametrisation is flat
    (an unknown at a bound) its column is kept finite."""
    P = len(prob.names)
    p = np.asarray(_to_p(prob, z))
    dpdz = np.asarray(_dp_dz(prob, z))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        J = Jz[:, :P] / np.maximum(dpdz, 1e-300)[None, :]  # d r / d p (physical)
    J = np.where(np.isfinite(J), J, 0.0)
    return p, J


def _covariance(J, p, s2, dof):
    """(C, std, ci95, ci95_log, correlation) of the unknowns p (P,) from the Jacobian J (N, P)
    of the weighted residuals with respect to them (the nuisance directions projected out),
    their variance s2 and `dof` degrees of freedom: the Gauss-Newton covariance s^2 (J^T J)^-1,
    Student t intervals of p and of log p."""
    from scipy import stats

    P = len(p)
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
    return C, std, ci, ci_log, corr


def _residual_stats(X, prob, mask, exps) -> dict:
    """The residuals of the fitted poses X (E, m, 3) against the measured ones, per experiment
    and channel (RMS and largest, in m and rad: to compare with the stated noise), and the RMS
    of the weighted residuals before the loss."""
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
    return {"experiments": rs,
            "rms_weighted": float(np.sqrt(np.mean(wr ** 2))),
            "note": "RMS of simulated minus measured pose; with the noise as stated and a "
                    "model that fits, RMS x, y ~ noise position and RMS phi ~ noise phi"}


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
    p, J = _physical_jacobian(prob, z, Jz)
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
