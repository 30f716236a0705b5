"""Running a scene for one robot or a batch: compiled once per (scene, model, shapes)."""

from __future__ import annotations

import dataclasses
from typing import Callable, Optional, Union

import diffrax
import equinox as eqx
import jax.numpy as jnp

from .._dispatch import FlatJit
from .._models import get_model
from .._params import RobotParams
from .._programs import cached_program
from .._robot import Robot
from ._base import AbstractScene, check_scene_commands
from ._batch import batch_devices, compress_shared, map_members, on_host_threads
from ._options import SceneOptions, default_solver, options_from
from ._registry import get_scene, scene_params
from ._result import SceneResult, finish, result_template
from ._solver_choice import choose_solver


def _scene_program(scene, model, robot, options):
    return scene.run(model, robot, options)


_scene_program.__name__ = _scene_program.__qualname__ = "scene_program"
#: one robot's run, compiled as `eqx.filter_jit` would, with a cheaper call (`_dispatch.py`);
#: a batch's runs likewise
scene_program = FlatJit(_scene_program)


def _member(robot_dyn, scene, model, robot_static, options):
    # `map_members` hands a member the model as it maps the members (`loops_members`)
    return scene.run(model, eqx.combine(robot_dyn, robot_static), options)


def scene_batch_program(scene, model, robot, options):
    dyn, static = eqx.partition(robot, eqx.is_array)
    return map_members(_member)(dyn, scene, model, static, options)


_JIT_BATCH = FlatJit(scene_batch_program)
_SHARDED: dict = {}


def _sharded(devices: tuple):
    """The batched run split over `devices` (compiled once per device set)."""
    if devices not in _SHARDED:
        def fn(scene, model, robot, options):
            dyn, static = eqx.partition(robot, eqx.is_array)
            return map_members(_member, devices)(dyn, scene, model, static, options)

        _SHARDED[devices] = FlatJit(fn)
    return _SHARDED[devices]


@dataclasses.dataclass(frozen=True)
class SceneCall:
    """A scene ready to run: `fn(*args)` is the compiled (and, for a batch, mapped) run;
    `args = (scene, model, robot, options)`. A plain record, not a module: it is built on
    every call and never traced, and an equinox module's construction took 90-200 us of a
    warm L1 `paper-circle` call on a 2-core CPU."""

    fn: Callable
    args: tuple
    scene: str
    batched: bool
    solver_name: str
    #: devices a batch is split over (0: not split)
    devices: int = 0

    def template(self) -> SceneResult:
        """The tree structure of this call's result (`_programs.py`)."""
        return result_template(self.scene, self.args[1].name)


def prepare(scene: Union[str, AbstractScene], params: Optional[RobotParams], model,
            options: SceneOptions, torque_model=None) -> SceneCall:
    """Check the options, decide every structural choice in Python and pick the compiled run:
    one robot, a batch (`RobotParams` with a leading axis), or a batch split over devices."""
    # Methods are called through the class on this path: equinox builds a bound-method
    # module on every method access of a module (30-70 us each on a 2-core CPU, where this
    # function took about a fifth of a warm L1 `paper-circle` call).
    Options = type(options)
    Options.check(options)
    scene = get_scene(scene, torque_model)
    Scene = type(scene)
    model = get_model(model)
    # Built here, outside any trace when params are concrete: the derived quantities once and
    # the structural choices (equal links, elbow) static, so a batch is branch-free. A scene's
    # default robot is built once per process.
    robot = Scene.default_robot(scene) if params is None else Robot(params)
    params = robot.params
    if not Scene.needs_integrator(scene, model):
        solver_name = "none (kinematics + inverse dynamics)"
    elif options.auto_solver:
        # decided here, on the concrete parameters, before anything is traced
        name, why = choose_solver(model, params, Options.tolerances(options, model)[0],
                                  default_solver(model))
        options = dataclasses.replace(options, solver=name)
        solver_name = f"{name} (auto: {why})"
    else:
        solver_name = Options.solver_name(options, model)
    opts = Options.prepared(options, model, Scene.trajectory(scene))
    # the commands a scene is given, against the robot and the path run (before any trace)
    check_scene_commands(scene, params, opts.trajectory, options.t_end)
    batched = jnp.ndim(params.a) == 1
    B = int(jnp.shape(params.a)[0]) if batched else 1
    devices = batch_devices(B) if batched else ()
    if batched:
        robot = compress_shared(robot)  # what the members share, computed once (`_batch.py`)
    if devices:
        fn = _sharded(devices)
    elif batched:
        fn = on_host_threads(_JIT_BATCH, B, argnum=2)
    else:
        fn = scene_program
    return SceneCall(fn=fn, args=(scene, model, robot, opts), scene=scene.name,
                     batched=batched, solver_name=solver_name, devices=len(devices))


