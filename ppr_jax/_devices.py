"""Use every core: host devices and XLA settings for batches of small models on a CPU.

A batch of robots is one program. On a CPU, XLA runs that program on one device: there the
members of L0-L2 run one after another and those of L3 vmapped, on about one core
(`_scenes/_batch.py`), so the batched scenes and sweeps run one device's batch in slices on
host threads, one a core (`_host_split.py`). Asked for one host device per core
(`--xla_force_host_platform_device_count`), JAX can split the batch over them with `shard_map`,
each device running its own members so that adaptive steps never synchronise across devices;
the batched scenes do this by themselves when more than one local device is present. Measured
on the 2-core CPU with vmapped members (L1 `paper-circle`, a batch of 1,024 at rtol 1e-6): 489
trajectories/s on one device, 731 on two; 4 or 8 host devices give no more than 2.

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

XLA's CPU runtime runs a program as one kernel launch per fused operation (about 60 ns each on
this CPU), and a Runge-Kutta step of these models is hundreds of them: the runs were bound by
launches, not arithmetic. XLA compiles a while loop that accesses fewer than a threshold of bytes
as one kernel instead (its `SmallWhileLoopHoistingPass`, which marks the loop a
`xla_cpu_small_call`; custom calls keep a loop out, and so do the larger dots: on jaxlib 0.10.2
a loop holding a 2 x 2 product or a 9 x 9 matrix-vector product was taken whole, one holding an
(8, 14) x (14, 18) product was not, which kept the quasi-static L3's loop out until its
right-hand side and Dopri8's interpolant were written without dots: `_lean.Method.interpolate`,
`_dynamics._eom_terms`). Its default threshold, 1,024 bytes,
takes none of the solver's loops; at 64 KiB it took a step's Runge-Kutta stages always, and a
run's whole loop of steps (a run is then a few hundred kernels instead of 100,000-1,000,000;
since the lean loop saves its outputs in blocks, also with 7,540 output times), but not a
batch's loops, whose members would then run on one thread (a batch of 1,024 L1 robots at a 16
MiB threshold: 665 -> 620 trajectories/s). Measured on the 2-core CPU (`paper-circle`'s
program, minimum of 10 warm runs, one process each): L0 7.6 -> 3.2 ms, L1 5.2 -> 2.8 ms, L2 30.9
-> 11.6 ms, poses equal to 1.4e-12 m. The quasi-static L3's loop of steps (Dopri8's 14 stages,
the strips' solves) accesses more: between 64 and 128 KiB at N = 4, between 128 and 256 KiB at
N = 8 (the default), more than 256 KiB at N = 16. At 256 KiB L3 `paper-circle` ran 523 -> 178
ms at N = 4 and 726 -> 348 ms at N = 8 against 64 KiB, while the scene programs of L0 and L1
compiled to the same programs.

A derivative's loop of steps carries every parameter's tangent, and XLA splits a step's JVP into
about ten times the kernels of the step itself (an L2 right-hand side 30 kernels, its JVP 293).
`SMALL_LOOP_BYTES` is 1 MiB (`loop_flags`): the loops of steps of a forward-mode sensitivity of
L2 (in slices of 10 tangents on two cores, `_studies/_jacobian.forward_jacobian`) and of reverse
mode's transposed replay are one kernel each. Measured on the 2-core CPU, two processes a
setting, interleaved (`benchmarks/results/loop_threshold_default.json`): the sensitivity of L2
`paper-circle` over 1 s to all 19 parameters 42-47 -> 21 ms in forward mode and 58-60 -> 28 ms
in reverse mode, against 256 KiB; runs of L0-L2 and the quasi-static L3, L2 with 7,540 output
times, and batches (L1 x1,024, L0 x256) within 3 %. `configure_cpu(derivatives=True)` sets the
threshold at `DERIVATIVE_LOOP_BYTES` (4 MiB), for larger models' derivatives. Against 64 KiB,
the import's threshold then (`benchmarks/results/loop_threshold.json`): the 19-parameter L2
sensitivity 65.9 -> 36.4 ms in forward mode and 91.2 -> 40.7 ms in reverse mode; single L0 and
L1 runs 1.1 and 1.4 times slower (4.1 -> 4.5 ms, 2.9 -> 4.0 ms); an identification's fit, one
process a setting, was not faster. XLA reads the threshold for the whole process, not per
program (a program's compile options cannot set a backend option).

All are process settings that XLA reads once, when JAX starts its backend. `import ppr_jax`
adds the two that change no number beyond rounding, the loop emitters and the small-loop
threshold (`default_flags`), to `XLA_FLAGS` when JAX's backend has not started yet: the
library's users get its measured speed without a call. A flag already in `XLA_FLAGS` is kept as
the user gave it, and `PPR_JAX_CPU_DEFAULTS=0` leaves `XLA_FLAGS` alone. Because the settings are
the process's, they apply to other JAX programs in it too (and to child processes, which inherit
the environment). Where JAX has computed before `import ppr_jax`, nothing is changed; call
`configure_cpu` (or set `XLA_FLAGS`) before the first computation instead. `configure_cpu` adds
the host devices and the small-dot setting for batches; the command line calls it for `sweep`,
the command that runs batches.
"""

