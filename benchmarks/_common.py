"""What several benchmark scripts share: a JSON store of rows merged by their keys, the
`--plot-only` option that redraws a script's figure from it, and the figures' finish.

Not a script: the scripts run from benchmarks/ and import it as `_common`, as
design_latency.py imports `latency`."""

from __future__ import annotations

import json
import pathlib


def load_json(path, empty: dict) -> dict:
    """The JSON document at `path`, or `empty` where there is none yet."""
    path = pathlib.Path(path)
    return json.loads(path.read_text()) if path.exists() else empty


def save_json(path, db: dict) -> None:
    """Write `db` to `path` (its folder made), one space of indent a level."""
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(db, indent=1))


def upsert(rows: list, row: dict, keys) -> None:
    """Replace the row of `rows` that agrees with `row` on every one of `keys`, or append it:
    a rerun of a setting replaces its row, a new setting adds one."""
    for i, r in enumerate(rows):
        if all(r.get(k) == row.get(k) for k in keys):
            rows[i] = row
            return
    rows.append(row)


def parse_or_plot(ap, load, plot):
    """`ap`'s arguments, with `--plot-only` added, and the stored results `load()`: (args, db).
    With --plot-only the figure is redrawn from them (`plot(db)`) and args is None: the script
    has nothing more to do."""
    ap.add_argument("--plot-only", action="store_true",
                    help="redraw the figure from the stored results, run nothing")
    args = ap.parse_args()
    db = load()
    if args.plot_only:
        plot(db)
        return None, db
    return args, db


def label_axes(ax, xlabel: str, ylabel: str, title: str, legend_size: int = 8) -> None:
    """A log-log panel's labels, title, grid (major and minor) and legend."""
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=legend_size)


def save_figure(fig, path) -> None:
    """Lay `fig` out, write it to `path` (its folder made) at 120 dpi and close it."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    pathlib.Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
