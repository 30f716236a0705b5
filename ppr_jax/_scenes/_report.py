"""The reporting layer on top of the scenes: timing, numpy conversion and the paper's metrics.

`paper_circle` / `servo_circle` are the computation (traceable, jitted, vmappable, one pytree
out); `run_scene` runs one of them with its compilation and run timed apart and reduces the
result to the numbers of MODEL.md section 6, for the CLI, the benchmarks and notebooks.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Optional, Union

import jax
import numpy as np

from .._metrics import metric_table
from .._params import RobotParams
from .._programs import compiled_program
from ._base import AbstractScene
from ._options import SceneOptions, deprecated_keywords, options_from
from ._registry import get_scene
from ._result import SceneResult, finish
from ._run import prepare


@dataclasses.dataclass
class SceneReport:
    """A timed scene run. `result` is the `SceneResult` with numpy leaves (leading batch axis for
    a batch); `metrics` the MODEL.md section 6 numbers (SI units unless the key says otherwise),
    a dict, or a list of dicts for a batch; `timing` {compile_s, run_s} (s, wall clock, the run
    after compilation); `solver` {name, rtol, atol}; `params` what ran."""

    result: SceneResult
    metrics: Union[dict, list]
    timing: dict
    solver: dict
    params: RobotParams

    # the result's name and the numpy signals most reports need, read through the report
    scene = property(lambda self: self.result.scene, doc="The scene's name.")
    model = property(lambda self: self.result.model, doc="The model's name.")
    ts = property(lambda self: self.result.ts, doc="The output times (s).")
    X = property(lambda self: self.result.X, doc="The platform's pose (m, m, rad).")
    X_nominal = property(lambda self: self.result.X_nominal, doc="The nominal pose.")
    tau = property(lambda self: self.result.tau, doc="The actuator torques (N m).")
    end_rot = property(lambda self: self.result.end_rot,
                       doc="Chain 1's compliant-joint end rotations (rad).")


def scene_metrics(res: SceneResult, trajectory=None) -> Union[dict, list]:
    """The metrics of MODEL.md section 6 (`metric_table`) and the solver statistics of a
    `SceneResult`: a dict, or a list of dicts (one per member) for a batched result.
    `trajectory`: the nominal path (default: the scene's own)."""
    traj = get_scene(res.scene).trajectory() if trajectory is None else trajectory
    res = jax.tree_util.tree_map(np.asarray, res)
    arrays = metric_table(res, traj, xp=np)
    arrays.update(num_steps=res.num_steps, num_accepted=res.num_accepted,
                  num_rejected=res.num_rejected)
    kinds = {k: (int if k.startswith("num_") else float) for k in arrays}
    if res.X.ndim == 3:
        return [{k: kinds[k](v[i]) for k, v in arrays.items()} for i in range(res.X.shape[0])]
    return {k: kinds[k](v) for k, v in arrays.items()}


def run_scene(
    scene: Union[str, AbstractScene],
    params: Optional[RobotParams] = None,
    *,
    model="reduced",
    options: Optional[SceneOptions] = None,
    torque_model="reduced",
    repeats: int = 1,
    program_dir: Optional[str] = None,
    **option_keywords,
) -> SceneReport:
    """Run a scene and time it: compilation ahead of time (lowering and compiling; a cache hit
    once a model and shapes have run), then `repeats` runs, each after `block_until_ready`.

    **Arguments:**

    - `scene`: `"paper-circle"`, `"servo-circle"`, a registered name or an `AbstractScene`.
    - `params`: a `RobotParams` or a batch (`stack_params`); None: the scene's defaults.
    - `model`: a model or its name.
    - `options`: a `SceneOptions` (horizon, output times, solver, tolerances); None: defaults.
    - `torque_model`: the model whose inverse dynamics gives `paper-circle`'s torques.
    - `repeats`: timed runs (at least one); `timing["run_s"]` is the fastest.
    - `program_dir`: a directory of exported scene programs (`_programs.py`; the command line
      passes one inside its compilation cache): the program is loaded from there, or exported
      there on first use, so that a later process skips tracing too; `timing["program"]` says
      which ("loaded", "exported", or "compiled" where the program cannot be stored).
    - `option_keywords`: `trajectory`, `t_end`, `n_out`, `solver`, `rtol`, `atol`,
      `max_steps`, deprecated spellings of `options`' fields (a `DeprecationWarning`; not
      together with `options`).

    **Returns:** a `SceneReport`: the result as NumPy arrays, the scene's metrics, and
    `timing = {compile_s, run_s, program}`. A failure raises `SimulationError` naming the
    failed members.
    """
    scene = get_scene(scene, torque_model)
    params = scene.default_params() if params is None else params
    options = options_from(options, "run_scene", True,
                           **deprecated_keywords("run_scene", option_keywords))
    c = prepare(scene, params, model, options)
    # Compiled ahead of time (a cache hit if this shape ran before: lowering shares the jit
    # cache), then run `repeats` times; no extra run just to separate compilation from the run.
    # Tolerances are arrays, so changing them does not recompile.
    t0 = time.perf_counter()
    # A batch split over devices is compiled as usual: the command line stores single runs (a
    # sweep stores its split chunk program, `_programs._caller`).
    directory = None if c.devices else program_dir
    fn, how = compiled_program(c.fn, c.args, c.template(), directory,
                               f"{scene.name}-{c.args[1].name}")
    compile_s = time.perf_counter() - t0
    runs = []
    for _ in range(max(int(repeats), 1)):
        t1 = time.perf_counter()
        res = fn(*c.args)
        jax.block_until_ready(res)
        runs.append(time.perf_counter() - t1)
    res = finish(res, params=params, solver_name=c.solver_name)
    m = scene_metrics(res, c.args[3].trajectory)
    timing = {"compile_s": compile_s, "run_s": min(runs), "program": how}
    for mm in m if isinstance(m, list) else [m]:
        mm.update(wall_time_s=timing["run_s"], compile_time_s=timing["compile_s"])
    return SceneReport(
        result=jax.tree_util.tree_map(np.asarray, res), metrics=m, timing=timing,
        solver={"name": c.solver_name, "rtol": float(c.args[3].rtol),
                "atol": float(c.args[3].atol)}, params=params,
    )
