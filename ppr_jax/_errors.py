"""The library's error vocabulary: one base exception (`PPRError`), the result codes of compiled
programs (`RESULTS`, diffrax's plus this library's own), and the host-side checks that turn them
into errors naming the failed batch members.

Compiled scene programs never raise: they return a `RESULTS` code per member (so batches keep
what succeeded, and the programs hold no host callbacks, which JAX's persistent compilation
cache cannot store). `raise_if` is for the eager, per-call checks of the public functions; under
a trace it falls back to `eqx.error_if`.
"""

from __future__ import annotations

from typing import Optional

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np


class PPRError(ValueError):
    """The base of this library's errors: bad input or an infeasible request (unreachable pose,
    singular configuration, a solver that failed: `SimulationError`). A `ValueError`, so code
    that catches bad input keeps working."""


class SimulationError(PPRError, RuntimeError):
    """A simulation or scene failed (the message says which batch members, why, and what to
    try). `result`, when set, is what was computed: a scene's `SceneResult` with every member,
    the failed ones included (their `result` codes say why), so a batch loses nothing."""

    result = None


class DataError(PPRError):
    """A measured-data file or array that cannot be used: missing or misnamed columns, bad units,
    non-increasing time, NaN rows, too few samples. The message names the file, column and lines."""


class CommandLogError(DataError):
    """A command log (actuated angles or torques) that does not fit the path it drives: its
    samples do not cover the path's span (or the run's horizon), so the run would follow
    commands extrapolated beyond them (`check_log_covers`). The message names the log, its span
    and the path's."""


class IdentificationError(PPRError):
    """An identification that cannot run as asked (unknown names, bounds, a failed simulation)."""


class DesignError(PPRError):
    """A design that cannot run as asked (unknown variables or metrics, bounds outside a
    parameter's physical range) or whose specification cannot be met (the message names the
    constraint and by how much it is violated at the best point found; `result`, when set, is
    that best `Design`)."""

    result = None


class ElasticaConvergenceError(PPRError, RuntimeError):
    """Raised (eagerly) when the shooting solver does not converge for the given load. A
    `PPRError` (as the library's other errors) and, as before, a `RuntimeError`."""


class RepairWarning(UserWarning):
    """A stored file this library wrote (an exported scene program, a persistent-cache entry, a
    sweep's chunk or its settings file) failed its check (checksum, deserialisation,
    compilation, or settings digest): it was deleted and its content computed afresh (a
    sweep's settings file: rewritten). The run's results are not affected; the
    warning names the file once. A recurring warning points at a failing disk or at two
    versions of the library sharing one cache directory."""


#: loop-closure residual (m) above which a chain counts as open at an output time
RESIDUAL_TOL = 1e-9


class RESULTS(diffrax.RESULTS):
    """Result codes of the compiled programs: diffrax's (and optimistix's) plus this library's.
    `RESULTS[code]` is the message; `RESULTS.promote(diffrax_result)` converts."""

    invalid_parameter = (
        "a parameter is not finite or out of its physical range (see ppr_jax.PARAM_RANGES)"
    )
    initial_state_failed = (
        "the quasi-static initial state was not found: the scene's initial loads are beyond "
        "what the joints hold near the nominal pose, or the pose is out of reach"
    )
    trajectory_out_of_reach = (
        "the nominal trajectory leaves the chains' reach (its inverse "
        "kinematics, which gives the scene's torques or prescribed angles, has an open loop): "
        "shrink the trajectory or check a, h, l1, l3, r"
    )
    loop_not_closed = (
        f"a kinematic chain does not close (loop-closure residual above {RESIDUAL_TOL:g} m at an "
        f"output time): the pose is out of the chains' reach (check a, h, l1, l3, r and the "
        f"trajectory) or the motion crosses a singularity"
    )
    input_table_too_coarse = (
        "the scene's input (torques or prescribed angles), interpolated from a table of its "
        "values on panels of the horizon, has an estimated relative error above 1e-8: ask for "
        "more output times (n_out; the table has at least one node per output time) or a "
        "shorter t_end (with a concrete t_end the table grows with the horizon by itself); "
        "or the path is not twice continuously differentiable inside the horizon (its "
        "acceleration jumps, as a rest-to-rest move with a cosine time law does at its ends): "
        "the torques then jump too"
    )
    kinematics_failed = (
        "forward kinematics did not converge along the prescribed path: the actuated angles "
        "leave the workspace or cross a singularity"
    )
    singular_path = (
        "the scene's path passes through (or within one output interval of) a type-II "
        "singularity (det S = 0, S = d th_a/dX): the inverse-dynamics torques along it are "
        "unbounded, and under prescribed angles forward kinematics folds back in its assembly "
        "mode instead of following the motion (det S extrapolated from the output times before "
        "changes sign, the solved pose's does not: the pose would be wrong); keep the "
        "trajectory away from the singularity (smaller radius or phi amplitude), or ask for "
        "more output times (n_out) if it only passes near one"
    )



