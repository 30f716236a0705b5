"""mkdocs hooks of the documentation site (`hooks:` in mkdocs.yml).

- The notebooks (`notebooks/*.ipynb`) join the site as `notebooks/<name>.ipynb`, rendered by
  mkdocs-jupyter without executing them, and the benchmark figures
  (`benchmarks/results/**/*.png`) as `benchmarks/results/...`: both stay where the code writes
  them, with no copy in `docs/`.
- Each `<!-- perf:NAME -->` marker of a page is replaced by the table `NAME` that
  `scripts/gen_perf.py` generates from `benchmarks/results/*.json`.
"""

from __future__ import annotations

import glob
import importlib.util
import os
import re

from mkdocs.plugins import event_priority
from mkdocs.structure.files import File

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
_MARKER = re.compile(r"<!--\s*perf:([a-z0-9-]+)\s*-->")
_TABLES = None


def _tables() -> dict:
    global _TABLES
    if _TABLES is None:
        spec = importlib.util.spec_from_file_location(
            "gen_perf", os.path.join(ROOT, "scripts", "gen_perf.py"))
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        _TABLES = module.tables()
    return _TABLES


@event_priority(100)  # before mkdocs-jupyter turns the notebooks into pages
def on_files(files, config):
    paths = sorted(glob.glob(os.path.join(ROOT, "notebooks", "*.ipynb")))
    paths += sorted(glob.glob(os.path.join(ROOT, "benchmarks", "results", "**", "*.png"),
                              recursive=True))
    for path in paths:
        # a file of the repository root, at the same path in the site (mkdocs-jupyter wraps it)
        uri = os.path.relpath(path, ROOT).replace(os.sep, "/")
        files.append(File(uri, ROOT, config["site_dir"], config["use_directory_urls"]))
    return files


def on_page_markdown(markdown, page, config, files):
    def table(match):
        name = match.group(1)
        tables = _tables()
        if name not in tables:
            raise KeyError(f"{page.file.src_uri}: no generated table {name!r} "
                           f"(scripts/gen_perf.py has {sorted(tables)})")
        return tables[name]

    return _MARKER.sub(table, markdown)
