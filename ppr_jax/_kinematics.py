"""Public kinematics: inverse and forward kinematics, Jacobians J and S, singularity measure and
the pre-deflection of the home pose (MODEL.md section 4; paper eqs 12-15, 46-47, 52)."""

from __future__ import annotations

from typing import Optional

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from ._custom_types import Array, Float
from ._errors import RESIDUAL_TOL, PPRError, check_array, raise_first, raise_if, result_code
from ._geometry import home_pose, singularity_measure
from ._linalg import SmallLU
from ._models import AbstractModel, Reduced
from ._robot import Robot, RobotLike, as_robot

#: below this inverse condition number of S (dimensionless) a configuration counts as singular
SINGULAR_TOL = 1e-6
#: below this reach margin (1 - |cos| of a chain's closure angle) a chain counts as stretched out
REACH_TOL = 1e-12


class IKResult(eqx.Module):
    """Inverse kinematics at a pose X.

    th: (3, k) chain angles (k = 3: th_i1, th_i2, th_i3 for L1; k = 2: th_i1, th_i3 for L0) (rad);
    th_a: (3,) actuated angles; J: (3k + 3, 3) dq/dX with q = (th_11, th_12, ..., x, y, phi)
    (eq 47); S: (3, 3) d th_a / dX (eq 52); singularity: inverse condition number of the
    dimensionless S (0 singular, 1 isotropic); margin: (3,) reach margin of each chain;
    deflection: spring deflections (rad) ((3, 2) for L1, (3,) for L0).
    """

    th: Array
    th_a: Array
    J: Array
    S: Array
    singularity: Array
    margin: Array
    deflection: Array


def ik_solve(model: AbstractModel, robot: Robot, X) -> IKResult:
    robot = as_robot(robot)

    def q_of_X(X):
        k = model.kinematics(robot, model.coords_from_pose(robot, X))
        return k.th.reshape(-1), k.th_a

    (thf, th_a) = q_of_X(X)
    Jth, S = jax.jacfwd(q_of_X)(X)
    k = model.kinematics(robot, model.coords_from_pose(robot, X))
    J = jnp.concatenate([Jth, jnp.eye(3)], axis=0)
    d = k.deflection
    d = d.reshape(3, -1).squeeze(-1) if d.size == 3 else d.reshape(3, 2)
    return IKResult(
        th=k.th, th_a=th_a, J=J, S=S, singularity=singularity_measure(S, robot.r1), margin=k.margin,
        deflection=d,
    )


_ik_jit = eqx.filter_jit(ik_solve)


def check_pose(res: IKResult, X):
    """Raise on an unreachable pose or a singular configuration (works under jit and vmap)."""
    th = raise_if(
        res.th, jnp.any(res.margin <= REACH_TOL, axis=-1),
        "unreachable pose: a chain cannot close (|E_i - A_i| outside the chain's reach); "
        "allowed poses keep every chain's closure angle inside (0, pi)",
    )
    th = raise_if(
        th, res.singularity < SINGULAR_TOL,
        f"singular configuration: the actuation Jacobian S = d th_a/dX is (nearly) singular "
        f"(inverse condition number < {SINGULAR_TOL:g})",
    )
    return eqx.tree_at(lambda r: r.th, res, th)


def _one_robot(robot: Robot, what: str) -> Robot:
    """Refuse a batch of robots where one is expected (a raw broadcasting error otherwise)."""
    n = np.shape(robot.params.a)
    if n:
        raise PPRError(f"{what} takes one robot, got a batch of {n[0]} (stacked RobotParams): "
                       f"call it per member, or jax.vmap it over the parameters")
    return robot


