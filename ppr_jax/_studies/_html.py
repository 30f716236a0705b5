"""What the studies' self-contained HTML reports share (identification's and design's): a page
with its style, tables, number formatting, figures embedded as base64 PNG, and matplotlib on
its Agg backend, imported only when a figure is drawn."""

from __future__ import annotations

import base64
import datetime
import html
import io
import math
import os
from typing import Sequence

#: the reports' style sheet
STYLE = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto;line-height:1.4}"
         "table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #bbb;"
         "padding:2px 8px;text-align:right}th{background:#eee}.bad{color:#b00;font-weight:bold}"
         ".ok{color:#070;font-weight:bold}img{max-width:100%}code{background:#f4f4f4}")


def pyplot():
    """matplotlib's pyplot on the Agg backend, imported when a figure is drawn (not with the
    package: `import ppr_jax` and a plain simulation stay without matplotlib)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def table(header: Sequence[str], rows: Sequence[Sequence]) -> str:
    """An HTML table of `rows` under `header`, every cell escaped."""
    esc = html.escape
    head = "".join(f"<th>{esc(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{esc(str(c))}</td>" for c in row) + "</tr>"
                   for row in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def fmt(x, digits: int = 6) -> str:
    """A number with `digits` significant digits; "open" for None, "undetermined" for NaN/inf."""
    if x is None:
        return "open"
    x = float(x)
    return f"{x:.{digits}g}" if math.isfinite(x) else "undetermined"


def _figure_html(data: bytes, name: str) -> str:
    b64 = base64.b64encode(data).decode("ascii")
    name = html.escape(name)
    return (f'<figure><img alt="{name}" src="data:image/png;base64,{b64}"/>'
            f"<figcaption>{name}</figcaption></figure>")


def image(path: str) -> str:
    """The PNG file `path` as an embedded figure (base64), captioned with its name."""
    with open(path, "rb") as f:
        return _figure_html(f.read(), os.path.basename(path))


def figure(fig, name: str, dpi: int = 110) -> str:
    """A matplotlib figure as an embedded PNG (base64), captioned `name`; the figure is closed."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    pyplot().close(fig)
    return _figure_html(buf.getvalue(), name)


def page(title: str, parts: Sequence[str], footer: Sequence[str] = ()) -> str:
    """A whole self-contained page: `title`, the body `parts`, the `footer` parts, the time it
    was written (UTC)."""
    return "\n".join(
        ["<!doctype html><html><head><meta charset='utf-8'>",
         f"<title>{html.escape(title)}</title>", f"<style>{STYLE}</style>", "</head><body>"]
        + list(parts) + list(footer)
        + [f"<p>Written {datetime.datetime.now(datetime.timezone.utc).isoformat()}.</p>",
           "</body></html>"])
