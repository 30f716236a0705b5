"""Shared test helpers: tree comparison, finite-difference directional derivatives and compiled
forms of the library's eager functions."""

import pathlib

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import ppr_jax as pj
from ppr_jax._geometry import home_pose
from ppr_jax._studies import explicit_params


def tree_allclose(a, b, rtol=1e-10, atol=1e-12):
    la, lb = jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)
    if len(la) != len(lb):
        return False
    return all(np.allclose(np.asarray(x), np.asarray(y), rtol=rtol, atol=atol)
               for x, y in zip(la, lb))


@eqx.filter_jit
def coords_from_pose(model, robot, X):
    """`model.coords_from_pose(robot, X)` as one compiled program per model (and static robot
    fields): evaluated eagerly, op by op, each primitive of the closure solve is a compilation
    of its own."""
    return model.coords_from_pose(robot, X)


@eqx.filter_jit
def energies(model, robot, z, zd):
    """(kinetic, potential) energy (J), each (n,), along states z, zd (n, n_dof), as one
    compiled program per model (eagerly, the vmapped kinematics' JVP is op-by-op compilation)."""
    from ppr_jax import energy

    return jax.vmap(lambda z, zd: energy(model, robot, z, zd))(z, zd)


@eqx.filter_jit
def outputs(model, robot, z, zd):
    """`ppr_jax.outputs` along states z, zd (n, n_dof) as one compiled program per model;
    `robot`: a `Robot` built outside (its static choices from the concrete parameters)."""
    from ppr_jax import outputs

    return outputs(model, robot, z, zd)


def fd_jvp(f, x, v, h=1e-6):
    """Central finite difference (f(x + h v) - f(x - h v)) / 2h of a function of an array x."""
    x = jnp.asarray(x)
    return (f(x + h * v) - f(x - h * v)) / (2 * h)


def fd_grad_scalar(f, x0, h):
    """Central finite difference of a scalar function of a scalar."""
    return (f(x0 + h) - f(x0 - h)) / (2 * h)


def rotate_pose(X, center, k=1):
    """Rotate a pose by k * 120 degrees about the base centroid, relabelling chain i as i + k.

    The platform is an equilateral triangle, so the relabelled platform keeps its angle phi."""
    a = 2 * jnp.pi / 3 * k
    R = jnp.array([[jnp.cos(a), -jnp.sin(a)], [jnp.sin(a), jnp.cos(a)]])
    p = center + R @ (X[:2] - center)
    return jnp.concatenate([p, X[2:3]])


def rotate_vel(Xd, k=1):
    a = 2 * jnp.pi / 3 * k
    R = jnp.array([[jnp.cos(a), -jnp.sin(a)], [jnp.sin(a), jnp.cos(a)]])
    return jnp.concatenate([R @ Xd[:2], Xd[2:3]])


def raises_in_compiled_code(match):
    """`pytest.raises` for a check that fails inside a compiled program (`eqx.error_if` under
    `jax.jit`): no library exception class can cross the compiled program, so JAX raises its own
    error with the library's message in it. jaxlib raises it as `jax.errors.JaxRuntimeError`, or
    as a bare `ValueError` ("INTERNAL: CpuCallback error") once the function has run
    successfully (its fast dispatch path); either way the text carries equinox's
    `EquinoxRuntimeError: <message>`. A library `PPRError` (a ValueError too) is not accepted."""
    import contextlib

    import pytest

    from ppr_jax import PPRError

    @contextlib.contextmanager
    def ctx():
        with eqx_raise_mode():
            with pytest.raises((jax.errors.JaxRuntimeError, ValueError), match=match) as info:
                yield info
        assert not isinstance(info.value, PPRError), type(info.value)
        assert "EquinoxRuntimeError: " in str(info.value)

    return ctx()


def eqx_raise_mode():
    """A context in which equinox's runtime checks (`eqx.error_if`) raise. The suite runs in NaN
    mode (conftest.py: programs without host callbacks are shared through the compilation
    cache); the mode is read when a program is traced, so JAX's trace caches are emptied on the
    way in and out, and neither mode's traces reach the other."""
    import contextlib

    from equinox import _errors

    @contextlib.contextmanager
    def ctx():
        old, _errors.EQX_ON_ERROR = _errors.EQX_ON_ERROR, "raise"
        jax.clear_caches()
        try:
            yield
        finally:
            _errors.EQX_ON_ERROR = old
            jax.clear_caches()

    return ctx()


def env_with_devices(devices=None):
    """`os.environ` for a subprocess that compiles what this process compiled: the suite's XLA
    settings (`conftest.py`: LLVM -O0 and `compile_flags`) kept, so that its results match this
    process's to the last bit, and `devices` host devices asked for (None: the child asks
    itself)."""
    import os

    name = "--xla_force_host_platform_device_count"
    flags = [f for f in os.environ.get("XLA_FLAGS", "").split() if f.split("=")[0] != name]
    if devices is not None:
        flags.append(f"{name}={int(devices)}")
    return dict(os.environ, XLA_FLAGS=" ".join(flags))


def suite_program_dir():
    """The program store the command line uses in the suite (`PROGRAM_SUBDIR` of the suite's
    cache, `conftest.py`), or None where the suite runs without a cache. A test that runs a
    setting a command-line test runs too passes it to `run_scene(program_dir=...)`: whichever
    runs first, on either worker, exports the program; the other loads it, neither tracing nor
    compiling."""
    import os

    from ppr_jax._programs import PROGRAM_SUBDIR

    d = os.environ.get("PPR_JAX_CACHE_DIR")
    return os.path.join(d, PROGRAM_SUBDIR) if d else None