def result_code(result):
    """The integer code of a result (traceable, batched like it; 0 is success): what a table
    column or a `lax` carry stores. The only place this package reads an enumeration's code."""
    result = result if isinstance(result, RESULTS) else RESULTS.promote(result)
    return result._value


def result_message(code: int) -> str:
    """The message of an integer result code (`result_code`)."""
    return RESULTS._index_to_message[int(code)]


def first_failure(*checks):
    """The result code of the first failed check, most fundamental cause first. A check is a
    pair (failed: bool array or None for "not checked", code), or a result code (diffrax's,
    optimistix's or ours) that counts as failed when it is not successful. Traceable and
    vmappable."""
    out = RESULTS.successful
    for check in reversed(checks):
        if isinstance(check, tuple):
            failed, code = check
            if failed is None:
                continue
        else:
            code = check if isinstance(check, RESULTS) else RESULTS.promote(check)
            failed = code != RESULTS.successful
        out = RESULTS.where(failed, code, out)
    return out


def failure_reasons(result, detail=None) -> dict:
    """{member index (None when not batched): reason} for every failed member of `result` (host
    side); `detail(i)` may add a member's particulars (for example when its loop opened)."""
    result = result if isinstance(result, RESULTS) else RESULTS.promote(result)
    # compared as host integers (numpy: no XLA program for the comparison)
    ok = np.asarray(result_code(result)) == int(result_code(RESULTS.successful))
    members = [None] if ok.ndim == 0 else np.flatnonzero(~ok).tolist()
    if ok.ndim == 0 and ok:
        return {}
    out = {}
    for i in members:
        r = result if i is None else jax.tree_util.tree_map(lambda x: x[i], result)
        extra = detail(i) if detail is not None else ""
        out[i] = RESULTS[r] + (f" ({extra})" if extra else "")
    return out


def check_result(result, what: str = "simulation", detail=None, value=None,
                 stiff: Optional[bool] = None) -> None:
    """Raise `SimulationError` if any (batch member's) `result` is not successful, naming the
    failed members and the reason of each (`failure_reasons`). `value` is attached to the error
    as `err.result`, so what succeeded is not lost. `stiff`: whether the solver that ran was an
    implicit one (None: unknown), so that a step failure does not advise the solver that
    failed."""
    result = result if isinstance(result, RESULTS) else RESULTS.promote(result)
    reasons = failure_reasons(result, detail)
    if not reasons:
        return
    if None in reasons:
        msg = f"{what} failed: {reasons[None]}"
    else:
        n = int(np.size(np.asarray(result_code(result))))
        shown = "; ".join(f"member {i}: {r}" for i, r in list(reasons.items())[:10])
        more = f"; and {len(reasons) - 10} more" if len(reasons) > 10 else ""
        msg = f"{what} failed ({len(reasons)} of {n} batch members): {shown}{more}"
    if any("step" in r for r in reasons.values()):
        if stiff:
            hint = ("the implicit solver that ran may need more steps (max_steps) or looser "
                    "tolerances (rtol, atol)")
        elif stiff is None:
            hint = ("a stiff model (thin strip, L2, the full L3) may need more steps "
                    "(max_steps), or an implicit solver (kvaerno5) where an explicit one ran")
        else:
            hint = ("a stiff model (thin strip, L2, the full L3) may need more steps "
                    "(max_steps) or an implicit solver (kvaerno5, kvaerno5-kept)")
        msg = (f"{msg.rstrip('.')}. {hint[0].upper()}{hint[1:]}; a chain leaving its reach or a "
               f"singular configuration also makes the step size collapse")
    err = SimulationError(msg)
    err.result = value
    raise err


