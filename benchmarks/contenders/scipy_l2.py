"""The L2 (`double1r`) robot on the `paper-circle` scene in plain NumPy and
`scipy.integrate.solve_ivp`: what a user would write without this library, as a contender for
the benchmark suite and as an independent second formulation of L2 to check the library against.

Formulation (MODEL.md sections 1-5; written from the model description, not from the library's
code, which integrates 6 independent coordinates with closed-form loop closure and Kane's
projection):

- 12 absolute coordinates q = (th_11, th_12, th_13, th_21, ..., th_33, x, y, phi) (eq 38), chain
  angles from the x axis (rad), platform pose (m, m, rad); state y = (q, q') (24,).
- Bodies (section 5): drive link (mass m1, central inertia I1 + J_rotor, COM l1/2 along its centre
  line, which is the chain angle th_i1 less sigma*delta1), pseudo-link (m2, I2 = m2 r2^2/12, COM
  at r2/2 from B_i), connecting link (m3, I3, COM l3/2 back from E_i along its centre line, at
  th_i3 + sigma*delta3), platform (m4, I4, COM at (x, y)). delta1 = delta3 = 0 on the centre
  lines (the default `joint_geometry`); the `strip` geometry (section 3a) only changes r1, r3 and
  these constant offsets, so it is supported by the same formulas.
- Mass matrix M(q) from T = sum_b (m_b |p_b'|^2 + I_b a_b'^2)/2 in closed form: block diagonal,
  one 3x3 block per chain whose entries are mu_jk cos(angle differences), and diag(m4, m4, I4)
  for the platform; the velocity terms h(q, q') = dM/dt q' - dT/dq follow from the same sums
  with sin instead of cos (derivation in `L2Model.rhs`).
- Springs U = (K/2) sum_i (d_i1^2 + d_i2^2) with d_i1 = (th_i2 - th_i1) - sigma (psi0 - delta1),
  d_i2 = (th_i3 - th_i2) - sigma (psi0 - delta3) (linear in q, no angle wrapping needed since
  absolute angles are continuous), their viscous damping c_spring, actuator friction c_act and the
  actuator torque tau_i on th_i1 (all generalized forces are exact gradients, no Jacobian).
- The 6 loop closures g_i(q) = A_i + r1 e(th_i1) + r2 e(th_i2) + r3 e(th_i3) - (x, y)
  - rho_E e(beta_i + phi) = 0 (eq 12) by Lagrange multipliers in index-1 form:

      [ M  G^T ] [ q'' ]   [ Q - h                                  ]
      [ G   0  ] [ lam ] = [ -G' q' - 2 alpha G q' - alpha^2 g(q)   ],

  an 18 x 18 dense solve per right-hand side, with Baumgarte stabilisation (critically damped,
  rate `alpha`): the constraint error obeys g'' + 2 alpha g' + alpha^2 g = 0, so the drift that
  integration errors feed into g decays at rate alpha instead of growing linearly/quadratically
  as it can in the plain index-1 form. On the constraint manifold the added terms vanish, so
  the solution is L2's exactly. `BAUMGARTE_ALPHA` = 20 1/s: a decay time of 50 ms, short against
  the 7.54 s scene, and below the fastest physical rate of L2 on this scene (about 88 rad/s, the
  largest eigenvalue of the right-hand side's Jacobian at t = 0: nearly undamped oscillatory
  pairs at 66, 77 and 88 rad/s), so it neither limits the explicit solver's step nor stiffens
  the implicit ones. Measured on paper-circle (DOP853, 7.54 s): the plain index-1 form
  (alpha = 0) drifts no further (largest residual 4e-9 / 3e-11 / 9e-13 m at rtol 1e-4 / 1e-6 /
  1e-8, against 6e-9 / 5e-11 / 1e-12 m with alpha = 20): over one turn the drift stays at the
  tolerance, so the stabilisation is insurance for longer runs rather than a correction this
  scene needs. A projection onto the manifold is not available inside `solve_ivp` (no step
  callback), which is why stabilisation, not projection, is used.

Inputs taken from the library (only data, never its dynamics):
- parameters and derived quantities: `ppr_jax.derived(params)` (PRB joint, masses);
- the scene's torques: L1 inverse dynamics along eq 55 (`ppr_jax.InverseDynamicsTorque` with the
  `reduced` model, as the scene builds them), evaluated once in JAX on a uniform grid of step
  `TORQUE_DT` = 1 ms over [-10 ms, t_end + 10 ms] and interpolated by a not-a-knot cubic spline. Its
  error is measured on every run at the grid's midpoints against the exact torques (about 6e-15
  N m against torques of 0.11 N m: rounding level) and returned as `torque_spline_max_err`.
  Evaluating L1's inverse dynamics in NumPy would be a third model to maintain; the torques are
  the scene's input, not the model under test.
- the initial state: the library's L2 quasi-static state at t = 0 (positions and velocities,
  `ppr_jax.quasi_static_state`, the same function the scene calls), or a given (z0, z0') in the
  library's coordinates (x, y, phi, th_a1..3) such as the first state of a library solution,
  or this formulation's own start (`quasi_static_start`, MODEL.md section 6, used by
  `scene_metrics`: the balance of the actuated coordinates projected on dq/dth_a, solved by
  Newton's iteration, with the rates of the quasi-static path by central differences).
  It is converted to absolute coordinates by closing each chain (two-link (r2, r3) problem on
  the elbow branch sigma) and solving the loop-closure velocity equations for th_i2', th_i3'.

Jacobian for the implicit methods (Radau, LSODA): forward finite differences, all 24 columns in
one vectorised right-hand side call (the right-hand side takes y of shape (24,) or (24, k)),
steps sqrt(eps) max(|y_j|, 1). An analytic Jacobian of the KKT solve is possible but is not what
a user would write; the finite-difference one is accurate to ~1e-8 relative, which is all a
Newton iteration needs.

`run(...)` returns the platform pose at the output times, the timing and the solver counts; see
its docstring for what is timed.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.integrate import solve_ivp
from scipy.interpolate import CubicSpline

#: Baumgarte rate (1/s), critically damped: see the module docstring
BAUMGARTE_ALPHA = 20.0
#: grid step (s) of the tabulated scene torques (spline error ~ dt^4: 6e-15 N m at 1 ms)
TORQUE_DT = 1e-3
#: margin (s) of the torque grid past t_end (the solvers never step past t_end; this is safety)
TORQUE_PAD = 1e-2
#: relative finite-difference step of the Jacobian (sqrt of float64 epsilon)
FD_REL = float(np.sqrt(np.finfo(float).eps))
#: platform joint directions beta_i (MODEL.md section 2)
BETA = np.array([7 * np.pi / 6, -np.pi / 6, np.pi / 2])
#: methods `run` supports and whether they take a Jacobian
METHODS = {"DOP853": False, "Radau": True, "LSODA": True}


# ---------------------------------------------------------------------------------------------
# Scene input: the torques
# ---------------------------------------------------------------------------------------------


def TorqueSpline(ts, taus):
    """Not-a-knot cubic spline t -> tau (3,) (N m) of torques taus (m, 3) tabulated at
    increasing times ts (m,) (s): scipy's `CubicSpline` (about 6 us per scalar call, a few
    percent of the right-hand side)."""
    return CubicSpline(np.asarray(ts, float), np.asarray(taus, float), axis=0)


def AnglesSpline(ts, ths):
    """Prescribed actuated angles t -> (th_a, th_a', th_a'') (3,) each (rad, rad/s, rad/s^2)
    from samples ths (m, 3) at increasing times ts (m,) (s): a quintic interpolating B-spline
    (scipy's `make_interp_spline`), so the accelerations are smooth (error ~ dt^4 in the angles,
    ~ dt^2 in their accelerations: 1e-14 rad and 1e-8 rad/s^2 at 1 ms for the scenes' motions)."""
    from scipy.interpolate import make_interp_spline

    spl = make_interp_spline(np.asarray(ts, float), np.asarray(ths, float), k=5, axis=0)
    d1, d2 = spl.derivative(1), spl.derivative(2)
    return lambda t: (spl(t), d1(t), d2(t))


def scene_torque(params, t_end, dt=TORQUE_DT, path=None):
    """The paper-circle torques (L1 inverse dynamics along eq 55, or along `path`, as
    `ppr_jax`'s scenes build them) on a grid of step `dt` over [-TORQUE_PAD, t_end + TORQUE_PAD]
    (the start's balance reads them just before t = 0), as a `TorqueSpline`, and the spline's
    largest error (N m) at the grid's midpoints against the exact torques."""
    from . import library

    n = int(np.ceil((t_end + 2 * TORQUE_PAD) / dt))
    ts = np.arange(n + 1) * dt - TORQUE_PAD
    mid = ts[:-1] + dt / 2
    taus = library.scene_torques(params, np.concatenate([ts, mid]), path)
    spline = TorqueSpline(ts, taus[: n + 1])
    err = float(np.max(np.abs(spline(mid) - taus[n + 1:])))
    return spline, err


def library_initial_state(params):
    """The library's L2 quasi-static initial state (z0, z0') at t = 0 of paper-circle, in its
    coordinates z = (x, y, phi, th_a1, th_a2, th_a3) (the scene's own function and inputs)."""
    from . import library

    return library.initial_state(params)


# ---------------------------------------------------------------------------------------------
# The model
# ---------------------------------------------------------------------------------------------


class L2Model:
    """L2 in absolute coordinates with Lagrange multipliers (module docstring).

    `params`: a `ppr_jax.RobotParams` (only its numbers are used); `torque`: a callable t -> (3,)
    actuator torques (N m); `alpha`: Baumgarte rate (1/s); `with_work`: append the actuators' and
    dampers' net work W (J) as a 25th state (W' = tau . th_i1' - friction and damping power), for
    the energy balance T + U - (T + U)(0) = W; `angles`: motion-driven instead (MODEL.md
    section 5): a callable t -> (th_a, th_a', th_a'') (3,) each (rad, rad/s, rad/s^2), the
    actuated angles prescribed by three more constraints th_i1 - sigma delta1 - th_a(t) = 0
    (rheonomic, Baumgarte-stabilised like the loop closures: a 21 x 21 KKT system), whose
    multipliers are the actuators' reaction torques (`torque` is then ignored and may be None).
    """

    def __init__(self, params, torque, alpha=BAUMGARTE_ALPHA, with_work=False, angles=None):
        import ppr_jax as pj

        dv = pj.derived(params)
        f = lambda v: float(np.asarray(v))  # noqa: E731
        self.torque = torque
        self.angles = angles
        self.nk = 18 if angles is None else 21  # KKT size: 12 coordinates, 6 or 9 constraints
        self.alpha = float(alpha)
        self.with_work = bool(with_work)
        self.n = 25 if with_work else 24
        sig = float(params.sigma)
        self.sigma = sig
        a = f(params.a)
        self.A = np.array([[0.0, 0.0], [a, 0.0], [a / 2, np.sqrt(3.0) * a / 2]])  # (3, 2)
        self.r1, self.r2, self.r3 = f(dv.r1), f(dv.r2), f(dv.r3)
        self.rhoE = f(dv.rho_E)
        self.K = f(dv.K)
        self.c_s, self.c_a = f(params.c_spring), f(params.c_act)
        self.delta1, self.delta3 = f(dv.delta1), f(dv.delta3)
        self.rest1 = sig * (f(dv.psi0) - self.delta1)  # spring rest turns (rad)
        self.rest2 = sig * (f(dv.psi0) - self.delta3)
        l1, l3 = f(params.l1), f(params.l3)
        m1, m2, m3, m4 = f(dv.m1), f(dv.m2), f(dv.m3), f(dv.m4)
        I1 = f(dv.I1) + f(params.J_rotor)
        I2, I3, I4 = f(dv.I2), f(dv.I3), f(dv.I4)
        r1, r2, r3 = self.r1, self.r2, self.r3
        # The connecting link's COM seen from D_i: r3 e(th3) - (l3/2) e(th3 + d), d = sigma delta3,
        # = rho3 e(th3) - kap3 n(th3) with rho3 = r3 - (l3/2) cos d, kap3 = (l3/2) sin d
        # (n(a) = e(a + pi/2)); on the centre lines rho3 = s + l3/2 (MODEL.md's r_dc), kap3 = 0.
        d = sig * self.delta3
        self.rho3 = r3 - (l3 / 2) * np.cos(d)
        self.kap3 = (l3 / 2) * np.sin(d)
        # Constant entries of each chain's 3x3 mass block (the drive link turns about A_i; its COM
        # distance l1/2 is unchanged by the offset delta1).
        self.M11 = m1 * (l1 / 2) ** 2 + I1 + (m2 + m3) * r1**2
        self.M22 = m2 * (r2 / 2) ** 2 + I2 + m3 * r2**2
        self.M33 = m3 * (self.rho3**2 + self.kap3**2) + I3
        self.mu12 = (m2 / 2 + m3) * r1 * r2
        self.a13, self.b13 = m3 * r1 * self.rho3, m3 * r1 * self.kap3
        self.a23, self.b23 = m3 * r2 * self.rho3, m3 * r2 * self.kap3
        # The 18 x 18 KKT template: constants once, the q-dependent entries written per call.
        T = np.zeros((self.nk, self.nk))
        for i in range(3):
            T[3 * i, 3 * i], T[3 * i + 1, 3 * i + 1], T[3 * i + 2, 3 * i + 2] = (
                self.M11, self.M22, self.M33)
            T[12 + 2 * i, 9] = T[9, 12 + 2 * i] = -1.0  # d g_ix / dx
            T[13 + 2 * i, 10] = T[10, 13 + 2 * i] = -1.0  # d g_iy / dy
        T[9, 9], T[10, 10], T[11, 11] = m4, m4, I4
        if angles is not None:
            for i in range(3):
                T[18 + i, 3 * i] = T[3 * i, 18 + i] = 1.0  # d (th_i1 - th_ai(t)) / d th_i1
        self.kkt0 = T
        # (row, column) of the 33 q-dependent entries in `_kkt`'s order: M12, M13, M23 per chain,
        # d g_ix / d th_ij, d g_iy / d th_ij (chain-major), d g_ix / d phi, d g_iy / d phi
        ch = np.arange(3)
        gq = (3 * ch[:, None] + np.arange(3)[None, :]).ravel()
        gx = np.repeat(12 + 2 * ch, 3)
        self.kr = np.concatenate([3 * ch, 3 * ch, 3 * ch + 1, gx, gx + 1, 12 + 2 * ch,
                                  13 + 2 * ch])
        self.kc = np.concatenate([3 * ch + 1, 3 * ch + 2, 3 * ch + 2, gq, gq, np.full(3, 11),
                                  np.full(3, 11)])
        self.rj = np.array([r1, r2, r3])[None, :, None]  # (1, 3 links, 1)
        self.jac_columns = 0  # right-hand side columns evaluated by `jac` (a counter)

    # -- kinematics -------------------------------------------------------------------------

    def constraints(self, q):
        """Loop-closure residuals g (3, 2, k) (m) at q (12, k)."""
        th = q[:9].reshape(3, 3, -1)
        rj = self.rj
        ex = self.A[:, 0, None] + np.sum(rj * np.cos(th), axis=1)
        ey = self.A[:, 1, None] + np.sum(rj * np.sin(th), axis=1)
        ap = BETA[:, None] + q[11]
        return np.stack([ex - q[9] - self.rhoE * np.cos(ap), ey - q[10] - self.rhoE * np.sin(ap)],
                        axis=1)

    def deflections(self, q):
        """Spring deflections (d_i1, d_i2) (3, 2, k) (rad)."""
        th = q[:9].reshape(3, 3, -1)
        return np.stack([th[:, 1] - th[:, 0] - self.rest1, th[:, 2] - th[:, 1] - self.rest2],
                        axis=1)

    def mass_matrix(self, q):
        """The 12 x 12 mass matrix M(q) (k, 12, 12) at q (12, k) (the KKT's upper-left block)."""
        return self._kkt(q[:9].reshape(3, 3, -1), q[11])[0][:, :12, :12]

    def _kkt(self, th, phi):
        """The KKT matrix (k, 18, 18) at chain angles th (3, 3, k) and platform angle phi (k,),
        and the trigonometric terms the right-hand side reuses. The 33 entries that depend on q
        (the chain blocks' off-diagonals, G's angle columns) are written by one indexed
        assignment per triangle into a copy of the constant template."""
        k = th.shape[2]
        c, s = np.cos(th), np.sin(th)
        c1, c2, c3 = c[:, 0], c[:, 1], c[:, 2]
        s1, s2, s3 = s[:, 0], s[:, 1], s[:, 2]
        C12, S12 = c1 * c2 + s1 * s2, s1 * c2 - c1 * s2  # cos, sin (th1 - th2)
        C13, S13 = c1 * c3 + s1 * s3, s1 * c3 - c1 * s3
        C23, S23 = c2 * c3 + s2 * s3, s2 * c3 - c2 * s3
        ap = BETA[:, None] + phi
        cp, sp = np.cos(ap), np.sin(ap)
        vals = np.empty((33, k))
        vals[0:3] = self.mu12 * C12  # M12
        vals[3:6] = self.a13 * C13 - self.b13 * S13  # M13 = m3 r1 A13
        vals[6:9] = self.a23 * C23 - self.b23 * S23  # M23 = m3 r2 A23
        rc, rs = self.rj * c, self.rj * s  # r_j e(th_ij) components
        vals[9:18] = -rs.reshape(9, k)  # d g_ix / d th_ij
        vals[18:27] = rc.reshape(9, k)  # d g_iy / d th_ij
        vals[27:30] = self.rhoE * sp  # d g_ix / d phi
        vals[30:33] = -self.rhoE * cp  # d g_iy / d phi
        KKT = np.repeat(self.kkt0[None], k, axis=0)
        v = vals.T
        KKT[:, self.kr, self.kc] = v
        KKT[:, self.kc, self.kr] = v
        H12 = self.mu12 * S12  # the velocity terms' coefficients (`rhs`)
        H13 = self.a13 * S13 + self.b13 * C13  # m3 r1 B13
        H23 = self.a23 * S23 + self.b23 * C23  # m3 r2 B23
        return KKT, c, s, rc, rs, cp, sp, H12, H13, H23

    def energy(self, y):
        """(kinetic, spring) energy (J) at states y (n,) or (n, k)."""
        Y = y.reshape(y.shape[0], -1)
        q, qd = Y[:12], Y[12:24]
        M = self.mass_matrix(q)
        T = 0.5 * np.einsum("ik,kij,jk->k", qd, M, qd)
        U = 0.5 * self.K * np.sum(self.deflections(q) ** 2, axis=(0, 1))
        return (T, U) if y.ndim == 2 else (T[0], U[0])

    # -- dynamics ---------------------------------------------------------------------------

    def rhs(self, t, y, return_tau=False):
        """y' = (q', q'') at time t for y (n,) or (n, k) (vectorised over the columns); with
        `return_tau`, also the actuator torques (3,) or (3, k) (N m).

        Per chain, with angles th1..th3, rates w1..w3 and the body COMs
          p1 = A + (l1/2) e(th1 - sigma delta1),  p2 = A + r1 e(th1) + (r2/2) e(th2),
          p3 = A + r1 e(th1) + r2 e(th2) + rho3 e(th3) - kap3 n(th3),
        T = sum m |p'|^2/2 + I w^2/2 gives M_jk = sum_b m_b (dp_b/dth_j).(dp_b/dth_k) + I:
          M11 = m1 (l1/2)^2 + I1 + (m2 + m3) r1^2, M22 = m2 (r2/2)^2 + I2 + m3 r2^2,
          M33 = m3 (rho3^2 + kap3^2) + I3, M12 = (m2/2 + m3) r1 r2 cos(th1 - th2),
          M13 = m3 r1 A13, M23 = m3 r2 A23, A_j3 = rho3 cos(th_j - th3) - kap3 sin(th_j - th3),
        and the velocity terms h_j = sum_b m_b (dp_b/dth_j).(p_b'' at zero q''):
          h1 = mu12 sin(th1 - th2) w2^2 + m3 r1 B13 w3^2,
          h2 = -mu12 sin(th1 - th2) w1^2 + m3 r2 B23 w3^2,
          h3 = -m3 r1 B13 w1^2 - m3 r2 B23 w2^2,  B_j3 = rho3 sin(th_j - th3) + kap3 cos(th_j - th3)
        (the platform's M = diag(m4, m4, I4), h = 0; its COM is the pose). The constraint rows:
          G q'' = sum_j r_j w_j^2 e(th_j) - rho_E phi'^2 e(beta + phi) - 2 alpha G q' - alpha^2 g,
        g = A + sum_j r_j e(th_j) - (x, y) - rho_E e(beta + phi), G q' = sum_j r_j w_j n(th_j)
        - (x', y') - rho_E phi' n(beta + phi), collected per term below.
        """
        vec = y.ndim == 2
        Y = y if vec else y[:, None]
        k = Y.shape[1]
        th = Y[:9].reshape(3, 3, k)
        w = Y[12:21].reshape(3, 3, k)
        KKT, c, s, rc, rs, cp, sp, H12, H13, H23 = self._kkt(th, Y[11])
        w1, w2, w3 = w[:, 0], w[:, 1], w[:, 2]
        w1s = w1 * w1
        tau = np.zeros((3, 1)) if self.angles is not None else self.torque(t)[:, None]
        b = np.zeros((self.nk, k))
        b[:9] = self._chain_forces(th, w, tau, H12, H13, H23)
        # constraint rows: sum_j r_j [(w_j^2 - al^2) e(th_j) - 2 al w_j n(th_j)]
        #   - rho_E [(phi'^2 - al^2) e(beta + phi) - 2 al phi' n(beta + phi)]
        #   + 2 al (x', y') + al^2 ((x, y) - A)
        al = self.alpha
        u, v = w * w - al * al, 2 * al * w
        px = u * rc + v * rs
        py = u * rs - v * rc
        wp = Y[23]
        up, vp = self.rhoE * (wp * wp - al * al), 2 * al * self.rhoE * wp
        b[12:18:2] = (px[:, 0] + px[:, 1] + px[:, 2] - up * cp - vp * sp
                    + 2 * al * Y[21] + al * al * (Y[9] - self.A[:, 0, None]))
        b[13:18:2] = (py[:, 0] + py[:, 1] + py[:, 2] - up * sp + vp * cp
                    + 2 * al * Y[22] + al * al * (Y[10] - self.A[:, 1, None]))
        if self.angles is not None:
            # th_i1'' = th_a'' - 2 al (th_i1' - th_a') - al^2 (th_i1 - sigma delta1 - th_a)
            tha, thad, thadd = (np.asarray(v, float)[:, None] for v in self.angles(t))
            b[18:21] = (thadd - 2 * al * (w1 - thad)
                        - al * al * (th[:, 0] - self.sigma * self.delta1 - tha))
        if k == 1:
            sol = np.linalg.solve(KKT[0], b)
        else:
            sol = np.linalg.solve(KKT, b.T[:, :, None])[:, :, 0].T
        out = np.empty((self.n, k))
        out[:12] = Y[12:24]
        out[12:24] = sol[:12]
        if self.angles is not None:
            tau = -sol[18:21]  # the reaction torques: M q'' = Q - h - G^T lambda
        if self.with_work:
            out[24] = (np.sum(tau * w1, axis=0) - self.c_a * np.sum(w1s, axis=0)
                       - self.c_s * np.sum((w2 - w1) ** 2 + (w3 - w2) ** 2, axis=0))
        if return_tau:  # the actuator torques too (applied, or the reactions)
            tau = np.broadcast_to(tau, (3, k))
            return (out, tau) if vec else (out[:, 0], tau[:, 0])
        return out if vec else out[:, 0]

    def _chain_forces(self, th, w, tau, H12, H13, H23):
        """The chains' rows (9, k) of Q - h: the springs, their damping, the actuator torques
        tau (3, 1 or k) and friction, less the velocity terms (`rhs`'s docstring); the
        platform's rows are zero."""
        w1, w2, w3 = w[:, 0], w[:, 1], w[:, 2]
        w1s, w2s, w3s = w1 * w1, w2 * w2, w3 * w3
        f1 = self.K * (th[:, 1] - th[:, 0] - self.rest1)  # spring moment of pivot 1 (N m)
        f2 = self.K * (th[:, 2] - th[:, 1] - self.rest2)
        if self.c_s:
            f1 = f1 + self.c_s * (w2 - w1)
            f2 = f2 + self.c_s * (w3 - w2)
        b = np.zeros((9, th.shape[2]))
        b[0:9:3] = f1 + tau - H12 * w2s - H13 * w3s
        if self.c_a:
            b[0:9:3] -= self.c_a * w1
        b[1:9:3] = f2 - f1 + H12 * w1s - H23 * w3s
        b[2:9:3] = H13 * w1s + H23 * w2s - f2
        return b

    def jac(self, t, y):
        """d y'/d y (n, n) by forward differences, all columns in one vectorised call (module
        docstring)."""
        n = y.shape[0]
        hstep = FD_REL * np.maximum(np.abs(y), 1.0)
        Y = np.empty((n, n + 1))
        Y[:, 0] = y
        Y[:, 1:] = y[:, None] + np.diag(hstep)
        hstep = np.diag(Y[:, 1:]) - y  # the steps as represented
        F = self.rhs(t, Y)
        self.jac_columns += n + 1
        return (F[:, 1:] - F[:, :1]) / hstep[None, :]

    # -- initial state ----------------------------------------------------------------------

    def state_from_library(self, z, zdot):
        """State y (n,) from the library's coordinates z = (x, y, phi, th_a1..3) and rates:
        th_i1 = th_ai + sigma delta1; th_i2, th_i3 close each chain from B_i to E_i (two links
        r2, r3, elbow branch sign(th_i3 - th_i2) = sigma, angles kept within pi of th_i1);
        th_i2', th_i3' from the closure's velocity equations (2 x 2 per chain)."""
        z, zdot = np.asarray(z, float), np.asarray(zdot, float)
        X, Xd = z[:3], zdot[:3]
        th1 = z[3:] + self.sigma * self.delta1
        w1 = zdot[3:]
        e = lambda a: np.stack([np.cos(a), np.sin(a)], axis=-1)  # noqa: E731
        nrm = lambda a: np.stack([-np.sin(a), np.cos(a)], axis=-1)  # noqa: E731
        ap = BETA + X[2]
        E = X[:2] + self.rhoE * e(ap)
        dvec = E - (self.A + self.r1 * e(th1))
        dd = np.sum(dvec**2, axis=-1)
        cosd = (dd - self.r2**2 - self.r3**2) / (2 * self.r2 * self.r3)
        if np.any(np.abs(cosd) >= 1):
            raise ValueError("initial pose out of reach of a chain")
        delta = self.sigma * np.arccos(cosd)
        th2 = np.arctan2(dvec[:, 1], dvec[:, 0]) - np.arctan2(
            self.r3 * np.sin(delta), self.r2 + self.r3 * np.cos(delta))
        th2 = th1 + np.angle(np.exp(1j * (th2 - th1)))
        th3 = th2 + delta
        vE = Xd[:2] + self.rhoE * Xd[2] * nrm(ap)
        w2 = np.empty(3)
        w3 = np.empty(3)
        for i in range(3):
            Mi = np.stack([self.r2 * nrm(th2[i]), self.r3 * nrm(th3[i])], axis=-1)
            w2[i], w3[i] = np.linalg.solve(Mi, vE[i] - self.r1 * w1[i] * nrm(th1[i]))
        q = np.concatenate([np.stack([th1, th2, th3], axis=1).ravel(), X])
        qd = np.concatenate([np.stack([w1, w2, w3], axis=1).ravel(), Xd])
        y = np.concatenate([q, qd] + ([np.zeros(1)] if self.with_work else []))
        return y


    def accelerations(self, q, qd, tha_dd, Xdd):
        """q'' (12,) at positions q (12,) and rates qd (12,) for the actuated angles'
        accelerations tha_dd (3,) and the platform's Xdd (3,): th_i2'', th_i3'' from each chain's
        closure differentiated twice, sum_j r_j (th_j'' n(th_j) - th_j'^2 e(th_j)) = E_i''."""
        e = lambda a: np.array([np.cos(a), np.sin(a)])  # noqa: E731
        nrm = lambda a: np.array([-np.sin(a), np.cos(a)])  # noqa: E731
        th, w = q[:9].reshape(3, 3), qd[:9].reshape(3, 3)
        r = (self.r1, self.r2, self.r3)
        qdd = np.zeros(12)
        qdd[9:] = Xdd
        for i in range(3):
            ap = BETA[i] + q[11]
            Edd = Xdd[:2] + self.rhoE * (Xdd[2] * nrm(ap) - qd[11] ** 2 * e(ap))
            rhs = (Edd - r[0] * tha_dd[i] * nrm(th[i, 0])
                   + sum(r[j] * w[i, j] ** 2 * e(th[i, j]) for j in range(3)))
            Mi = np.stack([r[1] * nrm(th[i, 1]), r[2] * nrm(th[i, 2])], axis=-1)
            qdd[3 * i] = tha_dd[i]
            qdd[3 * i + 1:3 * i + 3] = np.linalg.solve(Mi, rhs)
        return qdd

    def actuated_balance(self, tha, tha_d, tha_dd, X, Xd, Xdd, tau):
        """The balance of the actuated coordinates (3,) (N m) with the platform's motion
        (X, Xd, Xdd) (3,) each given: the equations of motion M q'' + h = Q projected on the
        three directions dq/dth_ai in which the actuated angles move with the pose held (the
        chain's other angles following its closure), at the actuated angles tha (3,), their rates
        tha_d and accelerations tha_dd (the rates of the path whose balance is sought, MODEL.md
        section 6), under the torques tau (3,). The constraint forces do no work along these
        directions, so the multipliers drop out."""
        z = np.concatenate([X, tha])
        y = self.state_from_library(z, np.concatenate([Xd, tha_d]))
        q, qd = y[:12], y[12:24]
        qdd = self.accelerations(q, qd, tha_dd, Xdd)
        KKT, c, s, rc, rs, cp, sp, H12, H13, H23 = self._kkt(q[:9].reshape(3, 3, 1), q[11:12])
        f = self._chain_forces(q[:9].reshape(3, 3, 1), qd[:9].reshape(3, 3, 1),
                               np.asarray(tau, float)[:, None], H12, H13, H23)[:, 0]
        r = KKT[0, :12, :12] @ qdd - np.concatenate([f, np.zeros(3)])
        # the directions: th_i1 moves by 1, th_i2 and th_i3 close the chain with E_i held
        nrm = lambda a: np.array([-np.sin(a), np.cos(a)])  # noqa: E731
        th = q[:9].reshape(3, 3)
        out = np.empty(3)
        for i in range(3):
            Mi = np.stack([self.r2 * nrm(th[i, 1]), self.r3 * nrm(th[i, 2])], axis=-1)
            v23 = np.linalg.solve(Mi, -self.r1 * nrm(th[i, 0]))
            out[i] = r[3 * i] + v23 @ r[3 * i + 1:3 * i + 3]
        return out

    def l1_angles(self, X):
        """The actuated angles (3,) (rad) of L1's closed-form inverse kinematics at the pose X
        (MODEL.md section 4: d_i1 = d_i2, so th_i2 = u and (2 r1 cos v + r2) e(u) = E_i - A_i
        with th_i1 = u - v, th_i3 = u + v; r1 = r3 required)."""
        if abs(self.r1 - self.r3) > 1e-12 * self.r1:
            raise ValueError("the closed-form L1 inverse kinematics needs r1 == r3")
        ap = BETA + X[2]
        d = X[:2] + self.rhoE * np.stack([np.cos(ap), np.sin(ap)], axis=-1) - self.A
        u = np.arctan2(d[:, 1], d[:, 0])
        v = self.sigma * np.arccos((np.hypot(d[:, 0], d[:, 1]) - self.r2) / (2 * self.r1))
        return u - v - self.sigma * self.delta1


#: time step (s) of the 5-point central differences that give a quasi-static path's rates and
#: accelerations (truncation (omega h)^4/30, below 1e-9 for the scenes' motions; rounding of the
#: 1e-14 rad balances over h^2: 1e-9 rad/s^2)
QS_H = 4e-3
#: the 5-point central-difference weights of the first and second derivative (unit step)
_D1 = np.array([1.0, -8.0, 0.0, 8.0, -1.0]) / 12.0
_D2 = np.array([-1.0, 16.0, -30.0, 16.0, -1.0]) / 12.0


def _newton(fun, x, t, tol=1e-14, max_iter=50):
    """Newton's iteration for fun(x) = 0 (3,) from x, the Jacobian by central differences
    (step 1e-7 rad: truncation 1e-14, rounding 1e-9 relative), until a step is below tol rad."""
    for _ in range(max_iter):
        J = np.stack([(fun(x + d) - fun(x - d)) / 2e-7 for d in 1e-7 * np.eye(x.size)], axis=1)
        dx = np.linalg.solve(J, -fun(x))
        x = x + dx
        if np.max(np.abs(dx)) < tol:
            return x
    raise RuntimeError(f"quasi-static balance not found at t = {t} (Newton did not converge)")


def quasi_static_start(model, pose, torque, t0=0.0, passes=2, h=QS_H):
    """The torque-driven start of MODEL.md section 6 in this formulation: the platform at its
    nominal pose and rate at t0, the actuated angles in quasi-static balance.

    `model`: an `L2Model`; `pose`: t -> (X, X', X'') (3,) each, the nominal path and its
    derivatives (m, m, rad and their rates); `torque`: t -> (3,) (N m); `passes`: 2 (the
    scenes' start) balances the actuated angles at the rates and accelerations of their own
    quasi-static path: pass 1 at those of L1's inverse kinematics of the path (`l1_angles`),
    pass 2 at pass 1's own (5-point central differences of step h). 1: pass 1 alone. 0: a
    plain static start, the balance with the actuated angles at rest (zero rates and
    accelerations) and their rate L1's. The rate returned is the time derivative of the last
    pass's path (L1's for passes = 0).

    Independent of the library's statics (its `quasi_static_state` balances in its reduced
    coordinates with a quartic through five solutions at 5 ms); the shared inputs are the path
    and the torques.

    Returns (z0, z0') (6,) each in the library's coordinates (x, y, phi, th_a1..3)."""
    memo = {}

    def ref_rates(t):
        th = np.array([model.l1_angles(pose(t + k * h)[0]) for k in range(-2, 3)])
        return _D1 @ th / h, _D2 @ th / h**2

    def solve(t, n):
        """The balance of pass n at time t (n = 0: L1's angles)."""
        key = (n, round(t / h))
        if key in memo:
            return memo[key]
        X, Xd, Xdd = pose(t)
        guess = model.l1_angles(X)
        if n == 0:
            memo[key] = guess
            return guess
        if passes == 0:
            rates = (np.zeros(3), np.zeros(3))
        elif n == 1:
            rates = ref_rates(t)
        else:
            th = np.array([solve(t + k * h, n - 1) for k in range(-2, 3)])
            rates = (_D1 @ th / h, _D2 @ th / h**2)
        tau = np.asarray(torque(t), float)
        memo[key] = _newton(lambda a: model.actuated_balance(a, *rates, X, Xd, Xdd, tau),
                            guess, t)
        return memo[key]

    n = max(int(passes), 1)
    tha = solve(t0, n)
    if passes == 0:
        tha_d = ref_rates(t0)[0]
    else:
        tha_d = _D1 @ np.array([solve(t0 + k * h, n) for k in range(-2, 3)]) / h
    X, Xd, _ = pose(t0)
    return np.concatenate([X, tha]), np.concatenate([Xd, tha_d])


def scene_metrics(params, path=None, *, t_end=7.54, n_out=755, passes=2, rtol=1e-11,
                  atol=1e-13, torque=None):
    """The scene metrics of MODEL.md section 6 for L2 under L1's torques along `path` (default
    eq 55's circle, `paper-circle`), from this formulation's own start (`quasi_static_start`
    with `passes`) and a DOP853 run with output at t_end k / (n_out - 1).

    Returns {metric: value} in `ppr_jax`'s names and units: the radial errors (a circle: `path`
    None or with `center` and `radius`), the position and phi errors against the path (max,
    RMS, end), chain 1's joint end-rotation difference d_11 - d_12 (deg; max, min, mean), and
    "start": (z0, z0')."""
    import ppr_jax as pj

    from . import library

    circle = path is None or hasattr(path, "radius")
    path = pj.Circle() if path is None else path
    if torque is None:
        torque = scene_torque(params, t_end, path=path)[0]
    pose = library.pose_derivatives(path)
    model = L2Model(params, torque)
    z0, zd0 = quasi_static_start(model, pose, torque, 0.0, passes=passes)
    t_eval = t_end * np.arange(n_out) / (n_out - 1)
    sol = simulate(model, model.state_from_library(z0, zd0), t_eval, "DOP853", rtol, atol)
    if sol.status != 0:
        raise RuntimeError(f"solve_ivp failed: {sol.message}")
    X = sol.y[9:12].T
    Xn = np.array([pose(t)[0] for t in t_eval])
    d = model.deflections(sol.y[:12])  # (3, 2, n)
    diff = np.degrees(d[0, 0] - d[0, 1])
    dpos = np.hypot(*(X[:, :2] - Xn[:, :2]).T)
    dphi = X[:, 2] - Xn[:, 2]
    out = dict(
        position_error_max_m=dpos.max(), position_error_rms_m=np.sqrt(np.mean(dpos**2)),
        position_error_end_m=dpos[-1], phi_error_max_rad=np.abs(dphi).max(),
        phi_error_rms_rad=np.sqrt(np.mean(dphi**2)), phi_error_end_rad=abs(dphi[-1]),
        end_rotation_diff_max_deg=diff.max(), end_rotation_diff_min_deg=diff.min(),
        end_rotation_diff_mean_deg=diff.mean(),
    )
    if circle:
        c, R = np.asarray(path.center), float(path.radius)
        er = np.hypot(X[:, 0] - c[0], X[:, 1] - c[1]) - R
        out.update(radial_error_max_m=er.max(), radial_error_min_m=er.min(),
                   radial_error_mean_m=er.mean())
    out = {k: float(v) for k, v in out.items()}
    out["start"] = (z0, zd0)
    return out


# ---------------------------------------------------------------------------------------------
# The contender
# ---------------------------------------------------------------------------------------------


def simulate(model, y0, t_eval, method, rtol, atol):
    """One `solve_ivp` run of `model` from y0 over [0, t_eval[-1]], output at t_eval."""
    kw = {}
    if METHODS[method]:
        kw["jac"] = model.jac
    model.jac_columns = 0
    return solve_ivp(model.rhs, (0.0, float(t_eval[-1])), y0, method=method, t_eval=t_eval,
                     rtol=rtol, atol=atol, **kw)


def run(scene_params, *, method="DOP853", rtol=1e-8, atol=1e-10, t_end=7.54, n_out=755,
        repeats=3, z0=None, zdot0=None, torque=None, alpha=BAUMGARTE_ALPHA):
    """The `paper-circle` scene of L2 with `scipy.integrate.solve_ivp`.

    `scene_params`: `ppr_jax.scene_params("paper-circle")` or any `RobotParams`; `method`:
    "DOP853" (explicit, order 8), "Radau" (implicit, order 5) or "LSODA" (Adams/BDF switching),
    the latter two with the finite-difference Jacobian of `L2Model.jac`; `rtol`, `atol`: scipy's
    tolerances on the 24 states (angles in rad, positions in m, rates per s; defaults as the
    library's scene); `z0, zdot0`: the initial state in the library's coordinates (default: the
    library's L2 quasi-static state, one JAX compilation of ~20 s); `torque`: a callable
    t -> (3,) torques (N m) to use instead of tabulating the scene's (one JAX compilation of
    ~7 s), e.g. `TorqueSpline(ts, taus)` of the scene's torques already at hand on a grid;
    `alpha`: Baumgarte rate.

    Returns {"t": (n_out,) output times t_end k/(n_out - 1) (s), "X": (n_out, 3) platform pose
    (x, y, phi) (m, m, rad), "run_s": fastest of `repeats` timed runs after one warm-up (s,
    `time.perf_counter`), "nfev": right-hand side calls counted by scipy (one per state, the
    Jacobian's finite differences excluded), "nfev_jac": right-hand side columns evaluated by the
    finite-difference Jacobian (0 for DOP853), "njev": Jacobian evaluations, "includes": what the
    timed part includes, "residual": largest loop-closure residual at the output times (m),
    "torque_spline_max_err": largest error of the torque spline (N m; None for a given
    `torque`), "status", "message", "method", "rtol", "atol", "alpha"}.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    tq_err = None
    if torque is None:
        torque, tq_err = scene_torque(scene_params, t_end)
    if z0 is None or zdot0 is None:
        z0, zdot0 = library_initial_state(scene_params)
    model = L2Model(scene_params, torque, alpha=alpha)
    y0 = model.state_from_library(z0, zdot0)
    t_eval = t_end * np.arange(n_out) / (n_out - 1)
    simulate(model, y0, t_eval, method, rtol, atol)  # warm-up
    times = []
    for _ in range(max(int(repeats), 1)):
        t0 = time.perf_counter()
        sol = simulate(model, y0, t_eval, method, rtol, atol)
        times.append(time.perf_counter() - t0)
    Y = sol.y
    ok = sol.status == 0 and Y.shape[1] == n_out
    residual = float(np.max(np.linalg.norm(model.constraints(Y[:12]), axis=1))) if ok else np.nan
    return {
        "t": t_eval,
        "X": Y[9:12].T.copy() if ok else np.full((n_out, 3), np.nan),
        "run_s": min(times),
        "nfev": int(sol.nfev),
        "nfev_jac": int(model.jac_columns),
        "njev": int(sol.njev),
        "includes": (
            "one scipy.integrate.solve_ivp call from the consistent initial state in absolute "
            "coordinates to t_end with output at the n_out times (NumPy right-hand side with the "
            "torque spline, the finite-difference Jacobian for the implicit methods); not the "
            "one-time torque tabulation in JAX, the library's initial state or the model setup"
        ),
        "residual": residual,
        "torque_spline_max_err": tq_err,
        "status": int(sol.status),
        "message": str(sol.message),
        "method": method,
        "rtol": rtol,
        "atol": atol,
        "alpha": float(alpha),
    }
