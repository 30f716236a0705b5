"""One evaluation under the studies: named parameters -> named metrics of the catalogue.

A sensitivity differentiates it, a design optimises it (and screens and verifies it in
batches): both evaluate an `Evaluation`, the variables' names, the catalogue's metrics and the
scene they run (`_catalogue.SceneContext`), at parameter values x (p,) that replace those fields
of a base robot; a sweep maps its scene run and metrics over its members, whole robots of a
batch (`Evaluation.run`); an identification fits the platform poses of its scene's run at
the measured sample times, for each experiment's actuation and initial-state offset
(`Evaluation.poses`). The structural choice of the robot (`Robot`'s `equal_links`: the
closed-form inverse kinematics where l1 == l3) is decided once, in Python, by `equal_links`.

An `Evaluation` is a pytree: its names are static (they key the compiled programs), the
context's arrays (the scene's path, the options' tolerances) are inputs, so one compiled (or
stored) program serves any of their values.
"""

from __future__ import annotations

import dataclasses
from typing import Optional

import equinox as eqx
import jax.numpy as jnp

from .._errors import result_code
from .._params import RobotParams
from .._robot import Robot
from ._catalogue import Inputs, SceneContext, evaluate, metric_blocks


def equal_links(base: RobotParams, names, local: bool) -> bool:
    """`Robot`'s static choice of the closed-form inverse kinematics (l1 == l3) for an
    evaluation that varies the fields `names` of `base`.

    **Arguments:**

    - `base`: the base robot (one robot, concrete values).
    - `names`: the fields varied.
    - `local`: True where only derivatives at `base` are taken (a sensitivity): the nominal
      robot's choice holds even where l1 or l3 is varied, whose one Newton step then carries
      the implicit-function derivative (`ppr_jax._robot`); False where the values move away
      from `base` (a design, a sweep): l1 == l3 only while neither is varied.

    **Returns:** the flag.
    """
    same = float(base.l1) == float(base.l3)
    return same if local else same and "l1" not in names and "l3" not in names


def params_at(base: RobotParams, names, x) -> RobotParams:
    """`base` with its fields `names` (p,) replaced by the values x (p,) (traced or not): the
    one conversion of a parameter vector to a robot's parameters, of every study.

    **Arguments:**

    - `base`: the `RobotParams` whose other fields stay.
    - `names`: the fields replaced, in x's order.
    - `x`: (p,) their values (SI).

    **Returns:** the `RobotParams`.
    """
    return eqx.tree_at(lambda q: [getattr(q, n) for n in names], base,
                       [x[i] for i in range(len(names))])


class Evaluation(eqx.Module):
    """The catalogue's `metrics` of a robot whose fields `names` take the values x, or the
    platform poses of its scene's run at given sample times (`poses`: what identification fits;
    no metrics then).

    `names` (p,) fields of `RobotParams`; `metrics` (k,) catalogue names; `equal_links` the
    robot's static choice (`equal_links` above); `samples` the metrics of
    `_catalogue.sampled_metrics` given as their samples; `ctx` the scene, its models and
    options (`SceneContext`)."""

    names: tuple = eqx.field(static=True)
    metrics: tuple = eqx.field(static=True)
    equal_links: bool = eqx.field(static=True)
    samples: tuple = eqx.field(static=True)
    ctx: SceneContext

    def params(self, x, base: RobotParams) -> RobotParams:
        """`base` with the fields `names` replaced by x (p,) (traced or not)."""
        return params_at(base, self.names, x)

    def robot(self, x, base: RobotParams) -> Robot:
        """The `Robot` at x (p,), with the evaluation's structural choice."""
        return Robot(self.params(x, base), equal_links=self.equal_links)

    def blocks(self, x, base: RobotParams, stroke=None, adjoint=None) -> list:
        """The metrics at x (p,) as one 1-D array each (`_catalogue.metric_blocks`: NaN for
        every scene metric where the scene failed).

        **Arguments:**

        - `x`: (p,) the values of `names` (SI).
        - `base`: the `RobotParams` whose other fields stay.
        - `stroke`: the joint rotation (rad) of `pivot_stress_Pa` (None where not asked for).
        - `adjoint`: diffrax's adjoint of the scene's solve (`ForwardMode` under `jacfwd`).

        **Returns:** a list of (1,) arrays, or a metric's samples where `samples` names it.
        """
        stroke = jnp.zeros(()) if stroke is None else stroke
        return metric_blocks(self.metrics, self.params(x, base), self.ctx, stroke, adjoint,
                             self.equal_links, self.samples)

    def run(self, robot: Robot, options=None) -> tuple:
        """The context's scene run for `robot` and the metrics `metrics` of its result: what a
        sweep maps over its members (each a whole robot of the batch).

        **Arguments:**

        - `robot`: a `Robot` (one member; traced leaves allowed).
        - `options`: `SceneOptions` that replace the context's (a sweep's, its tolerances the
          program's inputs); None: the context's.

        **Returns:** ({metric: value} (NaN where the run failed), the run's result code
        (`_errors.result_code`), its number of steps).
        """
        ctx = self.ctx if options is None else dataclasses.replace(self.ctx, options=options)
        res = ctx.scene.run(ctx.model, robot, ctx.options)
        values = evaluate(self.metrics, Inputs(robot, ctx, result=res), self.samples)
        return (dict(zip(self.metrics, (v[0] for v in values))), result_code(res.result),
                res.num_steps)

    def poses(self, x, base: RobotParams, ts, actuation=None, initial_offset=None,
              commands: Optional[Robot] = None, scene=None) -> tuple:
        """The platform poses of the context's scene run at the sample times ts for the robot at
        x: what identification fits to the measured poses.

        **Arguments:**

        - `x`: (p,) the values of `names` (SI).
        - `base`: the `RobotParams` whose other fields stay.
        - `ts`: (m,) the sample times (s), ts[0] the start (traced or not: the options'
          input table has its panels already, `SceneOptions.panels`).
        - `actuation`: the run's input (an experiment's measured angles or torques); None: the
          scene's commands for `commands`.
        - `initial_offset`: (6,) added to the start's platform pose and rate (m, m, rad, m/s,
          m/s, rad/s); None: the start of the scene.
        - `commands`: the `Robot` the scene's commands are computed for where `actuation` is
          None (identification holds them fixed, apart from the robot simulated); None: the
          robot at x.
        - `scene`: a scene replacing the context's (an experiment's own `PathScene`); None:
          the context's.

        **Returns:** (the poses (m, 3) (m, m, rad), their rates (m, 3), the run's result code
        (`_errors.result_code`)).
        """
        model, options = self.ctx.model, self.ctx.options
        scene = self.ctx.scene if scene is None else scene
        if options.trajectory is None:
            # the scene's own path, built in the program as the scene builds it (its numbers
            # the program's constants, as a scene's run has them)
            options = dataclasses.replace(options, trajectory=scene.trajectory())
        robot = self.robot(x, base)
        if actuation is None and commands is not None:
            actuation = scene.commands(model, commands, options.trajectory, ts,
                                       options.panels).actuation
        res = scene.run(model, robot, options, actuation, ts=ts, initial_offset=initial_offset)
        # z[:3] is the platform pose in every model: its rates are the pose's
        return res.X, res.zdot[:, :3], result_code(res.result)

    def values(self, x, base: RobotParams, stroke=None, adjoint=None):
        """`blocks` concatenated: (k,), or longer where `samples` asks for samples."""
        return jnp.concatenate(self.blocks(x, base, stroke, adjoint))


__all__ = ["Evaluation", "equal_links", "params_at"]
