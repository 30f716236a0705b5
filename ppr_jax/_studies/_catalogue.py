"""The metric catalogue of every study (`CATALOGUE`): each metric a sweep, a sensitivity or a
design may name, one entry each (`Metric`: its unit and meaning, and a traced, differentiable
function of the robot, the scene's result and the context, `Inputs`), and the one function that
says which metrics a scene allows a study (`allowed_metrics`; `sweep_metrics`, `design_metrics`
are its two other studies' views). `metric_blocks` evaluates any of them at a robot.

The metrics of a scene's run in its reports too are the columns of `_metrics.metric_table`
(an entry without a `value` reads that column).

Closed forms (no scene): `pivot_frequency_hz`, `pivot_stress_Pa`, `moving_mass_kg`. The robot's
first locked natural frequency `base_frequency_hz` (`ppr_jax.modes`' linearisation, differentiated
through the Rayleigh quotient: `_sensitivity.base_frequency`). On a scene (any registered name or
`AbstractScene`, run with `SceneOptions` through `AbstractScene.run`, as sensitivities run it):
every metric of `allowed_metrics` (tracking error, torque peak, ...) and `strip_stress_peak_Pa`.

**One strip pivot carrying a link** (`pivot_*`). The compliant joint taken alone as one straight
strip of length L = r theta_c, width w, thickness t, bent by a pure moment: its rotational
stiffness is the exact K0 = E I/L, I = w t^3/12 (the L0 pin's, MODEL.md section 5), its curvature
is uniform, theta/L at a rotation theta, so its surface stress is sigma = E (t/2) theta/L =
E t theta/(2 L) everywhere along it. The drive link is held; the connecting link (m3, I3 of
MODEL.md section 1) swings about the joint, J = I3 + m3 (l3/2)^2 = m3 (l3^2/3 + b_r^2/12); the
strip's own inertia is left out (under a gram against the link's 234 g). Its natural frequency
is sqrt(K0/J)/(2 pi). A figure of merit of the joint, not a mode of the robot
(`base_frequency_hz` is that).

**Strip stress over a scene** (`strip_stress_peak_Pa`). A spring of the model with stiffness k
deflected by d carries the moment M = k d; the strip there is bent by M, and its surface stress
is M/Z with the section modulus Z = I/(t/2) = w t^2/6. For the double-1R joint (L1, L2;
MODEL.md section 3) k = K = 2 E I rho K_theta/L, so sigma = E t/(2 L) * 2 rho K_theta |d| at each
characteristic pivot, d its PRB angle from rest (d_i1, d_i2); for L0's pin k = K0 and
sigma = E t |d|/(2 L), the pure-moment value above; for L3's beam elements the spring between
two elements of length h has k = E I/h and sigma = E t |d|/(2 h), the curvature's stress. The
peak is the exact max over the output times and the springs of all three chains (its
derivative is the arg-max's, a subgradient, as for the other max metrics). What it assumes: the
PRB spring's moment is the strip's moment at the characteristic pivot; under tip forces the
moment varies along the strip and the clamps may carry more than the pivots (L3's curvature,
with `model="beam"`, is the check).

**Peaks as samples** (`SAMPLED_METRICS`). The stress and torque peaks and the path margins are
extremes over samples; `metric_values(samples=...)` gives such a metric as its samples (the
stresses (m, ns) of every spring at every output time, |tau| (m, 3), the reach margins (m, 3)
per chain, the singularity margins (m,)), flattened, which a design constrains one by one.

**Actuator torques over a scene** (`torque_peak_Nm`, the scene's own, and `torque_rms_Nm`):
the scene's actuator torques tau (m, 3) at its output times (applied, or the reactions of a
motion-driven scene), their peak max |tau| and their RMS sqrt(mean tau^2) over the times and
the three actuators.

**Reach and singularity margins of the path** (`path_reach_margin`,
`path_singularity_margin`): the scene's nominal poses at its output times through the
kinematics of the scene's input model (L1 or L0, the model whose inverse kinematics or dynamics
drives the scene), with the two checks the scenes make (`ppr_jax._kinematics`): each chain's
reach margin 1 - |cos| of its closure angle (<= 0 out of reach), least over the chains and
times; and the relative determinant of S = d th_a/dX (translations scaled by r1; |det| over
the product of its column norms: 0 singular, 1 isotropic), signed so that it is positive at
the path's first sample and least over the times: where the path crosses a type-II
singularity det S changes sign, so the margin is negative (a crossing between two samples
shows; two within one interval cancel, as in `path_singular`). Neither needs the scene's run.
The paths of the registered scenes do not depend on the robot; the margins do.

**One strip by the elastica** (`strip_tip_rotation_rad`, `strip_elastica_stress_Pa`): the
robot's strip alone, an inextensible Euler-Bernoulli cantilever of length L = r theta_c, rest
curvature 1/r (kappa0 = L/r = theta_c), bending stiffness E w t^3/12, clamped at one end and
loaded at the other by the dead load `strip_load` = (fx, fy, m) (N, N, N m) in the clamp's
tangent frame (`ppr_jax.elastica.solve_cantilever`, exact to its RK4 grid, differentiated
implicitly): its tip's rotation from rest theta(L) - theta_c, and its peak surface stress
max_s |M(s)| 6/(w t^2). Large deflections, no PRB model: the check of a strip's static design
against a load-deflection target (benchmark tier 2). A load the solver cannot follow gives NaN.

**Static compliance at a pose** (`compliance_xy_m_per_N`, `compliance_phi_rad_per_Nm`): the
platform's compliance C = K^-1 with the actuators locked, K = -dQ/dX the stiffness of
`frequency_model` (L2 or L3) in the pose about its static equilibrium near the pose `pose`
(`_sensitivity.locked_stiffness`): a small wrench (Fx, Fy, Mz) moves the platform by
C (Fx, Fy, Mz). `compliance_xy_m_per_N` is the largest eigenvalue of C's translational block
(the displacement per newton of a force in the worst direction, no moment),
`compliance_phi_rad_per_Nm` is C's rotational entry (rotation per N m of a moment, no force).
At an isotropic pose (home of a symmetric robot) the two eigenvalues coincide and the
derivative is that of their mean.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Callable, Optional

import equinox as eqx
import jax
import jax.numpy as jnp

from .._dynamics import energy, eom_terms, generalized_force, potential_of
from .._errors import RESULTS, PPRError
from .._geometry import home_pose
from .._kinematics import path_margins as kinematic_margins
from .._metrics import is_circle, metric_table
from .._modes import reduced_eigh
from .._names import (  # the sensitivity table's default rows, SI units
    PATH_SENSITIVITY_METRICS,
    SENSITIVITY_METRICS,
)
from .._prb import Derived
from .._robot import Robot
from .._statics import assemble, springs_from_potential, static_equilibrium

#: eigenvalues within this relative distance of the lowest are one (repeated) cluster
CLUSTER_RTOL = 1e-6


def locked_stiffness(model, robot: Robot, X=None):
    """The stiffness of `model` about its static equilibrium near the pose X (default home)
    with the actuators locked, in its free coordinates, differentiable (no host callback: a
    failed equilibrium is returned as a flag).

    **Arguments:**

    - `model`: a model with free coordinates when locked (L2, L3); `robot`: a `Robot`.
    - `X`: the pose (3,) (m, m, rad) near which the equilibrium is found.

    **Returns:** `(z_eq, free, K, failed)`: the equilibrium (n,), the free coordinates' indices,
    K = -dQ/dz_free (symmetrised), Q the generalised force at rest, and whether Newton failed.

    **Raises:** `PPRError` for a model without free coordinates when locked (L0, L1).
    """
    X = home_pose(robot) if X is None else X
    z_eq, free, failed = static_equilibrium(model, robot, model.coords_from_pose(robot, X),
                                            locked=True, wrench=jnp.zeros(3), check=False,
                                            return_failed=True)
    if not free:
        raise PPRError(f"model {model.name!r} has no free coordinate with locked actuators; "
                       f"use double1r (or beam) for the base frequency or the compliance")
    n = model.n_dof
    known = tuple(i for i in range(n) if i not in free)
    f = jnp.array(free)
    zk = z_eq[jnp.array(known)] if known else None

    def U(zf):
        return potential_of(model, robot, model.kinematics(robot, assemble(n, free, zf, known,
                                                                           zk)))

    def Q(zf):
        z = assemble(n, free, zf, known, zk)
        return generalized_force(eom_terms(model, robot, z, jnp.zeros(n)), jnp.zeros(3),
                                 jnp.zeros(3))[f]

    # K = -dQ/dz_f at rest is the Hessian of the springs' potential energy (Q there is the
    # springs' -dU/dz alone: no velocity, no load, the actuators locked; `springs_from_potential`
    # says where): equal to the Jacobian of the equations of motion's Q to 1.5e-14 relative
    # (L2, full L3), and the energy's derivatives hold no mass matrix and no velocity terms,
    # which a forward-mode sensitivity differentiates once more (with the equilibrium's own
    # balance from the potential: L2's base frequency in a 10-parameter slice traced in 6.5 ->
    # 2.0 s, 19,163 -> 11,538 StableHLO lines)
    K = jax.hessian(U)(z_eq[f]) if springs_from_potential(model) else -jax.jacfwd(Q)(z_eq[f])
    return z_eq, free, (K + K.T) / 2, failed


def base_frequency(model, robot: Robot, X=None):
    """The lowest natural frequency (Hz, signed: negative = unstable) of `model` about its static
    equilibrium near X (default home) with the actuators locked, differentiable (module
    docstring: Rayleigh quotient with the mode shapes held fixed; repeated lowest eigenvalues
    averaged). Raises for a model without free coordinates when locked (L0, L1)."""
    z_eq, free, K, failed = locked_stiffness(model, robot, X)
    n = model.n_dof
    f = jnp.array(free)
    known = tuple(i for i in range(n) if i not in free)

    def T(zdf):
        zd = assemble(n, free, zdf, known, jnp.zeros(len(known)))
        return energy(model, robot, z_eq, zd)[0]

    # the free coordinates' mass matrix as the kinetic energy's Hessian in their rates (equal
    # to the equations of motion's M to 1e-15 relative; no velocity terms, see K), where the
    # bodies are explicit in z (`springs_from_potential`: not the quasi-static L3's inner solve)
    if springs_from_potential(model):
        M = jax.hessian(T)(jnp.zeros(len(free), z_eq.dtype))
    else:
        M = eom_terms(model, robot, z_eq, jnp.zeros(n)).M[f][:, f]
    # Mode shapes from a non-differentiated eigenproblem: eigh's derivative is NaN at repeated
    # eigenvalues. The Rayleigh quotients below carry the exact first derivative.
    Ms, Ks = jax.lax.stop_gradient(M), jax.lax.stop_gradient(K)
    lam0, _, shapes = reduced_eigh(Ms, Ks)  # shapes M-orthonormal
    lam = jnp.einsum("ik,ij,jk->k", shapes, K, shapes) / jnp.einsum("ik,ij,jk->k", shapes, M,
                                                                    shapes)
    w = (jnp.abs(lam0 - lam0[0]) <= CLUSTER_RTOL * jnp.abs(lam0[0])).astype(lam.dtype)
    lam1 = jnp.sum(w * lam) / jnp.sum(w)
    f = jnp.sign(lam1) * jnp.sqrt(jnp.abs(lam1)) / (2 * jnp.pi)
    return jnp.where(failed, jnp.nan, f)


def pivot_frequency(params, dv: Derived):
    """First natural frequency (Hz) of one strip pivot carrying the connecting link (module
    docstring): sqrt(K0/J)/(2 pi), K0 = E w t^3/(12 L), J = I3 + m3 (l3/2)^2.

    **Arguments:**

    - `params`: `RobotParams`.
    - `dv`: `derived(params)`.

    **Returns:** the frequency (Hz), traced like the parameters.
    """
    J = dv.I3 + dv.m3 * (params.l3 / 2) ** 2
    return jnp.sqrt(dv.K0 / J) / (2 * jnp.pi)


def pivot_stress(params, dv: Derived, stroke):
    """The strip's surface bending stress (Pa) at the joint rotation `stroke` (rad) under a pure
    moment (module docstring): E t stroke/(2 L), L = r theta_c."""
    return params.E * params.t * stroke / (2 * dv.L)


def moving_mass(dv: Derived):
    """Mass (kg) of every moving body: 3 (m1 + m2 + m3) + m4 (MODEL.md section 1)."""
    return 3 * (dv.m1 + dv.m2 + dv.m3) + dv.m4


def strip_stresses(model, robot: Robot, z):
    """Bending stress (Pa) of every spring at the coordinates z (m, n) of a scene's output times
    (module docstring): |k d| 6/(w t^2), (m, ns)."""
    k = model.stiffness(robot)
    d = jax.vmap(lambda zz: model.kinematics(robot, zz).deflection)(z)
    p = robot.params
    return jnp.abs(k * d) * 6 / (p.w * p.t**2)


def strip_stress_peak(model, robot: Robot, z):
    """Peak bending stress (Pa) of the strips over the coordinates z (m, n) of a scene's
    output times (module docstring): max |k d| 6/(w t^2) over the times and springs."""
    return jnp.max(strip_stresses(model, robot, z))


def strip_elastica(params, dv: Derived, load):
    """(tip rotation from rest (rad), peak stress (Pa)) of one strip under the end load
    `load` = (fx, fy, m) by the elastica (module docstring); NaN where it did not converge."""
    from ..elastica import solve_cantilever

    EI = params.E * params.w * params.t**3 / 12
    fx, fy, m = (jnp.asarray(v, dtype=jnp.float64) for v in load)
    sol = solve_cantilever(dv.L, EI, params.theta_c, (fx, fy), m, throw=False)
    rot = sol.tip_angle - params.theta_c
    sigma = jnp.max(jnp.abs(sol.moment)) * 6 / (params.w * params.t**2)
    return (jnp.where(sol.converged, rot, jnp.nan), jnp.where(sol.converged, sigma, jnp.nan))


def torque_rms(tau):
    """RMS (N m) of the actuator torques tau (m, 3) over the times and the actuators."""
    return jnp.sqrt(jnp.mean(tau**2))


def path_margins(ref_model, robot: Robot, X):
    """(reach, singularity) margins of the nominal poses X (m, 3) for `ref_model` (L0 or L1)
    (module docstring): the least reach margin over the chains and samples, and the least
    relative det S over the samples, signed positive at the robot's home pose (its working
    mode)."""
    reach, sing = path_margin_samples(ref_model, robot, X)
    return jnp.min(reach), jnp.min(sing)


def path_margin_samples(ref_model, robot: Robot, X):
    """The margins of `path_margins` before their minimum: (reach (m, 3) per sample and chain,
    singularity (m,) per sample): `_kinematics.path_margins` of the home pose and X, the
    relative det S signed by its value at home."""
    m = kinematic_margins(ref_model, robot, jnp.concatenate([home_pose(robot)[None], X]))
    sign = jax.lax.stop_gradient(jnp.where(m.det[0] < 0, -1.0, 1.0))
    return m.reach[1:], sign * m.det[1:]


def compliance(model, robot: Robot, X=None):
    """(largest translational compliance (m/N), rotational compliance (rad/(N m))) of the
    platform at its locked equilibrium near the pose X (default home) (module docstring)."""
    _, free, K, failed = locked_stiffness(model, robot, X)
    if tuple(free)[:3] != (0, 1, 2):
        raise ValueError(f"model {model.name!r}: the pose is not its first free coordinates")
    # the pose's compliance: the pose block of K^-1 (L3's other free coordinates condensed)
    C = jnp.linalg.inv(K)[:3, :3]
    C = (C + C.T) / 2
    a, b, d = C[0, 0], C[0, 1], C[1, 1]
    disc = ((a - d) / 2) ** 2 + b**2
    pos = disc > 0
    root = jnp.where(pos, jnp.sqrt(jnp.where(pos, disc, 1.0)), 0.0)
    bad = failed | ~jnp.all(jnp.isfinite(C))
    return jnp.where(bad, jnp.nan, (a + d) / 2 + root), jnp.where(bad, jnp.nan, C[2, 2])


class SceneContext(eqx.Module):
    """What the scene metrics need: the scene, the model that runs it and its prepared
    `SceneOptions` (or None: no scene metric asked for), the model of the pose metrics
    (`POSE_METRICS`), the pose (3,) of the compliance (None: home) and the elastica's end load.
    A pytree: the design's programs take it as an argument, so the scene's and the options'
    arrays are the programs' inputs, not constants, and a stored program serves any of their
    values."""

    scene: Optional[object]
    model: Optional[object]
    options: Optional[object]
    frequency_model: object
    pose: Optional[tuple] = None
    strip_load: Optional[tuple] = None




class Inputs:
    """What the catalogue's metrics of one robot are computed from: the robot, the
    `SceneContext`, the stroke and the adjoint, and what they give (the scene's run, its
    `metric_table`, the path's margins, ...), each computed once, on first use, so that metrics
    sharing a quantity share its trace. A metric's `Metric.value` reads its attributes.

    **Arguments:**

    - `robot`: the `Robot` (traced leaves allowed).
    - `ctx`: the `SceneContext`.
    - `stroke`: the joint rotation (rad) of `pivot_stress_Pa` (None: 0).
    - `adjoint`: diffrax's adjoint for the scene's solve (`ForwardMode` under `jax.jacfwd`).
    - `result`: the scene's `SceneResult` where it is run already (a sweep's member); None:
      run on first use.
    """

    def __init__(self, robot: Robot, ctx: SceneContext, stroke=None, adjoint=None,
                 result=None):
        self.robot, self.ctx, self.adjoint = robot, ctx, adjoint
        self.stroke = jnp.zeros(()) if stroke is None else stroke
        if result is not None:
            self.result = result

    @property
    def params(self):
        return self.robot.params

    @functools.cached_property
    def dv(self) -> Derived:
        return self.robot.dv

    @functools.cached_property
    def options(self):
        """The scene's `SceneOptions`, with the adjoint where one is given."""
        opts = self.ctx.options
        return opts if self.adjoint is None else dataclasses.replace(opts, adjoint=self.adjoint)

    @functools.cached_property
    def result(self):
        """The scene's `SceneResult` for the robot."""
        return self.ctx.scene.run(self.ctx.model, self.robot, self.options)

    @functools.cached_property
    def table(self) -> dict:
        """`_metrics.metric_table` of the run, traced."""
        return metric_table(self.result, self.options.trajectory)

    @functools.cached_property
    def path(self) -> tuple:
        """`path_margin_samples` of the scene's input model at its nominal poses at the output
        times: (reach (m, 3), singularity (m,))."""
        opts = self.ctx.options
        X = jax.vmap(opts.trajectory)(opts.times())
        return path_margin_samples(self.ctx.scene.input_model, self.robot, X)

    @functools.cached_property
    def stresses(self):
        """`strip_stresses` over the run: (m, ns) (Pa)."""
        return strip_stresses(self.ctx.model, self.robot, self.result.z)

    @functools.cached_property
    def elastica(self) -> tuple:
        """`strip_elastica` under the context's `strip_load`."""
        return strip_elastica(self.params, self.dv, self.ctx.strip_load)

    @functools.cached_property
    def compliance(self) -> tuple:
        """`compliance` of the context's frequency model at its pose (None: home)."""
        pose = self.ctx.pose
        X = None if pose is None else jnp.asarray(pose, dtype=jnp.float64)
        return compliance(self.ctx.frequency_model, self.robot, X)


