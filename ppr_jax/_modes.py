"""Natural frequencies linearized about a static equilibrium (MODEL.md section 6, scene `modes`).

K_eff = -dQ/dz at the equilibrium includes the geometric stiffness of the pre-load (the springs'
pre-deflection times the curvature of their deflection maps), so an unstable equilibrium has a
negative eigenvalue; it is reported as a negative signed frequency and a growth rate, never NaN.
"""

from __future__ import annotations

from typing import Optional

import equinox as eqx
import jax
import jax.numpy as jnp

from ._custom_types import Array
from ._dynamics import eom_terms, generalized_force
from ._errors import PPRError, check_array, raise_if
from ._geometry import home_pose
from ._models import AbstractModel
from ._programs import cached_program
from ._robot import RobotLike, as_robot
from ._statics import assemble, free_coordinates, static_equilibrium


class Modes(eqx.Module):
    """freq_hz (k,): signed natural frequencies sign(lambda) sqrt(|lambda|)/(2 pi), ascending;
    growth_rate (k,): sqrt(-lambda) (1/s) for unstable modes, 0 otherwise; eigvals (k,) lambda
    (rad^2/s^2); shapes (k, k) mass-normalized mode shapes in the free coordinates; z_eq (n,)
    the equilibrium; free: indices of the free coordinates; M, K (k, k) the linearization."""

    freq_hz: Array
    growth_rate: Array
    eigvals: Array
    shapes: Array
    z_eq: Array
    M: Array
    K: Array
    free: tuple = eqx.field(static=True)


def modes(
    model: AbstractModel,
    robot: RobotLike,
    X=None,
    *,
    actuators: str = "locked",
    wrench=None,
    program_dir: Optional[str] = None,
) -> Modes:
    """Linear modes of `model` about its static equilibrium near pose X (default home).

    **Arguments:**

    - `model`: a model (L0-L3); `robot`: a `Robot` or `RobotParams`.
    - `X`: (3,) pose near which the equilibrium is sought (m, m, rad); None (default): home.
    - `actuators`: "locked" (default): the actuated angles are held at the L1
      inverse-kinematics angles of X (the L0 model's own for L0); L0 and L1 then have no free
      coordinate and no mode. "free": zero actuator torque, every coordinate free.
    - `wrench`: (3,) constant platform load (N, N, N m); None (default): no load.
    - `program_dir`: a directory of stored programs (`run_scene`'s; the command line's): the
      program is loaded from there, or exported there on first use; None (default): compiled in
      this process.

    **Returns:**

    `Modes`: signed natural frequencies (Hz, negative = unstable), growth rates (1/s),
    eigenvalues (rad^2/s^2), mass-normalized mode shapes, the equilibrium z_eq (n,), the
    linearization M, K over the free coordinates, and their indices `free`.

    **Raises:**

    `PPRError` for `actuators` other than "locked" or "free", a pose or wrench not of shape
    (3,), or if the static equilibrium is not found (the load may exceed what the joints hold,
    or the pose is far from an equilibrium).
    """
    if actuators not in ("locked", "free"):
        raise PPRError(f"actuators must be 'locked' or 'free', got {actuators!r}")
    X = home_pose(robot) if X is None else check_array("X", X, (3,))
    w = jnp.zeros(3) if wrench is None else check_array("wrench", wrench, (3,))
    args = (model, as_robot(robot), X, actuators, w)
    free = free_coordinates(model, actuators == "locked")
    template = (Modes(*[0] * 7, free), 0)
    res, failed = cached_program(_modes_jit, args, template, program_dir,
                                 f"modes-{model.name}-{actuators}")(*args)
    # The check outside the compiled program: a status, not a host callback inside it.
    return raise_if(
        res, failed,
        "static equilibrium not found (Newton did not converge): the load may exceed what the "
        "joints hold, or the pose is far from an equilibrium",
    )


def _modes_core(model, robot, X, actuators, w):
    robot = as_robot(robot)
    locked = actuators == "locked"
    z_eq, free, failed = static_equilibrium(
        model, robot, model.coords_from_pose(robot, X), locked=locked, wrench=w, check=False,
        return_failed=True,
    )
    n = model.n_dof
    if not free:
        e = jnp.zeros((0,))
        z = jnp.zeros((0, 0))
        return Modes(e, e, e, z, z_eq, z, z, ()), failed
    known = tuple(i for i in range(n) if i not in free)
    f = jnp.array(free)
    zk = z_eq[jnp.array(known)] if known else None

    def Q(zf):
        z = assemble(n, free, zf, known, zk)
        return generalized_force(eom_terms(model, robot, z, jnp.zeros(n)), jnp.zeros(3), w)[f]

    K = -jax.jacfwd(Q)(z_eq[f])
    K = (K + K.T) / 2  # symmetric at an equilibrium of conservative forces; remove rounding
    M = eom_terms(model, robot, z_eq, jnp.zeros(n)).M[f][:, f]
    lam, V, shapes = reduced_eigh(M, K)
    freq = jnp.sign(lam) * jnp.sqrt(jnp.abs(lam)) / (2 * jnp.pi)
    growth = jnp.where(lam < 0, jnp.sqrt(jnp.abs(lam)), 0.0)
    return Modes(freq, growth, lam, shapes, z_eq, M, K, free), failed


_modes_jit = eqx.filter_jit(_modes_core)


def reduced_eigh(M, K):
    """Eigenpairs of K v = lam M v (M symmetric positive definite) through the Cholesky factor
    M = L L^T: lam, V of L^-1 K L^-T, and the mode shapes L^-T V (M-orthonormal). L^-1 comes
    from one triangular solve (a general inverse would factor L again)."""
    L = jnp.linalg.cholesky(M)
    Li = jax.scipy.linalg.solve_triangular(L, jnp.eye(L.shape[-1]), lower=True)
    lam, V = jnp.linalg.eigh(Li @ K @ Li.T)
    return lam, V, Li.T @ V