#: the tests' data files: design specifications (TOML)
DATA = pathlib.Path(__file__).resolve().parent / "data"
#: a design specification with a closed-form optimum (tier 1 of tests/test_design.py):
#: tests/data/design_tier1.toml
DESIGN_SPEC = (DATA / "design_tier1.toml").read_text()


class SmoothLine(eqx.Module):
    """The line with a quintic rest-to-rest time law (C2: zero velocity and acceleration at both
    ends), so its inverse-dynamics torques are continuous at the horizon's ends. The cosine
    law of `Line` starts with a jump of acceleration: its tabulated torques are refused as an
    input table too coarse, rightly (`test_a_path_that_is_not_c2_is_refused`). Also the path of
    the new scene in tests/test_extending.py (its source, copied into the new scene's file)."""

    start: jax.Array = eqx.field(default_factory=lambda: jnp.array([0.40, 0.27, 0.0]))
    end: jax.Array = eqx.field(default_factory=lambda: jnp.array([0.49, 0.24, 0.03]))
    duration: float = 1.0

    def __call__(self, t):
        u = jnp.clip(t / self.duration, 0.0, 1.0)
        return self.start + u**3 * (10 - 15 * u + 6 * u**2) * (self.end - self.start)


class OneSidedStart(eqx.Module):
    """`path` declaring a kink at t = 0 (`Waypoints.kinks`), the end of a hold: a scene's
    start there is the hold's balance at rest (tests/test_scene_interface.py)."""

    path: eqx.Module
    kinks: tuple = (0.0,)

    def __call__(self, t):
        return self.path(t)


# Random states of the closed-loop levels, for the equations of motion and their derivatives
# (test_fused_eom.py, test_forward_dynamics.py)

EOM_MODELS = ["rigid", "reduced", "double1r"]
EOM_N_STATES = 4
#: the parameters whose derivatives are compared (the strip's t, E and gamma, and the radius,
#: density, damping and rotor inertia that enter the fused formulas directly; l1 and l3 stay
#: concrete, so that L1 keeps its closed form)
EOM_PARAMS = ("t", "E", "gamma", "r", "rho_m", "c_spring", "c_act", "J_rotor")
EOM_TOL = 1e-12


def _eom_robots():
    base = explicit_params(pj.RobotParams())
    full = explicit_params(pj.RobotParams(
        joint_geometry="strip", c_spring=2e-3, c_act=1e-3, J_rotor=1e-4))
    return {"default": base, "all-terms": full}


EOM_ROBOTS = _eom_robots()


def eom_states(model, params, seed):
    """Random states near the workspace's centre: poses within a few cm and 0.1 rad of home,
    the internal coordinates off the quasi-static manifold, velocities of order 1."""
    rng = np.random.default_rng(seed)
    robot = pj.Robot(params)
    n = model.n_dof
    Xs = np.asarray(home_pose(robot)) + rng.uniform(-1, 1, (EOM_N_STATES, 3)) * [0.03, 0.03, 0.1]
    z = np.stack([np.asarray(model.coords_from_pose(robot, jnp.asarray(X))) for X in Xs])
    z[:, 3:] += rng.uniform(-0.02, 0.02, (EOM_N_STATES, n - 3))
    zd = rng.normal(size=(EOM_N_STATES, n)) * np.r_[0.2, 0.2, 1.0, [1.0] * (n - 3)]
    tau = rng.normal(size=(EOM_N_STATES, 3))
    values = jnp.array([float(getattr(params, p)) for p in EOM_PARAMS])
    scale = np.asarray(values) + 1e-3  # relative directions (the damping terms are zero-based)
    dv = rng.normal(size=(EOM_N_STATES, len(EOM_PARAMS))) * scale
    dz, dzd = rng.normal(size=(EOM_N_STATES, n)), rng.normal(size=(EOM_N_STATES, n))
    ct = rng.normal(size=(EOM_N_STATES, n))
    return values, tuple(jnp.asarray(a) for a in (z, zd, tau, dv, dz, dzd, ct))


def relative_close(a, b, what):
    a, b = np.asarray(a), np.asarray(b)
    scale = max(np.abs(b).max(), 1e-300)
    err = np.abs(a - b).max() / scale
    assert err <= EOM_TOL, f"{what}: relative difference {err:.2e}"


def sensitivity_small_calls(rows=None) -> dict:
    """{"fwd": [...], "rev": [...]}: the op names of the loops XLA compiles as one kernel (calls
    marked `xla_cpu_small_call`) in L2 `paper-circle`'s sensitivity programs over 0.05 s:
    forward mode along the first `rows` parameters' directions (None: all 19), reverse mode."""
    import re

    import diffrax

    from ppr_jax._studies._sensitivity import _jacobian_fwd, _jacobian_rev, _metric_function

    *_, (base, ev) = _metric_function(
        "paper-circle", None, model="double1r", torque_model=None, frequency_model="double1r",
        parameters=None, options=pj.SceneOptions(t_end=0.05, n_out=6), metrics=None)
    x0 = jnp.array([float(getattr(base, n)) for n in ev.names])
    V = jnp.eye(x0.size)[:rows]

    def small_calls(program, *args):
        text = program.lower(*args).compile().compiled.as_text()
        return [re.search(r'op_name="([^"]*)"', line).group(1) for line in text.splitlines()
                if " call(" in line and "xla_cpu_small_call" in line and "op_name" in line]

    adjoint = diffrax.RecursiveCheckpointAdjoint()
    return {"fwd": small_calls(_jacobian_fwd, x0, V, base, ev),
            "rev": small_calls(_jacobian_rev, x0, base, ev, adjoint)}
