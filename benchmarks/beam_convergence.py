"""Convergence of the L3 `beam` model in the number of elements N.

1. Single strip vs the elastica (`ppr_jax.elastica.solve_cantilever`): the robot's strip
   (L = r theta_c, kappa0 = theta_c, EI = E w t^3/12, t = 0.3 mm) under a combined end load
   F L^2/EI = 2.5, m L/EI = 0.5; tip position, tip angle and shape (node) errors for
   N = 4 .. 64 and the observed order log2(e_N / e_2N).
2. The robot at home, actuators locked at L1's inverse-kinematics angles: static equilibrium
   (platform rotation phi_eq and compliance under a platform wrench) and the lowest locked and
   free natural frequencies for N = 4, 8, 16, 32, beside L2 (`double1r`); observed order from
   three successive N (Richardson: log2((f_N - f_N/2)/(f_2N - f_N))).
3. Optional (--paper-circle T): paper-circle of L3 (N = 4, 8) torque-driven by L1's inverse
   dynamics torques from the quasi-static state over [0, T] with Kvaerno5, radial-error metrics.

Writes benchmarks/results/beam_convergence.json and .png. Run: python benchmarks/beam_convergence.py
"""

from __future__ import annotations

import argparse
import json
import pathlib
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import ppr_jax as pj
from ppr_jax._models.beam import Beam, solve_strip, strip_constants
from ppr_jax.elastica import solve_cantilever

OUT = pathlib.Path(__file__).parent / "results"
WRENCH = jnp.array([0.4, -0.3, 0.004])  # N, N, N m


