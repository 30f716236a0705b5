"""The one batch mapper: members one after another or in vmapped chunks on a device, split over
devices by shard_map, or over a CPU's cores by host threads.

A scene's batch (`solve_scene` on stacked parameters) and a sweep's chunks map their members
through `map_members`; sensitivities and identification differentiate single runs.
Adaptive steps never synchronise across devices (`_devices.py`). On a device, how the members
run is a structural choice made in Python before tracing (`loops_members`):

- On a CPU, when every model among the shared arguments has fused equations of motion (L0-L2),
  the members run one after another (`jax.lax.map`), each as a single run is compiled: the fused
  terms and the lean loop (`_lean.py`), whose whole loop of steps XLA's CPU backend runs as one
  kernel (`_devices.py`), and each member with its own steps. Under `vmap` that loop is not one
  kernel: every fused operation of a step is a kernel over the chunk's members, and every member
  takes the steps of the chunk's slowest. Measured on the 2-core CPU (`paper-circle`, one
  device, minimum of 2-3 warm runs; trajectories/s, vmapped chunks against one after another):
  L0 x256 151 -> 198; L1 x1,024 at the scenes' defaults 198 -> 246, at rtol 1e-6 323 -> 439;
  L2 x64 at the scenes' defaults 15 -> 35. The first call compiled in less time too (L1 x1,024
  24 -> 16 s, L2 x64 30 -> 19 s): the program is a single run's inside one loop.
- Otherwise (a GPU, where one member at a time would leave the device idle, or L3, whose
  quasi-static strip solves vectorise: x16 1.0 against 0.7 trajectories/s one after another) a
  plain local vmap over the members, a chunk at a time. Every model among the shared arguments
  takes the generic equations of motion there (`_dynamics.for_batch`: faster under vmap on a
  CPU).

On one CPU device a batch keeps about one core busy, whether its members run one after
another or vmapped: the scenes' batches and a sweep's chunks run it in slices on host threads
instead, one a core (`host_parts`, `on_host_threads`, `_host_split.HostSplit`), the same
program on every slice. Measured on the 2-core CPU (`paper-circle`): L1 x1,024 at the scene's
defaults 1.27-1.32 -> 0.68 s, its results equal to the unsplit batch's exactly; quasi-static L3
(N = 4) x16 over 1 s 0.92 -> 0.44 s. Several host devices (`configure_cpu`) split the batch by
`shard_map` instead.

A batch over some parameters leaves the rest equal in every member (a sweep of the strip
thickness leaves 43 of a robot's 49 arrays alone). `compress_shared` keeps one copy of such an
array, its leading axis of length 1, and `map_members` hands it to every member unbatched, so
that what depends on it alone (the path's inverse kinematics, the geometry) is computed once
for the batch, not once a member. Which arrays are shared is decided on the concrete values,
before tracing, and is part of the arguments' shapes (so of every program's key).
"""

from __future__ import annotations

from typing import Callable, Sequence

import equinox as eqx
import jax
import numpy as np

from .._dynamics import for_batch, has_fused_terms
from .._host_split import HostSplit, host_cores
from .._models import AbstractModel

#: members vectorised together on one device at most: a larger local batch runs as a loop over
#: chunks of this size (`chunked_vmap`)
MEMBER_CHUNK = 64
#: the platforms on which the members of fused models run one after another (`loops_members`)
LOOP_PLATFORMS = ("cpu",)
#: the platforms on which one device's batch runs in slices on host threads (`host_parts`)
THREAD_PLATFORMS = ("cpu",)


def chunked_vmap(f: Callable, xs):
    """`jax.vmap(f)(xs)` in sequential chunks of at most `MEMBER_CHUNK` members
    (`jax.lax.map` with `batch_size`): the same values, but a chunk's members wait only for the
    slowest of their chunk and its temporaries stay in cache."""
    n = jax.tree_util.tree_leaves(xs)[0].shape[0]
    if n <= MEMBER_CHUNK:
        return jax.vmap(f)(xs)
    return jax.lax.map(f, xs, batch_size=MEMBER_CHUNK)


def batch_devices(batch: int) -> tuple:
    """The local devices a batch of `batch` members is split over: all of them when there are
    several and they divide the batch, else none (one device)."""
    devices = jax.local_devices()
    if len(devices) > 1 and batch % len(devices) == 0:
        return tuple(devices)
    return ()


def host_parts(batch: int, devices: Sequence = ()) -> int:
    """The slices a batch of `batch` members runs in side by side on one device of a platform
    of `THREAD_PLATFORMS` (`devices`' own, else JAX's default backend), one host thread each
    (`_host_split.HostSplit`): one a core this process may use, at most one a member; else 1
    (not split: a GPU takes the whole batch at once). Decided in Python before tracing."""
    platform = devices[0].platform if devices else jax.default_backend()
    if batch < 2 or platform not in THREAD_PLATFORMS:
        return 1
    return min(host_cores(), batch)


_SPLITS: dict = {}