#: what a metric is computed from (`Metric.needs`), in the order an evaluation traces them:
#: the scene's nominal path (not its run), the scene's run, the robot's parameters alone (a
#: closed form, or one strip's elastica), the robot at rest or a pose through the context's
#: `frequency_model`
NEEDS = ("path", "run", "robot", "pose")
#: the studies that evaluate the catalogue (`Metric.studies`)
STUDIES = ("sweep", "sensitivity", "design")


@dataclasses.dataclass(frozen=True)
class Metric:
    """One entry of the catalogue (`CATALOGUE`): a traced, differentiable function of the
    robot, the scene's result and the context (`Inputs`), and what it is.

    **Arguments:**

    - `unit`: its SI unit ("-" for a dimensionless one).
    - `description`: what it measures, in a line.
    - `value`: `Inputs` -> the value, a traced scalar; None: the scene's `metric_table` column
      of the entry's name (a metric of `run_scene`'s reports too).
    - `needs`: what it is computed from (`NEEDS`); "path" and "run" need a scene.
    - `studies`: the studies that offer it (`STUDIES`): a sweep's columns, a sensitivity's
      metrics, a design's objective and constraints.
    - `circle`: it needs a circular path (`_metrics.is_circle`: a `center` and a `radius`).
    - `tracking`: it measures how far the platform leaves the path: of a model that follows
      its own input, the solver's error (`AbstractScene.follows_its_input`), refused there.
    - `samples`: `Inputs` -> the samples (any shape) whose `extreme` the value is, for a
      design that bounds each sample; None: not sampled.
    - `extreme`: "max" or "min", the samples' reduction (with `samples`).
    - `requires`: the design's keywords it needs (`stroke`, `strip_load`).
    """

    unit: str
    description: str
    value: Optional[Callable] = None
    needs: str = "run"
    studies: tuple = STUDIES
    circle: bool = False
    tracking: bool = False
    samples: Optional[Callable] = None
    extreme: Optional[str] = None
    requires: tuple = ()