def strip_vs_elastica(params, Ns=(4, 8, 16, 32, 64)):
    sc = strip_constants(params, 1)
    L, EI, k0 = params.r * params.theta_c, sc.EI, params.theta_c
    F, M = jnp.array([-1.5, 2.0]) * EI / L**2, 0.5 * EI / L
    n_nodes = 2 * max(Ns) + 1
    ela = solve_cantilever(L, EI, k0, F, M, n_nodes=n_nodes, substeps=4)
    rows = []
    shapes = {}
    for N in Ns:
        s = solve_strip(L, EI, k0, F, M, n_elements=N)
        idx = np.arange(0, n_nodes, (n_nodes - 1) // N)
        rows.append(dict(
            N=N,
            tip_position_error_rel_L=float(
                np.hypot(*(np.asarray(s.tip[:2]) - np.asarray(ela.tip[:2]))) / L),
            tip_angle_error_rad=float(abs(s.tip[2] - ela.tip_angle)),
            shape_error_max_rel_L=float(np.max(np.hypot(s.x - ela.x[idx], s.y - ela.y[idx])) / L),
        ))
        shapes[N] = (np.asarray(s.x), np.asarray(s.y))
    for key in ("tip_position_error_rel_L", "tip_angle_error_rad", "shape_error_max_rel_L"):
        for a, b in zip(rows[:-1], rows[1:]):
            b[f"order_{key}"] = float(np.log2(a[key] / b[key]))
    return dict(
        load=dict(F_L2_over_EI=[-1.5, 2.0], m_L_over_EI=0.5, L_m=float(L), EI_Nm2=float(EI),
                  kappa0=float(k0)),
        elastica_tip=[float(v) for v in ela.tip], rows=rows,
    ), (np.asarray(ela.x), np.asarray(ela.y)), shapes


def richardson(vals):
    """Observed orders from successive values at N, 2N, 4N."""
    v = np.asarray(vals)
    return [float(np.log2(abs((v[i + 1] - v[i]) / (v[i + 2] - v[i + 1]))))
            for i in range(len(v) - 2)]


def robot(params, Ns=(4, 8, 16, 32)):
    robot = pj.Robot(params)
    X = pj.home_pose(params)
    stat = eqx.filter_jit(
        lambda m, p, z, w: pj.static_equilibrium(m, p, z, locked=True, wrench=w)[0]
    )
    res = {}
    for name, m in [("double1r", pj.Double1R())] + [(f"beam{N}", Beam(N)) for N in Ns]:
        t0 = time.perf_counter()
        z = m.coords_from_pose(robot, X)
        z0 = stat(m, params, z, jnp.zeros(3))
        zw = stat(m, params, z0, WRENCH)
        ml = pj.modes(m, params, actuators="locked")
        mf = pj.modes(m, params, actuators="free")
        jax.block_until_ready((ml.freq_hz, mf.freq_hz))
        res[name] = dict(
            phi_eq_rad=float(z0[2]),
            displacement_under_wrench=[float(v) for v in (zw[:3] - z0[:3])],
            locked_hz=[float(f) for f in np.asarray(ml.freq_hz)[:6]],
            free_hz=[float(f) for f in np.asarray(mf.freq_hz)[:6]],
            highest_locked_hz=float(np.asarray(ml.freq_hz)[-1]),
            wall_s=time.perf_counter() - t0,
        )
        print(name, res[name], flush=True)
    beams = [res[f"beam{N}"] for N in Ns]
    orders = dict(
        phi_eq=richardson([b["phi_eq_rad"] for b in beams]),
        displacement_x=richardson([b["displacement_under_wrench"][0] for b in beams]),
        locked_hz=[richardson([b["locked_hz"][j] for b in beams]) for j in range(3)],
        free_hz=[richardson([b["free_hz"][j] for b in beams]) for j in range(4)],
    )
    return dict(wrench=[float(v) for v in WRENCH], models=res, observed_orders=orders, Ns=list(Ns))


def paper_circle_metrics(params, t_end, Ns=(4, 8)):
    out_all = {}
    for N in Ns:
        t0 = time.perf_counter()
        r = pj.run_scene(
            "paper-circle",
            params,
            model=Beam(N),
            options=pj.SceneOptions(
                solver="kvaerno5",
                rtol=1e-8,
                atol=1e-10,
                t_end=t_end,
                n_out=int(round(t_end * 100)) + 1,
            ),
        )
        mt = dict(r.metrics, result=str(r.result.result),
                  wall_incl_compile_s=time.perf_counter() - t0)
        out_all[f"beam{N}"] = mt
        print(N, mt, flush=True)
    return dict(t_end_s=t_end, solver="kvaerno5 rtol 1e-8 atol 1e-10", metrics=out_all)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paper-circle", type=float, default=0.0,
                    help="also run paper-circle for N = 4, 8 over [0, T] s (slow)")
    ap.add_argument("--max-n", type=int, default=32, help="largest N of the robot study")
    args = ap.parse_args()
    OUT.mkdir(parents=True, exist_ok=True)
    params = pj.RobotParams()
    t0 = time.perf_counter()
    strip, ela_xy, shapes = strip_vs_elastica(params)
    print(json.dumps(strip, indent=1), flush=True)
    Ns = tuple(n for n in (4, 8, 16, 32) if n <= args.max_n)
    rob = robot(params, Ns)
    result = dict(strip_vs_elastica=strip, robot_home_locked=rob, device=str(jax.devices()[0]))
    if args.paper_circle > 0:
        result["paper_circle"] = paper_circle_metrics(params, args.paper_circle)
    result["total_wall_s"] = time.perf_counter() - t0
    (OUT / "beam_convergence.json").write_text(json.dumps(result, indent=1))

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(15, 4.5))
    rows = strip["rows"]
    n = [r["N"] for r in rows]
    for key, lab in [("tip_position_error_rel_L", "tip position / L"),
                     ("tip_angle_error_rad", "tip angle (rad)"),
                     ("shape_error_max_rel_L", "max node position / L")]:
        ax[0].loglog(n, [r[key] for r in rows], "o-", label=lab)
    ax[0].loglog(n, [rows[0]["tip_position_error_rel_L"] * (n[0] / k) ** 2 for k in n], "k--",
                 label="O(1/N^2)")
    ax[0].set_xlabel("elements N")
    ax[0].set_ylabel("error vs elastica")
    ax[0].legend()
    ax[0].set_title("discrete strip vs elastica")
    ax[1].plot(*ela_xy, "k-", lw=3, alpha=0.3, label="elastica")
    for N, (x, y) in shapes.items():
        ax[1].plot(x, y, ".-", label=f"N={N}")
    ax[1].set_aspect("equal")
    ax[1].legend(fontsize=7)
    ax[1].set_title("deformed strip (clamp frame)")
    models = rob["models"]
    for j in range(3):
        ax[2].semilogx(Ns, [models[f"beam{N}"]["locked_hz"][j] for N in Ns], "o-",
                       label=f"L3 locked mode {j + 1}")
        ax[2].axhline(models["double1r"]["locked_hz"][j], ls=":", color=f"C{j}")
    ax[2].set_xlabel("elements N")
    ax[2].set_ylabel("Hz")
    ax[2].set_title("locked modes at home (dotted: L2)")
    ax[2].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(OUT / "beam_convergence.png", dpi=110)
    print("wrote", OUT / "beam_convergence.json", "in", result["total_wall_s"], "s")


if __name__ == "__main__":
    main()
