"""Batches over every core: `configure_cpu` asks XLA for host devices before JAX starts, and a
batched scene split over them (shard_map, a local vmap on each device) equals the same batch on
one device member by member, failures included."""

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import ppr_jax as pj
from ppr_jax._devices import _merged, cpu_flags, loop_flags
from tests.helpers import env_with_devices

SHORT = dict(t_end=0.3, n_out=31, rtol=1e-8, atol=1e-10)

TWO_DEVICES = textwrap.dedent(
    """
    import json, sys
    import ppr_jax as pj
    print(pj.configure_cpu(2), file=sys.stderr)  # before the first computation
    import jax
    import numpy as np
    assert len(jax.devices()) == 2, jax.devices()
    from ppr_jax._scenes import SceneOptions, prepare
    kw, ts = json.loads(sys.argv[1])
    p = pj.scene_params("paper-circle")
    batch = pj.stack_params([p.replace(t=t) if t > 0 else p.replace(a=3.0) for t in ts])
    c = prepare("paper-circle", batch, "reduced", SceneOptions(**kw))
    assert c.devices == 2
    r = pj.paper_circle(batch, model="reduced", throw=False, **kw)
    print(json.dumps({"X": np.asarray(r.X).tolist(), "ok": np.asarray(r.ok).tolist(),
                      "steps": np.asarray(r.num_steps).tolist(),
                      "failures": {str(k): v for k, v in r.failures().items()}}))
    """
)


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_split_batch_equals_one_device():
    """Four robots, one of them out of reach (a = 3 m), on two host devices in a fresh process
    against the same batch here on one device: the same trajectories to rounding, the same step
    counts, the same failure."""
    ts = [0.3e-3, 0.35e-3, -1.0, 0.4e-3]  # -1: the member with a = 3 m
    p = pj.scene_params("paper-circle")
    batch = pj.stack_params([p.replace(t=t) if t > 0 else p.replace(a=3.0) for t in ts])
    ref = pj.paper_circle(batch, model="reduced", throw=False, **SHORT)
    env = env_with_devices()  # the child asks for two devices itself
    proc = subprocess.run([sys.executable, "-c", TWO_DEVICES, json.dumps([SHORT, ts])],
                          capture_output=True, text=True, timeout=600, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["ok"] == [True, True, False, True]
    assert list(out["failures"]) == ["2"] and "reach" in out["failures"]["2"]
    assert out["steps"] == np.asarray(ref.num_steps).tolist()
    for i in (0, 1, 3):
        np.testing.assert_allclose(out["X"][i], np.asarray(ref.X[i]), rtol=0, atol=1e-12)


def test_configure_cpu_after_the_backend_started_is_a_clear_error():
    """In this process JAX has computed already: flags that are not in force cannot be set."""
    import jax.numpy as jnp

    jnp.zeros(1).block_until_ready()
    if "--xla_force_host_platform_device_count=7" in os.environ.get("XLA_FLAGS", ""):
        pytest.skip("XLA_FLAGS already asks for 7 devices")
    with pytest.raises(pj.PPRError, match="before JAX's first computation"):
        pj.configure_cpu(7)


def test_cpu_flags():
    f = cpu_flags(3)
    assert f[0] == "--xla_force_host_platform_device_count=3"
    assert cpu_flags(1, small_dots=False, fast_compile=False) == [
        "--xla_force_host_platform_device_count=1", *loop_flags()]


def test_loop_emitters_only_on_the_measured_jaxlib(monkeypatch):
    """XLA aborts on a flag it does not know: the fusion-emitter flag is asked for on jaxlib 0.10
    (where it was measured) and on no other version."""
    import importlib.metadata

    import ppr_jax._devices as devices

    for v, want in [("0.10.2", ["--xla_cpu_use_fusion_emitters=false"]), ("0.9.0", []),
                    ("0.11.0", []), ("1.10.0", []), ("garbage", [])]:
        monkeypatch.setattr(importlib.metadata, "version", lambda name, v=v: v)
        assert devices.compile_flags() == want, v
        loops = ([f"--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold="
                  f"{devices.SMALL_LOOP_BYTES}"] if want else [])
        assert devices.loop_flags() == loops, v
        assert cpu_flags(1, small_dots=False)[1:] == want + loops, v


def test_derivatives_replace_the_imports_threshold_not_the_users(monkeypatch):
    """`configure_cpu(derivatives=True)` asks for `DERIVATIVE_LOOP_BYTES`: it replaces the
    small-loop threshold that `import ppr_jax` added (`_drop_default_threshold`), keeping the
    other flags and backend options, and keeps a threshold the user set before the import."""
    import ppr_jax._devices as devices

    if not loop_flags():
        pytest.skip("no small-loop threshold on this jaxlib")
    key = "xla_cpu_small_while_loop_byte_threshold"
    opts = "--xla_backend_extra_options"
    want = cpu_flags(1, small_dots=False, fast_compile=False, derivatives=True)
    assert want[-1] == f"{opts}={key}={devices.DERIVATIVE_LOOP_BYTES}"
    # the import's threshold beside another backend option and another flag
    user = f"--xla_cpu_use_thunk_runtime=true {opts}=other_key=1"
    monkeypatch.setattr(devices, "_FLAGS_BEFORE_DEFAULTS", (user,))
    monkeypatch.setenv("XLA_FLAGS", f"--xla_cpu_use_thunk_runtime=true "
                                    f"{opts}=other_key=1,{key}={devices.SMALL_LOOP_BYTES}")
    devices._drop_default_threshold()
    assert _merged(devices._xla_flags(), want) == [
        "--xla_cpu_use_thunk_runtime=true", f"{opts}=other_key=1,{key}={4 << 20}",
        "--xla_force_host_platform_device_count=1"]
    # the import's threshold alone: the option goes, and comes back with the new value
    monkeypatch.setattr(devices, "_FLAGS_BEFORE_DEFAULTS", (None,))
    monkeypatch.setenv("XLA_FLAGS", f"{opts}={key}={devices.SMALL_LOOP_BYTES}")
    devices._drop_default_threshold()
    assert devices._xla_flags() == []
    # the user's own threshold, even at the import's value, stays
    own = f"{opts}={key}={devices.SMALL_LOOP_BYTES}"
    monkeypatch.setattr(devices, "_FLAGS_BEFORE_DEFAULTS", (own,))
    monkeypatch.setenv("XLA_FLAGS", own)
    devices._drop_default_threshold()
    assert _merged(devices._xla_flags(), want)[0] == own


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_the_command_line_sets_the_compile_flag_before_jax_starts():
    """A fresh `ppr-jax` process adds the library's default flags (the loop emitters and the
    small-loop threshold) to the user's XLA_FLAGS (kept) before JAX's backend starts;
    `PPR_JAX_CPU_DEFAULTS=0` leaves XLA_FLAGS alone."""
    code = textwrap.dedent(
        """
        import os, sys
        from ppr_jax._cli import main
        rc = main(["simulate", "--model", "rigid", "--t-end", "-1"])  # refused before compiling
        print(rc, os.environ.get("XLA_FLAGS", ""))
        """
    )
    from ppr_jax._devices import default_flags

    for defaults, want in [("1", default_flags()), ("0", [])]:
        env = dict(os.environ, XLA_FLAGS="--xla_cpu_enable_fast_math=false",
                   PPR_JAX_CPU_DEFAULTS=defaults, PPR_JAX_CACHE="0")
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                              timeout=300, env=env)
        rc, *flags = proc.stdout.split()
        assert rc == "2", proc.stderr[-2000:]
        assert "t_end" in proc.stderr or "t-end" in proc.stderr, proc.stderr[-2000:]
        assert flags == ["--xla_cpu_enable_fast_math=false"] + want, flags
    with pytest.raises(pj.PPRError, match="devices must be at least 1"):
        cpu_flags(0)