def _circle(what):
    return Metric("m", what, circle=True, tracking=True)


def _tracking(unit, what):
    return Metric(unit, what, tracking=True)


#: the tracking errors' reductions over the output times (`metric_table`), on any path
_TRACKING = {"max": "the largest {} against the nominal pose",
             "rms": "the {}'s RMS over the output times", "end": "the {} at the last output time"}


#: The metric catalogue: name -> `Metric`, in the order the studies list them (`allowed_metrics`).
#: A new metric is one entry here; every study, the command line and `allowed_metrics` follow.
CATALOGUE: dict[str, Metric] = {
    # the radial error e_r = |(x, y) - c| - R of a circle (`metric_table`)
    "radial_error_max_m": _circle("the largest radial error e_r over the output times"),
    "radial_error_min_m": _circle("the least radial error e_r over the output times"),
    "radial_error_mean_m": _circle("the mean radial error e_r over the output times"),
    "radial_error_max_relative_percent": Metric(
        "%", "the largest |e_r| over the output times, relative to the radius", circle=True,
        tracking=True),
    # the tracking error against the nominal pose, on any path (`metric_table`)
    **{f"position_error_{k}_m": _tracking("m", what.format("position error"))
       for k, what in _TRACKING.items()},
    **{f"phi_error_{k}_rad": _tracking("rad", what.format("orientation error"))
       for k, what in _TRACKING.items()},
    # the robot's response (`metric_table`)
    "end_rotation_diff_max_deg": Metric(
        "deg", "the largest difference of chain 1's two compliant-joint end rotations"),
    "end_rotation_diff_min_deg": Metric(
        "deg", "the least difference of chain 1's two compliant-joint end rotations"),
    "end_rotation_diff_mean_deg": Metric(
        "deg", "the mean difference of chain 1's two compliant-joint end rotations"),
    "torque_peak_Nm": Metric(
        "N m", "the actuator torques' peak max |tau| over the output times and the actuators",
        samples=lambda i: jnp.abs(i.result.tau), extreme="max"),
    "constraint_residual_max_m": Metric("m", "the largest loop-closure residual of the run"),
    "base_frequency_hz": Metric(
        "Hz", "the robot's first natural frequency, actuators locked, at home (frequency_model)",
        lambda i: base_frequency(i.ctx.frequency_model, i.robot), needs="pose",
        studies=("sensitivity", "design")),
    "pivot_frequency_hz": Metric(
        "Hz", "first natural frequency of one strip pivot (K0 = E I/L) carrying the connecting "
              "link, the drive link held",
        lambda i: pivot_frequency(i.params, i.dv), needs="robot", studies=("design",)),
    "pivot_stress_Pa": Metric(
        "Pa", "the strip's peak bending stress at the joint rotation `stroke` under a pure "
              "moment, E t stroke/(2 L)",
        lambda i: pivot_stress(i.params, i.dv, i.stroke), needs="robot", studies=("design",),
        requires=("stroke",)),
    "moving_mass_kg": Metric(
        "kg", "mass of every moving body: three drive links, strips and connecting links, and "
              "the platform",
        lambda i: moving_mass(i.dv), needs="robot", studies=("design",)),
    "strip_stress_peak_Pa": Metric(
        "Pa", "the strips' peak bending stress over the scene, from each spring's moment K d "
              "over the strip's section modulus w t^2/6",
        lambda i: jnp.max(i.stresses), studies=("design",), samples=lambda i: i.stresses,
        extreme="max"),
    "torque_rms_Nm": Metric(
        "N m", "the actuator torques' RMS over the scene's output times and the three actuators",
        lambda i: torque_rms(i.result.tau), studies=("design",)),
    "path_reach_margin": Metric(
        "-", "the least reach margin (1 - |cos| of a chain's closure angle) of the scene's "
             "input model along its nominal path (<= 0: out of reach)",
        lambda i: jnp.min(i.path[0]), needs="path", studies=("design",),
        samples=lambda i: i.path[0], extreme="min"),
    "path_singularity_margin": Metric(
        "-", "the least relative det S along the scene's nominal path, signed so that it is "
             "positive at the home pose (<= 0: the path meets or crosses a type-II singularity)",
        lambda i: jnp.min(i.path[1]), needs="path", studies=("design",),
        samples=lambda i: i.path[1], extreme="min"),
    "strip_tip_rotation_rad": Metric(
        "rad", "one strip (length r theta_c, rest curvature 1/r) clamped at one end under the "
               "end load `strip_load` (fx, fy, m): its tip's rotation from rest, by the elastica",
        lambda i: i.elastica[0], needs="robot", studies=("design",), requires=("strip_load",)),
    "strip_elastica_stress_Pa": Metric(
        "Pa", "that strip's peak bending stress, max |M(s)| 6/(w t^2) along it, by the "
              "elastica",
        lambda i: i.elastica[1], needs="robot", studies=("design",), requires=("strip_load",)),
    "compliance_xy_m_per_N": Metric(
        "m/N", "the platform's largest translational compliance under a force, actuators "
               "locked, at the pose `pose` (frequency_model)",
        lambda i: i.compliance[0], needs="pose", studies=("design",)),
    "compliance_phi_rad_per_Nm": Metric(
        "rad/(N m)", "the platform's rotational compliance under a moment, actuators locked, at "
                     "the pose `pose` (frequency_model)",
        lambda i: i.compliance[1], needs="pose", studies=("design",)),
}


