"""The metric catalogue of every study: each metric a sweep, a sensitivity or a design may name,
as a traced, differentiable function of the parameters (`metric_blocks`, one entry per metric),
and which metrics a scene allows (`sweep_metrics`, `allowed_metrics`, `design_metrics`).

The scene metrics are the columns of `_metrics.metric_table` of a run (`traced_metrics`).

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
from typing import Optional, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp

from .._dynamics import eom_terms, generalized_force
from .._errors import RESULTS, PPRError
from .._geometry import home_pose
from .._kinematics import det3
from .._metrics import CIRCLE_METRICS, TRACKING_METRICS, metric_table, path_metrics
from .._modes import reduced_eigh
from .._names import (  # the tables' rows, SI units
    DESIGN_METRICS,
    PATH_SENSITIVITY_METRICS,
    SENSITIVITY_METRICS,
)
from .._prb import Derived
from .._robot import Robot
from .._statics import assemble, static_equilibrium

#: the per-member metrics computed inside the program besides the path's (`sweep_metrics`)
ROBOT_METRICS = (
    "end_rotation_diff_max_deg",
    "end_rotation_diff_min_deg",
    "end_rotation_diff_mean_deg",
    "torque_peak_Nm",
    "constraint_residual_max_m",
)


def sweep_metrics(trajectory) -> tuple:
    """The per-member metrics of a sweep along `trajectory`: how far the platform leaves it
    (`_metrics.path_metrics`: the radial error for a circle, the tracking error for any path)
    and `ROBOT_METRICS`."""
    return path_metrics(trajectory) + ROBOT_METRICS


#: the metrics of a sweep of the circle scenes (the columns of their tables)
METRICS = CIRCLE_METRICS + TRACKING_METRICS + ROBOT_METRICS


def traced_metrics(res, trajectory, names: Optional[Sequence[str]] = None) -> dict:
    """The metrics `names` (default `sweep_metrics(trajectory)`) of one member's
    `SceneResult` as traced scalars (jit-, vmap- and grad-able): the program-side columns of
    `metric_table`."""
    table = metric_table(res, trajectory)
    names = sweep_metrics(trajectory) if names is None else names
    missing = [k for k in names if k not in table]
    if missing:
        raise PPRError(f"metric {missing[0]!r} does not apply to this scene's path; allowed: "
                       f"{', '.join(table)}")
    return {k: table[k] for k in names}


#: eigenvalues within this relative distance of the lowest are one (repeated) cluster
CLUSTER_RTOL = 1e-6


def default_metrics(trajectory) -> tuple:
    """The sensitivity table's default metrics along `trajectory`: `SENSITIVITY_METRICS` on a
    circle, `PATH_SENSITIVITY_METRICS` on any other path."""
    return (SENSITIVITY_METRICS if "radial_error_max_m" in path_metrics(trajectory)
            else PATH_SENSITIVITY_METRICS)


def allowed_metrics(trajectory) -> tuple:
    """Every metric a sensitivity may ask for along `trajectory`."""
    return sweep_metrics(trajectory) + ("base_frequency_hz",)


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

    def Q(zf):
        z = assemble(n, free, zf, known, zk)
        return generalized_force(eom_terms(model, robot, z, jnp.zeros(n)), jnp.zeros(3),
                                 jnp.zeros(3))[f]

    K = -jax.jacfwd(Q)(z_eq[f])
    return z_eq, free, (K + K.T) / 2, failed


def base_frequency(model, robot: Robot, X=None):
    """The lowest natural frequency (Hz, signed: negative = unstable) of `model` about its static
    equilibrium near X (default home) with the actuators locked, differentiable (module
    docstring: Rayleigh quotient with the mode shapes held fixed; repeated lowest eigenvalues
    averaged). Raises for a model without free coordinates when locked (L0, L1)."""
    z_eq, free, K, failed = locked_stiffness(model, robot, X)
    n = model.n_dof
    f = jnp.array(free)
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


#: the catalogue's metrics that need no scene and no model of the robot (closed forms, and one
#: strip's elastica)
CLOSED_FORM_METRICS = ("pivot_frequency_hz", "pivot_stress_Pa", "moving_mass_kg",
                       "strip_tip_rotation_rad", "strip_elastica_stress_Pa")
#: the catalogue's metrics of one strip's elastica (they need `strip_load`)
ELASTICA_METRICS = ("strip_tip_rotation_rad", "strip_elastica_stress_Pa")
#: the catalogue's metrics at the robot's rest or a pose (no scene), through frequency_model
POSE_METRICS = ("base_frequency_hz", "compliance_xy_m_per_N", "compliance_phi_rad_per_Nm")
#: the catalogue's metrics that need the scene's run (besides the scene's own metrics)
SCENE_OWN_METRICS = ("strip_stress_peak_Pa", "torque_rms_Nm")
#: the catalogue's metrics of the scene's nominal path alone (a scene, not its run)
PATH_METRICS = ("path_reach_margin", "path_singularity_margin")
#: the metrics that are an extreme ('max' or 'min') over samples (output times, springs,
#: actuators, chains): a bound on the extreme's side (metric <= b for a max) is the same bound on
#: every sample, which the optimiser is given instead (`metric_values(samples=...)`): each
#: sample is smooth where the extreme has a kink at a tie between two samples
SAMPLED_METRICS = {"strip_stress_peak_Pa": "max", "torque_peak_Nm": "max",
                   "path_reach_margin": "min", "path_singularity_margin": "min"}


def design_metrics(trajectory=None) -> tuple:
    """Every metric a design may name: the catalogue's own (`DESIGN_METRICS`) and, along a
    scene's `trajectory`, the scene metrics of `allowed_metrics` and `SCENE_OWN_METRICS`
    (without a trajectory: the metrics that need no scene)."""
    own = tuple(DESIGN_METRICS)
    if trajectory is None:
        return tuple(m for m in own if m not in SCENE_OWN_METRICS + PATH_METRICS)
    return own + tuple(m for m in allowed_metrics(trajectory) if m not in own)


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
    singularity (m,) per sample)."""

    def one(x):
        k = ref_model.kinematics(robot, ref_model.coords_from_pose(robot, x))
        S = jax.jacfwd(lambda xx: ref_model.kinematics(
            robot, ref_model.coords_from_pose(robot, xx)).th_a)(x)
        return k.margin, S

    reach, S = jax.vmap(one)(jnp.concatenate([home_pose(robot)[None], X]))
    r1 = jnp.asarray(robot.r1, dtype=S.dtype)
    Sn = S * jnp.stack([r1, r1, jnp.ones_like(r1)])[None, None, :]
    rel = det3(Sn) / jnp.prod(jnp.linalg.norm(Sn, axis=-2), axis=-1)
    sign = jax.lax.stop_gradient(jnp.where(rel[0] < 0, -1.0, 1.0))
    return reach[1:], sign * rel[1:]


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

    - `names`: catalogue names (`design_metrics`).
    - `params`: `RobotParams` (traced leaves allowed).
    - `ctx`: `SceneContext`.
    - `stroke`: the joint rotation (rad) of `pivot_stress_Pa`.
    - `adjoint`: diffrax's adjoint for the scene's solve (`ForwardMode` under `jax.jacfwd`).
    - `equal_links`: `Robot`'s static choice of the closed-form inverse kinematics (l1 == l3).
    - `samples`: names of `SAMPLED_METRICS` given as their samples (the values whose max or min
      they are, flattened) instead of that extreme.

    **Returns:** a list of the values in SI units, each metric's in `names`' order (one entry,
    or its samples); NaN for every scene metric where the scene failed.
    """
    robot = Robot(params, equal_links=equal_links)
    dv = robot.dv
    out = {}
    scene_names = [n for n in names
                   if n not in CLOSED_FORM_METRICS + POSE_METRICS + PATH_METRICS]
    if any(n in PATH_METRICS for n in names):
        opts = ctx.options
        X = jax.vmap(opts.trajectory)(opts.times())
        reach, sing = path_margin_samples(ctx.scene.input_model, robot, X)
        out["path_reach_margin"] = reach if "path_reach_margin" in samples else jnp.min(reach)
        out["path_singularity_margin"] = (sing if "path_singularity_margin" in samples
                                          else jnp.min(sing))
    if scene_names:
        opts = ctx.options if adjoint is None else dataclasses.replace(ctx.options,
                                                                       adjoint=adjoint)
        res = ctx.scene.run(ctx.model, robot, opts)
        table = [n for n in scene_names if n not in SCENE_OWN_METRICS]
        if table:
            out.update(traced_metrics(res, opts.trajectory, table))
        if "torque_peak_Nm" in samples:
            out["torque_peak_Nm"] = jnp.abs(res.tau)
        if "strip_stress_peak_Pa" in scene_names:
            sig = strip_stresses(ctx.model, robot, res.z)
            out["strip_stress_peak_Pa"] = sig if "strip_stress_peak_Pa" in samples \
                else jnp.max(sig)
        if "torque_rms_Nm" in scene_names:
            out["torque_rms_Nm"] = torque_rms(res.tau)
        bad = res.result != RESULTS.successful
        out = {k: jnp.where(bad, jnp.nan, v) for k, v in out.items()}
    for n in names:
        if n == "pivot_frequency_hz":
            out[n] = pivot_frequency(params, dv)
        elif n == "pivot_stress_Pa":
            out[n] = pivot_stress(params, dv, stroke)
        elif n == "moving_mass_kg":
            out[n] = moving_mass(dv)
        elif n == "base_frequency_hz":
            out[n] = base_frequency(ctx.frequency_model, robot)
    if any(n in ELASTICA_METRICS for n in names):
        rot, sig = strip_elastica(params, dv, ctx.strip_load)
        out.update(strip_tip_rotation_rad=rot, strip_elastica_stress_Pa=sig)
    if any(n.startswith("compliance_") for n in names):
        X = None if ctx.pose is None else jnp.asarray(ctx.pose, dtype=jnp.float64)
        cxy, cphi = compliance(ctx.frequency_model, robot, X)
        out.update(compliance_xy_m_per_N=cxy, compliance_phi_rad_per_Nm=cphi)
    return [jnp.ravel(jnp.asarray(out[n], dtype=jnp.float64)) for n in names]
