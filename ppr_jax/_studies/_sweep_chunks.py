"""A sweep's chunks: the compiled program over a chunk's members (`map_members`, split over
devices by `shard_map` where there are several), each member's row from its metrics, and the
chunks run in turn, a chunk that raises retried member by member, the first chunk of each
program timed apart (it compiles)."""

from __future__ import annotations

import dataclasses
import sys
import time
from typing import Callable, Union

import equinox as eqx
import numpy as np

from .._errors import result_message
from .._params import stack_params
from .._programs import cached_program
from .._robot import Robot
from .._scenes import compress_shared, map_members, on_host_threads
from .._simulate import default_controller
from ._catalogue import SceneContext
from ._evaluation import Evaluation

#: a member whose max loop-closure residual (m) at the output times exceeds this has failed
RESIDUAL_TOL = 1e-9


def _member(robot_dyn, robot_static, ev: Evaluation, rtol, atol):
    """One member's ({metric: value}, result code, steps) at tolerances (rtol, atol):
    `Evaluation.run`."""
    options = ev.ctx.options
    opts = eqx.tree_at(lambda o: o.controller, options,
                       default_controller(options.solver, rtol, atol))
    # `map_members` hands the member its models as it maps them (`loops_members`)
    return ev.run(eqx.combine(robot_dyn, robot_static), opts)


@eqx.filter_jit
def _chunk_program(robot, ev, rtol, atol, devices):
    """A chunk's ({metric: (B,)}, result codes (B,), num_steps (B,)) for the batched `robot`.

    `ev`: the sweep's `Evaluation` (its context's prepared `SceneOptions`, their tolerances
    replaced by the program's inputs `rtol`, `atol`). Members are mapped as the scenes' batches
    are (`map_members`: one after another or in vmapped chunks, split over `devices` by
    `shard_map` when there are several): adaptive steps never synchronise across devices. Every
    array of the arguments is an input, so one program serves any values of the same shapes; the
    command line keeps it in its program store."""
    dyn, static = eqx.partition(robot, eqx.is_array)
    return map_members(_member, devices)(dyn, static, ev, rtol, atol)


def member_rows(idx, members, names, out, codes, steps) -> list:
    """The rows of the members `idx` from their chunk's metrics `out`, result `codes` and
    `steps`: failed (with the reason, metrics NaN) where the solver failed, a metric is not
    finite or the loop-closure residual exceeds `RESIDUAL_TOL`."""
    rows = []
    for j, i in enumerate(idx):
        row = {"member": int(i), **{k: float(members[k][i]) for k in names}}
        m = {k: float(out[k][j]) for k in out}
        code = int(codes[j])
        if code != 0:
            reason = result_message(code)
        elif not all(np.isfinite(v) for v in m.values()):
            reason = "non-finite metrics (NaN or inf)"
        elif m["constraint_residual_max_m"] > RESIDUAL_TOL:
            reason = (f"loop-closure residual {m['constraint_residual_max_m']:.3g} m above "
                      f"{RESIDUAL_TOL:g} m")
        else:
            reason = ""
        if reason:
            m = {k: float("nan") for k in out}
        row.update(status="failed" if reason else "ok", reason=reason, **m, result_code=code,
                   num_steps=int(steps[j]))
        rows.append(row)
    return rows


def failed_row(i, members, names, reason, metrics) -> dict:
    """The row of member i, not run (result code -1) or raising: failed for `reason`."""
    return {"member": int(i), **{k: float(members[k][i]) for k in names}, "status": "failed",
            "reason": reason, **{k: float("nan") for k in metrics}, "result_code": -1,
            "num_steps": 0}


def progress_callbacks(progress: Union[bool, Callable], total: int, desc: str) -> tuple:
    """(update(k), close()) of a sweep's `progress`: True, a bar on stderr (tqdm if installed,
    else one plain line per update); a callable, `progress(done, total)`; False, silent."""
    if progress is True:
        return _progress(total, desc)
    if callable(progress):
        done = {"n": 0}

        def update(k):
            done["n"] += k
            progress(done["n"], total)

        return update, lambda: None
    return (lambda k: None), (lambda: None)


def _progress(total: int, desc: str):
    """A progress bar: tqdm if installed, else one plain line per update on stderr."""
    try:
        from tqdm.auto import tqdm

        bar = tqdm(total=total, desc=desc, unit="member", file=sys.stderr)
        return bar.update, bar.close
    except ImportError:
        state = {"n": 0, "t0": time.perf_counter()}

        def update(k):
            state["n"] += k
            el = time.perf_counter() - state["t0"]
            print(f"{desc}: {state['n']}/{total} members ({el:.1f} s)", file=sys.stderr,
                  flush=True)

        return update, lambda: None