def allowed_metrics(trajectory=None, study: str = "sensitivity") -> tuple:
    """The metrics of the catalogue that `study` may compute along a scene's path: the one
    list every study and the command line read.

    **Arguments:**

    - `trajectory`: the scene's nominal path (a circle allows the radial errors); None: no
      scene, the metrics that need none (`Metric.needs` "robot" or "pose").
    - `study`: "sweep" (its columns), "sensitivity" or "design" (`Metric.studies`).

    **Returns:** the names, in the catalogue's order.

    **Raises:** `PPRError` for an unknown study.
    """
    if study not in STUDIES:
        raise PPRError(f"unknown study {study!r}; allowed: {', '.join(STUDIES)}")
    circle = trajectory is not None and is_circle(trajectory)
    return tuple(n for n, m in CATALOGUE.items()
                 if study in m.studies and (circle or not m.circle)
                 and (trajectory is not None or m.needs not in ("path", "run")))


def names_where(**fields) -> tuple:
    """The catalogue's names whose `Metric` fields have the values given
    (`names_where(needs="pose")`); a value that is a tuple matches any of its members."""
    def match(m):
        return all(getattr(m, k) in v if isinstance(v, tuple) else getattr(m, k) == v
                   for k, v in fields.items())
    return tuple(n for n, m in CATALOGUE.items() if match(m))


