"""What a design returns: the optimum, its history, the active constraints with their
multipliers, the verification, and the designed robot as a parameter file."""

from __future__ import annotations

import dataclasses
import json
from typing import Callable, Optional

import numpy as np

from ..._files import write_file
from ..._params import RobotParams
from ..._params_file import save_params
from ._goals import bound_text
from ._optimise import FEAS_TOL


@dataclasses.dataclass
class Design:
    """The result of `ppr_jax.design`.

    **Fields:**

    - `variables`: the design variables' names; `bounds` {name: (lo, hi)} (SI).
    - `x`: {name: value} the optimum (SI); `x_start`: the start the optimum came from.
    - `objective`: {metric, sense, value, start_value}, in the metric's unit.
    - `constraints`: one dict per constraint side: {metric, side ('upper': metric <= bound,
      'lower': metric >= bound, 'avoid': a band, bound [lo, hi]), bound, value, active,
      active_samples, multiplier, violation, violation_abs};
      `multiplier` is d(optimal objective)/d(bound) (objective unit per metric unit; 0 where
      inactive): what relaxing the bound by one unit would gain. A band also has `edge`
      ('lower' or 'upper': the side of the band the value lies on) and `multipliers`
      {lower: d(optimum)/d lo, upper: d(optimum)/d hi}; its `multiplier` is its `edge`'s,
      `violation_abs` the distance to the nearer edge inside the band. A peak over samples
      (`sampled_metrics`, bounded on its extreme's side) is one constraint per sample for the
      optimiser: `active_samples` counts those on the bound, `multiplier` is their sum.
    - `active_bounds`: [{variable, side, bound, multiplier}] the variables' bounds the optimum
      lies on, the multiplier d(optimal objective)/d(bound) likewise.
    - `metrics`: {name: value} every metric evaluated, at the optimum.
    - `params`: the designed robot's `RobotParams`.
    - `history`: the optimiser's iterations from the chosen start: [{iteration, x (SI),
      objective, max_violation (relative to each bound)}].
    - `starts`: one summary per start run (start, optimum, objective, feasible, iterations,
      evaluations (scipy's function calls), jacobians (the points whose values and Jacobian
      were computed), message).
    - `verification`: {kkt_residual, gradient_check, grid, ok} (`_verify`), and `l3`: the
      optimum re-scored with the quasi-static L3 against the PRB error band (`_rescore`; not
      part of `ok`).
    - `info`: the settings (optimizer, derivative mode, stroke, scene, models); `timing`
      {screen_s, optimise_s, verify_s, total_s} (s).
    - `evaluate`: the metrics (in `metrics`' order) at physical variable values (p,) (SI).
    """

    variables: list
    bounds: dict
    x: dict
    x_start: dict
    objective: dict
    constraints: list
    active_bounds: list
    metrics: dict
    params: RobotParams
    history: list
    starts: list
    verification: dict
    info: dict
    timing: dict
    evaluate: Optional[Callable] = dataclasses.field(default=None, repr=False)

    @property
    def feasible(self) -> bool:
        """Whether every constraint holds at the optimum: the one judgement of `design`
        (`_optimise.FEAS_TOL`), on each constraint's metric against its bound or its band's
        edges, to 1e-8 of the bound (`violation`), never on the optimiser's smooth form."""
        return all(c["violation"] <= FEAS_TOL for c in self.constraints)

    @property
    def infeasibility(self) -> Optional[str]:
        """None for a feasible design; else the worst violated constraint, the metric's value
        against its bound or band, and by how much, as one sentence (the `DesignError`'s, the
        report's and the designed robot's file's)."""
        if self.feasible:
            return None
        c = max(self.constraints, key=lambda c: c["violation"])
        m, v = c["metric"], c["value"]
        if c["side"] == "avoid":
            lo, hi = c["bound"]
            edge = lo if c["edge"] == "lower" else hi
            how = (f"{m} = {v:.6g} lies inside the band, {c['violation_abs']:.6g} from its "
                   f"nearer edge {edge:g}")
        else:
            how = (f"{m} = {v:.6g} is {'above' if c['side'] == 'upper' else 'below'} it by "
                   f"{c['violation_abs']:.6g} ({c['violation']:.3g} of the bound)")
        return (f"constraint {m} {bound_text(c['side'], c['bound'])} is violated at the best "
                f"point found ({', '.join(f'{k} = {x:.6g}' for k, x in self.x.items())}): "
                f"{how}")

    def to_params_file(self, path: str) -> str:
        """Write the designed robot to a TOML or JSON parameter file (by extension) that
        `ppr_jax.load_params` and the command line's `--params-file` read; a TOML file says
        where it comes from in a comment, and an infeasible design begins with a `WARNING`
        comment naming the violated constraint (`infeasibility`). Returns the path."""
        if str(path).lower().endswith(".json"):
            return save_params(self.params, path)
        o = self.objective
        notes = [f"designed by ppr_jax.design: {o['sense']} {o['metric']} = {o['value']:.9g}"]
        if not self.feasible:
            notes.insert(0, f"WARNING: INFEASIBLE design, not to be built as it is: "
                            f"{self.infeasibility}")
        return save_params(self.params, path, comments=notes)

    def to_mjcf(self, path: str, dt: float = 1e-4) -> str:
        """Write the designed robot as an MJCF document (`ppr_jax.to_mjcf`: the L2 robot,
        MuJoCo time step `dt` (s)) that `mujoco.MjModel.from_xml_path` loads. Returns the
        path."""
        from ..._mjcf import to_mjcf

        with write_file(path, "w", encoding="utf-8") as fh:
            fh.write(to_mjcf(self.params, dt=dt))
        return str(path)

    def report(self, path: str, command: Optional[str] = None) -> str:
        """Write a self-contained HTML report (`report.html`: the optimum against its start,
        the active constraints with their multipliers, the sensitivity to every bound, the
        history and the verification, figures embedded). Returns the path."""
        from ._report import write_design_report

        return write_design_report(self, path, command=command)

    def to_dict(self) -> dict:
        """Everything but `params` and `evaluate`, as JSON-ready values (the designed robot's
        parameters under "params", `feasible` and `infeasibility` beside them)."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
               if f.name not in ("params", "evaluate")}
        out["feasible"] = self.feasible
        out["infeasibility"] = self.infeasibility
        out["params"] = {f.name: _plain(getattr(self.params, f.name))
                         for f in dataclasses.fields(self.params)
                         if getattr(self.params, f.name) is not None}
        return _jsonable(out)

    def save(self, path: str) -> str:
        """Write `to_dict()` as JSON. Returns the path."""
        with write_file(path, "w", encoding="utf-8") as fh:
            json.dump(self.to_dict(), fh, indent=2)
            fh.write("\n")
        return str(path)

    def summary(self) -> str:
        """A few lines: the optimum, the binding constraints, the verification."""
        o = self.objective
        lines = [] if self.feasible else [f"INFEASIBLE: {self.infeasibility}"]
        lines += [f"{o['sense']} {o['metric']}: {o['value']:.9g} (start {o['start_value']:.6g})"]
        lines += [f"  {k} = {v:.9g}" for k, v in self.x.items()]
        for c in self.constraints:
            tag = "active" if c["active"] else "inactive"
            if c["active"] and c.get("active_samples", 1) > 1:
                tag += f" on {c['active_samples']} samples"
            if c["side"] == "avoid":
                tag = f"{c['edge']} side, {tag}, multipliers d/d lo " \
                      f"{c['multipliers']['lower']:.4g}, d/d hi {c['multipliers']['upper']:.4g}"
            else:
                tag += f", multiplier {c['multiplier']:.4g}"
            lines.append(f"  {c['metric']} {bound_text(c['side'], c['bound'])}: "
                         f"{c['value']:.6g} ({tag})")
        for b in self.active_bounds:
            lines.append(f"  bound {b['variable']} {b['side']} {b['bound']:g} active "
                         f"(multiplier {b['multiplier']:.4g})")
        v = self.verification
        if "grid" not in v:
            lines.append(f"  verification: not run ({v.get('skipped', 'skipped')})")
            return "\n".join(lines)
        g = v["grid"]
        lines.append(f"  verification: KKT residual {v['kkt_residual']:.2e}; gradient vs finite "
                     f"differences {v['gradient_check']['worst']:.2e}; {g['kind']} of "
                     f"{g['points']} points, best {g['best_objective']}, gap {g['gap']}; "
                     f"{'ok' if v['ok'] else 'NOT ok'}")
        l3 = v.get("l3")
        if l3 is not None:
            lines.append(f"  L3 (quasi-static, N = {l3['n_elements']}), PRB band "
                         f"{l3['band']:.1%} at kappa0 = {l3['kappa0']:.3g}: {l3['note']}")
        return "\n".join(lines)


def _plain(v):
    return v if isinstance(v, (int, str)) else float(v)


def _jsonable(v):
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, np.ndarray):
        return _jsonable(v.tolist())
    if isinstance(v, (np.floating, np.integer, np.bool_)):
        return v.item()
    if isinstance(v, float) and not np.isfinite(v):
        return None
    return v
