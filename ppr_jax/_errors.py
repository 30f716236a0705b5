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
        "the scene's path passes through a type-II singularity (det S = 0, S = d th_a/dX): the "
        "inverse-dynamics torques along it are unbounded (det S changes sign between two nodes "
        "of the input table), and under prescribed angles forward kinematics folds back in its "
        "assembly mode instead of following the motion (det S extrapolated from the output "
        "times before changes sign, the solved pose's does not: the pose would be wrong); keep "
        "the trajectory away from the singularity (smaller radius or phi amplitude); under "
        "prescribed angles, ask for more output times (n_out) if it only passes within one "
        "output interval of one"
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
                 integer: bool = False, open_lo: bool = False, error=PPRError):
    """Validate a scalar argument before any computation: a finite number (an integer if
    `integer`) in [lo, hi] (lo excluded with `open_lo`). Returns it as float or int; raises
    `error` (a `PPRError` class) naming the argument and the allowed range."""
    rng = f"{'(' if open_lo else '['}{lo:g}, {hi:g}] {unit}".rstrip()
    kind = "an integer" if integer else "a number"
    if integer and isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        v = int(value)  # exact: an integer beyond float's range is out of range, not an error
        if v < lo or v > hi or (open_lo and v == lo):
            raise error(f"{name} = {_shown(value)} is out of its allowed range {rng}")
        return v
    v = check_real(name, value, error=error, allowed=f"allowed range {rng}", kind=kind)
    if integer and v != int(v):
        raise error(f"{name} must be an integer, got {value!r} (allowed range {rng})")
    if v < lo or v > hi or (open_lo and v == lo):
        raise error(f"{name} = {_shown(value)} is out of its allowed range {rng}")
    return int(v) if integer else v


# --- the studies' argument checks: one place for the type, count and range of each argument,
# so that any bad value is a `PPRError` subclass naming it (never a TypeError from float(),
# an IndexError from b[1] or an OverflowError from a huge integer), before anything compiles


def _shown(value, limit: int = 60) -> str:
    """`repr(value)`, an integer too long for it as its digit count, cut at `limit`."""
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool) \
            and abs(int(value)) >= 10**30:
        return f"an integer of {len(str(abs(int(value))))} digits"
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _ndim(value) -> int:
    """np.ndim, -1 for what NumPy cannot make an array of (a ragged list)."""
    try:
        return np.ndim(value)
    except (TypeError, ValueError):
        return -1


def check_real(name: str, value, *, error=PPRError, allowed: str = "",
               kind: str = "a number") -> float:
    """`value` as a finite float: a real number (a Python or NumPy scalar, a 0-d array), not a
    bool, string, None, sequence, or an integer beyond float64's range (1.8e308). Raises
    `error` naming the argument `name` and `allowed` (the allowed values, appended in
    parentheses where given)."""
    tail = f" ({allowed})" if allowed else ""
    if value is None or isinstance(value, (bool, str, bytes)) or _ndim(value) != 0:
        raise error(f"{name} must be {kind}, got {_shown(value)}{tail}")
    try:
        v = float(value)
    except OverflowError:
        raise error(f"{name} = {_shown(value)} is beyond the range of a float (1.8e308)"
                    f"{tail}") from None
    except (TypeError, ValueError):
        raise error(f"{name} must be {kind}, got {_shown(value)}{tail}") from None
    if not np.isfinite(v):
        raise error(f"{name} must be finite: {_shown(value)} is not finite{tail}")
    return v


def check_int(name: str, value, lo: int, hi: Optional[int] = None, *, error=PPRError) -> int:
    """`value` as an int in [lo, hi] (hi None: no upper limit): an integer (a float with an
    integer value too), not a bool or string. Raises `error` naming `name` and the range."""
    return check_number(name, value, lo, float("inf") if hi is None else hi, integer=True,
                        error=error)