#: the columns of a sweep on a circle (on another path, those of `sweep_metrics`)
METRICS = tuple(n for n, m in CATALOGUE.items() if "sweep" in m.studies)
#: every metric a design may name: name -> what it measures (unit), as the catalogue has them
DESIGN_METRICS = {n: f"{m.description} ({m.unit})" for n, m in CATALOGUE.items()
                  if "design" in m.studies}


def sampled_metrics() -> dict:
    """{name: "max" or "min"} of the catalogue's metrics that are an extreme over samples
    (output times, springs, actuators, chains): a bound on the extreme's side (metric <= b for
    a max) is the same bound on every sample, which a design gives the optimiser instead
    (`metric_values(samples=...)`): each sample is smooth where the extreme has a kink at a tie
    between two samples."""
    return {n: m.extreme for n, m in CATALOGUE.items() if m.samples is not None}


def sweep_metrics(trajectory) -> tuple:
    """The columns of a sweep along `trajectory`: `allowed_metrics(trajectory, "sweep")`."""
    return allowed_metrics(trajectory, "sweep")


def design_metrics(trajectory=None) -> tuple:
    """Every metric a design may name along a scene's `trajectory` (None: without a scene,
    the metrics that need none): `allowed_metrics(trajectory, "design")`."""
    return allowed_metrics(trajectory, "design")


