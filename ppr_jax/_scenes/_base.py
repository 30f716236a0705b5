"""The scene interface: what a scene is and how every scene runs.

A scene names a nominal motion, the input that realises it (torques, or prescribed angles) and
the strip thickness of its paper figure. `AbstractScene.run` is the one way any scene is run, by
the scene functions, `run_scene`, sweeps, sensitivities and identification: traced, for one
robot (batches map it, `_batch.py`). It computes only what the scene needs: a motion-driven
L0/L1 scene is forward kinematics plus inverse dynamics (no ODE); every other case integrates the
model from its quasi-static state under the input.
"""

# No `from __future__ import annotations` here: equinox reads `eqx.AbstractVar` from the
# evaluated annotation; as a string it would make `input_model` a field of every scene.
import abc
from typing import Callable, Optional

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp

from .._actuation import (
    AbstractActuation,
    InverseDynamicsTorque,
    InverseKinematicsAngles,
    MotionDriven,
    TorqueDriven,
)
from .._custom_types import Array
from .._dynamics import inverse_dynamics
from .._errors import RESIDUAL_TOL, RESULTS, PPRError, first_failure
from .._kinematics import det3, fold_flags, path_margins, singular_flags
from .._metrics import outputs
from .._models import AbstractModel
from .._params import RobotParams, params_invalid, table1_with_thickness
from .._robot import Robot, table1_robot
from .._simulate import Solution, simulate_core
from .._statics import kinematic_state, quasi_static_core
from .._tabulated import breakpoints, input_too_coarse, scene_input
from .._trajectory import derivatives
from ._options import SceneOptions
from ._result import SceneResult


class SceneInput(eqx.Module):
    """A scene's input for one robot: the actuation, and what building it found (traced bools,
    None where not checked): `out_of_reach`, the nominal path leaves the reach of the model that
    computed the input; `singular`, the nominal path meets a type-II singularity of that model
    (`singular_at_nodes`); `coarse`, its table is too coarse for the horizon. `step_ts`: times
    (k,) (s) the integrator steps to, where the input is less smooth (the knots of the spline
    path it is computed from, or of a command log: a kink of the torques or of the prescribed
    accelerations), so that no step straddles one (a Runge-Kutta step across a kink loses its
    order, and its error estimate does not see it: a drift of 1e-6 m over 2 s of L1 under its
    own torques on a 20 Hz spline at rtol 1e-8, against 1e-10 m on the circle); None: none.
    `start`: the actuation the quasi-static start reads, where it differs from `actuation`: the
    exact commands a table was made from. A prescribed motion's start takes the angles' rates
    and accelerations at t0, and a table's polynomials give them to ~1e-7 only, differently for
    every horizon (the start of a 5 ms run was 5e-9 rad from a 1 s run's); the exact commands
    make the start independent of the table, as a torque drive's is. None: `actuation`."""

    actuation: AbstractActuation
    out_of_reach: Optional[Array] = None
    coarse: Optional[Array] = None
    singular: Optional[Array] = None
    step_ts: Optional[Array] = None
    start: Optional[AbstractActuation] = None


def step_times(fn, traj) -> Optional[Array]:
    """The times (k,) (s) a run driven by `fn` along `traj` steps to (`SceneInput.step_ts`):
    fn's own knots where it has them (a command log's samples: `PiecewiseCubic`,
    `Interpolated`), else the path's (an input computed from the path kinks where the path's
    third derivative jumps); None where neither has any. One rule for a scene's own commands
    and for an input given to `AbstractScene.run` (identification's), so that both runs step
    alike."""
    knots = breakpoints(fn)
    return breakpoints(traj) if knots is None else knots


