"""Write tests/durations.json, each test file's seconds on one worker, from a run of the suite
with `PPR_TEST_COMPILE_STATS=DIR` (one JSON line per test and worker, `tests/conftest.py`).

A file's seconds are from the end of the test before it on its worker to the end of its last
test: its module fixtures, its tests and the teardown of the file before. The suite hands out
the longest files first (`conftest._longest_files_first`).

Run: `PPR_TEST_COMPILE_STATS=/tmp/stats python -m pytest` then
`python scripts/test_durations.py /tmp/stats`.
"""

import collections
import json
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]


def file_seconds(directory: str) -> dict:
    """{test file: seconds} from the JSON lines in `directory`."""
    out = collections.Counter()
    paths = sorted(pathlib.Path(directory).glob("*.jsonl"))
    workers = [p for p in paths if p.stem.startswith("gw")]
    # main.jsonl, beside the workers' files, is the `xla_defaults` subprocesses': their time
    # is inside the worker's test that ran them
    for path in workers or paths:
        rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
        prev = None
        for row in rows:
            name = row["test"].split("::")[0]
            if "end" in row and prev is not None:
                out[name] += row["end"] - prev
            else:
                out[name] += row["wall_s"]
            prev = row.get("end")
    return dict(out)


def main(argv):
    cost = file_seconds(argv[1])
    text = json.dumps({k: round(v, 1) for k, v in sorted(cost.items(), key=lambda kv: -kv[1])},
                      indent=1)
    (ROOT / "tests" / "durations.json").write_text(text + "\n")
    total = sum(cost.values())
    print(f"{len(cost)} files, {total:.0f} worker-seconds, at best {total / 2:.0f} s on two "
          f"workers")


if __name__ == "__main__":
    main(sys.argv)
