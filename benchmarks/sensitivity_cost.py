"""Cost of a derivative through the scene against the forward run: L1 `paper-circle`.

L1 runs under the rigid model's (L0's) torques, the paper's "simplified model", so that its
radial error is the two models' difference; under its own torques L1 would follow the circle
to the solver's tolerance and the scalar would be the integrator's error.

The scalar is the radial error's minimum over the run (`radial_error_min_m`) as a function of
every float parameter (19). Timed (each after `block_until_ready`, minimum of `--repeats`, after
a first call that compiles): the plain metric (forward run), one `jax.jvp` (one tangent, with
`diffrax.ForwardMode()`), the full forward Jacobian (`jax.jacfwd`, 19 tangents in one vmapped
pass) and `jax.grad` (reverse mode, `RecursiveCheckpointAdjoint` with diffrax's default number
of checkpoints and with the given `--checkpoints`). Memory: XLA's `memory_analysis()` of each
compiled program (temporary buffers, bytes). Writes benchmarks/results/sensitivity_cost.json.

Run: python benchmarks/sensitivity_cost.py [--model reduced] [--t-end 7.54] [--checkpoints 64 4096]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import diffrax
import jax
import jax.numpy as jnp

from ppr_jax._studies import metric_function

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")


def _compile(fn, x):
    """(compile time (s), compiled program): one compilation, reused for timing and memory."""
    t0 = time.perf_counter()
    compiled = fn.lower(x).compile()
    return time.perf_counter() - t0, compiled


def _run_time(compiled, x, repeats):
    jax.block_until_ready(compiled(x))
    runs = []
    for _ in range(repeats):
        t1 = time.perf_counter()
        jax.block_until_ready(compiled(x))
        runs.append(time.perf_counter() - t1)
    return min(runs)


def _memory(compiled):
    try:
        m = compiled.memory_analysis()
        return {"temp_bytes": int(m.temp_size_in_bytes),
                "argument_bytes": int(m.argument_size_in_bytes),
                "output_bytes": int(m.output_size_in_bytes)}
    except Exception as err:  # noqa: BLE001 (not every backend reports it)
        return {"error": str(err)}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="reduced")
    ap.add_argument("--torque-model", default="rigid",
                    help="the model whose inverse dynamics gives the torques (not --model "
                         "itself: a model under its own torques follows the circle exactly)")
    ap.add_argument("--t-end", type=float, default=7.54)
    ap.add_argument("--n-out", type=int, default=755)
    ap.add_argument("--rtol", type=float, default=1e-8)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--checkpoints", type=int, nargs="*", default=[])
    ap.add_argument("--skip-jacfwd", action="store_true")
    ap.add_argument("--backsolve", action="store_true",
                    help="also try diffrax.BacksolveAdjoint (continuous adjoint; JAX refuses it "
                         "here: custom_vjp of closed-over parameters, recorded as refused)")
    ap.add_argument("--out", default="sensitivity_cost.json",
                    help="file name under benchmarks/results/")
    ap.add_argument("--only-grad", action="store_true",
                    help="forward run and reverse-mode variants only (no jvp)")
    args = ap.parse_args()
    os.makedirs(OUT, exist_ok=True)
    f, x0, names = metric_function("paper-circle", model=args.model,
                                   torque_model=args.torque_model, t_end=args.t_end,
                                   n_out=args.n_out, rtol=args.rtol, atol=args.rtol * 1e-2,
                                   metrics=("radial_error_min_m",))
    out = {"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
           "jax": jax.__version__, "diffrax": diffrax.__version__,
           "backend": jax.default_backend(), "model": args.model,
           "torque_model": args.torque_model, "t_end_s": args.t_end,
           "n_out": args.n_out, "rtol": args.rtol, "n_parameters": len(names),
           "scalar": "radial_error_min_m", "rows": {}}
    path = os.path.join(OUT, args.out)

    def write():
        with open(path, "w") as fh:
            json.dump(out, fh, indent=2)

    def record(name, fn):
        try:
            c, compiled = _compile(fn, x0)
        except Exception as err:  # noqa: BLE001 (an adjoint JAX refuses: say so, go on)
            out["rows"][name] = {"refused": str(err).strip().splitlines()[0]}
            print(name, "refused:", out["rows"][name]["refused"], flush=True)
            return write()
        r = _run_time(compiled, x0, args.repeats)
        out["rows"][name] = {"compile_s": c, "run_s": r, "memory": _memory(compiled)}
        base = out["rows"].get("forward_run")
        if base:
            out["rows"][name]["ratio_to_forward_run"] = r / base["run_s"]
        print(name, json.dumps(out["rows"][name]), flush=True)
        write()

    tangent = jnp.zeros_like(x0).at[names.index("t")].set(x0[names.index("t")])
    record("forward_run", jax.jit(lambda x: f(x)[0]))
    if not args.only_grad:
        record("jvp_one_tangent", jax.jit(
            lambda x: jax.jvp(lambda y: f(y, diffrax.ForwardMode())[0], (x,), (tangent,))[1]))
    record("grad_checkpoints_default", jax.jit(jax.grad(lambda x: f(x)[0])))
    for c in args.checkpoints:
        adj = diffrax.RecursiveCheckpointAdjoint(checkpoints=c)
        record(f"grad_checkpoints_{c}", jax.jit(jax.grad(lambda x, adj=adj: f(x, adj)[0])))
    if args.backsolve:
        adj = diffrax.BacksolveAdjoint(solver=diffrax.Tsit5())
        record("grad_backsolve", jax.jit(jax.grad(lambda x: f(x, adj)[0])))
    if not args.skip_jacfwd and not args.only_grad:
        record("jacfwd_all_parameters", jax.jit(
            jax.jacfwd(lambda x: f(x, diffrax.ForwardMode())[0])))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