def inverse_kinematics(
    robot: RobotLike, X: Float[Array, "3"], model: Optional[AbstractModel] = None
) -> IKResult:
    """Inverse kinematics of the L1 (default) or L0 model at pose X = (x, y, phi) (m, m, rad),
    or at a batch of poses X (m, 3) (the result then has a leading axis).

    L1 imposes the quasi-static assumption th_i1 - 2 th_i2 + th_i3 = 0 (eq 29) and is closed form
    when r1 = r3 (Newton otherwise); L0 is the rigid two-link closure. Raises `PPRError` for an
    unreachable pose or a singular configuration (under jit: an equinox runtime error).
    """
    robot = _one_robot(as_robot(robot), "inverse_kinematics")
    model = Reduced() if model is None else model
    if model.actuated_index is not None:
        raise PPRError(
            f"inverse_kinematics is defined for models whose pose fixes every joint (rigid, "
            f"reduced), not {model.name!r}"
        )
    X = check_array("X", X)
    if X.ndim == 2:  # a batch of poses: one vmapped call; errors name the failing members
        res = _ik_path_jit(model, robot, X)
        return check_pose(res, X)
    if X.shape != (3,):
        raise PPRError(f"X must be a pose (x, y, phi) of shape (3,) or (m, 3), got {X.shape}")
    return check_pose(_ik_jit(model, robot, X), X)


def jacobians(robot: RobotLike, X, model: Optional[AbstractModel] = None):
    """(J, S) at pose X: J = dq/dX (12, 3) (eq 47, the last 3 rows the identity), S = d th_a/dX."""
    r = inverse_kinematics(robot, X, model)
    return r.J, r.S


def predeflection(robot: RobotLike, X=None) -> dict:
    """Spring deflections at pose X (default home) for L1 (per pivot) and L0 (per pin) (rad).

    Table 1's lengths do not put the home pose exactly on the joint's natural (spring-free) arc:
    the default robot carries about -0.0152 rad per L1 pivot at home (MODEL.md section 4)."""
    from ._models import Rigid

    robot = as_robot(robot)
    X = home_pose(robot) if X is None else jnp.asarray(X, dtype=jnp.float64)
    r1 = inverse_kinematics(robot, X, Reduced())
    r0 = inverse_kinematics(robot, X, Rigid())
    return {"reduced": r1.deflection, "rigid": r0.deflection}


# ---------------------------------------------------------------------------------------------
# Forward kinematics (Newton, warm-startable)
# ---------------------------------------------------------------------------------------------


def fk_solve(model, robot, th_a, X_guess, rtol, atol, max_steps):
    robot = as_robot(robot)

    def resid(X, th_a):
        k = model.kinematics(robot, model.coords_from_pose(robot, X))
        return k.th_a - th_a

    sol = optx.root_find(
        resid, optx.Newton(rtol=rtol, atol=atol, linear_solver=SmallLU()), X_guess, args=th_a,
        max_steps=max_steps, throw=False,
    )
    return sol.value, sol.result


_fk_jit = eqx.filter_jit(fk_solve)


def _fk_inputs(robot, th_a, X_guess, model, names=("th_a", "X_guess")):
    """Defaults shared by the forward-kinematics wrappers: L1 model, home pose as the guess;
    the arrays checked finite (`check_array`)."""
    robot = _one_robot(as_robot(robot), "forward kinematics")
    model = Reduced() if model is None else model
    th_a = check_array(names[0], th_a)
    X_guess = home_pose(robot) if X_guess is None else check_array(names[1], X_guess, (3,))
    return robot, model, th_a, X_guess


def forward_kinematics(
    robot: RobotLike,
    th_a: Float[Array, "3"],
    X_guess: Optional[Float[Array, "3"]] = None,
    model: Optional[AbstractModel] = None,
    *,
    rtol: float = 1e-13,
    atol: float = 1e-13,
    max_steps: int = 50,
) -> Float[Array, "3"]:
    """Platform pose X (m, m, rad) of the L1 (default) or L0 model from the actuated angles th_a.

    Newton on th_a(X) = th_a (optimistix, differentiable by the implicit function theorem),
    started at `X_guess` (default home): pass the previous solution to warm-start along a path.
    The assembly mode found is the one nearest the guess.

    **Arguments:**

    - `robot`: a `Robot` or `RobotParams` (one robot, not a batch).
    - `th_a`: (3,) actuated angles (rad).
    - `X_guess`: (3,) starting pose of Newton (m, m, rad); None (default): the home pose.
    - `model`: `Reduced()` (L1, the default when None) or `Rigid()` (L0).
    - `rtol`, `atol`: Newton's relative and absolute tolerances (default 1e-13).
    - `max_steps`: the most Newton steps (default 50).

    **Returns:**

    (3,) platform pose X (m, m, rad).

    **Raises:**

    `PPRError` if Newton does not converge or lands on an unreachable / singular configuration.
    """
    robot, model, th_a, X_guess = _fk_inputs(robot, th_a, X_guess, model)
    X, result = _fk_jit(model, robot, th_a, X_guess, rtol, atol, max_steps)
    X = raise_if(
        X, result != optx.RESULTS.successful,
        "forward kinematics did not converge: the actuated angles are out of reach or near a "
        "singular configuration; try a closer X_guess",
    )
    check_pose(_ik_jit(model, robot, X), X)
    return X


