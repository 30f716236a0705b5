"""The result tables of the docs and the README are what the code computes: the numbers are read
from the text (never copied here), so editing the docs without the code, or the code without the
docs, fails. Only physics numbers are pinned; run times and step counts depend on the machine.

- docs/scenes.md: the `paper-circle` and `servo-circle` tables (the fixed-width blocks that
  `ppr-jax simulate` prints, default 7.54 s) and the modes table (home, t = 0.3 mm);
- README.md: the headline table's L2 radial errors and the paper's values.

A printed value is checked to one unit of its last digit: half a unit of rounding, and as much
again for the integrators' spread between machines (an error extreme of a vibrating L2 moves by
about 1e-4 of its unit with the step sequence). Mode frequencies, from an eigenproblem, are
checked to half a unit."""

import pathlib
import re

import numpy as np
import pytest

import ppr_jax as pj

ROOT = pathlib.Path(__file__).resolve().parents[1]
SCENES_MD = (ROOT / "docs" / "scenes.md").read_text()
README = (ROOT / "README.md").read_text()

#: the table's columns that are physics (the rest: residual, steps, run time), with the metric
#: each shows and its scale to the printed unit
COLUMNS = (
    ("radial_error_max_m", 1e3), ("radial_error_min_m", 1e3), ("radial_error_mean_m", 1e3),
    ("radial_error_max_relative_percent", 1.0), ("phi_error_max_rad", 1e3),
    ("end_rotation_diff_max_deg", 1.0), ("end_rotation_diff_min_deg", 1.0),
    ("end_rotation_diff_mean_deg", 1.0), ("end_rotation_diff_max_relative_percent", 1.0),
)
MODELS = ("rigid", "reduced", "double1r")
SCENES = {"paper-circle": pj.PaperCircle, "servo-circle": pj.ServoCircle}


def unit(token: str) -> float:
    """One unit of the last printed digit of a number as written ("0.1863" -> 1e-4)."""
    mantissa = token.lower().split("e")[0]
    decimals = len(mantissa.split(".")[1]) if "." in mantissa else 0
    exponent = int(token.lower().split("e")[1]) if "e" in token.lower() else 0
    return 10.0 ** (exponent - decimals)


def scene_table(scene: str) -> dict:
    """{row name: [number tokens]} of the fixed-width table under the scene's heading."""
    section = SCENES_MD.split(f"## `{scene}`", 1)[1]
    block = section.split("```", 2)[1]
    rows = {}
    for line in block.splitlines():
        words = line.split()
        if words and words[0] in MODELS + ("paper",):
            rows[words[0]] = words[1:]
    assert set(rows) == set(MODELS) | {"paper"}, (scene, sorted(rows))
    return rows


def modes_table() -> list:
    """[(model cell, actuators, [number tokens])] of the modes table; parentheses dropped."""
    section = SCENES_MD.split("## `modes`", 1)[1]
    out = []
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 3 or cells[1] not in ("locked", "free"):
            continue
        freqs = re.sub(r"\([^)]*\)", "", cells[2])
        out.append((cells[0], cells[1], re.findall(r"-?\d+(?:\.\d+)?(?:e-?\d+)?", freqs)))
    return out


@pytest.fixture(scope="module")
def report(paper_circle_L1):
    """report(scene, model): the scene's `run_scene` report at its defaults, computed once."""
    done = {("paper-circle", "reduced"): paper_circle_L1}

    def get(scene, model):
        if (scene, model) not in done:
            done[scene, model] = pj.run_scene(scene, model=model)
        return done[scene, model]

    return get


def _rows():
    # the README's headline needs L2 on both scenes, and L1's paper-circle run is the session's;
    # L0's rows and L1's servo row: second tier
    for model in MODELS:
        for scene in ("paper-circle", "servo-circle"):
            slow = model == "rigid" or (scene == "servo-circle" and model == "reduced")
            yield pytest.param(scene, model, id=f"{model}-{scene}",
                               marks=[pytest.mark.slow] if slow else [])


@pytest.mark.parametrize(("scene", "model"), list(_rows()))
def test_scene_table_row(report, scene, model):
    tokens = scene_table(scene)[model]
    m = report(scene, model).metrics
    for (key, scale), tok in zip(COLUMNS, tokens):
        got = float(m[key]) * scale
        # (and 1e-6 of the value: L0's 276 mm runaway amplifies rounding differences)
        assert abs(got - float(tok)) <= unit(tok) + 1e-6 * abs(got), (scene, model, key, got, tok)


@pytest.mark.parametrize("scene", ["paper-circle", "servo-circle"])
def test_scene_table_paper_row(scene):
    """The "paper" row is the scene's published reference (`reference`), at half a unit."""
    tokens = scene_table(scene)["paper"]
    ref = SCENES[scene].reference
    for (key, scale), tok in zip(COLUMNS[:4], tokens):
        assert abs(ref[key] * scale - float(tok)) <= 0.5 * unit(tok), (scene, key, tok)