@dataclasses.dataclass(frozen=True)
class Chunks:
    """The chunks of a sweep's valid members and how they run: `plist` every member's
    `RobotParams` (None where invalid), `members` {name: (N,)} the varied values, `metrics` the
    columns, `ctx` the scene, model and prepared options, `chunk_size` members per call (the
    last chunk padded with copies of its first member), `tol` the (rtol, atol) inputs, `devices`
    to split a chunk over, `program_dir` and `label` the program store's."""

    plist: list
    members: dict
    metrics: tuple
    ctx: SceneContext
    chunk_size: int
    tol: tuple
    devices: tuple
    program_dir: object
    label: str
    #: {equal: `shared_mask` of the group's members at once}: each chunk computes what the
    #: group shares once, and every chunk of a group runs the same program (a chunk's own mask
    #: would change with the members it happens to hold)
    masks: dict = dataclasses.field(default_factory=dict)

    def run(self, equal: bool, idx) -> tuple:
        """The chunk of members `idx` (all of one structure: `equal` links or not) in its
        compiled program: ({metric: (B,)}, codes (B,), steps (B,)) as numpy arrays."""
        members_p = [self.plist[i] for i in idx] + [self.plist[idx[0]]] * (
            self.chunk_size - len(idx))
        ev = Evaluation(names=tuple(self.members), metrics=self.metrics, equal_links=equal,
                        samples=(), ctx=self.ctx)
        robot = compress_shared(Robot(stack_params(members_p), equal_links=equal),
                                self.masks[equal])
        args = (robot, ev, *self.tol, self.devices)
        template = ({m: 0 for m in self.metrics}, 0, 0)
        # on one device, the chunk's members in slices on host threads (`HostSplit`); one
        # compilation per group (equal links or not) and shape, kept for later chunks
        prog = (_chunk_program if self.devices else
                on_host_threads(_chunk_program, self.chunk_size, argnum=0))
        fn = cached_program(prog, args, template, self.program_dir, self.label)
        out, codes, steps = fn(*args)
        return {k: np.asarray(v) for k, v in out.items()}, np.asarray(codes), np.asarray(steps)

    def rows(self, equal: bool, idx) -> list:
        """The rows of the chunk `idx`; where it raises as a whole (an `eqx.error_if` inside the
        program), member by member (a chunk of copies of one member: the same compiled shape),
        so the error is pinned on the members that raise it."""
        names = list(self.members)
        try:
            return member_rows(idx, self.members, names, *self.run(equal, idx))
        except Exception:  # noqa: BLE001 (a runtime check inside the program)
            new = []
            for i in idx:
                try:
                    new += member_rows([i], self.members, names, *self.run(equal, [i]))
                except Exception as err1:  # noqa: BLE001
                    msg = str(err1).strip().splitlines()[0] if str(err1).strip() else repr(err1)
                    new.append(failed_row(i, self.members, names, f"error: {msg}",
                                          self.metrics))
            return new

    def run_all(self, chunks, store, update, timing: dict) -> dict:
        """Every chunk of `chunks` [(equal, idx)]: loaded from `store` where it holds it, else
        run (`rows`) and saved there. The first chunk of each program (it compiles) is timed
        apart in `timing` (first_chunk_s, programs), the others summed (run_s, chunks_timed).

        **Returns:** {member: row}."""
        rows = {}
        compiled = set()  # groups whose program has run once (its first chunk compiles)
        for c, (equal, idx) in enumerate(chunks):
            new = store.load(c, idx) if store else None
            if new is None:
                t1 = time.perf_counter()
                new = self.rows(equal, idx)
                dt = time.perf_counter() - t1
                if equal not in compiled:
                    timing["first_chunk_s"] = timing.get("first_chunk_s", 0.0) + dt
                    timing["programs"] = timing.get("programs", 0) + 1
                    compiled.add(equal)
                else:
                    timing["run_s"] += dt
                    timing.setdefault("chunks_timed", 0)
                    timing["chunks_timed"] += 1
                if store:
                    store.save(c, idx, new)
            for r in new:
                rows[r["member"]] = r
            update(len(idx))
        return rows


def chunk_timing(timing: dict, chunk_size: int) -> dict:
    """`timing` with, where chunks after the first of each program ran, the time per chunk and
    per member and the compilation's share of the first chunks (compile_s)."""
    nt = timing.get("chunks_timed", 0)
    if nt:
        per_chunk = timing["run_s"] / nt
        timing["per_chunk_s"] = per_chunk
        timing["per_member_ms"] = per_chunk / chunk_size * 1e3
        timing["compile_s"] = max(timing["first_chunk_s"] - timing["programs"] * per_chunk, 0.0)
    return timing