#: why a path is refused by `fold_flags`
FOLD_MESSAGE = (
    "the path passes through (or within one sample of) a type-II singularity: det S, "
    "extrapolated from the samples before, changes sign and the solution's does not, so "
    "forward kinematics folded back onto its own assembly mode instead of following the "
    "motion (a wrong pose, not a result); keep the motion away from the singularity, or sample "
    "it more finely if it only passes near one"
)


def det3(S):
    """det of 3x3 matrices (..., 3, 3) by cofactors (no second LAPACK call beside the SVD; see
    README, Batches)."""
    return (S[..., 0, 0] * (S[..., 1, 1] * S[..., 2, 2] - S[..., 1, 2] * S[..., 2, 1])
            - S[..., 0, 1] * (S[..., 1, 0] * S[..., 2, 2] - S[..., 1, 2] * S[..., 2, 0])
            + S[..., 0, 2] * (S[..., 1, 0] * S[..., 2, 1] - S[..., 1, 1] * S[..., 2, 0]))


def fold_flags(det, ts=None):
    """(m,) bool: the samples of a path just past a fold (the first one past it, and possibly
    the next), from det S at the path's solved poses (`det3`) and the sample times `ts`
    (default: equally spaced).

    Along a motion through a type-II singularity det S changes sign, about linearly. A warm-
    started forward kinematics cannot follow it: the angles past the singularity have a
    solution in the same assembly mode as well (the mirror pose), Newton finds that one, and the
    returned pose turns back while |det S| turns up again, its sign unchanged: every check of
    the solved poses (convergence, reach, conditioning, sign of det S) passes. The fold shows in
    det S itself: extrapolated linearly from the two samples on one side of the interval, it
    changes sign across the interval, and the solved sample on the other side has not. A
    regular motion trips this only where det S changes by more than its own size in one
    sample, that is within about one sample of a singularity, where which pose follows is
    undecidable from the samples anyway. Traceable."""
    m = det.shape[0]
    if m < 3:
        return jnp.zeros(m, bool)
    ts = jnp.arange(m, dtype=det.dtype) if ts is None else jnp.asarray(ts, det.dtype)
    dt = jnp.diff(ts)
    sign = jnp.sign(det)
    mid = det[1:-1]
    # Forward: from samples k-2, k-1 onto k (k = 2 .. m-1).
    ahead = mid + (mid - det[:-2]) / dt[:-1] * dt[1:]
    fwd = (jnp.sign(ahead) != sign[1:-1]) & (sign[2:] == sign[1:-1])
    # Backward: from samples k+1, k onto k-1 (k = 1 .. m-2).
    behind = mid - (det[2:] - mid) / dt[1:] * dt[:-1]
    bwd = (jnp.sign(behind) != sign[1:-1]) & (sign[:-2] == sign[1:-1])
    flags = jnp.zeros(m, bool)
    flags = flags.at[2:].set(fwd)
    return flags.at[1:-1].set(flags[1:-1] | bwd)