def tabulated(fn, ts, panels: int):
    """(table, coarse, out_of_reach, singular): the input `fn` (an `InverseDynamicsTorque` or
    `InverseKinematicsAngles`) tabulated over the output times `ts` and the quasi-static
    start's reach about ts[0] (`_tabulated.scene_input`; with the path's breakpoints among the
    panel boundaries, `_tabulated.breakpoints`), whether the table is too coarse, whether the
    nominal path leaves the chains' reach at a node, and whether it meets a type-II singularity
    of fn's model (`singular_at_nodes`; None for an input that does not solve with S), all from
    the table's own evaluations (`with_checks`)."""
    table, (resid, det, t) = scene_input(fn.with_checks, ts, panels, aux=True,
                                         breaks=breakpoints(fn.trajectory))
    singular = None if det is None else singular_at_nodes(det, t)
    return table, input_too_coarse(table), ~(jnp.max(resid) <= RESIDUAL_TOL), singular


def singular_at_nodes(det, t):
    """Whether a path meets a type-II singularity, from det S (relative, `relative_det`) at an
    input table's nodes t (any order): S singular at a node, or det S changing sign between
    two nodes adjacent in time (`singular_flags`). Where the inverse-dynamics torques are
    unbounded the table cannot hold them: two crossings between two nodes, which cancel in
    the signs, leave a pole inside a panel, which the table's own error estimate reports as
    too coarse. The nodes span the table, the horizon and the start's margin before ts[0]
    (`START_MARGIN`), where the quasi-static start reads the torques too. On the scenes'
    default 755 output times this check by the output times cost about a fifth of an L1
    `paper-circle` program (1.1 of 5.7 ms on a 2-core CPU); by the nodes it costs nothing."""
    order = jnp.argsort(t)
    return jnp.any(singular_flags(det[order]))


def path_out_of_reach(ref_model, robot, traj, ts):
    """The nominal path is out of reach at some output time for `ref_model` (L0 or L1), whose
    inverse kinematics gives the input (`PathMargins.out_of_reach` of `path_margins`)."""
    return jnp.any(path_margins(ref_model, robot, jax.vmap(traj)(ts)).out_of_reach())


def torque_input(input_model, robot, traj, ts, panels: int) -> SceneInput:
    """`input_model`'s inverse-dynamics torques along `traj`, tabulated over `ts`, with the
    path's reach, the table's fineness and the path's type-II singularities checked (where
    the torques are unbounded) at the table's nodes."""
    fn = InverseDynamicsTorque(input_model, robot, traj)
    torque, coarse, out, singular = tabulated(fn, ts, panels)
    return SceneInput(TorqueDriven(torque), out_of_reach=out, coarse=coarse, singular=singular,
                      step_ts=step_times(fn, traj))


def motion_input(model, input_model, robot, traj, ts, panels: int) -> SceneInput:
    """`input_model`'s inverse-kinematics angles along `traj`: exact for a model whose
    coordinates are the pose (L0, L1: forward kinematics follows them, no table), tabulated
    over `ts` for the others (th, th' and th'' at every stage from the table's polynomials)."""
    angles = InverseKinematicsAngles(input_model, robot, traj)
    if model.actuated_index is None:
        return SceneInput(MotionDriven(angles),
                          out_of_reach=path_out_of_reach(input_model, robot, traj, ts))
    table, coarse, out, _ = tabulated(angles, ts, panels)
    return SceneInput(MotionDriven(table), out_of_reach=out, coarse=coarse,
                      step_ts=step_times(angles, traj), start=MotionDriven(angles))


def stepping_to(controller, step_ts):
    """`controller` made to step to the times `step_ts` (`SceneInput.step_ts`; None: as it is):
    an adaptive controller wrapped in diffrax's `ClipStepSizeController` (one that clips
    already, or a constant step, is kept as given)."""
    if (step_ts is None or isinstance(controller, diffrax.ClipStepSizeController)
            or not isinstance(controller, diffrax.AbstractAdaptiveStepSizeController)):
        return controller
    return diffrax.ClipStepSizeController(controller, step_ts=step_ts)


