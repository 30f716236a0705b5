"""Execute a notebook's code cells in order in one namespace, without a Jupyter kernel.

    python scripts/run_notebook.py notebooks/quickstart.ipynb

Used by the tests (with PPR_NOTEBOOK_SMALL=1, which every notebook reads to shrink its settings)
so that CI needs no Jupyter installation. IPython magics and shell lines (% and !) are skipped.
"""

import json
import os
import sys
import time


def run(path: str) -> None:
    os.environ.setdefault("MPLBACKEND", "Agg")
    with open(path) as f:
        nb = json.load(f)
    ns = {"__name__": "__main__"}
    for i, cell in enumerate(nb["cells"]):
        if cell["cell_type"] != "code":
            continue
        src = "".join(cell["source"])
        src = "\n".join(ln for ln in src.splitlines() if not ln.lstrip().startswith(("%", "!")))
        t0 = time.perf_counter()
        exec(compile(src, f"{path}[cell {i}]", "exec"), ns)
        print(f"cell {i}: {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)


if __name__ == "__main__":
    for p in sys.argv[1:]:
        run(p)