def solve_scene(
    scene: Union[str, AbstractScene],
    params: Optional[RobotParams] = None,
    *,
    model="reduced",
    options: Optional[SceneOptions] = None,
    throw: bool = True,
    program_dir: Optional[str] = None,
) -> SceneResult:
    """Run a scene, by name or an `AbstractScene` instance (your own, too).

    **Arguments:**

    - `scene`: `"paper-circle"`, `"servo-circle"` or an `AbstractScene`.
    - `params`: a `RobotParams`, or a batch of them (`stack_params`: one compiled, mapped call);
      None: the scene's defaults.
    - `model`: a model or its name.
    - `options`: a `SceneOptions` (default horizon 7.54 s, 755 output times, the model's
      default solver and tolerances).
    - `throw`: raise `SimulationError` naming the failed members; False, or under a JAX
      transformation: check `result` instead (as diffrax's `throw`).
    - `program_dir`: a directory of stored programs (as `run_scene`'s; the command line's): the
      scene's program is loaded from there, or exported there on first use, so that a later
      process skips tracing it; None (or a batch split over devices): compiled as usual.

    **Returns:** a `SceneResult`, with a leading axis for a batch.
    """
    options = SceneOptions() if options is None else options
    c = prepare(scene, params, model, options)
    fn = c.fn
    if program_dir is not None and not c.devices:
        fn = cached_program(c.fn, c.args, c.template(), program_dir,
                            f"{c.scene}-{c.args[1].name}")
    return finish(fn(*c.args), throw, params, c.solver_name)


def _options(options, where, t_end, n_out, solver, rtol, atol, max_steps, adjoint,
             trajectory) -> SceneOptions:
    # the scene conveniences keep `SceneOptions`' fields as keywords (not deprecated)
    return options_from(options, where, False, t_end=t_end, n_out=n_out, solver=solver,
                        rtol=rtol, atol=atol, max_steps=max_steps, adjoint=adjoint,
                        trajectory=trajectory)


def paper_circle(
    params: Optional[RobotParams] = None,
    *,
    model="reduced",
    torque_model="reduced",
    options: Optional[SceneOptions] = None,
    throw: bool = True,
    trajectory=None,
    t_end: Optional[float] = None,
    n_out: Optional[int] = None,
    solver=None,
    rtol: Optional[float] = None,
    atol: Optional[float] = None,
    max_steps: Optional[int] = None,
    adjoint: Optional[diffrax.AbstractAdjoint] = None,
) -> SceneResult:
    """Scene `paper-circle` (paper Fig 8-12, `PaperCircle`): torques from `torque_model`'s
    inverse dynamics along eq 55, `model` simulated torque-driven from its quasi-static state
    at t = 0. Metrics and timings: `run_scene`.

    **Arguments:**

    - `params`: a `RobotParams`, or a batch of them (`stack_params`): one compiled vmapped
      call; None (default): Table 1 with t = 0.3 mm.
    - `model`: the simulated model, a name or instance (default `reduced`, L1).
    - `torque_model`: the model whose inverse dynamics gives the torques (default `reduced`,
      L1; `rigid` gives the paper's "simplified model" torques).
    - `options`: a `SceneOptions`; or, as a convenience, its fields as keywords (`t_end`,
      `n_out`, `solver`, `rtol`, `atol`, `max_steps`, `trajectory`, `adjoint`), not both.
    - `throw`: raise on a failed member (default True); False, as diffrax's `throw`.
    - `adjoint`: diffrax's default (reverse mode, `jax.grad`) or `diffrax.ForwardMode()` for
      `jax.jvp` / `jax.jacfwd` through the scene.

    **Returns:**

    A `SceneResult`, with a leading axis for batched `params`.

    **Raises:**

    `SimulationError` naming a failed member; with `throw=False`, or under a JAX
    transformation, check `result` instead (as diffrax's `throw`).
    """
    opts = _options(options, "paper_circle", t_end, n_out, solver, rtol, atol, max_steps,
                    adjoint, trajectory)
    c = prepare("paper-circle", params, model, opts, torque_model)
    return finish(c.fn(*c.args), throw, params, c.solver_name)


def servo_circle(
    params: Optional[RobotParams] = None,
    *,
    model="double1r",
    options: Optional[SceneOptions] = None,
    throw: bool = True,
    trajectory=None,
    t_end: Optional[float] = None,
    n_out: Optional[int] = None,
    solver=None,
    rtol: Optional[float] = None,
    atol: Optional[float] = None,
    max_steps: Optional[int] = None,
    adjoint: Optional[diffrax.AbstractAdjoint] = None,
) -> SceneResult:
    """Scene `servo-circle` (paper Fig 17-18, `ServoCircle`): the actuated angles follow L1's
    inverse kinematics of eq 55 exactly (motion-driven); the platform's response of `model`.
    L0/L1 need no ODE (forward kinematics + inverse dynamics).

    **Arguments:**

    - `params`: a `RobotParams`, or a batch of them (`stack_params`), as `paper_circle`; None
      (default): Table 1 with t = 0.5 mm.
    - `model`: the simulated model, a name or instance (default `double1r`, L2).
    - `options`: a `SceneOptions`, or its fields as keywords (`t_end`, `n_out`, `solver`,
      `rtol`, `atol`, `max_steps`, `trajectory`, `adjoint`), not both, as `paper_circle`.
    - `throw`, `adjoint`: as `paper_circle`.

    **Returns:**

    A `SceneResult` (batched like `paper_circle`).

    **Raises:**

    `SimulationError` naming a failed member, as `paper_circle`.
    """
    opts = _options(options, "servo_circle", t_end, n_out, solver, rtol, atol, max_steps,
                    adjoint, trajectory)
    c = prepare("servo-circle", params, model, opts)
    return finish(c.fn(*c.args), throw, params, c.solver_name)


__all__ = ["SceneCall", "paper_circle", "prepare", "scene_params", "servo_circle", "solve_scene"]