def _open_at(model, robot, z):
    """A chain is open at coordinates z (loop-closure residual above `RESIDUAL_TOL`)."""
    k = model.kinematics(robot, z)
    return ~(jnp.max(jnp.linalg.norm(model.loop_residual(robot, k), axis=-1)) <= RESIDUAL_TOL)


def _any(*flags):
    """Or of the flags that were checked (None: not checked)."""
    out = False
    for f in flags:
        if f is not None:
            out = out | f
    return out


def kinematic_motion(model, robot, angles, X0, ts):
    """L0/L1 motion-driven: X(t) by warm-started forward kinematics from X0, X' and X'' from
    th_a(X) = th_a(t) differentiated once and twice, torques by inverse dynamics. No ODE.
    Returns (X, Xd, tau, codes, folds): (m, 3) poses, rates, torques, the forward kinematics'
    status per time, and whether the path folds through a type-II singularity (`fold_flags`)."""

    def step(X, t):
        X, Xd, Xdd, code, S = kinematic_state(model, robot, derivatives(angles, t), X)
        tau, _ = inverse_dynamics(model, robot, X, Xd, Xdd)
        return X, (X, Xd, tau, code, det3(S))

    _, (X, Xd, tau, codes, det) = jax.lax.scan(step, X0, ts)
    # A motion through a type-II singularity: the warm start folds back in its assembly mode
    # and every solve converges; det S along the solved poses shows it.
    return X, Xd, tau, codes, fold_flags(det, ts)


def check_scene_commands(scene, params, traj: Callable, t_end) -> None:
    """`scene.check_commands` for concrete parameters: one robot, or every member of a batch
    (`AbstractScene.check_members`: the members' geometry may differ, and with it the assembly
    mode an angle log's samples belong to), the error naming the member; nothing where the
    parameters or the horizon are traced."""
    from .._errors import is_traced
    from .._params import unstack_params

    kind = type(scene)
    if (kind.check_commands is AbstractScene.check_commands
            and kind.check_members is AbstractScene.check_members):
        # nothing to check (a built-in scene computes its input from its path): a batch is not
        # cut into its members for it, which for 1,024 robots cost as long as their simulation
        return
    if is_traced(params) or is_traced(t_end):
        return
    t_end = None if t_end is None else float(t_end)
    if jnp.ndim(params.a) >= 1:
        for i, err in enumerate(scene.check_members(unstack_params(params), traj, t_end)):
            if err is not None:
                raise type(err)(f"batch member {i}: {err}") from None
        return
    scene.check_commands(params, traj, t_end)