class PathMargins(eqx.Module):
    """How far a pose path stays from the edges of a kinematic model's workspace (L0 or L1:
    the model whose inverse kinematics or dynamics drives a scene), at each of its m samples:
    the one reach and singularity check of a path (`path_margins`), which the scenes, sweeps,
    designs and identification's data check read, each with its own tolerance and message.

    `reach`: (m, 3) each chain's reach margin 1 - |cos| of its closure angle (<= `REACH_TOL`:
    out of reach; negative beyond it). `residual`: (m,) the largest loop-closure residual (m)
    of the chains the inverse kinematics closed. `det`: (m,) the relative determinant of
    S = d th_a/dX (translations scaled by r1): det S over the product of its column norms, 0
    singular, +-1 isotropic, signed (a type-II singularity crossed between two samples flips
    it). `th_a`: (m, 3) the actuated angles (rad)."""

    reach: Array
    residual: Array
    det: Array
    th_a: Array

    def out_of_reach(self) -> Array:
        """(m,) bool: a chain cannot close at the sample (its reach margin at most
        `REACH_TOL`, or the inverse kinematics leaves a loop-closure residual above
        `RESIDUAL_TOL`)."""
        return jnp.any(self.reach <= REACH_TOL, axis=-1) | ~(self.residual <= RESIDUAL_TOL)

    def singular(self) -> Array:
        """(m,) bool: S is singular at the sample (|det| below `SINGULAR_TOL`), or det S has
        changed sign since the sample before: the path crossed a type-II singularity between
        the two (det S is continuous in the pose). A pose out of reach (NaN) is not flagged
        here. Two crossings between one pair of samples cancel: sample finely."""
        return singular_flags(self.det)


def relative_det(S, r1):
    """(...,) det S over the product of its column norms, S (..., 3, 3) = d th_a/dX with its
    translation columns scaled by r1 (m): 0 singular, +-1 isotropic, signed."""
    r1 = jnp.asarray(r1, dtype=S.dtype)
    scale = jnp.stack([r1, r1, jnp.ones_like(r1)])
    Sn = S * jnp.broadcast_to(scale, S.shape)  # each row's translation entries times r1
    return det3(Sn) / jnp.prod(jnp.linalg.norm(Sn, axis=-2), axis=-1)


def singular_flags(det):
    """(m,) bool from relative determinants (m,) (`relative_det`) along a path in time order:
    singular at a sample (|det| below `SINGULAR_TOL`) or crossed since the sample before (a
    sign change; det S is continuous in the pose). NaN (out of reach) is not flagged."""
    sign = jnp.sign(det)
    crossed = jnp.concatenate([jnp.zeros(1, bool), sign[1:] * sign[:-1] < 0])
    return crossed | (jnp.abs(det) < SINGULAR_TOL)


def path_margins(model: AbstractModel, robot: RobotLike, X) -> PathMargins:
    """The reach and singularity margins (`PathMargins`) of `model` (L0 or L1) along the pose
    path X (m, 3) (m, m, rad). Traceable; what a caller does not read is not computed in its
    compiled program.

    Only S is differentiated (one forward-mode Jacobian of the actuated angles) and only plain
    XLA operations follow: it runs on every paper-circle input (thousands of samples), where
    `ik_solve`'s chain-angle Jacobian and its SVD (a batched LAPACK call) cost 8 ms a run.

    **Arguments:**

    - `model`: a model whose coordinates are the pose (`Rigid`, `Reduced`).
    - `robot`: a `Robot` or `RobotParams` (traced leaves allowed).
    - `X`: (m, 3) the poses.

    **Returns:** the `PathMargins`.
    """
    robot = as_robot(robot)

    def kin(x):
        return model.kinematics(robot, model.coords_from_pose(robot, x))

    def closure(x):
        k = kin(x)
        return k.margin, jnp.max(jnp.linalg.norm(model.loop_residual(robot, k), axis=-1)), k.th_a

    reach, residual, th_a = jax.vmap(closure)(X)
    S = jax.vmap(jax.jacfwd(lambda x: kin(x).th_a))(X)
    return PathMargins(reach=reach, residual=residual, det=relative_det(S, robot.r1),
                       th_a=th_a)


def path_singular(model: AbstractModel, robot: RobotLike, X) -> Array:
    """(m,) bool: the samples of a pose path X (m, 3) (m, m, rad) at which `model`'s (L0 or L1)
    S = d th_a / dX is singular or has changed sign since the sample before
    (`PathMargins.singular` of `path_margins`). Traceable."""
    return path_margins(model, robot, X).singular()


def _fk_path(model, robot, th_a_path, X0, rtol, atol, max_steps):
    def step(X, th_a):
        Xn, res = fk_solve(model, robot, th_a, X, rtol, atol, max_steps)
        return Xn, (Xn, result_code(res))

    _, (Xs, codes) = jax.lax.scan(step, X0, th_a_path)
    return Xs, codes


