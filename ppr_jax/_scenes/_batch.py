"""The one batch mapper: members in vmapped chunks on a device, split over devices by shard_map.

Scenes, sweeps, sensitivities and identification map their members through `map_members`.
Adaptive steps never synchronise across devices (`_devices.py`): each device runs a plain local
vmap over its members, a chunk at a time. Every model among the shared arguments takes the
generic equations of motion there (`_dynamics.for_batch`: faster under vmap on a CPU).
"""

from __future__ import annotations

from typing import Callable, Sequence

import equinox as eqx
import jax
import numpy as np

from .._dynamics import for_batch
from .._models import AbstractModel

#: members vectorised together on one device at most: a larger local batch runs as a loop over
#: chunks of this size (`chunked_vmap`)
MEMBER_CHUNK = 64


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


def map_members(member: Callable, devices: Sequence = ()) -> Callable:
    """`fn(batched, *shared)`: `member(one, *shared)` for every member of the pytree `batched`
    (leading axis), traceable. Without `devices` (or one), a chunked vmap; with several, the
    batch axis split over a 1-D mesh by `shard_map`, `shared` replicated. Every model in
    `shared` (an `AbstractModel` anywhere in its pytrees) is handed to `member` as a batch
    takes it (`for_batch`), a structural choice made before tracing."""

    def local(batched, *shared):
        shared = jax.tree_util.tree_map(
            lambda x: for_batch(x) if isinstance(x, AbstractModel) else x, shared,
            is_leaf=lambda x: isinstance(x, AbstractModel))
        return chunked_vmap(lambda one: member(one, *shared), batched)

    if len(devices) <= 1:
        return local
    from jax.sharding import Mesh, PartitionSpec as P

    mesh = Mesh(np.asarray(devices), ("batch",))

    def sharded(batched, *shared):
        shared_dyn, shared_static = eqx.partition(shared, eqx.is_array)

        def body(b, sd):
            return local(b, *eqx.combine(sd, shared_static))

        # check_vma=False: diffrax's loops carry values that are replicated at entry and vary
        # per device after one step, which the varying-axes check rejects; each device's body
        # is a plain local vmap, with no collective to get wrong.
        return jax.shard_map(body, mesh=mesh, in_specs=(P("batch"), P()),
                             out_specs=P("batch"), check_vma=False)(batched, shared_dyn)

    return sharded