class AbstractScene(eqx.Module):
    """A scene of MODEL.md section 6, or your own: a nominal motion and the input realising it.

    A concrete scene sets the class variables (or fields: `PathScene`) and implements
    `commands`; `run` is shared. Everything that differs between scenes is a member of the
    scene, so that the studies, identification and the command line run any scene one way:

    - `name`: the scene's name (the CLI's and the registry's; a label in reports).
    - `thickness`: its default strip thickness (m).
    - `reference`: the values its paper figure reports, {metric: value} (may be empty).
    - `drive`: `"torque"` (the actuators apply a torque history: the robot's response moves
      the platform off the path) or `"motion"` (the actuated angles are prescribed: a
      kinematic model, L0 or L1, then needs no integrator).
    - `input_model`: the model (L0 or L1) whose inverse dynamics or kinematics along the path
      gives the input; its reach and type-II singularities along the path are checked.
    - `trajectory()`: the nominal path when the options name none.
    """

    name: eqx.AbstractClassVar[str]
    thickness: eqx.AbstractClassVar[float]
    reference: eqx.AbstractClassVar[dict]
    drive: eqx.AbstractClassVar[str]
    input_model: eqx.AbstractVar[AbstractModel]

    @abc.abstractmethod
    def trajectory(self) -> Callable:
        """The scene's nominal pose path t -> X (3,) (m, m, rad): an `equinox.Module`."""

    @abc.abstractmethod
    def commands(self, model: AbstractModel, robot: Robot, traj: Callable, ts: Array,
                 panels: int) -> SceneInput:
        """The scene's input for `robot` (the robot the commands are computed for, which
        identification keeps apart from the robot simulated) along `traj` over `ts`, for
        simulating `model`; `panels` the input table's (static)."""

    @abc.abstractmethod
    def follows_its_input(self, model: AbstractModel) -> str:
        """Why `model` follows the nominal path exactly (its error is the solver's alone), or
        ""; derivatives of its tracking error then say nothing about the robot."""

    def run(
        self,
        model: AbstractModel,
        robot: Robot,
        options: SceneOptions,
        actuation: Optional[AbstractActuation] = None,
        *,
        ts: Optional[Array] = None,
        initial_offset: Optional[Array] = None,
    ) -> SceneResult:
        """Run the scene for one robot (traced; `options` from `SceneOptions.prepared`).

        **Arguments:**

        - `model`, `robot`: what is simulated.
        - `options`: the prepared options (`SceneOptions.prepared`).
        - `actuation`: the input; None: the scene's `commands` for `robot`. A `MotionDriven`
          input of a kinematic model (L0/L1) runs as forward kinematics + inverse dynamics.
        - `ts`: output times (s), ts[0] the start; None: `options.times()`.
        - `initial_offset`: (6,) added to the platform pose and its rate of the quasi-static
          initial state (m, m, rad, m/s, m/s, rad/s), as identification estimates them.

        **Returns:** a `SceneResult` (its `result` the first failed check, or success).
        """
        ts = options.times() if ts is None else ts
        traj = options.trajectory
        if actuation is None:
            inp = self.commands(model, robot, traj, ts, options.panels)
        else:
            fn = getattr(actuation, "torque", getattr(actuation, "angles", None))
            inp = SceneInput(actuation, coarse=input_too_coarse(fn),
                             step_ts=step_times(fn, traj))
        act = inp.actuation
        # the pose, its rates and accelerations that the start takes (the path's by default)
        start = self.start_trajectory(traj)
        if isinstance(act, MotionDriven) and model.actuated_index is None:
            X, Xd, tau, codes, folds = kinematic_motion(model, robot, act.angles, start(ts[0]),
                                                        ts)
            # A status code, not a callback: forward kinematics failing along the path is
            # reported like a solver failure (and the program stays free of host callbacks).
            result = first_failure((jnp.any(folds), RESULTS.singular_path),
                                   (jnp.any(codes != 0), RESULTS.kinematics_failed))
            zero = jnp.asarray(0)
            sol = Solution(ts=ts, z=X, zdot=Xd, tau=tau, result=result, num_steps=zero,
                           num_accepted=zero, num_rejected=zero)
            return self._result(model, robot, traj, sol, ref_open=inp.out_of_reach,
                                singular=inp.singular)
        z0, zd0, failed = quasi_static_core(model, robot, start, ts[0],
                                            act if inp.start is None else inp.start)
        if initial_offset is not None:
            # the platform pose and its rate are z[:3] in every model
            z0, zd0 = z0.at[:3].add(initial_offset[:3]), zd0.at[:3].add(initial_offset[3:])
        open0 = _open_at(model, robot, z0)
        sol = simulate_core(
            model, robot, act, z0, zd0, ts, options.solver,
            stepping_to(options.controller, inp.step_ts), None,
            options.max_steps, jnp.zeros(3), False, diffrax.NoProgressMeter(), options.adjoint,
            _any(failed, open0, inp.out_of_reach, inp.singular, inp.coarse,
                 params_invalid(robot.params)),
        )
        return self._result(model, robot, traj, sol, failed, open0, inp.out_of_reach, inp.coarse,
                            inp.singular)

    def _result(self, model, robot, traj, sol: Solution, qs_failed=None, open0=None,
                ref_open=None, coarse=None, singular=None) -> SceneResult:
        out = outputs(model, robot, sol.z, sol.zdot)
        # Every precondition as a status code (most fundamental cause first): invalid
        # parameters, the input out of reach, through a singularity (where it is unbounded,
        # so before its table is judged) or too coarse, no initial state, the solver's
        # failure, a chain that does not close at some output time (an L0/L1 pose out of reach
        # integrates happily on an open chain).
        result = first_failure(
            (params_invalid(robot.params), RESULTS.invalid_parameter),
            (ref_open, RESULTS.trajectory_out_of_reach),
            (singular, RESULTS.singular_path),
            (coarse, RESULTS.input_table_too_coarse),
            (qs_failed, RESULTS.initial_state_failed),
            (open0, RESULTS.loop_not_closed),
            sol.result,
            (~(jnp.max(out.residual) <= RESIDUAL_TOL), RESULTS.loop_not_closed),
        )
        return SceneResult(
            ts=sol.ts, z=sol.z, zdot=sol.zdot, X=out.X, X_nominal=jax.vmap(traj)(sol.ts),
            tau=sol.tau, end_rot=out.end_rot, residual=out.residual, kinetic=out.kinetic,
            potential=out.potential, result=result, num_steps=sol.num_steps,
            num_accepted=sol.num_accepted, num_rejected=sol.num_rejected, scene=self.name,
            model=model.name,
        )

    def start_trajectory(self, traj: Callable) -> Callable:
        """The pose path t -> X (3,) whose pose, rate and acceleration at the first output time
        the quasi-static start takes (MODEL.md section 6): `traj`, the nominal path, unless the
        scene holds a start of its own (`PathScene.start_path`: an experiment's first samples,
        smoothed)."""
        return traj

    def check_commands(self, params: RobotParams, traj: Callable, t_end) -> None:
        """Check the commands the scene is given against the robot and the path, on the host
        before anything is traced (`check_scene_commands` calls it for every run, sweep,
        sensitivity and design): none for a scene that computes its input from its path.
        `PathScene` checks its command log (`check_log_covers`, `check_assembly_mode`).

        **Arguments:**

        - `params`: one concrete robot's `RobotParams`.
        - `traj`: the nominal path the run follows (the options' or the scene's).
        - `t_end`: the run's horizon (s), or None.
        """

    def check_members(self, members, traj: Callable, t_end) -> list:
        """`check_commands` of each robot of a batch, judged one by one (their geometry decides
        the assembly mode an angle log's samples belong to): a sweep refuses the members whose
        commands do not fit them, `check_scene_commands` names the first. A check that does
        not depend on the robot (a log's span) raises at once.

        **Arguments:**

        - `members`: a list of concrete `RobotParams`.
        - `traj`, `t_end`: as `check_commands`'.

        **Returns:** a list, one entry per member: None, or the `PPRError` refusing its
        commands.
        """
        out = []
        for params in members:
            try:
                self.check_commands(params, traj, t_end)
                out.append(None)
            except PPRError as err:
                out.append(err)
        return out

    def needs_integrator(self, model: AbstractModel) -> bool:
        """False where the scene is forward kinematics and inverse dynamics alone: prescribed
        angles (`drive="motion"`) of a model whose coordinates are the pose (L0, L1)."""
        return not (self.drive == "motion" and model.actuated_index is None)

    def default_robot(self) -> Robot:
        """`Robot(self.default_params())`, built once per thickness."""
        return table1_robot(float(self.thickness))

    def default_params(self, **overrides) -> RobotParams:
        """Table 1 with the scene's strip thickness, and `overrides` applied."""
        if not overrides:
            return table1_with_thickness(float(self.thickness))
        kw = {"t": self.thickness}
        kw.update(overrides)
        return RobotParams().replace(**kw)
