"""Write `tests/durations.json`, each test file's seconds in one worker (setup, call and teardown
of its tests, from a JUnit report), which `tests/conftest.py` uses to hand the heaviest files to
the workers first.

    python -m pytest --junitxml=/tmp/report.xml && python scripts/test_durations.py /tmp/report.xml
"""

import collections
import json
import os
import sys
import xml.etree.ElementTree as ET

OUT = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tests",
                   "durations.json")


def main(report: str) -> None:
    per_file = collections.Counter()
    for case in ET.parse(report).getroot().iter("testcase"):
        # classname "tests.test_x" (or "tests.test_x.Class"): the file is its first two parts
        parts = case.get("classname", "").split(".")
        per_file["/".join(parts[:2]) + ".py"] += float(case.get("time", 0.0))
    with open(OUT, "w") as f:
        json.dump({k: round(v, 1) for k, v in sorted(per_file.items(), key=lambda kv: -kv[1])},
                  f, indent=1)
        f.write("\n")
    print(f"wrote {OUT}: {len(per_file)} files, {sum(per_file.values()):.0f} s in all")


if __name__ == "__main__":
    main(sys.argv[1])
