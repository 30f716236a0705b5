"""Statements of docs/performance.md about measured behaviour are generated from the benchmark
JSON (`scripts/gen_perf.py`, `<!-- perf:NAME -->` markers), not written by hand: the page said
both that L0-L2's Kvaerno5 "rejects a third of its steps" (its JSON: 51-57 %) and that the stage
solve had fixed that. Reads JSON only; nothing is compiled."""

import importlib.util
import json
import pathlib
import re

ROOT = pathlib.Path(__file__).resolve().parents[1]
PERF_MD = (ROOT / "docs" / "performance.md").read_text()


def _gen_perf():
    spec = importlib.util.spec_from_file_location("gen_perf", ROOT / "scripts" / "gen_perf.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_kvaerno_statement_is_generated_from_the_json():
    assert "<!-- perf:kvaerno-l0-l2 -->" in PERF_MD
    assert not re.search(r"rejects? (a third|half|\d+ ?%) of its steps", PERF_MD)
    text = _gen_perf().tables()["kvaerno-l0-l2"]
    wp = json.loads((ROOT / "benchmarks/results/cpu/work_precision.json").read_text())
    kv = [r for r in wp["rows"] if r["solver"] == "kvaerno5"
          and r["model"] in ("rigid", "reduced", "double1r")]
    fr = [100 * r["rejected"] / r["steps"] for r in kv]
    assert f"rejected {min(fr):.0f}-{max(fr):.0f} % of its steps" in text, text
    imp = json.loads((ROOT / "benchmarks/results/implicit_l2.json").read_text())
    fi = [100 * r["rejected_fraction"] for r in imp["rows"]
          if r.get("ok") and r["solver"] == "kvaerno5"]
    assert f"it rejects {min(fi):.0f}-{max(fi):.0f} %" in text, text
    # rows measured before the current stage solve say so
    predates = wp["machine"]["date"][:10] < _gen_perf().STAGE_SOLVE_DATE
    assert ("predate the current stage solve" in text) == predates


def test_design_latency_sentences_quote_the_benchmark():
    """The first and second `ppr-jax design` processes quoted by the README, docs/design.md and
    docs/performance.md are `benchmarks/results/design_latency.json`'s (its rows' minima)."""
    d = json.loads((ROOT / "benchmarks/results/design_latency.json").read_text())
    new, base = d["rows"]["new"], d["rows"]["base"]
    first, second = new["first_wall_s"], new["second_wall_s"]

    def text(path):
        return " ".join((ROOT / path).read_text().split())

    assert f"| {first:.0f} s / {second:.1f} s |" in text("README.md")
    assert (f"takes {first:.0f} s in a first process and {second:.1f} s in a second"
            in text("docs/design.md"))
    assert (f"{first:.1f} s in a first process and {second:.1f} s in a second, where the second "
            f"had taken {base['second_wall_s']:.1f} s" in text("docs/performance.md"))
    assert new["second_over_first"] < 0.5 * base["second_over_first"]
    assert max(d["x_rel_diff"].values()) < 1e-9


def test_engine_profile_section_is_generated_from_the_json():
    """docs/performance.md's "Where a run's time goes" is `engine_profile.json`'s: every model's
    steps, run, kernels a step and a right-hand side's element operations, before and after
    where both were measured."""
    assert "<!-- perf:engine-profile -->" in PERF_MD
    d = json.loads((ROOT / "benchmarks/results/engine_profile.json").read_text())
    text = _gen_perf().tables()["engine-profile"]
    sides = [s for s in ("before", "after") if s in d]
    for m, row in d["after"]["models"].items():
        if "error" in row:
            continue
        rows = [d[s]["models"][m] for s in sides]
        line = next(ln for ln in text.splitlines() if ln.startswith(f"| {m} |"))
        assert " / ".join(f"{r['steps']:,}" for r in rows) in line, line
        assert " / ".join(f"{r['kernels_per_step']:.0f}" for r in rows) in line, line
        # a right-hand side's arithmetic as traced and as compiled, where it was counted
        for r in rows:
            rhs = r.get("rhs", {})
            if "traced_element_ops" in rhs:
                pair = f"{rhs['traced_element_ops']:,}, {rhs['compiled_element_ops']:,}"
                assert pair in line, line


def test_engine_ab_section_is_generated_from_the_json():
    """The engine's A/B rows on docs/performance.md are every `engine_ab*.json`'s, each row with
    its goal's verdict."""
    assert "<!-- perf:engine-ab -->" in PERF_MD
    text = _gen_perf().tables()["engine-ab"]
    files = sorted((ROOT / "benchmarks/results").glob("engine_ab*.json"))
    assert files
    for path in files:
        d = json.loads(path.read_text())
        head = f"`{path.name}`: {d['base']} (base) against {d['new']} (new)"
        assert head in text
        # this file's section: from its heading to the next file's (rows repeat across files)
        section = text[text.index(head):].split("\n`engine_ab", 1)[0]
        for r in d["rows"]:
            line = next(x for x in section.splitlines() if x.startswith(f"| {r['row']} |"))
            verdict = {True: "| met |", False: "| not met |"}.get(r.get("met"), "| - |")
            assert line.endswith(verdict), line


def test_engine_profile_batch_section_is_generated_from_the_json():
    """docs/performance.md's batch profile is `engine_profile_batch.json`'s: every model's run
    time and trajectories per second on each side."""
    assert "<!-- perf:engine-profile-batch -->" in PERF_MD
    d = json.loads((ROOT / "benchmarks/results/engine_profile_batch.json").read_text())
    text = _gen_perf().tables()["engine-profile-batch"]
    for side in ("before", "after"):
        for m, row in d.get(side, {}).get("models", {}).items():
            if "error" in row:
                continue
            assert f"{row['trajectories_per_s']:,.0f} trajectories/s" in text, (side, m)


def test_readme_contenders_row_quotes_the_benchmark():
    """README's headline row of L2 at 2e-8 m (ppr_jax, MuJoCo and scipy) quotes the matched
    times of `cpu/contenders.json` (`gen_perf.headline`), each to its printed digit."""
    readme = (ROOT / "README.md").read_text()
    row = re.search(r"\| L2 `paper-circle` \(7\.54 s\) at 2e-8 m error \| ([\d.]+) ms \(([^)]+)\) "
                    r"\| MuJoCo ([\d.]+) ms, scipy (\w+) ([\d.]+) ms \|", readme)
    assert row, "the README's contenders row is not where this test reads it"
    ours, method, mujoco, scipy_method, scipy = row.groups()
    times = _gen_perf().headline()
    d = json.loads((ROOT / "benchmarks/results/cpu/contenders.json").read_text())
    fastest = {r["tool"]: r["method"] for r in d["matched"] if r["error_m"] == 2e-8}
    assert method.lower() == fastest["ppr_jax"].lower()
    assert scipy_method == fastest["scipy"]
    for tok, key in ((ours, "ppr_jax@2e-08"), (mujoco, "mujoco@2e-08"), (scipy, "scipy@2e-08")):
        digits = len(tok.partition(".")[2])
        assert abs(1e3 * times[key] - float(tok)) <= 0.5 * 10.0 ** -digits, (key, tok)


def test_readme_simulate_row_quotes_the_latency_benchmark():
    """README's `ppr-jax simulate` row (first / second process) is `latency.json`'s whole-command
    walls of the new checkout (`gen_perf.simulate_headline`)."""
    readme = " ".join((ROOT / "README.md").read_text().split())
    cell = _gen_perf().simulate_headline()
    assert f"| `ppr-jax simulate` (1 s), whole command, first / second process | {cell} |" in readme


def test_first_compile_time_sentences_agree_and_quote_the_benchmark():
    """The first run's compile time per model is said the same way on the Getting started,
    Command line and index pages (they said 5-10 s and 7-13 s), and it is the one a cold
    `ppr-jax simulate` logs in `benchmarks/results/latency.json` (a fresh 2-core machine): L0-L2
    and the L3 beam, rounded to whole seconds."""
    d = json.loads((ROOT / "benchmarks/results/latency.json").read_text())
    assert d["machine"]["cpus"] == 2
    cold = {r["model"]: r["new"]["compile_s"] for r in d["rows"]
            if r.get("part") == "simulate" and r.get("kind") == "cold"}
    lo = round(min(cold[m] for m in ("rigid", "reduced", "double1r")))
    hi = round(max(cold[m] for m in ("rigid", "reduced", "double1r")))
    beam = f"about {cold['beam']:.0f} s for the L3 beam"

    def text(path):
        return " ".join((ROOT / path).read_text().split())

    assert f"({lo}-{hi} s per model on a 2-core CPU for L0-L2, {beam})" in text(
        "docs/getting_started.md")
    assert f"takes {lo}-{hi} s per model on a 2-core CPU for L0-L2 ({beam})" in text(
        "docs/cli.md")
    assert f"compilation of {lo}-{hi} s per model" in text("docs/index.md")
    for path in ("docs/getting_started.md", "docs/cli.md", "docs/index.md"):
        assert not re.search(r"\b(5-10|7-13) s\b", text(path)), path