from __future__ import annotations

import os
from typing import Optional

_DEVICES_FLAG = "--xla_force_host_platform_device_count"
_YNN_FLAG = "--xla_cpu_experimental_ynn_fusion_type"
_EMITTERS_FLAG = "--xla_cpu_use_fusion_emitters"
_BACKEND_OPTIONS_FLAG = "--xla_backend_extra_options"
#: bytes: XLA compiles a while loop that accesses fewer as one kernel (module docstring)
SMALL_LOOP_BYTES = 1 << 20
#: the threshold of `configure_cpu(derivatives=True)`: a sensitivity's loops too (module
#: docstring)
DERIVATIVE_LOOP_BYTES = 4 << 20
_THRESHOLD_KEY = "xla_cpu_small_while_loop_byte_threshold"


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


def _measured_jaxlib() -> bool:
    """The jaxlib whose fusion-emitter flag was measured (module docstring): 0.10."""
    return _jaxlib_version() == (0, 10)


def compile_flags() -> list[str]:
    """The XLA flag `fast_compile` sets: the CPU's loop emitters instead of its fusion emitters
    (module docstring) on jaxlib 0.10; none elsewhere."""
    return [f"{_EMITTERS_FLAG}=false"] if _measured_jaxlib() else []


def loop_flags(loop_bytes: int = SMALL_LOOP_BYTES) -> list[str]:
    """The XLA flag that compiles a Runge-Kutta step's stages as one kernel (module docstring):
    the small-loop threshold at `loop_bytes` (default `SMALL_LOOP_BYTES`), on the jaxlib it was
    measured with (0.10); none elsewhere."""
    if not _measured_jaxlib():
        return []
    return [f"{_BACKEND_OPTIONS_FLAG}={_THRESHOLD_KEY}={int(loop_bytes)}"]


def default_flags() -> list[str]:
    """The flags `import ppr_jax` sets (module docstring): `compile_flags` and `loop_flags`."""
    return compile_flags() + loop_flags()


def apply_defaults() -> list[str]:
    """Add `default_flags` to `XLA_FLAGS` unless `PPR_JAX_CPU_DEFAULTS=0` or JAX's backend has
    started (then nothing changes). Called by `import ppr_jax`; imports no JAX. Returns the
    flags added."""
    if os.environ.get("PPR_JAX_CPU_DEFAULTS", "1") == "0":
        return []
    import sys

    if "jax" in sys.modules and _backend_started():
        return []
    global _FLAGS_BEFORE_DEFAULTS
    before = os.environ.get("XLA_FLAGS")
    added = _add_flags(default_flags())
    if added:
        _FLAGS_BEFORE_DEFAULTS = (before,)
    return added


#: (XLA_FLAGS before `apply_defaults` changed it,), or () where it changed nothing
_FLAGS_BEFORE_DEFAULTS: tuple = ()


def environment_without_defaults(env: dict) -> dict:
    """A copy of `env` (a child process's environment) with XLA_FLAGS as it was before
    `import ppr_jax` added the defaults: a benchmark that starts another checkout compares it as
    its own users run it."""
    env = dict(env)
    if _FLAGS_BEFORE_DEFAULTS:
        (before,) = _FLAGS_BEFORE_DEFAULTS
        env.pop("XLA_FLAGS", None)
        if before is not None:
            env["XLA_FLAGS"] = before
    return env


def cpu_flags(devices: Optional[int] = None, small_dots: bool = True,
              fast_compile: bool = True, derivatives: bool = False) -> list[str]:
    """The XLA flags `configure_cpu` sets (module docstring).

    **Arguments:**

    - `devices`: host devices; None (default): one per core.
    - `small_dots`: no YNNPACK fusions, on a jaxlib that has them.
    - `fast_compile`: the CPU's loop emitters (`compile_flags`).
    - `derivatives`: the small-loop threshold at `DERIVATIVE_LOOP_BYTES` instead of
      `SMALL_LOOP_BYTES` (`loop_flags`).

    **Returns:** the flags, a list of `--name=value` strings.

    **Raises:** `PPRError` for fewer than one device.
    """
    from ._errors import PPRError

    n = (os.cpu_count() or 1) if devices is None else int(devices)
    if n < 1:
        raise PPRError(f"devices must be at least 1, got {devices}")
    flags = [f"{_DEVICES_FLAG}={n}"]
    if small_dots and _ynn_supported():
        flags.append(f"{_YNN_FLAG}=")
    if fast_compile:
        flags += compile_flags()
    return flags + loop_flags(DERIVATIVE_LOOP_BYTES if derivatives else SMALL_LOOP_BYTES)