def check_number(name: str, value, lo: float, hi: float, unit: str = "", *,
                 integer: bool = False, open_lo: bool = False):
    """Validate a scalar argument before any computation: a finite number (an integer if
    `integer`) in [lo, hi] (lo excluded with `open_lo`). Returns it as float or int; raises
    `PPRError` naming the argument and the allowed range."""
    rng = f"{'(' if open_lo else '['}{lo:g}, {hi:g}] {unit}".rstrip()
    kind = "an integer" if integer else "a number"
    if isinstance(value, (bool, str, bytes)):  # "0.5" would pass float() and reach JAX
        raise PPRError(f"{name} must be {kind}, got {value!r} (allowed range {rng})")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise PPRError(f"{name} must be {kind}, got {value!r} (allowed range {rng})") from None
    if not np.isfinite(v):
        raise PPRError(f"{name} must be finite: {value!r} is not finite (allowed range {rng})")
    if integer and v != int(v):
        raise PPRError(f"{name} must be an integer, got {value!r} (allowed range {rng})")
    if v < lo or v > hi or (open_lo and v == lo):
        raise PPRError(f"{name} = {value!r} is out of its allowed range {rng}")
    return int(v) if integer else v


def check_array(name: str, value, shape: Optional[tuple] = None):
    """Validate an array argument before any computation: numbers, of `shape` (None: any; None
    entries: any size), every entry finite. Returns it as a float64 array; raises `PPRError`
    naming the argument ("is not finite" with the first bad entries, or the shape expected).
    A traced value (under jit, vmap, grad) is checked for its shape only."""
    try:
        a = jnp.asarray(value, dtype=jnp.float64)
    except (TypeError, ValueError):
        text = repr(value)
        text = text if len(text) <= 60 else text[:57] + "..."
        raise PPRError(f"{name} must be an array of numbers, got {text}") from None
    if shape is not None and (a.ndim != len(shape) or any(
            want is not None and want != got for want, got in zip(shape, a.shape))):
        want = "(" + ", ".join("n" if w is None else str(w) for w in shape) + \
            ("," if len(shape) == 1 else "") + ")"
        raise PPRError(f"{name} must have shape {want}, got {tuple(a.shape)}")
    if not is_traced(a):
        bad = ~np.isfinite(np.asarray(a))
        if bad.any():
            where = [tuple(int(i) for i in ix) for ix in np.argwhere(bad)[:5]]
            where = [w[0] if len(w) == 1 else w for w in where]
            more = ", ..." if bad.sum() > 5 else ""
            at = f" at entries {', '.join(map(str, where))}{more}" if a.ndim else ""
            raise PPRError(f"{name} is not finite (NaN or inf{at})")
    return a


def is_traced(tree) -> bool:
    """Whether any leaf of `tree` is a JAX tracer (inside jit, vmap, grad...): the one test the
    package uses to choose between an eager check and a status code."""
    return any(isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves(tree))


def raise_if(x, bad, message: str, what: str = "batch members"):
    """Return `x`, raising `PPRError(message)` where `bad` holds.

    Concrete `bad`: raised now; if `bad` has a leading batch axis, the failing batch members are
    listed. Traced `bad`: `eqx.error_if` (the returned `x` must be used for the check to run)."""
    if is_traced(bad):
        return eqx.error_if(x, jnp.any(bad), message)
    b = np.asarray(bad)
    if b.any():
        if b.ndim >= 1 and b.shape[0] > 1:
            members = np.flatnonzero(b.reshape(b.shape[0], -1).any(axis=1)).tolist()
            shown = members if len(members) <= 10 else members[:10] + ["..."]
            raise PPRError(f"{message} ({len(members)} {what}: {shown})")
        raise PPRError(message)
    return x
