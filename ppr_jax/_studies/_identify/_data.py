"""Experiments to the problem's arrays: padding, weights, the actuation each experiment is driven
by."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..._data import DataError, Experiment
from ..._params import RobotParams
from ..._paths import fit_start
from ..._prb import derived
from ..._trajectory import spline_pieces


def _fill_prb(params: RobotParams, names) -> RobotParams:
    """Unknown PRB parameters that `params` leaves to the table become explicit leaves."""
    dv = derived(params)
    kw = {n: float(getattr(dv, n)) for n in ("gamma", "K_theta", "rho")
          if n in names and getattr(params, n) is None}
    return params.replace(**kw) if kw else params


def _pack(experiments: Sequence[Experiment], w_pos, w_phi, drive, actuation="commanded",
          own=False):
    """Pad the experiments to one length: times start at 0 (a leading t = 0 sample of weight 0
    when the data start later) and continue past the end at the median step (weight 0).
    With measured actuation, also the spline pieces of each experiment's angles on its padded
    times (the spline's first piece continued back to 0, a linear continuation after the end).
    `drive`: the scene's ("motion" or "torque"); the measured torques are packed for a torque
    drive. `own`: the experiments' own scenes (no scene named): each experiment's times count
    from its first sample, and the spline pieces of its poses (its path) and the start's fit of
    its first samples (pose, rate, acceleration, `fit_start`) are packed too.

    Returns (ts, X, W, tau, th, mask, paths, starts): paths (E, m - 1, 4, 3) and starts
    (E, 3, 3) None unless `own`."""
    rows = []
    for e in experiments:
        ts = np.asarray(e.ts, dtype=np.float64)
        if own:
            ts = ts - ts[0]
        elif ts[0] < 0:
            raise DataError(f"{e.name}: times must start at or after 0 (the start of the motion), "
                            f"got {ts[0]:g} s")
        lead = ts[0] > 0
        rows.append((ts, lead))
    m = max(len(ts) + int(lead) for ts, lead in rows)
    TS, XX, WW, TT, MASK = [], [], [], [], []
    has_tau = [e.tau is not None for e in experiments]
    use_tau = drive == "torque" and all(has_tau)
    if drive == "torque" and any(has_tau) and not all(has_tau):
        lack = [e.name for e, h in zip(experiments, has_tau) if not h]
        raise DataError(f"a torque drive takes either every experiment's torques tau_1..tau_3 or "
                        f"none; missing in {', '.join(lack)}")
    if actuation == "measured":
        lack = [e.name for e in experiments if e.th is None]
        if lack:
            raise DataError(f"actuation 'measured' needs the actuated angles th_1, th_2, th_3 in "
                            f"every experiment; missing in {', '.join(lack)}")
        short = [e.name for e in experiments if e.n < 4]
        if short:
            raise DataError(f"actuation 'measured' needs at least 4 samples of the angles (a "
                            f"cubic spline); too few in {', '.join(short)}")
    TH, PATHS, STARTS = [], [], []
    for e, (ts0, lead) in zip(experiments, rows):
        ts = ts0
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
            TH.append(spline_pieces(ts, ts0, e.th))
        if own:
            PATHS.append(spline_pieces(ts, ts0, np.asarray(e.X)))
            STARTS.append(fit_start(ts0, np.asarray(e.X)))
        TS.append(ts)
        XX.append(X)
        MASK.append(mask)
        WW.append(mask[:, None] * np.array([1 / w_pos, 1 / w_pos, 1 / w_phi]))
        TT.append(tau)
    tau = np.stack(TT) if use_tau else None
    th = np.stack(TH) if TH else None
    paths = np.stack(PATHS) if own else None
    starts = np.stack(STARTS) if own else None
    return (np.stack(TS), np.stack(XX), np.stack(WW), tau, th, np.stack(MASK), paths, starts)
