"""Parameter sweeps: one compiled, vmapped (and optionally sharded) program over many robots.

`sweep` runs any scene (a registered name or an `AbstractScene`, such as a `PathScene` on
your own path) over a grid or a Latin hypercube of
parameter values. The members are validated first (parameter ranges, reach and singularity along
the whole nominal path) and the invalid ones are reported with their reason, not run. The valid
ones run in chunks of a fixed size: the last chunk is padded with copies of its first member, so
every chunk has the same static shape and the program compiles once. Inside the program each
member's trajectory is reduced to a handful of scalars (the catalogue's `sweep_metrics`), so
only small arrays come back to the host. A member whose solver fails (diffrax result code),
whose metrics are not finite, or whose loop-closure residual exceeds `RESIDUAL_TOL` is reported
as failed with the reason; the others are kept. A chunk that raises as a whole (an
`eqx.error_if` inside the program) is retried member by member, so one bad member never
discards its neighbours.

Structural choices are decided outside the trace: the members are grouped by `equal_links`
(l1 == l3: the closed-form inverse kinematics; otherwise Newton), each group runs its own
program (compiled once), and so every member runs the same program as its single run.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import os
import time
import warnings
from typing import Callable, Optional, Sequence, Union

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import PPRError, RepairWarning
from .._files import write_file
from .._kinematics import SINGULAR_TOL, path_margins
from .._models import get_model
from .._params import PARAM_RANGES, RobotParams, stack_params
from .._robot import Robot
from .._scenes import (
    T_END,
    AbstractScene,
    SceneOptions,
    deprecated_keywords,
    get_scene,
    shared_mask,
)
from ._catalogue import (
    METRICS as METRICS,
    SceneContext,
    sweep_metrics as sweep_metrics,
)
from ._evaluation import equal_links
from ._sweep_arguments import check_arguments, check_model, plain, settings
from ._sweep_chunks import (
    RESIDUAL_TOL as RESIDUAL_TOL,
    Chunks,
    chunk_timing,
    failed_row,
    progress_callbacks,
)

#: the float parameters a sweep (or a sensitivity) may vary
FLOAT_PARAMS = tuple(PARAM_RANGES)


def follows_its_input(scene, model, torque_model=None) -> str:
    """`AbstractScene.follows_its_input` of `scene` (a name or a scene) for `model`."""
    return get_scene(scene, torque_model).follows_its_input(get_model(model))


# ---------------------------------------------------------------------------------------------
# Designs: which members to run
# ---------------------------------------------------------------------------------------------


def design_members(vary: dict, design: str = "grid", n: Optional[int] = None,
                   seed: int = 0) -> dict:
    """The members of a sweep as {name: (N,) values}.

    **Arguments:**

    - `vary`: {name: values} of float parameters of `RobotParams` (SI units), each a non-empty
      1-D list of finite numbers.
    - `design`: "grid" (default): the Cartesian product of the given values (the first name
      varies slowest). "lhs": a Latin hypercube of `n` members, seeded, over [min, max] of each
      entry of `vary` (a (low, high) pair or the grid values): each parameter's range is cut
      into `n` equal strata and every stratum holds exactly one member, at a uniform random
      point in it. "list": the members as given, member i taking entry i of every list (all of
      one length), e.g. one process's share of a larger design.
    - `n`: the number of members of "lhs" (>= 1); unused otherwise.
    - `seed`: the seed of "lhs" (`numpy.random.default_rng`, default 0).

    **Returns:**

    A dict {name: (N,) float64 values}, one entry per name of `vary`.

    **Raises:**

    `PPRError` for an empty `vary`, a name that is not a float parameter, values that are not a
    non-empty 1-D list of finite numbers, lists of different lengths under "list", a missing
    or non-positive `n` under "lhs", or an unknown `design`.
    """
    if not vary:
        raise PPRError("a sweep needs at least one parameter to vary")
    for name in vary:
        if name not in FLOAT_PARAMS:
            raise PPRError(f"cannot vary {name!r}; allowed: {', '.join(FLOAT_PARAMS)}")
    vals = {k: np.atleast_1d(np.asarray(v, dtype=np.float64)) for k, v in vary.items()}
    for k, v in vals.items():
        if v.ndim != 1 or v.size == 0 or not np.all(np.isfinite(v)):
            raise PPRError(f"the values of {k!r} must be a non-empty 1-D list of finite numbers")
    if design == "grid":
        prod = list(itertools.product(*vals.values()))
        return {k: np.array([p[i] for p in prod]) for i, k in enumerate(vals)}
    if design == "list":
        sizes = {v.size for v in vals.values()}
        if len(sizes) != 1:
            raise PPRError(f"design 'list' needs lists of one length, got {sorted(sizes)}")
        return vals
    if design == "lhs":
        if n is None or int(n) < 1:
            raise PPRError("a Latin hypercube needs a number of members n >= 1")
        n = int(n)
        rng = np.random.default_rng(seed)
        out = {}
        for k, v in vals.items():
            lo, hi = float(v.min()), float(v.max())
            u = (rng.permutation(n) + rng.uniform(size=n)) / n
            out[k] = lo + u * (hi - lo)
        return out
    raise PPRError(f"unknown design {design!r}; allowed: grid, lhs, list")


# ---------------------------------------------------------------------------------------------
# Validation before running: parameters, reach and singularity along the nominal path
# ---------------------------------------------------------------------------------------------

#: samples of the nominal path checked for reach and singularity before a member runs
N_PATH_CHECK = 64


def _path_check(model, robot, Xs):
    """(out of reach, least reach margin, singular, least |relative det S|) of the path Xs
    (`_kinematics.path_margins`, the scenes' check)."""
    m = path_margins(model, robot, Xs)
    return (jnp.any(m.out_of_reach()), jnp.min(m.reach), jnp.any(m.singular()),
            jnp.min(jnp.abs(m.det)))


_path_check_batch = eqx.filter_jit(eqx.filter_vmap(_path_check, in_axes=(None, 0, None)))


def validate_members(scene, base: RobotParams, members: dict, *, torque_model=None,
                     trajectory=None, t_end=T_END):
    """Build each member's `RobotParams` and check it before any solve.

    Returns (params list with None for invalid members, reasons list: '' or why the member cannot
    run). Checks: parameter ranges (`RobotParams`); the scene's commands (a command log) fit
    the member (`AbstractScene.check_members`: an angle log's assembly mode); every chain
    closes with margin and the actuation is not singular at `N_PATH_CHECK` samples of the
    nominal path over [0, t_end] (default the scene's own path), with the kinematics of the
    scene's `input_model`, which gives the input (`_kinematics.path_margins`: the scenes' own
    check of reach and type-II singularities)."""
    names = list(members)
    N = len(members[names[0]])
    plist, reasons = [], []
    for i in range(N):
        try:
            p = base.replace(**{k: float(members[k][i]) for k in names})
            plist.append(p)
            reasons.append("")
        except (ValueError, PPRError) as err:
            plist.append(None)
            reasons.append(f"invalid parameters: {err}")
    ok = [i for i in range(N) if plist[i] is not None]
    if not ok:
        return plist, reasons
    scene_ = get_scene(scene, torque_model)
    traj = scene_.trajectory() if trajectory is None else trajectory
    # the commands the scene is given, against each member (an angle log's assembly mode is
    # each member's own: its geometry decides it)
    for i, err in zip(ok, scene_.check_members([plist[i] for i in ok], traj, t_end)):
        if err is not None:
            reasons[i] = f"commands: {err}"
            plist[i] = None
    ok = [i for i in ok if plist[i] is not None]
    if not ok:
        return plist, reasons
    Xs = jax.vmap(traj)(jnp.linspace(0.0, t_end, N_PATH_CHECK))
    kin = scene_.input_model
    # One vmapped call for all valid members, in fixed-size pieces (a few compiles at most).
    parts = []
    for lo in range(0, len(ok), 256):
        idx = ok[lo:lo + 256]
        batch = stack_params([plist[i] for i in idx])
        parts.append([np.asarray(v) for v in
                      _path_check_batch(kin, Robot(batch, equal_links=False), Xs)])
    out, margin, singular, det = (np.concatenate(v) for v in zip(*parts))
    for j, i in enumerate(ok):
        if out[j] or not np.isfinite(margin[j]):
            reasons[i] = ("unreachable path: a chain cannot close along the nominal path "
                          f"(min closure margin {margin[j]:.3g})")
            plist[i] = None
        elif singular[j] or not np.isfinite(det[j]):
            reasons[i] = ("singular configuration along the nominal path (least relative det S "
                          f"{det[j]:.3g}, below {SINGULAR_TOL:g} or changing sign: the path "
                          f"meets or crosses a type-II singularity)")
            plist[i] = None
    return plist, reasons


# ---------------------------------------------------------------------------------------------
# The compiled program: a vmap over members, optionally shard_map'ed over devices
# ---------------------------------------------------------------------------------------------


def shard_batch(params: RobotParams, devices: Optional[Sequence] = None):
    """Place a batched `RobotParams` (leading axis divisible by the number of devices) split
    over `devices` (default: all local devices) along its leading axis: each device holds its
    slice. The sweep does this itself through `shard_map`; use it to feed your own jitted,
    vmapped functions."""
    from jax.sharding import Mesh, NamedSharding, PartitionSpec as P

    devices = list(jax.local_devices() if devices is None else devices)
    mesh = Mesh(np.asarray(devices), ("batch",))
    n = params.a.shape[0]
    if n % len(devices):
        raise PPRError(f"a batch of {n} cannot be split evenly over {len(devices)} devices")
    return jax.device_put(params, NamedSharding(mesh, P("batch")))


# ---------------------------------------------------------------------------------------------
# The sweep
# ---------------------------------------------------------------------------------------------


@dataclasses.dataclass
class SweepResult:
    """A sweep's tidy table: one row per member (`rows`, a list of dicts with the keys
    `columns`): `member` (index), the varied parameters, `status` ('ok' or 'failed'), `reason`
    ('' or why), the metrics of `sweep_metrics` (NaN for a failed member), `result_code` (`RESULTS`,
    -1 if the member was not run), `num_steps`. `varied` the varied names; `timing`
    {compile_s, run_s, per_member_ms} (s; wall clock); `info` the sweep's settings."""

    rows: list
    columns: list
    varied: list
    timing: dict
    info: dict

    @property
    def ok(self) -> list:
        return [r for r in self.rows if r["status"] == "ok"]

    @property
    def failed(self) -> list:
        return [r for r in self.rows if r["status"] != "ok"]

    def column(self, name: str) -> np.ndarray:
        """One column as a numpy array (float for numeric columns)."""
        vals = [r[name] for r in self.rows]
        return np.asarray(vals, dtype=object if isinstance(vals[0], str) else np.float64)

    def to_numpy(self) -> np.ndarray:
        """The table as a numpy structured array."""
        dt = [(c, "U400" if isinstance(self.rows[0][c], str) else np.float64)
              for c in self.columns]
        return np.array([tuple(r[c] for c in self.columns) for r in self.rows], dtype=dt)

    def to_pandas(self):
        """The table as a pandas DataFrame (needs pandas)."""
        import pandas as pd

        return pd.DataFrame(self.rows, columns=self.columns)


def sweep(
    scene: Union[str, AbstractScene] = "paper-circle",
    base_params: Optional[RobotParams] = None,
    vary: Optional[dict] = None,
    *,
    design: str = "grid",
    n: Optional[int] = None,
    seed: int = 0,
    model="double1r",
    torque_model=None,
    options: Optional[SceneOptions] = None,
    chunk_size: int = 64,
    devices: Optional[Sequence] = None,
    checkpoint_dir: Optional[str] = None,
    progress: Union[bool, Callable] = False,
    program_dir: Optional[str] = None,
    **option_keywords,
) -> SweepResult:
    """Run `scene` over a design of parameter values and return a `SweepResult` table.

    Members are validated first (`validate_members`; the invalid ones are reported, not run),
    then run `chunk_size` at a time in one compiled program (the last chunk padded to the same
    shape). The columns are `sweep_metrics` of the scene's path (the radial error for a
    circle, the tracking error for any path).

    **Arguments:**

    - `scene`: a registered scene's name (default `paper-circle`) or an `AbstractScene` (a
      `PathScene` on your own path and drive).
    - `base_params`: one `RobotParams` (not a batch) giving the parameters not varied; None
      (default): the scene's.
    - `vary`: {name: values} of float parameters (`PARAM_RANGES`, SI units).
    - `design`, `n`, `seed`: "grid" (default) runs the Cartesian product of the values, "lhs"
      a Latin hypercube of `n` members over each entry's [min, max], seeded by `seed`
      (default 0), "list" the members as listed (`design_members`).
    - `model`: the simulated model, a name or instance. The default is L2 (`double1r`) under
      L1's torques, as in `sensitivity` (a model that follows its own input tracks the path to
      the solver's tolerance, and such a sweep warns that its tracking errors are the
      solver's).
    - `torque_model`: for a registered torque-driven scene, the model whose inverse dynamics
      gives the torques (a scene object carries its own); None: the scene's default.
    - `options`: a `SceneOptions`; None: default horizon, output times, the model's solver and
      tolerances.
    - `option_keywords`: `trajectory`, `t_end`, `n_out`, `solver`, `rtol`, `atol`,
      `max_steps`, deprecated spellings of the options' fields (a `DeprecationWarning`), which
      replace the options' where not None.
    - `chunk_size`: members per compiled call (default 64).
    - `devices`: a list of devices to split each chunk over (`chunk_size` must be divisible by
      their number); None (default): one device.
    - `checkpoint_dir`: each finished chunk's rows are written there, and a rerun with the same
      settings loads them instead of running them again (resume); None (default): none kept.
    - `progress`: True for a bar on stderr, or a callable `f(done, total)`; False (default):
      silent.
    - `program_dir`: a directory of stored programs (as `run_scene`'s; the command line's): the
      chunk's program is exported there once and loaded by later processes, which skip tracing
      it; None (default): compiled in this process (and kept for later sweeps of the same
      setting and shapes).

    **Returns:**

    A `SweepResult`: one row per member (status, reason, varied parameters, metrics), with
    timings and the sweep's settings.

    **Raises:**

    `PPRError` for a batch as `base_params`, a `chunk_size` out of range or not divisible by
    the number of `devices`, an invalid design (`design_members`) or invalid options.
    """
    scene_, base, chunk_size, devices, opts = check_arguments(
        scene, base_params, torque_model, chunk_size, devices, options,
        deprecated_keywords("sweep", option_keywords, warn=True))
    members = design_members(vary or {}, design, n, seed)
    names = list(members)
    N = len(members[names[0]])
    model_, options = check_model(scene_, model, base, opts)
    metric_names = sweep_metrics(options.trajectory)
    info = settings(scene, scene_, model_, base, opts, options.trajectory, vary=vary,
                    design=design, n=N, seed=seed, chunk_size=chunk_size)
    t0 = time.perf_counter()
    plist, reasons = validate_members(scene_, base, members, trajectory=options.trajectory,
                                      t_end=float(opts.t_end))
    rows: dict = {i: failed_row(i, members, names, reasons[i], metric_names)
                  for i in range(N) if reasons[i]}
    valid = [i for i in range(N) if not reasons[i]]
    # Members grouped by the static structure of their program (equal links or not), so that
    # each runs the same program as its single run; one compilation per group present.
    groups = {eq: [i for i in valid if equal_links(plist[i], (), local=False) == eq]
              for eq in (True, False)}
    chunks = [(eq, g[k:k + chunk_size]) for eq, g in groups.items()
              for k in range(0, len(g), chunk_size)]
    timing = {"validate_s": time.perf_counter() - t0, "compile_s": 0.0, "run_s": 0.0}

    store = _ChunkStore(checkpoint_dir, info) if checkpoint_dir else None
    update, close = progress_callbacks(progress, N, f"sweep {scene_.name} ({model_.name})")
    update(len(rows))
    dev = tuple(devices or ())
    runner = Chunks(plist=plist, members=members, metrics=tuple(metric_names),
                    ctx=SceneContext(scene_, model_, options, None), chunk_size=chunk_size,
                    tol=(options.rtol, options.atol), devices=dev, program_dir=program_dir,
                    label=f"sweep-{scene_.name}-{model_.name}-{len(dev) or 1}dev",
                    masks={eq: shared_mask(Robot(stack_params([plist[i] for i in g]),
                                                 equal_links=eq))
                           for eq, g in groups.items() if g})
    rows.update(runner.run_all(chunks, store, update, timing))
    close()
    columns = ["member", *names, "status", "reason", *metric_names, "result_code", "num_steps"]
    return SweepResult(rows=[rows[i] for i in range(N)], columns=columns, varied=names,
                       timing=chunk_timing(timing, chunk_size), info=info)


def library_digest() -> dict:
    """What a sweep's numbers depend on beyond its settings: the versions of ppr_jax and its
    numerical dependencies (`_programs.DEPENDENCIES`) and a hash of this package's source and
    data files. Part of each chunk's digest, so chunks of another library are recomputed."""
    from .._programs import dependency_versions, source_hash

    return {"versions": dependency_versions(), "source": source_hash()}


def _rows_checksum(rows) -> str:
    return hashlib.sha256(json.dumps(rows, sort_keys=True).encode()).hexdigest()


def _read_settings(path):
    """The sweep settings stored at `path` (a dict with a string "digest"), or None where there
    are none, or where the file is damaged (then a `RepairWarning` names it: the caller
    rewrites it)."""
    try:
        with open(path, "rb") as f:
            old = json.loads(f.read().decode("utf-8"))
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as err:  # UnicodeDecodeError, JSONDecodeError are ValueErrors
        why = f"unreadable: {type(err).__name__}"
    else:
        if isinstance(old, dict) and isinstance(old.get("digest"), str):
            return old
        why = "not a sweep's settings (no digest)"
    warnings.warn(f"sweep settings {path} are damaged ({why}): rewritten; each chunk is still "
                  f"checked against its own digest", RepairWarning, stacklevel=4)
    return None


class _ChunkStore:
    """Finished chunks on disk (`chunk_00000.json`, ...) next to the sweep's settings
    (`sweep_settings.json`): a rerun with the same settings skips the chunks found there.

    Nothing is trusted unchecked: each chunk file holds its rows with the sweep's digest (the
    settings and `library_digest`) and the sha256 of its rows. A chunk whose checksum fails,
    whose digest differs (another ppr_jax, its source edited, another dependency version) or
    whose members are not the chunk's is named once in a `RepairWarning` and computed afresh.
    Other settings in the same directory are refused (`PPRError`), not mixed in.

    The settings file is written atomically (a temporary file, then `os.replace`). One that
    cannot be read as this library's settings (damaged: not JSON, not an object, no digest) is
    named in a `RepairWarning` and rewritten: the chunks need it for nothing, since each chunk
    carries the digest of its sweep's settings and library and is checked against it, so the
    chunks of this sweep are still used and any other chunk is computed afresh."""

    def __init__(self, path, info):
        self.path = path
        os.makedirs(path, exist_ok=True)
        spec = json.dumps(info, sort_keys=True)
        self.settings_digest = hashlib.sha256(spec.encode()).hexdigest()[:16]
        library = library_digest()
        self.digest = hashlib.sha256(
            (spec + json.dumps(library, sort_keys=True)).encode()).hexdigest()[:16]
        settings = os.path.join(path, "sweep_settings.json")
        old = _read_settings(settings)
        if old is not None and old.get("digest") != self.settings_digest:
            raise PPRError(f"{path} holds the chunks of a different sweep (other settings); "
                           f"use another output directory or remove it")
        # whole or not at all: an interrupted write leaves the old file or none
        with write_file(settings) as f:
            json.dump({"digest": self.settings_digest, "library": library, "settings": info},
                      f, indent=2)

    def _file(self, c):
        return os.path.join(self.path, f"chunk_{c:05d}.json")

    def load(self, c, idx):
        """The rows of finished chunk `c`, or None where it is absent or fails a check (then
        one `RepairWarning` names it; the caller computes it afresh and `save` replaces it)."""
        path = self._file(c)
        try:
            with open(path, "rb") as f:
                data = json.loads(f.read().decode("utf-8"))
        except FileNotFoundError:
            return None
        except (OSError, ValueError) as err:
            return self._bad(path, f"unreadable: {type(err).__name__}")
        if not isinstance(data, dict) or not isinstance(data.get("rows"), list):
            return self._bad(path, "no checksum (an older layout)")
        rows = data["rows"]
        if data.get("checksum") != _rows_checksum(rows):
            return self._bad(path, "checksum mismatch: its content was changed")
        if data.get("digest") != self.digest:
            return self._bad(path, "computed by another ppr_jax, source or dependency version, "
                                   "or other settings")
        if [r.get("member") for r in rows] != list(idx):
            return self._bad(path, "its members are not this chunk's")
        for r in rows:  # JSON has no NaN by default: stored as null
            for k, v in r.items():
                if v is None:
                    r[k] = float("nan")
        return rows

    @staticmethod
    def _bad(path, why):
        warnings.warn(f"sweep chunk {path} is not used ({why}): computed afresh", RepairWarning,
                      stacklevel=3)
        return None

    def save(self, c, idx, rows):
        clean = [{k: (None if isinstance(v, float) and not np.isfinite(v) else plain(v))
                  for k, v in r.items()} for r in rows]
        data = {"digest": self.digest, "checksum": _rows_checksum(clean), "rows": clean}
        with write_file(self._file(c)) as f:  # an interrupted write leaves no partial chunk
            json.dump(data, f)
