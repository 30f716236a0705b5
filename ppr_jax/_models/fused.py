"""Equations of motion of the closed-loop levels (L0-L2) as straight-line arithmetic.

The generic projection (`_dynamics._eom_terms` with `AbstractClosedLoop.motion`) takes its
Jacobians from JVPs vmapped over the identity, multiplies them in einsums and solves the closures'
blocks with small matrix products: on a CPU each of those is an XLA kernel of its own, and one L1
right-hand side was 73 kernels (11 dots) for a few hundred flops. Here the same quantities are
written out for what the three levels have in common: every chain is a sum of rigid links,

    Phi_i = A_i + sum_k c_k e(alpha_k) - E_i(X) = 0      (2 closure equations per chain),

with link angles alpha_k affine in the independent coordinates z and in two dependent chain
angles u_i (`ChainSpec`: constant coefficients `Gz`, `Gu`), and every body is such a sum too. Then

    dalpha/dz = Gz + Gu u_z,   u_z = -Phi_u^-1 Phi_z   (Phi_u a 2 x 2 block per chain, Cramer),
    dp/dz = sum c e_perp(alpha) dalpha/dz,
    p''_conv = sum c (e_perp(alpha) alpha''_conv - e(alpha) alpha'^2),
    alpha''_conv = Gu u''_conv,
    u''_conv = -Phi_u^-1 (-sum c alpha'^2 e(alpha) + rho_E phi'^2 e(psi)),

which is the generic projection's algorithm (implicit differentiation of the closures, Kane's
form) with every derivative in closed form: elementwise operations on the three chains' (3,)
arrays, unrolled over the n coordinates, and sums over the chains, which XLA fuses into a few
kernels. A coordinate that moves one chain alone (L2's actuated angles, `ChainSpec.own`) takes
one column for the three chains, entry i chain i's derivative along its own coordinate: its
terms are the chains' own, not sums, and the mass matrix is an arrow matrix whose diagonal
block the right-hand side eliminates first (`_linalg.solve_arrow`). The physics is unchanged;
`tests/test_fused_eom.py` compares every term with the generic projection, in value and in
forward and reverse derivatives.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from .._fusion import cos_sin, cos_sin_of
from .._geometry import BETA
from .._robot import Robot


class Link(NamedTuple):
    """c e(alpha_k + offset): a link of length `c` along chain angle `k`, turned by the fixed
    angle `offset` (None: 0)."""

    k: int
    c: object
    offset: object = None


class Body(NamedTuple):
    """A chain's body: COM at A_i + sum of `links`, angle alpha_`angle` + `offset`, mass `m`,
    central moment of inertia `I` (scalars, the same on the three chains)."""

    links: tuple
    angle: int
    m: object
    I: object


class ChainSpec(NamedTuple):
    """What `fused_eom` needs of a closed-loop level (module docstring).

    `alpha`: the chain angles, a list of (3,) arrays (one entry per chain) at (z, u);
    `Gz` (K, 3, n) and `Gu` (K, 2) NumPy constants: d alpha_k / dz of chain i (holding u) and
    d alpha_k / du_i; `closure`: the links of Phi (`Link`s, offsets None) from A_i to E_i;
    `bodies`: the chains' bodies (the platform, m4 and I4 at X, is added here);
    `springs`: one (K,) NumPy coefficient vector per spring of a chain (the deflection's
    Jacobian is coef . d alpha/dz; its value comes from `Kin.deflection`, chain-major);
    `actuated`: the chain angle whose derivative is the actuated angle's;
    `own`: the coordinates that each chain depends on alone, one per chain in chain order, the
    last of z (L2's actuated angles), or () (L0, L1: every coordinate is the platform's);
    `trig`: the angles' cosines and sines (`_geometry.ChainTrig`) where the closure computed
    them, or None (they are evaluated here)."""

    alpha: list
    Gz: np.ndarray
    Gu: np.ndarray
    closure: tuple
    bodies: tuple
    springs: tuple
    actuated: int
    own: tuple = ()
    trig: object = None


#: entries per stack in the sums over the chains (`fused_eom`)
GROUP = 6


def _perp(v):
    return (-v[1], v[0])


def _turned(ev, offset):
    """e(alpha + offset) from ev = e(alpha) (a pair of (3,) arrays): one sine and cosine of the
    offset instead of one per chain."""
    if offset is None:
        return ev
    c, s = cos_sin_of(offset)  # a scalar or one per chain
    return (c * ev[0] - s * ev[1], s * ev[0] + c * ev[1])


def _dot(a, b):
    """sum_j a_j b_j over Python lists, skipping the structural zeros (None)."""
    out = None
    for x, y in zip(a, b):
        if x is None or y is None:
            continue
        out = x * y if out is None else out + x * y
    return out


class _Chains(NamedTuple):
    """What the mass matrix, the balance and the passive forces share (`_chains`): per-chain
    (3,) arrays, Python floats or None (a structural zero)."""

    n: int
    ns: int  # shared coordinates
    nl: int  # shared coordinates, then one column for the chains' own ones
    own: tuple
    zd: list  # z' in local columns
    A_z: list  # [k][j]: d alpha_k / dz_j
    bodies: list  # per body: (Jx, Jy, ax, ay), the COM's Jacobian columns and its convective
    #   acceleration
    Q: list  # [j]: the springs', their damping's and the actuators' friction's force
    Jth: list  # [j]: d th_a / dz_j


def _chains(spec: ChainSpec, robot: Robot, z, zdot, kin, stiffness, damping,
            once=None) -> _Chains:
    """The closure's implicit derivatives, the bodies' Jacobians and convective accelerations
    and the passive forces (module docstring). `once`, where given, is applied to the list of
    the angles' derivatives and the links' directions (`_fusion.tangents_once` in
    `fused_balance`)."""
    n = z.shape[0]
    K = len(spec.alpha)
    own = tuple(int(j) for j in spec.own)
    ns = n - len(own)  # the shared coordinates, the platform's pose first
    Gz = _local_columns(spec.Gz, own)
    nl = Gz.shape[-1]  # the shared coordinates, then one column for the chains' own ones
    zd = [zdot[j] for j in range(ns)] + ([zdot[ns:]] if own else [])
    phi = z[2]
    # the sines and cosines once, not once per kernel that reads them (`_fusion.py`)
    if spec.trig is None:
        cos_, sin_ = cos_sin(*spec.alpha, phi[None])
        ev = list(zip(cos_[:-1], sin_[:-1]))
    else:
        cos_, sin_ = cos_sin(phi[None])
        ev = list(zip(spec.trig.cos, spec.trig.sin))
    ep = [_perp(v) for v in ev]
    # platform joint directions psi_i = beta_i + phi, turned from the constant beta_i
    eb = (np.cos(BETA), np.sin(BETA))
    cphi, sphi = cos_[-1][0], sin_[-1][0]
    epsi = (cphi * eb[0] - sphi * eb[1], sphi * eb[0] + cphi * eb[1])
    rho_E = robot.rho_E

    def gz(k, j):
        g = Gz[k, :, j]
        if not g.any():
            return None
        return float(g[0]) if np.all(g == g[0]) else jnp.asarray(g)

    # Closure blocks. Phi_u[m] and Phi_z[j] are (x, y) pairs of (3,) arrays (None: zero).
    def closure_col(coefs):
        out = None
        for link, g in zip(spec.closure, coefs):
            if g is None:
                continue
            t = (link.c * g * ep[link.k][0], link.c * g * ep[link.k][1])
            out = t if out is None else (out[0] + t[0], out[1] + t[1])
        return out

    Phi_u = [closure_col([float(spec.Gu[link.k, m]) or None for link in spec.closure])
             for m in range(2)]
    Phi_z = []
    for j in range(nl):
        col = closure_col([gz(link.k, j) for link in spec.closure])
        # minus dE_i/dz_j: E_i = (x, y) + rho_E e(psi_i)
        if j < 2:
            one = (-1.0, 0.0) if j == 0 else (0.0, -1.0)
            col = one if col is None else (col[0] + one[0], col[1] + one[1])
        elif j == 2:
            t = (rho_E * epsi[1], -rho_E * epsi[0])  # -rho_E e_perp(psi)
            col = t if col is None else (col[0] + t[0], col[1] + t[1])
        Phi_z.append(col)
    (a, c), (b, d) = Phi_u  # Phi_u = [[a, b], [c, d]] per chain
    inv_det = 1.0 / (a * d - b * c)

    def solve2(r):
        """-Phi_u^-1 r for r an (x, y) pair (None: zero)."""
        if r is None:
            return (None, None)
        rx, ry = r
        return (-(d * rx - b * ry) * inv_det, -(a * ry - c * rx) * inv_det)

    u_z = [solve2(Phi_z[j]) for j in range(nl)]  # u_z[j] = (du_0/dz_j, du_1/dz_j)

    def add(x, y):
        return y if x is None else (x if y is None else x + y)

    # d alpha_k / dz_j (None: zero) and the angular rates alpha_k'
    A_z = []
    for k in range(K):
        row = []
        for j in range(nl):
            v = gz(k, j)
            for m in range(2):
                g = float(spec.Gu[k, m])
                if g and u_z[j][m] is not None:
                    v = add(v, g * u_z[j][m] if g != 1.0 else u_z[j][m])
            row.append(v)
        A_z.append(row)
    A_d = [_dot(A_z[k], zd) for k in range(K)]
    # convective closure term and the dependent angles' convective accelerations
    conv = (rho_E * zd[2] ** 2 * epsi[0], rho_E * zd[2] ** 2 * epsi[1])
    for link in spec.closure:
        w = link.c * A_d[link.k] ** 2
        conv = (conv[0] - w * ev[link.k][0], conv[1] - w * ev[link.k][1])
    udd = solve2(conv)
    A_dd = [add(float(spec.Gu[k, 0]) * udd[0] if spec.Gu[k, 0] else None,
                float(spec.Gu[k, 1]) * udd[1] if spec.Gu[k, 1] else None) for k in range(K)]

    if once is not None:
        K = len(ev)
        rows = [list(v) for v in ev] + [list(r) for r in A_z] + [list(A_d), list(A_dd)]
        _once(once, rows)
        ev, A_z = [tuple(v) for v in rows[:K]], rows[K : 2 * K]
        A_d, A_dd = rows[2 * K], rows[2 * K + 1]

    # Bodies: the Jacobians of their centres of mass and their convective accelerations
    per_body = []
    for body in spec.bodies:
        Jx, Jy = [None] * nl, [None] * nl
        ax, ay = None, None
        for link in body.links:
            e_ = _turned(ev[link.k], link.offset)
            p_ = _perp(e_)
            for j in range(nl):
                if A_z[link.k][j] is not None:
                    Jx[j] = add(Jx[j], link.c * A_z[link.k][j] * p_[0])
                    Jy[j] = add(Jy[j], link.c * A_z[link.k][j] * p_[1])
            w = link.c * A_d[link.k] ** 2
            ax, ay = add(ax, -w * e_[0]), add(ay, -w * e_[1])
            if A_dd[link.k] is not None:
                ax = ax + link.c * A_dd[link.k] * p_[0]
                ay = ay + link.c * A_dd[link.k] * p_[1]
        per_body.append((Jx, Jy, ax, ay, A_z[body.angle], A_dd[body.angle]))

    # Springs with their damping, and the actuators' viscous friction
    defl = kin.deflection.reshape(3, -1)
    Q = [None] * nl
    for s, coef in enumerate(spec.springs):
        Jd = [_dot([float(c_) or None for c_ in coef], [A_z[k][j] for k in range(K)])
              for j in range(nl)]
        f = -stiffness * defl[:, s] - damping * _dot(Jd, zd)
        for j in range(nl):
            if Jd[j] is not None:
                Q[j] = add(Q[j], Jd[j] * f)
    Jth = A_z[spec.actuated]
    fa = -robot.c_act * _dot(Jth, zd)
    for j in range(nl):
        if Jth[j] is not None:
            Q[j] = add(Q[j], Jth[j] * fa)
    return _Chains(n=n, ns=ns, nl=nl, own=own, zd=zd, A_z=A_z, bodies=per_body, Q=Q, Jth=Jth)


def _add(x, y):
    return y if x is None else (x if y is None else x + y)


def _once(once, rows):
    """`once` applied to every array in `rows` (lists of per-chain entries), in place; Python
    floats and structural zeros (None) pass by."""
    live = [(r, j) for r, row in enumerate(rows) for j, x in enumerate(row)
            if x is not None and not isinstance(x, float)]
    for (r, j), v in zip(live, once([jnp.broadcast_to(rows[r][j], (3,)) for r, j in live])):
        rows[r][j] = v


def fused_eom(spec: ChainSpec, robot: Robot, z, zdot, kin, stiffness, damping):
    """(M (n, n), h (n,), Q_passive (n,), Jth (3, n), JX (3, n)) of the generic projection
    (`_dynamics.EOM`) from a `ChainSpec` at (z, z') with `kin` the kinematics at z."""
    ch = _chains(spec, robot, z, zdot, kin, stiffness, damping)
    n, ns, nl, own = ch.n, ch.ns, ch.nl, ch.own
    add = _add
    # Bodies: mass matrix and convective terms, per chain
    M = [[None] * nl for _ in range(nl)]
    h = [None] * nl
    for body, (Jx, Jy, ax, ay, Ja, Ja_dd) in zip(spec.bodies, ch.bodies):
        for i in range(nl):
            for j in range(i, nl):
                t = _dot([Jx[i], Jy[i]], [Jx[j], Jy[j]])
                t = body.m * t if t is not None else None
                if Ja[i] is not None and Ja[j] is not None:
                    t = add(t, body.I * Ja[i] * Ja[j])
                M[i][j] = add(M[i][j], t)
            t = _dot([Jx[i], Jy[i]], [ax, ay])
            t = body.m * t if t is not None else None
            if Ja[i] is not None and Ja_dd is not None:
                t = add(t, body.I * Ja[i] * Ja_dd)
            h[i] = add(h[i], t)
    Q, Jth = ch.Q, ch.Jth

    # The sums over the chains, in groups of `GROUP` entries: XLA's CPU fusion takes a stack of
    # a few operands into the reduction that consumes it, but computes every operand of a longer
    # stack as a kernel of its own (one stack of L2's 48 entries: 49 kernels; in groups: 5).
    # Only the shared coordinates' terms are sums; a chain's own coordinate takes its chain's.
    zero = jnp.zeros(3, dtype=z.dtype)

    def chains(x):
        return zero if x is None else jnp.broadcast_to(x, (3,))

    cols = [M[i][j] for i in range(ns) for j in range(i, ns)] + h[:ns] + Q[:ns]
    cols = [chains(x) for x in cols]
    # A chain's own terms ride in the same array as the sums: every output then depends on
    # every input that any does, as the generic projection's do, which a custom derivative
    # under `vmap` needs (its outputs' batching is the primal's; L2's h does not depend on
    # the rotor inertia here and does there)
    own_terms = ([chains(M[i][ns]) for i in range(ns)] + [chains(M[ns][ns]), chains(h[ns]),
                                                          chains(Q[ns])]) if own else []
    S = jnp.concatenate([jnp.sum(jnp.stack(cols[g : g + GROUP]), axis=-1)
                         for g in range(0, len(cols), GROUP)] + own_terms)
    iu = np.triu_indices(ns)
    upper = np.zeros((ns, ns), dtype=int)
    upper[iu] = np.arange(len(iu[0]))
    upper = np.maximum(upper, upper.T)  # the symmetric entry's index
    nm = len(iu[0])
    # the platform: m4 at (x, y), I4 about phi (no convective acceleration in X)
    plat = jnp.stack([robot.m4, robot.m4, robot.I4])
    Mss = jnp.stack([jnp.stack([S[int(upper[i, j])] for j in range(ns)]) for i in range(ns)])
    Mss = Mss + jnp.diag(jnp.pad(plat, (0, ns - 3)))
    h_s, Q_s = S[nm : nm + ns], S[nm + ns : nm + 2 * ns]
    Jth_s = _jth_matrix(Jth, ns, own, z.dtype)
    if own:
        # chain i's own coordinate couples with the shared ones and with itself only
        o = nm + 2 * ns
        B = S[o : o + 3 * ns].reshape(ns, 3)
        D, h_o, Q_o = (S[o + 3 * (ns + m) : o + 3 * (ns + m + 1)] for m in range(3))
        M = jnp.concatenate([jnp.concatenate([Mss, B], axis=1),
                             jnp.concatenate([B.T, jnp.diag(D)], axis=1)])
        h = jnp.concatenate([h_s, h_o])
        Q = jnp.concatenate([Q_s, Q_o])
        Jth = Jth_s
    else:
        M, h, Q, Jth = Mss, h_s, Q_s, Jth_s
    JX = jnp.asarray(np.eye(3, n), dtype=z.dtype)
    return M, h, Q, Jth, JX


def _jth_matrix(Jth, ns, own, dtype):
    """d th_a / dz (3, n) from its local columns (a chain's own coordinate: its own entry)."""
    zero = jnp.zeros(3, dtype=dtype)

    def chains(x):
        return zero if x is None else jnp.broadcast_to(x, (3,))

    shared = jnp.stack([chains(x) for x in Jth[:ns]], axis=-1)
    if not own:
        return shared
    return jnp.concatenate([shared, jnp.diag(chains(Jth[ns]))], axis=1)


def fused_balance(spec: ChainSpec, robot: Robot, z, zdot, zdd, kin, stiffness, damping,
                  once=None):
    """(Q_passive - M z'' - h (n,), Jth (3, n), JX (3, n)) at (z, z') for given accelerations
    z'' (n,): the equations of motion's balance without the actuators and the wrench, written
    as the bodies' inertial forces (Kane's form, `sum_b m_b Jp_b^T (Jp_b z'' + p_b''_conv)` and
    likewise for the rotations) instead of M and h. It needs no n x n matrix, so its
    derivative is a fraction of M's: forward dynamics takes its tangents from it
    (`_dynamics.forward_dynamics`). `once`: as `_chains`'."""
    ch = _chains(spec, robot, z, zdot, kin, stiffness, damping, once=once)
    ns, nl, own = ch.ns, ch.nl, ch.own
    a = [zdd[j] for j in range(ns)] + ([zdd[ns:]] if own else [])
    F = list(ch.Q)
    # the bodies' accelerations Jp z'' + p''_conv (per chain)
    acc = [[_add(_dot(Jx, a), ax), _add(_dot(Jy, a), ay), _add(_dot(Ja, a), Ja_dd)]
           for Jx, Jy, ax, ay, Ja, Ja_dd in ch.bodies]
    jac = [[list(Jx), list(Jy), list(Ja)] for Jx, Jy, _, _, Ja, _ in ch.bodies]
    if once is not None:
        _once(once, [r for b in range(len(acc)) for r in (acc[b], *jac[b])])
    for body, (vx, vy, va), (Jx, Jy, Ja) in zip(spec.bodies, acc, jac):
        for j in range(nl):
            t = _dot([Jx[j], Jy[j]], [vx, vy])
            t = body.m * t if t is not None else None
            if Ja[j] is not None and va is not None:
                t = _add(t, body.I * Ja[j] * va)
            if t is not None:
                F[j] = -t if F[j] is None else F[j] - t
    zero = jnp.zeros(3, dtype=z.dtype)
    cols = jnp.stack([zero if x is None else jnp.broadcast_to(x, (3,)) for x in F[:ns]])
    plat = jnp.stack([robot.m4, robot.m4, robot.I4])
    r = jnp.sum(cols, axis=-1) - jnp.pad(plat, (0, ns - 3)) * zdd[:ns]
    if own:
        r = jnp.concatenate([r, zero if F[ns] is None else jnp.broadcast_to(F[ns], (3,))])
    return r, _jth_matrix(ch.Jth, ns, own, z.dtype), jnp.asarray(np.eye(3, z.shape[0]),
                                                                   dtype=z.dtype)


def _local_columns(Gz, own):
    """Gz (K, 3, n) with the chains' own coordinates `own` (one per chain, the last of z) merged
    into one column (K, 3, n - len(own) + 1): entry i of the merged column is chain i's
    derivative along its own coordinate. The terms of the three own coordinates are then one
    (3,) array each instead of three, two thirds of them structural zeros."""
    if not own:
        return Gz
    n, ns = Gz.shape[-1], Gz.shape[-1] - len(own)
    if own != tuple(range(ns, n)) or len(own) != Gz.shape[1]:
        raise ValueError(f"own coordinates {own}: one per chain, the last of z ({n} coordinates)")
    merged = np.stack([Gz[:, i, j] for i, j in enumerate(own)], axis=1)  # (K, 3)
    others = Gz[:, :, ns:].copy()
    others[:, np.arange(len(own)), np.arange(len(own))] = 0.0
    if others.any():
        raise ValueError("a chain's own coordinate moves another chain's angles")
    return np.concatenate([Gz[:, :, :ns], merged[:, :, None]], axis=2)