def test_backend_options_gain_the_keys_they_lack():
    """XLA's backend options are one flag holding a map: the small-loop key joins a user's
    other keys, and a user's own threshold is kept."""
    ours = "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=65536"
    assert _merged(["--xla_foo=1"], [ours]) == ["--xla_foo=1", ours]
    assert _merged(["--xla_backend_extra_options=a=1"], [ours]) == [
        "--xla_backend_extra_options=a=1,xla_cpu_small_while_loop_byte_threshold=65536"]
    mine = "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=9"
    assert _merged([mine], [ours]) == [mine]
    assert _merged(["--xla_cpu_use_fusion_emitters=true"], ["--xla_cpu_use_fusion_emitters=false"]
                   ) == ["--xla_cpu_use_fusion_emitters=true"]


def test_import_sets_the_defaults_before_jax_starts():
    """`import ppr_jax` adds the default flags to the user's XLA_FLAGS (kept) and imports no
    JAX; with PPR_JAX_CPU_DEFAULTS=0, or where JAX computed first, XLA_FLAGS is left alone."""
    from ppr_jax._devices import default_flags

    code = textwrap.dedent(
        """
        import os, sys
        if sys.argv[1] == "late":
            import jax.numpy as jnp
            jnp.zeros(1).block_until_ready()
        import ppr_jax
        print("jax" in sys.modules, os.environ.get("XLA_FLAGS", ""))
        """
    )
    user = "--xla_cpu_enable_fast_math=false"
    for defaults, when, want in [("1", "first", [user, *default_flags()]), ("0", "first", [user]),
                                 ("1", "late", [user])]:
        env = dict(os.environ, XLA_FLAGS=user, PPR_JAX_CPU_DEFAULTS=defaults)
        proc = subprocess.run([sys.executable, "-c", code, when], capture_output=True,
                              text=True, timeout=300, env=env)
        assert proc.returncode == 0, proc.stderr[-2000:]
        imported, *flags = proc.stdout.split()
        assert imported == ("True" if when == "late" else "False")
        assert flags == want, (defaults, when, flags)


def test_a_child_of_another_checkout_gets_the_flags_as_they_were(monkeypatch):
    """Benchmarks that start another checkout hand it XLA_FLAGS as it was before the import
    added the defaults."""
    import ppr_jax._devices as devices

    monkeypatch.setattr(devices, "_FLAGS_BEFORE_DEFAULTS", ("--xla_foo=1",))
    env = devices.environment_without_defaults({"XLA_FLAGS": "--xla_foo=1 --bar", "A": "1"})
    assert env == {"XLA_FLAGS": "--xla_foo=1", "A": "1"}
    monkeypatch.setattr(devices, "_FLAGS_BEFORE_DEFAULTS", (None,))
    assert devices.environment_without_defaults({"XLA_FLAGS": "--bar"}) == {}
    monkeypatch.setattr(devices, "_FLAGS_BEFORE_DEFAULTS", ())
    assert devices.environment_without_defaults({"XLA_FLAGS": "--bar"}) == {"XLA_FLAGS": "--bar"}
