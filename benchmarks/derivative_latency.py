"""What a user waits for before a derivative's first answer, in fresh processes: the gradient of
docs/getting_started.md, a forward- and a reverse-mode sensitivity and `modes`; one checkout, or
two side by side.

    python benchmarks/derivative_latency.py [--quick]                      # this checkout
    python benchmarks/derivative_latency.py --base ../old --new . [--quick]  # A/B

Rows, each a fresh process per checkout (`latency.Checkout`: `PYTHONPATH=<checkout>`, the
library checked to come from it; base and new interleaved):

- `gradient`: getting_started's example, `jax.jit(jax.grad(loss))` of the tracking error of
  1 s of L1 under the exact inverse-dynamics torques of another robot (`--t-end`), traced,
  lowered and compiled apart, then its warm run (minimum of 5);
- `sensitivity-fwd`, `sensitivity-rev`: `pj.sensitivity` of L2 `paper-circle` over `--t-end`,
  every float parameter and the default metrics, its first call (tracing and compilation
  included) and its warm run (minimum of 3 later calls);
- `modes`: `pj.modes` of L2 with free actuators, first call and warm.

The first call is the process's own clock around the call (after `import ppr_jax`), so that a
machine's start-up noise stays out. `--quick`: 0.2 s horizons. Writes
`benchmarks/results/derivative_latency.json` (`--out`).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from latency import MARK, Checkout, _interleaved, machine  # noqa: E402

OUT = os.path.join(HERE, "results", "derivative_latency.json")

_PRELUDE = f"""
import json, sys, time
import jax, jax.numpy as jnp, numpy as np
import ppr_jax as pj
print('{MARK}' + pj.__file__)
t_end = float(sys.argv[1])
"""

CODE = {
    "gradient": _PRELUDE + """
p = pj.RobotParams(t=0.5e-3); traj = pj.Circle()
act = pj.TorqueDriven(pj.InverseDynamicsTorque(pj.Reduced(), p, traj))
def loss(q):
    robot = pj.Robot(q, equal_links=True)
    s = pj.simulate(pj.Reduced(), robot, act, traj(0.0), pj.derivatives(traj, 0.0)[1],
                    jnp.linspace(0, t_end, 11))
    return jnp.sum((s.z[:, :2] - jax.vmap(traj)(s.ts)[:, :2]) ** 2)
q = p.replace(t=0.45e-3)
f = jax.jit(jax.grad(loss))
t0 = time.perf_counter(); tr = f.trace(q); t1 = time.perf_counter(); lo = tr.lower()
t2 = time.perf_counter(); c = lo.compile(); t3 = time.perf_counter()
g = jax.block_until_ready(c(q)); t4 = time.perf_counter()
warm = []
for _ in range(5):
    s = time.perf_counter(); jax.block_until_ready(c(q)); warm.append(time.perf_counter() - s)
print(json.dumps(dict(first_s=t4 - t0, trace_s=t1 - t0, lower_s=t2 - t1, compile_s=t3 - t2,
                      warm_s=min(warm), value=float(g.t),
                      stablehlo_lines=lo.as_text().count(chr(10)))))
""",
    "sensitivity": _PRELUDE + """
mode = sys.argv[2]
o = pj.SceneOptions(t_end=t_end, n_out=int(round(100 * t_end)) + 1)
t0 = time.perf_counter()
s = pj.sensitivity("paper-circle", model="double1r", mode=mode, options=o)
first = time.perf_counter() - t0
warm = min(pj.sensitivity("paper-circle", model="double1r", mode=mode, options=o).timing["run_s"]
           for _ in range(3))
print(json.dumps(dict(first_s=first, compile_s=s.timing["compile_s"], warm_s=warm,
                      value=float(np.asarray(s.jacobian)[0, 0]))))
""",
    "modes": _PRELUDE + """
p = pj.scene_params("paper-circle")
t0 = time.perf_counter(); m = pj.modes(pj.Double1R(), p, actuators="free")
f = np.asarray(m.freq_hz); first = time.perf_counter() - t0
warm = []
for _ in range(3):
    s = time.perf_counter(); pj.modes(pj.Double1R(), p, actuators="free")
    warm.append(time.perf_counter() - s)
print(json.dumps(dict(first_s=first, warm_s=min(warm), value=float(f[1]))))
""",
}

ROWS = (("gradient", "gradient", ()), ("sensitivity-fwd", "sensitivity", ("fwd",)),
        ("sensitivity-rev", "sensitivity", ("rev",)), ("modes", "modes", ()))


def _parsed(sample: dict) -> dict:
    line = [x for x in sample["text"].splitlines() if x.startswith("{")][-1]
    return dict(json.loads(line), wall_s=sample["wall_s"])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--new", default=os.path.dirname(HERE), help="the checkout measured")
    ap.add_argument("--base", default=None, help="a second checkout to compare against")
    ap.add_argument("--python", default=sys.executable)
    ap.add_argument("--rows", nargs="+", choices=[r[0] for r in ROWS],
                    default=[r[0] for r in ROWS])
    ap.add_argument("--t-end", type=float, default=1.0, help="horizon (s) of the derivatives")
    ap.add_argument("--repeats", type=int, default=1, help="processes per row and checkout")
    ap.add_argument("--quick", action="store_true", help="0.2 s horizons")
    ap.add_argument("--out", default=OUT)
    args = ap.parse_args(argv)
    t_end = 0.2 if args.quick else args.t_end
    pycache = tempfile.mkdtemp(prefix="derivative_latency_pycache_")
    checkouts = [Checkout("new", args.new, args.python, pycache)]
    if args.base:
        checkouts.insert(0, Checkout("base", args.base, args.python, pycache))
    data = {"machine": machine(), "date": datetime.date.today().isoformat(),
            "t_end_s": t_end, "checkouts": {c.label: c.describe() for c in checkouts},
            "rows": []}
    for name, code, extra in ROWS:
        if name not in args.rows:
            continue
        best = _interleaved(checkouts, args.repeats,
                            lambda c, code=code, extra=extra: c.run(
                                CODE[code], (str(t_end), *extra)))
        row = {"row": name, **{label: _parsed(s) for label, s in best.items()}}
        if args.base:
            row["first_new_over_base"] = row["new"]["first_s"] / row["base"]["first_s"]
        data["rows"].append(row)
        print(json.dumps(row), flush=True)
        os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
        with open(args.out, "w") as f:
            json.dump(data, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
