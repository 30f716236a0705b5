"""The engine profile's attribution (`benchmarks/kernel_counts.py --all-models`): each kernel of a
compiled program is attributed to a part of a run by the Python call stack XLA keeps for its HLO
instruction. Checked on a tiny program (compiled in well under a second): the stacks read from
the module's text are whole (every frame up to this test), and the parts follow the frames."""

import importlib.util
import pathlib

import jax
import jax.numpy as jnp
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def kc():
    spec = importlib.util.spec_from_file_location("kernel_counts",
                                                  ROOT / "benchmarks" / "kernel_counts.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _inner_sine(x):
    return jnp.sin(x) * 2.0


def _outer_loop(x):
    return jax.lax.fori_loop(0, 3, lambda i, c: jnp.cumsum(_inner_sine(c)), x)


def test_call_stacks_are_read_whole(kc):
    text = jax.jit(_outer_loop).lower(jnp.linspace(0.0, 1.0, 5)).compile().as_text()
    index = kc.hlo_index(text)
    stacks = [st for _, st in index.values() if st]
    assert stacks, "no instruction has a call stack"
    inner = [[f for _, f, _ in st] for st in stacks if st[0][1] == "_inner_sine"]
    assert inner, sorted({st[0][1] for st in stacks})
    for funcs in inner:
        # innermost first, through the loop's body, out to this test
        assert funcs.index("_inner_sine") < funcs.index("_outer_loop") < funcs.index(
            "test_call_stacks_are_read_whole"), funcs
    # the loop itself is a container, not a kernel
    loops = [n for n, (op, _) in index.items() if op == "while"]
    assert loops and not any(kc._is_kernel(n, index) for n in loops)


def test_parts_follow_the_frames(kc):
    integrate = "/site-packages/diffrax/_integrate.py"
    body = (integrate, "loop.<locals>.body_fun_aux", 1)
    vf = ("/ppr_jax/_simulate.py", "_vector_field", 1)
    cases = {
        "rhs_spring_solve": [("/ppr_jax/_geometry.py", "ik_reduced", 1),
                             ("/ppr_jax/_models/base.py", "AbstractClosedLoop.motion", 1), vf,
                             body],
        "rhs_loop_closure": [("/ppr_jax/_models/rigid.py", "Rigid.kin_at", 1), vf, body],
        "rhs_mass_solve": [("/ppr_jax/_linalg.py", "solve_spd", 1), vf, body],
        "input_lookup": [("/ppr_jax/_tabulated.py", "Chebyshev.__call__", 1),
                         ("/ppr_jax/_actuation.py", "TorqueDriven.torque_at", 1), vf, body],
        "rhs_eom": [("/ppr_jax/_dynamics.py", "_eom_terms", 1), vf, body],
        "saving": [(integrate, "loop.<locals>.body_fun_aux.<locals>.save_ts_impl", 1), body],
        "error_controller": [("/diffrax/_step_size_controller/pid.py",
                              "PIDController.adapt_step_size", 1), body],
        "loop_status": [body],
        "solver_start": [(integrate, "diffeqsolve", 1)],
        "start": [("/ppr_jax/_statics.py", "quasi_static_core", 1)],
        "input_table": [("/ppr_jax/_tabulated.py", "scene_input", 1)],
        "outputs": [("/ppr_jax/_metrics.py", "outputs", 1)],
        "other_fixed": [],
    }
    for part, stack in cases.items():
        assert kc.classify(tuple(stack)) == part, (part, stack)
    # diffrax's Runge-Kutta step: the stages before the error estimate's line, the estimate after
    rk = ("/diffrax/_solver/runge_kutta.py", "AbstractRungeKutta.step", 100)
    assert kc.classify((rk, body), rk_error_line=200) == "rk_stages"
    assert kc.classify((rk, body), rk_error_line=50) == "error_controller"
    # the project's own loop (`_lean.py`)
    lean = ("/ppr_jax/_lean.py", "lean_solve.<locals>.step", 1)
    lean_cases = {
        "rk_stages": [("/ppr_jax/_lean.py", "lean_solve.<locals>.step.<locals>.stage", 1), lean],
        "error_controller": [("/ppr_jax/_lean.py", "_adapt", 1), lean],
        "saving": [("/ppr_jax/_lean.py", "_interpolant", 1),
                   ("/ppr_jax/_lean.py", "lean_solve.<locals>.step.<locals>.save", 1), lean],
        "loop_status": [lean],
        "rhs_mass_solve": [("/ppr_jax/_linalg.py", "solve_spd", 1), vf,
                           ("/ppr_jax/_lean.py", "lean_solve.<locals>.step.<locals>.stage", 1),
                           lean],
        "solver_start": [("/ppr_jax/_lean.py", "lean_solve", 1)],
    }
    for part, stack in lean_cases.items():
        assert kc.classify(tuple(stack)) == part, (part, stack)


def _sine_twice_plus(x):
    return jnp.sin(x) * 2.0 + x


def test_element_operations_counted_as_traced_and_as_compiled(kc):
    """A right-hand side's arithmetic, counted in the traced program and in the compiled one:
    one count per output element of each elementwise operation, nested programs included."""
    x = jnp.linspace(0.0, 1.0, 4)
    # sine, product and sum of 4 elements; twice through the inner program, plus one sum
    assert kc.jaxpr_element_ops(jax.make_jaxpr(_sine_twice_plus)(x).jaxpr) == 12
    twice = jax.make_jaxpr(lambda x: jax.jit(_sine_twice_plus)(x) + _sine_twice_plus(x))(x)
    assert kc.jaxpr_element_ops(twice.jaxpr) == 28
    # XLA computes the same 12 in one fusion (no operand is needed twice)
    text = jax.jit(_sine_twice_plus).lower(x).compile().as_text()
    assert kc.hlo_element_ops(text) == 12
