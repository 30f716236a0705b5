"""Use every core: host devices and XLA settings for batches of small models on a CPU.

A batch of robots is one vmapped program. On a CPU, XLA runs that program on one device, which
keeps about 1.5 of this machine's two cores busy (it overlaps independent kernels). Asked for one
host device per core (`--xla_force_host_platform_device_count`), JAX can split the batch over
them with `shard_map`, each device running a local vmap over its members so that adaptive steps
never synchronise across devices; the batched scenes do this by themselves when more than one
local device is present (`_scenes/_batch.py`). Measured on the 2-core CPU (L1 `paper-circle`, a
batch of 1,024 at rtol 1e-6): 489 trajectories/s on one device, 731 on two; 4 or 8 host devices
give no more than 2.

XLA's YNNPACK fusions (jaxlib 0.10) turn the batched 2 x 2 to 6 x 6 products of the equations of
motion into library calls that are slower than XLA's own loops: switching them off
(`--xla_cpu_experimental_ynn_fusion_type=`) made the batch above 15 % faster (731 -> 843
trajectories/s) and a single L2 run no slower (32.0 against 31.9 ms).

Both are process settings that XLA reads once, when JAX starts its backend, so `configure_cpu`
must run before the first computation; the library itself starts nothing at import. The command
line calls it for `sweep`, the command that runs batches. The library does not
call it on import, because the number of devices is visible to everything else in the process.
"""

from __future__ import annotations

import os
from typing import Optional

from ._errors import PPRError

_DEVICES_FLAG = "--xla_force_host_platform_device_count"
_YNN_FLAG = "--xla_cpu_experimental_ynn_fusion_type"


def _backend_started() -> bool:
    try:
        from jax._src import xla_bridge

        return bool(xla_bridge.backends_are_initialized())
    except (ImportError, AttributeError):  # another JAX: assume the worst
        return True


def _ynn_supported() -> bool:
    """The YNNPACK flag exists from jaxlib 0.10 on (XLA aborts on a flag it does not know)."""
    try:
        import jaxlib

        major, minor = (int(p) for p in jaxlib.__version__.split(".")[:2])
    except (ImportError, ValueError):
        return False
    return (major, minor) >= (0, 10)


def cpu_flags(devices: Optional[int] = None, small_dots: bool = True) -> list[str]:
    """The XLA flags `configure_cpu` sets: `devices` host devices (default: one per core) and,
    with `small_dots` on a jaxlib that has them, no YNNPACK fusions."""
    n = (os.cpu_count() or 1) if devices is None else int(devices)
    if n < 1:
        raise PPRError(f"devices must be at least 1, got {devices}")
    flags = [f"{_DEVICES_FLAG}={n}"]
    if small_dots and _ynn_supported():
        flags.append(f"{_YNN_FLAG}=")
    return flags


def configure_cpu(devices: Optional[int] = None, small_dots: bool = True) -> list[str]:
    """Set the XLA flags for fast batches on a CPU (module docstring): `devices` host devices
    (default: one per core; batched scenes split over them) and, with `small_dots`, XLA's own
    code for small matrix products. Call it before JAX's first computation (right after
    `import ppr_jax` is fine); flags already in `XLA_FLAGS` are kept, not overridden. Returns the
    flags now in force for these settings. Raises `PPRError` if JAX's backend has started and
    the flags differ from what it started with."""
    wanted = cpu_flags(devices, small_dots)
    current = os.environ.get("XLA_FLAGS", "").split()
    name = lambda f: f.split("=")[0]  # noqa: E731
    wanted_names = {name(f) for f in wanted}
    add = [f for f in wanted if name(f) not in {name(c) for c in current}]
    if not add:
        return [f for f in current if name(f) in wanted_names]
    if _backend_started():
        raise PPRError(
            "configure_cpu must run before JAX's first computation (XLA reads its flags once); "
            f"call it right after import, or start Python with XLA_FLAGS='{' '.join(wanted)}'"
        )
    os.environ["XLA_FLAGS"] = " ".join(current + add)
    return [f for f in current + add if name(f) in wanted_names]