def configure_cpu(devices: Optional[int] = None, small_dots: bool = True,
                  fast_compile: bool = True, derivatives: bool = False) -> list[str]:
    """Set the XLA flags for fast batches on a CPU (module docstring). Call it before JAX's
    first computation (right after `import ppr_jax` is fine): XLA reads them once. Flags
    already in `XLA_FLAGS` are kept, not overridden (XLA's backend options gain the keys they
    lack), except the small-loop threshold that `import ppr_jax` added, which `derivatives`
    replaces.

    **Arguments:**

    - `devices`: host devices; None (default): one per core. Batched scenes split over them.
    - `small_dots`: XLA's own code for small matrix products (no YNNPACK fusions).
    - `fast_compile`: a code generator that compiles in about half the time for the same run
      time (what `import ppr_jax` sets by itself, with the small-loop threshold: a solver's
      loop as one kernel).
    - `derivatives`: the small-loop threshold at `DERIVATIVE_LOOP_BYTES`, for a process that
      runs sensitivities: their loops then run as one kernel too, about twice as fast. The
      setting is the process's, so other programs' loops are taken too, some of them (single
      L0 and L1 runs) a little slower (module docstring).

    **Returns:** the flags now in force for these settings.

    **Raises:** `PPRError` if JAX's backend has started and the flags differ from what it
    started with.
    """
    if derivatives and not _backend_started():
        _drop_default_threshold()
    return set_xla_flags(cpu_flags(devices, small_dots, fast_compile, derivatives),
                         "configure_cpu")


def _drop_default_threshold() -> None:
    """Take the small-loop threshold out of `XLA_FLAGS` where `apply_defaults` put it there (not
    where the user's own `XLA_FLAGS` held it), so that another value can take its place."""
    if not _FLAGS_BEFORE_DEFAULTS:
        return
    (before,) = _FLAGS_BEFORE_DEFAULTS
    if before is not None and f"{_THRESHOLD_KEY}=" in before:
        return
    out = []
    for flag in _xla_flags():
        if _name(flag) == _BACKEND_OPTIONS_FLAG:
            kvs = [kv for kv in flag.partition("=")[2].split(",")
                   if kv and kv != f"{_THRESHOLD_KEY}={SMALL_LOOP_BYTES}"]
            if not kvs:
                continue
            flag = f"{_BACKEND_OPTIONS_FLAG}=" + ",".join(kvs)
        out.append(flag)
    os.environ["XLA_FLAGS"] = " ".join(out)


def set_xla_flags(wanted: list[str], caller: str = "set_xla_flags") -> list[str]:
    """Add `wanted` to `XLA_FLAGS`, keeping the flags already there (`configure_cpu`'s rules;
    XLA's backend options, a map, gain the keys they lack). Returns the flags of `wanted`'s
    names now in force; raises `PPRError` if the backend has started and one is missing."""
    if _merged(_xla_flags(), wanted) != _xla_flags() and _backend_started():
        from ._errors import PPRError

        raise PPRError(
            f"{caller} must run before JAX's first computation (XLA reads its flags once); "
            f"call it right after import, or start Python with "
            f"XLA_FLAGS='{' '.join(wanted)}'"
        )
    _add_flags(wanted)
    wanted_names = {_name(f) for f in wanted}
    return [f for f in _xla_flags() if _name(f) in wanted_names]


def _xla_flags() -> list[str]:
    return os.environ.get("XLA_FLAGS", "").split()


def _add_flags(wanted: list[str]) -> list[str]:
    """Write `wanted` into `XLA_FLAGS` by `_merged`'s rules; returns what changed (flags new or
    merged), [] when nothing did (then `XLA_FLAGS` is left as it was, even unset)."""
    current = _xla_flags()
    new = _merged(current, wanted)
    if new == current:
        return []
    os.environ["XLA_FLAGS"] = " ".join(new)
    return [f for f in new if f not in current]


def _name(flag: str) -> str:
    return flag.split("=")[0]


def _merged(current: list[str], wanted: list[str]) -> list[str]:
    """`current` with `wanted` added: a flag already there is kept as given, except XLA's
    backend options (`--xla_backend_extra_options=k=v,k2=v2`), which gain the keys they lack."""
    out = list(current)
    for flag in wanted:
        names = [_name(c) for c in out]
        if _name(flag) not in names:
            out.append(flag)
        elif _name(flag) == _BACKEND_OPTIONS_FLAG:
            i = names.index(_name(flag))
            have = [kv for kv in out[i].partition("=")[2].split(",") if kv]
            keys = {_name(kv) for kv in have}
            extra = [kv for kv in flag.partition("=")[2].split(",") if kv and _name(kv) not in keys]
            if extra:
                out[i] = f"{_BACKEND_OPTIONS_FLAG}=" + ",".join(have + extra)
    return out