def check_bounds(name: str, value, *, error=PPRError, unit: str = "",
                 ordered: bool = True) -> tuple:
    """`value` as bounds (lo, hi): exactly two finite numbers, with lo < hi if `ordered` (else
    the caller checks the order with its range). Raises `error` naming `name` (a third value
    is refused, not ignored)."""
    want = f"{name} must be (lo, hi), two finite numbers{' in ' + unit if unit else ''}" \
           f"{' with lo < hi' if ordered else ''}"
    if isinstance(value, (str, bytes, dict)) or not hasattr(value, "__len__") \
            or _ndim(value) != 1 or len(value) != 2:
        raise error(f"{want}, got {_shown(value)}")
    try:
        lo, hi = (check_real(name, v) for v in value)
    except PPRError:
        raise error(f"{want}, got {_shown(value)}") from None
    if ordered and not lo < hi:
        raise error(f"{want}, got lo = {lo:g} >= hi = {hi:g}")
    return lo, hi


def check_vector(name: str, value, n: int, *, error=PPRError, what: str = "") -> tuple:
    """`value` as a tuple of `n` finite floats (`what` describes them: "(x, y, phi) (m, m,
    rad)"). Raises `error` naming `name`."""
    want = f"{name} must be {what + ', ' if what else ''}{n} finite numbers"
    if isinstance(value, (str, bytes, dict)) or not hasattr(value, "__len__") \
            or _ndim(value) != 1 or len(value) != n:
        raise error(f"{want}, got {_shown(value)}")
    return tuple(check_real(f"{name}[{i}]", v, error=error, allowed=want) for i, v in
                 enumerate(value))


def check_mapping(name: str, value, allowed=None, *, error=PPRError, what: str = "") -> dict:
    """`value` (None: empty) as a dict with string keys, each among `allowed` (None: any).
    Raises `error` naming `name`, the stray keys and the allowed ones (`what` describes the
    values: "{name: (lo, hi)}")."""
    from collections.abc import Mapping

    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise error(f"{name} must be a mapping {what or '{name: value}'}, got "
                    f"{type(value).__name__} {_shown(value)}")
    out = dict(value)
    bad = [k for k in out if not isinstance(k, str)]
    stray = sorted(map(str, bad)) + sorted(k for k in out if isinstance(k, str)
                                           and allowed is not None and k not in allowed)
    if stray:
        listed = f"; allowed: {', '.join(allowed)}" if allowed is not None else \
            "; keys are names (strings)"
        raise error(f"{name}: unknown key(s) {stray}{listed}")
    return out


def check_names(name: str, value, allowed, *, error=PPRError) -> tuple:
    """`value` as a tuple of names, each among `allowed`; one string is one name (not its
    letters). Raises `error` naming `name`, the bad entry and the allowed names."""
    if isinstance(value, str):
        value = (value,)
    if isinstance(value, (bytes, dict)) or not hasattr(value, "__iter__"):
        raise error(f"{name} must be a sequence of names among {', '.join(allowed)}, got "
                    f"{_shown(value)}")
    out = tuple(value)
    for item in out:
        if not isinstance(item, str) or item not in allowed:
            raise error(f"unknown {name} {_shown(item)}; allowed: {', '.join(allowed)}")
    return out


def check_instance(name: str, value, cls, *, error=PPRError, what: str = ""):
    """`value` if it is a `cls`, else `error` naming `name` and the type expected."""
    if not isinstance(value, cls):
        raise error(f"{name} must be {what or cls.__name__}, got {type(value).__name__} "
                    f"{_shown(value)}")
    return value


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


def raise_first(x, checks, what: str = "samples"):
    """Return `x`, raising `PPRError` for the first member (in order along the leading axis)
    that fails any of `checks`, [(bad (m,), message), ...] in order of precedence: the message
    is that of the first check the member fails, listing the members that fail that check
    (from the first failing one). A path's error then names where it first goes wrong, not the
    first check some later sample fails (one failure at a sample leaves the warm start of the
    samples after it anywhere). Traced flags: `raise_if` for each, in order."""
    if any(is_traced(bad) for bad, _ in checks):
        for bad, message in checks:
            x = raise_if(x, bad, message, what)
        return x
    flags = [np.asarray(bad).reshape(np.shape(bad)[0], -1).any(axis=1) for bad, _ in checks]
    failing = np.flatnonzero(np.any(flags, axis=0))
    if failing.size:
        first = failing[0]
        bad, message = next((f, m) for f, (_, m) in zip(flags, checks) if f[first])
        raise_if(x, bad, message, what)
    return x