_fk_path_jit = eqx.filter_jit(_fk_path)


def forward_kinematics_path(
    robot: RobotLike,
    th_a_path: Float[Array, "m 3"],
    X0: Optional[Float[Array, "3"]] = None,
    model: Optional[AbstractModel] = None,
    *,
    rtol: float = 1e-13,
    atol: float = 1e-13,
    max_steps: int = 50,
) -> Float[Array, "m 3"]:
    """Forward kinematics along a sampled path of actuated angles, each Newton solve warm-started
    from the previous pose (one `lax.scan`, compiled once per shape).

    Checked sample by sample (a `PPRError` names the samples): Newton converged; every chain
    closes (reach margin); no singular configuration; no silent change of assembly mode
    between consecutive samples: the sign of det S (S = d th_a/dX) flips exactly when the path
    crosses a singularity or Newton jumped to another branch, which a warm start does not
    otherwise reveal (sample the path more finely if the jump is only too large a step); and no
    fold: angles that pass through a type-II singularity, where the solution turns back in its
    own assembly mode with det S's sign unchanged (`fold_flags`). The error is that of the
    first failing sample (after it, the warm start may be anywhere), with the samples that
    fail the same check.

    **Arguments:**

    - `robot`: a `Robot` or `RobotParams` (one robot, not a batch).
    - `th_a_path`: (m, 3) actuated angles at the m samples (rad).
    - `X0`: (3,) starting pose of the first Newton solve (m, m, rad); None (default): the home
      pose.
    - `model`: `Reduced()` (L1, the default when None) or `Rigid()` (L0).
    - `rtol`, `atol`: Newton's relative and absolute tolerances (default 1e-13).
    - `max_steps`: the most Newton steps per sample (default 50).

    **Returns:**

    (m, 3) platform poses X (m, m, rad), one per sample.

    **Raises:**

    `PPRError` naming the failed samples for any of the checks above, or if `th_a_path` is not
    of shape (m, 3)."""
    robot, model, th_a_path, X0 = _fk_inputs(robot, th_a_path, X0, model, ("th_a_path", "X0"))
    if th_a_path.ndim != 2 or th_a_path.shape[-1] != 3:
        raise PPRError(f"th_a_path must have shape (m, 3), got {th_a_path.shape}")
    Xs, codes = _fk_path_jit(model, robot, th_a_path, X0, rtol, atol, max_steps)
    res = _ik_path_jit(model, robot, Xs)
    # Newton's attainable accuracy is about eps / (S's inverse condition number): within a
    # factor of ten of its tolerance, whether it converges is a matter of rounding, and the
    # singularity, not the solve, is the reason to name
    floor = 10.0 * float(jnp.finfo(Xs.dtype).eps) / max(min(rtol, atol), 1e-300)
    stuck = codes != 0
    det = det3(res.S)
    sign = jnp.sign(det)
    flips = jnp.concatenate([jnp.zeros(1, bool), sign[1:] != sign[:-1]])
    return raise_first(Xs, [
        (stuck & (res.singularity < floor),
         f"forward kinematics along the path did not converge next to a singular configuration "
         f"(S's inverse condition number below {floor:.2g} at the last iterate, where Newton's "
         f"attainable accuracy is about its tolerance): a type-II singularity, or a chain "
         f"stretched to its reach; keep the motion away from it"),
        (stuck,
         "forward kinematics along the path did not converge (out of reach, singular, or a jump "
         "between samples too large for the warm start)"),
        (jnp.any(res.margin <= REACH_TOL, axis=-1),
         "unreachable pose along the path: a chain cannot close"),
        (res.singularity < SINGULAR_TOL,
         f"singular configuration along the path (inverse condition number of S < "
         f"{SINGULAR_TOL:g})"),
        (flips,
         "the path changes assembly mode between consecutive samples (det S changes "
         "sign: a singularity is crossed, or Newton jumped to another branch)"),
        (fold_flags(det), FOLD_MESSAGE),
    ])


_ik_path_jit = eqx.filter_jit(eqx.filter_vmap(ik_solve, in_axes=(None, None, 0)))