def default_metrics(trajectory) -> tuple:
    """The sensitivity table's default metrics along `trajectory`: `SENSITIVITY_METRICS` on a
    circle, `PATH_SENSITIVITY_METRICS` on any other path."""
    return SENSITIVITY_METRICS if is_circle(trajectory) else PATH_SENSITIVITY_METRICS


def tracking_metrics(names) -> list:
    """The metrics of `names` that measure how far the platform leaves the path
    (`Metric.tracking`)."""
    return [n for n in names if n in CATALOGUE and CATALOGUE[n].tracking]


def metric_values(names, params, ctx: SceneContext, stroke, adjoint=None, equal_links=True,
                  samples=()):
    """The metrics `names` (tuple) at `params` as one traced array: (k,), or longer where
    `samples` asks for some metrics' samples: `metric_blocks` concatenated."""
    return jnp.concatenate(metric_blocks(names, params, ctx, stroke, adjoint, equal_links,
                                         samples))


def metric_blocks(names, params, ctx: SceneContext, stroke, adjoint=None, equal_links=True,
                  samples=()):
    """The metrics `names` (tuple) at `params` as one traced 1-D array each: its value (1,), or
    its samples where `samples` names it.

    **Arguments:**

    - `names`: catalogue names (`allowed_metrics`).
    - `params`: `RobotParams` (traced leaves allowed).
    - `ctx`: `SceneContext`.
    - `stroke`: the joint rotation (rad) of `pivot_stress_Pa`.
    - `adjoint`: diffrax's adjoint for the scene's solve (`ForwardMode` under `jax.jacfwd`).
    - `equal_links`: `Robot`'s static choice of the closed-form inverse kinematics (l1 == l3).
    - `samples`: names of `sampled_metrics` given as their samples (the values whose max or
      min they are, flattened) instead of that extreme.

    **Returns:** a list of the values in SI units, each metric's in `names`' order (one entry,
    or its samples); NaN for every scene metric where the scene failed.
    """
    inputs = Inputs(Robot(params, equal_links=equal_links), ctx, stroke, adjoint)
    return evaluate(names, inputs, samples)