def on_host_threads(fn: Callable, batch: int, argnum: int) -> Callable:
    """`fn`, a batched program whose argument `argnum` holds `batch` members, run in
    `host_parts(batch)` slices on host threads (`HostSplit`), or `fn` itself where that is
    one. One object per (fn, slices, batch, argnum), so that `cached_program` keys it once."""
    parts = host_parts(batch)
    if parts < 2:
        return fn
    key = (fn, parts, batch, argnum)
    if key not in _SPLITS:
        _SPLITS[key] = HostSplit(fn, parts, batch, argnum)
    return _SPLITS[key]


def shared_mask(batched):
    """A pytree of bools like `batched` (arrays with a leading batch axis, concrete): True for
    an array whose members are all equal. All False for a batch of one member or of identical
    members (one array then keeps the batch's length)."""
    def same(x):
        if not eqx.is_array(x) or isinstance(x, jax.core.Tracer) or x.shape[0] <= 1:
            return False
        a = np.asarray(x)
        return bool(np.all(a == a[:1]))

    mask = jax.tree_util.tree_map(same, batched)
    if all(jax.tree_util.tree_leaves(mask)):
        return jax.tree_util.tree_map(lambda _: False, mask)
    return mask


def compress_shared(batched, mask=None):
    """`batched` with every array that `mask` marks (default `shared_mask(batched)`: those whose
    members are all equal) cut to its first member, leading axis kept (length 1), for
    `map_members` to hand to every member unbatched. A study whose batches run in chunks takes
    one mask for all of them, so that every chunk runs the same program."""
    mask = shared_mask(batched) if mask is None else mask
    return jax.tree_util.tree_map(lambda x, c: x[:1] if c else x, batched, mask)


def _split_shared(batched):
    """(varying, shared): the arrays of `batched` with the batch's length on their leading axis,
    and those of length 1 in a batch of more members (`compress_shared`) without that axis; each
    tree with None where the other has the array."""
    lengths = [x.shape[0] for x in jax.tree_util.tree_leaves(batched) if eqx.is_array(x)]
    n = max(lengths, default=1)
    if n <= 1:
        return batched, None
    is_shared = jax.tree_util.tree_map(lambda x: eqx.is_array(x) and x.shape[0] == 1, batched)
    shared, varying = eqx.partition(batched, is_shared)
    return varying, jax.tree_util.tree_map(lambda x: x[0], shared)


def _is_model(x) -> bool:
    return isinstance(x, AbstractModel)


def _models_in(tree) -> list:
    """Every `AbstractModel` anywhere in the pytree `tree`."""
    return [x for x in jax.tree_util.tree_leaves(tree, is_leaf=_is_model) if _is_model(x)]


def loops_members(shared, devices: Sequence = ()) -> bool:
    """Whether a device runs a batch's members one after another (`jax.lax.map`, the models
    unchanged) rather than in vmapped chunks (`chunked_vmap`, the models `for_batch`): on a
    platform of `LOOP_PLATFORMS` (`devices`' own, else JAX's default backend), when the shared
    arguments hold at least one model and every model among them has fused equations of motion
    (module docstring). Decided in Python before tracing."""
    platform = devices[0].platform if devices else jax.default_backend()
    models = _models_in(shared)
    return (platform in LOOP_PLATFORMS and bool(models)
            and all(has_fused_terms(m) for m in models))


def map_members(member: Callable, devices: Sequence = ()) -> Callable:
    """`fn(batched, *shared)`: `member(one, *shared)` for every member of the pytree `batched`
    (leading axis), traceable. Without `devices` (or one), the members on one device; with
    several, the batch axis split over a 1-D mesh by `shard_map`, `shared` replicated. On a
    device, the members run one after another with the models of `shared` unchanged, or in
    vmapped chunks with every model (an `AbstractModel` anywhere in `shared`'s pytrees) as a
    vmapped batch takes it (`for_batch`): `loops_members` decides, before tracing. An array of
    `batched` whose leading axis has length 1 in a batch of more members (`compress_shared`) is
    the same for every member: it is handed to each unbatched."""

    def one_member(varying, common, *shared):
        return member(varying if common is None else eqx.combine(varying, common), *shared)

    def local(varying, common, *shared):
        if loops_members(shared, devices):
            return jax.lax.map(lambda one: one_member(one, common, *shared), varying)
        shared = jax.tree_util.tree_map(lambda x: for_batch(x) if _is_model(x) else x, shared,
                                        is_leaf=_is_model)
        return chunked_vmap(lambda one: one_member(one, common, *shared), varying)

    if len(devices) <= 1:
        def mapped(batched, *shared):
            return local(*_split_shared(batched), *shared)

        return mapped
    from jax.sharding import Mesh, PartitionSpec as P

    mesh = Mesh(np.asarray(devices), ("batch",))

    def sharded(batched, *shared):
        varying, common = _split_shared(batched)
        shared_dyn, shared_static = eqx.partition((common, shared), eqx.is_array)

        def body(b, sd):
            c, s = eqx.combine(sd, shared_static)
            return local(b, c, *s)

        # check_vma=False: diffrax's loops carry values that are replicated at entry and vary
        # per device after one step, which the varying-axes check rejects; each device's body
        # is a plain local vmap, with no collective to get wrong.
        return jax.shard_map(body, mesh=mesh, in_specs=(P("batch"), P()),
                             out_specs=P("batch"), check_vma=False)(varying, shared_dyn)

    return sharded