def test_readme_headline(report):
    """README: "+0.19 / -0.17 mm" (L2 paper-circle), "-0.27 to -0.45 mm" (L2 servo-circle) and
    the paper's values beside them."""
    num = r"([+-]?\d+\.\d+)"
    paper = re.search(rf"`paper-circle`[^|]*L2 radial error \| {num} / {num} mm \|"
                      rf"[^|]*ADAMS-ANSYS: {num} / {num} mm", README)
    servo = re.search(rf"`servo-circle`[^|]*L2 radial error \| {num} to {num} mm \|"
                      rf"[^|]*Optotrak: {num} / {num} mm", README)
    assert paper and servo, "the README's headline rows are not where this test reads them"
    for match, scene in ((paper, "paper-circle"), (servo, "servo-circle")):
        m = report(scene, "double1r").metrics
        ref = SCENES[scene].reference
        hi, lo, ref_hi, ref_lo = match.groups()
        for tok, got in ((hi, m["radial_error_max_m"]), (lo, m["radial_error_min_m"]),
                         (ref_hi, ref["radial_error_max_m"]), (ref_lo, ref["radial_error_min_m"])):
            assert abs(got * 1e3 - float(tok)) <= 0.5 * unit(tok), (scene, tok, got)


MODE_ROWS = [r for r in modes_table() if r[2]]


def _model(cell: str):
    if "reduced" in cell:
        return pj.Reduced()
    if "double1r" in cell:
        return pj.Double1R()
    n = re.search(r"N = (\d+)", cell)
    assert "beam" in cell and n, cell
    return pj.QuasiStaticBeam(int(n.group(1)))


def test_modes_table_is_complete():
    """Every row this file recomputes is there (a row renamed away would skip its check), and
    the kinematic models' locked row says they have none."""
    rows = modes_table()
    names = [(c, a) for c, a, _ in rows]
    for want in (("L1 `reduced`", "free"), ("L2 `double1r`", "locked"),
                 ("L2 `double1r`", "free")):
        assert want in names, want
    assert sum("N = 32" in c for c, _ in names) == 2
    kinematic = [t for c, a, t in rows if c.startswith("L0 / L1")]
    assert kinematic == [[]]
    assert pj.modes(pj.Reduced(), pj.RobotParams(), actuators="locked").freq_hz.size == 0


@pytest.mark.parametrize("row", [
    # second tier: the modes themselves meet simulated free vibration in tests/test_modes.py
    pytest.param(r, id=f"{r[0]}-{r[1]}", marks=[pytest.mark.slow]) for r in MODE_ROWS])
def test_modes_table_row(row):
    """Each row with frequencies, L3 at N = 32 included (about 15 s each on 2 cores)."""
    cell, actuators, tokens = row
    f = np.asarray(pj.modes(_model(cell), pj.RobotParams(), actuators=actuators).freq_hz)
    assert f.shape == (len(tokens),), (cell, actuators, f)
    for got, tok in zip(f, tokens):
        assert abs(got - float(tok)) <= 0.5 * unit(tok) + 1e-12, (cell, actuators, got, tok)


# -- docs/sweeps.md: how much the start moves the sensitivities ------------------------------

SWEEPS_MD = (ROOT / "docs" / "sweeps.md").read_text()
START_JSON = ROOT / "benchmarks" / "results" / "start_sensitivity.json"


def _start_effect(metric: str, start: str = "one-pass") -> float:
    """|change| (%) of paper-circle's d(metric)/dt between the two-pass start and `start` in
    benchmarks/results/start_sensitivity.json (the independent scipy L2's central
    differences)."""
    import json

    ref = json.loads(START_JSON.read_text())["scenes"]["paper-circle"]["reference"]
    d2 = ref["two-pass"]["derivatives"][metric]
    return 100 * abs(ref[start]["derivatives"][metric] / d2 - 1)


def test_start_effect_sentences_quote_the_benchmark():
    """The prose's percentages are the benchmark's, to one unit of their last digit; the table
    under `<!-- perf:start-sensitivity -->` is generated from the same JSON."""
    m = re.search(r"a one-pass start moves\s+d\(e_r max\)/dt by ([\d.]+) % and d\(e_r min\)/dt"
                  r" by ([\d.]+) %", SWEEPS_MD)
    assert m, "the sentence on the one-pass start's effect is gone from docs/sweeps.md"
    for token, metric in zip(m.groups(), ("radial_error_max_m", "radial_error_min_m")):
        assert abs(_start_effect(metric) - float(token)) <= unit(token), (metric, token)
    m = re.search(r"so its derivative changes by ([\d.]+) %", SWEEPS_MD)
    assert m and abs(_start_effect("end_rotation_diff_max_deg") - float(m.group(1))) <= unit(
        m.group(1)), m
    assert "<!-- perf:start-sensitivity -->" in SWEEPS_MD


def test_start_sensitivity_table_agreement():
    """The published library-against-reference agreement is the one the tests hold
    (tests/test_sensitivity_reference.py): 1e-6 on the metrics, 1e-4 on paper-circle's
    derivatives, 1e-3 on the Fourier path's."""
    import json

    d = json.loads(START_JSON.read_text())
    for name, sc in d["scenes"].items():
        lib, ref = sc["library"]["two-pass"], sc["reference"]["two-pass"]
        tol = 1e-4 if name == "paper-circle" else 1e-3
        for k in sc["metrics"]:
            assert abs(lib["derivatives"][k] / ref["derivatives"][k] - 1) < tol, (name, k)