def evaluate(names, inputs: Inputs, samples=()) -> list:
    """The catalogue's metrics `names` from `inputs` (`metric_blocks`, whose list it returns):
    the path's first, then the run's (all of them NaN where the run failed), then the others.

    **Raises:** `PPRError` for a name not in the catalogue.
    """
    missing = [n for n in names if n not in CATALOGUE]
    if missing:
        raise PPRError(f"unknown metric {missing[0]!r}; allowed: {', '.join(CATALOGUE)}")
    out = {}

    def compute(group):
        for n in names:
            m = CATALOGUE[n]
            if m.needs in group:
                fn = m.samples if n in samples else m.value
                if fn is None and n not in inputs.table:
                    raise PPRError(f"metric {n!r} does not apply to this scene's path; allowed: "
                                   f"{', '.join(k for k in inputs.table if k in CATALOGUE)}")
                out[n] = inputs.table[n] if fn is None else fn(inputs)

    compute(("path",))
    compute(("run",))
    if any(CATALOGUE[n].needs == "run" for n in names):
        bad = inputs.result.result != RESULTS.successful
        out = {k: jnp.where(bad, jnp.nan, v) for k, v in out.items()}
    compute(("robot", "pose"))
    return [jnp.ravel(jnp.asarray(out[n], dtype=jnp.float64)) for n in names]
