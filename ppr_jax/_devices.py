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

XLA's MLIR fusion emitters (jaxlib 0.10's default CPU code generator) spend most of a scene
program's compilation; its older loop emitters (`--xla_cpu_use_fusion_emitters=false`) compile
the same programs in 40-55 % less time and run them as fast. Measured on the 2-core CPU, XLA's
compile seconds and the run of `paper-circle` (7.54 s): L0 3.4 -> 1.8 s (10.6 -> 9.7 ms), L2
5.5 -> 3.2 s (51 -> 52 ms), full L3 (N = 4, Kvaerno5, 50 ms) 33.4 -> 26.4 s (241 -> 229 ms). The
two code generators round differently (poses differ by 1.5e-12 m), nothing more. XLA aborts on a
flag it does not know, so `fast_compile` sets it only on the jaxlib it was measured with (0.10).

All are process settings that XLA reads once, when JAX starts its backend, so `configure_cpu`
must run before the first computation; the library itself starts nothing at import. The command
line sets the compile flag for every command (`PPR_JAX_CPU_DEFAULTS=0` keeps XLA's defaults),
and the devices too for `sweep`, the command that runs batches. The library does not call it on
import, because XLA's settings are visible to everything else in the process.
"""

from __future__ import annotations

import os
from typing import Optional

from ._errors import PPRError

_DEVICES_FLAG = "--xla_force_host_platform_device_count"
_YNN_FLAG = "--xla_cpu_experimental_ynn_fusion_type"
_EMITTERS_FLAG = "--xla_cpu_use_fusion_emitters"


def _backend_started() -> bool:
    try:
        from jax._src import xla_bridge

        return bool(xla_bridge.backends_are_initialized())
    except (ImportError, AttributeError):  # another JAX: assume the worst
        return True


def _jaxlib_version() -> Optional[tuple[int, int]]:
    """(major, minor) of the installed jaxlib, from the package's metadata (no import of JAX, so
    that flags can be chosen before it starts); None if unknown."""
    try:
        from importlib.metadata import version

        major, minor = (int(p) for p in version("jaxlib").split(".")[:2])
    except Exception:  # no metadata or an odd version string
        return None
    return major, minor


def _ynn_supported() -> bool:
    """The YNNPACK flag exists from jaxlib 0.10 on (XLA aborts on a flag it does not know)."""
    v = _jaxlib_version()
    return v is not None and v >= (0, 10)


def _loop_emitters_measured() -> bool:
    """The jaxlib whose fusion-emitter flag was measured (module docstring): 0.10."""
    return _jaxlib_version() == (0, 10)


def compile_flags() -> list[str]:
    """The XLA flag `fast_compile` sets: the CPU's loop emitters instead of its fusion emitters
    (module docstring) on jaxlib 0.10; none elsewhere."""
    return [f"{_EMITTERS_FLAG}=false"] if _loop_emitters_measured() else []


def cpu_flags(devices: Optional[int] = None, small_dots: bool = True,
              fast_compile: bool = True) -> list[str]:
    """The XLA flags `configure_cpu` sets: `devices` host devices (default: one per core), with
    `small_dots` on a jaxlib that has them no YNNPACK fusions, and with `fast_compile` the
    loop emitters (`compile_flags`)."""
    n = (os.cpu_count() or 1) if devices is None else int(devices)
    if n < 1:
        raise PPRError(f"devices must be at least 1, got {devices}")
    flags = [f"{_DEVICES_FLAG}={n}"]
    if small_dots and _ynn_supported():
        flags.append(f"{_YNN_FLAG}=")
    if fast_compile:
        flags += compile_flags()
    return flags


def configure_cpu(devices: Optional[int] = None, small_dots: bool = True,
                  fast_compile: bool = True) -> list[str]:
    """Set the XLA flags for fast batches on a CPU (module docstring): `devices` host devices
    (default: one per core; batched scenes split over them), with `small_dots` XLA's own code
    for small matrix products, and with `fast_compile` a code generator that compiles in about
    half the time for the same run time. Call it before JAX's first computation (right after
    `import ppr_jax` is fine); flags already in `XLA_FLAGS` are kept, not overridden. Returns the
    flags now in force for these settings. Raises `PPRError` if JAX's backend has started and
    the flags differ from what it started with."""
    return set_xla_flags(cpu_flags(devices, small_dots, fast_compile), "configure_cpu")


def set_xla_flags(wanted: list[str], caller: str = "set_xla_flags") -> list[str]:
    """Add `wanted` to `XLA_FLAGS`, keeping the flags already there (`configure_cpu`'s rules).
    Returns the flags of `wanted`'s names now in force; raises `PPRError` if the backend has
    started and one is missing."""
    current = os.environ.get("XLA_FLAGS", "").split()
    name = lambda f: f.split("=")[0]  # noqa: E731
    wanted_names = {name(f) for f in wanted}
    add = [f for f in wanted if name(f) not in {name(c) for c in current}]
    if not add:
        return [f for f in current if name(f) in wanted_names]
    if _backend_started():
        raise PPRError(
            f"{caller} must run before JAX's first computation (XLA reads its flags once); "
            f"call it right after import, or start Python with XLA_FLAGS='{' '.join(wanted)}'"
        )
    os.environ["XLA_FLAGS"] = " ".join(current + add)
    return [f for f in current + add if name(f) in wanted_names]
