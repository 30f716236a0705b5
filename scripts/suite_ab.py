"""The test suite's A/B: `.ci/run` on fresh clones of two commits, one after the other on the
same machine, from their pytest logs (run with `--durations=0`, which `.ci/run` passes on).

    git clone -q REPO /tmp/a && cd /tmp/a && git checkout -q BASE
    bash -c 'time bash .ci/run --durations=0' > /tmp/a.log 2>&1   # then NEW in /tmp/b
    python scripts/suite_ab.py /tmp/a.log BASE /tmp/b.log NEW [--note TEXT]

Writes `benchmarks/results/suite_ab_2core.json` (`--out`): each run's tests, failures, pytest's
wall and its workers' seconds (the sum of every test's setup, call and teardown), the whole
command's seconds with the install (`ci_run_s`, from `time`, where the log has it), and each test
file's worker-seconds on both sides, largest change first. The wall alone says little across
machines (the same suite took 640 s on the machine that set the goal and 2,074 s on a slower
one); the A/B is what compares.
"""

from __future__ import annotations

import argparse
import collections
import json
import pathlib
import platform
import re

ROOT = pathlib.Path(__file__).resolve().parents[1]
_DURATION = re.compile(r"\s*([\d.]+)s (call|setup|teardown)\s+(\S+)")


def read_log(path: str) -> dict:
    """{tests, passed, failed, wall_s, worker_s, files: {file: worker-seconds}} of a pytest
    log with `--durations=0`."""
    text = pathlib.Path(path).read_text()
    summary = [ln for ln in text.splitlines() if re.search(r" in [\d.]+s( \(|\s*=)", ln)]
    if not summary:
        raise SystemExit(f"{path}: no pytest summary line")
    counts = {k: int(n) for n, k in re.findall(r"(\d+) (passed|failed|error)", summary[-1])}
    files = collections.Counter()
    for line in text.split("slowest durations")[-1].splitlines():
        m = _DURATION.match(line)
        if m:
            files[m.group(3).split("::")[0]] += float(m.group(1))
    if not files:
        raise SystemExit(f"{path}: no durations (run the suite with --durations=0)")
    passed, failed = counts.get("passed", 0), counts.get("failed", 0) + counts.get("error", 0)
    out = {"tests": passed + failed, "passed": passed, "failed": failed,
           "wall_s": float(re.search(r" in ([\d.]+)s", summary[-1])[1]),
           "worker_s": round(sum(files.values()), 1), "files": dict(files)}
    # `time bash .ci/run ...`: the whole command, the install included (the 10-minute rule's)
    real = re.findall(r"^real\s+(\d+)m([\d.]+)s", text, flags=re.M)
    if real:
        out["ci_run_s"] = round(60 * int(real[-1][0]) + float(real[-1][1]), 1)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("base_log")
    ap.add_argument("base_commit")
    ap.add_argument("new_log")
    ap.add_argument("new_commit")
    ap.add_argument("--note", default="")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "suite_ab_2core.json"))
    a = ap.parse_args(argv)
    base, new = read_log(a.base_log), read_log(a.new_log)
    names = sorted(set(base["files"]) | set(new["files"]),
                   key=lambda f: -abs(new["files"].get(f, 0.0) - base["files"].get(f, 0.0)))
    per_file = {f: {"base_s": round(base["files"].get(f, 0.0), 1),
                    "new_s": round(new["files"].get(f, 0.0), 1)} for f in names}
    out = {
        "what": "the test suite (`.ci/run`) on fresh clones of two commits, one after the other "
                "on one machine, 2 xdist workers; worker_s is the sum of every test's setup, "
                "call and teardown",
        "machine": f"{platform.machine()}, {platform.system()}, 2 cores",
        "base": {"commit": a.base_commit, **{k: v for k, v in base.items() if k != "files"}},
        "new": {"commit": a.new_commit, **{k: v for k, v in new.items() if k != "files"}},
        "wall_new_over_base": round(new["wall_s"] / base["wall_s"], 3),
        "worker_s_per_test_new_over_base": round(
            (new["worker_s"] / new["tests"]) / (base["worker_s"] / base["tests"]), 3),
        "files": per_file,
        "note": a.note,
    }
    if "ci_run_s" in base and "ci_run_s" in new:
        out["ci_run_new_over_base"] = round(new["ci_run_s"] / base["ci_run_s"], 3)
    pathlib.Path(a.out).write_text(json.dumps(out, indent=1) + "\n")
    print(f"wall {base['wall_s']:.0f} -> {new['wall_s']:.0f} s "
          f"({out['wall_new_over_base']:.2f}), tests {base['tests']} -> {new['tests']}, "
          f"worker-seconds {base['worker_s']:.0f} -> {new['worker_s']:.0f}")


if __name__ == "__main__":
    main()
