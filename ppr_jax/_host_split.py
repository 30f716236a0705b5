"""A batch's members split over the host's cores: one slice of members a thread, one program.

On a CPU, XLA runs a program on one thread where its operations are small: the members of L0-L2
run one after another there, those of L3 in vmapped chunks (`_scenes/_batch.py`), and a batch
keeps about one core busy, whatever the machine has. JAX runs a compiled program from several
Python threads at once, each call on its own thread. `HostSplit` cuts a batch into as many
equal slices as the process may use cores (its CPU affinity), member j into slice j mod slices
(a sweep's members are ordered, and their steps with them: strided slices share the work
evenly), runs one compiled program (of one slice's shape) on each slice from a thread of its
own, and joins the results in the members' order. Measured on the 2-core CPU, L1 `paper-circle`
at the scene's defaults, 1,024 members (strip thickness 0.28-0.40 mm): one program over the
whole batch 1.27-1.32 s; two slices of 512 one after the other 1.29 s, dispatched
asynchronously from one thread 1.28 s (no overlap), from two threads 0.69 s in contiguous
halves, 0.68 s strided. Joining the 130 MB of results took 54 ms on one thread; the joins run
on the threads too. Sixteen quasi-static L3 (N = 4) robots over 1 s (vmapped chunks): 0.92 s
whole, 0.44 s in two slices.

A member that runs alone in the program's loop (L0-L2 on a CPU) computes what it computes in
an unsplit batch (the same program body, the members independent): the results equal the
unsplit batch's exactly, member by member. Vmapped members (L3) may round differently in a
chunk of another size, as in any batch of another size. A
batch whose size the slices do not divide is padded with repeats of its last member, which
are dropped. Several host devices (`configure_cpu`) split a batch by `shard_map` instead, and the
slices are not used then. Under a JAX transformation (traced arguments) the whole batch runs as
one program, as before.
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np


def host_cores() -> int:
    """The cores this process may run on: its CPU affinity (`taskset`, a container's quota as
    the OS reports it), else the machine's count."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


_POOLS: dict = {}
_POOLS_LOCK = threading.Lock()


def _pool(workers: int) -> ThreadPoolExecutor:
    # one pool per size for the process (threads are cheap to keep, not to start: ~50 us each)
    with _POOLS_LOCK:
        pool = _POOLS.get(workers)
        if pool is None:
            pool = _POOLS[workers] = ThreadPoolExecutor(workers, "ppr_jax-batch")
        return pool


def _is_traced(args) -> bool:
    return any(isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves(args))


class HostSplit:
    """`fn(*args)` for a batch, its members in `parts` slices run side by side (module
    docstring).

    **Arguments:**

    - `fn`: the batched program (a `FlatJit` or `eqx.filter_jit` function), whose result has
      the members on the leading axis of every array.
    - `parts`: slices (threads), at least 2.
    - `batch`: the members.
    - `argnum`: the argument that holds the batch: its arrays whose leading axis has `batch`
      entries are cut; its others (a shared array's length-1 axis, `compress_shared`) and every
      other argument are handed to each slice whole.
    """

    def __init__(self, fn: Callable, parts: int, batch: int, argnum: int):
        if not 2 <= parts <= batch:
            raise ValueError(f"HostSplit: parts must be in [2, batch = {batch}], got {parts}")
        self.fn, self.parts, self.batch, self.argnum = fn, parts, batch, argnum
        self.size = -(-batch // parts)

    def slices(self, args: tuple) -> list:
        """`args` for each slice, in the members' order."""
        pad = self.size * self.parts - self.batch

        def cut(x):
            if not (eqx.is_array(x) and x.ndim and x.shape[0] == self.batch):
                return [x] * self.parts
            a = np.asarray(x)  # the host's view of a CPU array: slices without a dispatch each
            if pad:
                a = np.concatenate([a, np.repeat(a[-1:], pad, axis=0)])
            # member j in slice j % parts: a sweep's members are ordered (strip thickness
            # 0.28 ... 0.40 mm), and their steps with them; strided slices share the work evenly
            return [a[i::self.parts] for i in range(self.parts)]

        held = args[self.argnum]
        leaves, treedef = jax.tree_util.tree_flatten(held)
        cuts = [cut(x) for x in leaves]
        out = []
        for i in range(self.parts):
            part = jax.tree_util.tree_unflatten(treedef, [c[i] for c in cuts])
            out.append(args[:self.argnum] + (part,) + args[self.argnum + 1:])
        return out

    def run(self, call: Callable, args: tuple):
        """`call` (the program of one slice) on every slice, one thread each; the results joined
        along their leading axis, the repeated members dropped."""
        pool = _pool(self.parts)
        outs = list(pool.map(lambda a: jax.block_until_ready(call(*a)), self.slices(args)))
        flat = [jax.tree_util.tree_flatten(o) for o in outs]
        treedef = flat[0][1]
        pad = self.size * self.parts - self.batch

        def join(xs):
            if not eqx.is_array(xs[0]):
                return xs[0]
            x = jnp.stack(xs, axis=1).reshape((-1,) + xs[0].shape[1:])
            return x[:self.batch] if pad else x

        # the joins on the pool's threads too: a batch's results are large (L1 x1,024 at the
        # scene's defaults: 130 MB, 54 ms joined on one thread)
        leaves = list(pool.map(join, zip(*(f[0] for f in flat))))
        return jax.block_until_ready(jax.tree_util.tree_unflatten(treedef, leaves))

    def over(self, call: Callable) -> Callable:
        """A callable taking the whole batch's arguments and running `call`, a program compiled
        for one slice's (`slices(args)[0]`), on every slice."""
        return lambda *args: self.run(call, args)

    def __call__(self, *args):
        if _is_traced(args):
            return self.fn(*args)
        return self.run(self.fn, args)

    def lower(self, *args) -> "_Lowered":
        """One slice's program lowered; its `compile()` runs the whole batch's arguments."""
        return _Lowered(self, self.fn.lower(*self.slices(args)[0]))


class _Lowered:
    def __init__(self, split: HostSplit, lowered):
        self._split, self._lowered = split, lowered

    def as_text(self, *a, **kw):
        return self._lowered.as_text(*a, **kw)

    def compile(self, *a, **kw) -> Callable:
        return self._split.over(self._lowered.compile(*a, **kw))
