"""A plot of a sweep's summary table: one metric against one parameter, one line per value of another."""

from __future__ import annotations

import csv
import math
from pathlib import Path

from ..errors import PLOT_EXTRA, ConfigError, MissingDependencyError
from .metrics import UNITS


def read_summary(path):
    """The rows of ``summary.csv`` as dicts, numbers as float where they parse."""
    def number(text):
        try:
            return float(text)
        except ValueError:
            return text
    with open(path, newline="") as stream:
        return [{key: number(value) if value != "" else math.nan for key, value in row.items()}
                for row in csv.DictReader(stream)]


def require_matplotlib():
    """Raise ``MissingDependencyError`` unless matplotlib can be imported (checked before a sweep
    whose plot would otherwise fail only after every run)."""
    import importlib.util

    if importlib.util.find_spec("matplotlib") is None:
        raise MissingDependencyError(f"the sweep plot needs matplotlib: {PLOT_EXTRA}")


def plot_summary(summary_path, image_path, x, y="tip_displacement", lines=None, title=None):
    """Plot column ``y`` of ``summary_path`` against column ``x``, one line per value of ``lines``.

    Only complete runs are drawn; failed ones are counted in the legend.  An axis whose values
    are all positive and span a factor of 3 or more is logarithmic (a power law is a straight
    line).  Needs matplotlib (``PLOT_EXTRA``).  Returns ``image_path``.
    """
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise MissingDependencyError(f"the sweep plot needs matplotlib: {PLOT_EXTRA}") from None
    rows = read_summary(summary_path)
    if not rows:
        raise ConfigError(f"{summary_path}: the summary has no runs")
    for column in (x, y, lines):
        if column is not None and column not in rows[0]:
            columns = ", ".join(rows[0])
            raise ConfigError(f"plot column {column!r}: not in {summary_path} (columns: {columns})")
    groups = {}
    for row in rows:
        groups.setdefault(row[lines] if lines else None, []).append(row)
    figure, axes = plt.subplots(figsize=(6.4, 4.4), dpi=120)
    for value, group in sorted(groups.items(), key=lambda item: str(item[0])):
        done = sorted((row for row in group if row["status"] == "complete"), key=lambda row: row[x])
        failed = len(group) - len(done)
        label = f"{lines.rsplit('.', 1)[-1]} = {value:g}" if isinstance(value, float) else str(value or y)
        if failed:
            label += f" ({failed} failed, not drawn)"
        axes.plot([row[x] for row in done], [row[y] for row in done], "o-", label=label)
    for column, set_scale in ((x, axes.set_xscale), (y, axes.set_yscale)):
        values = [row[column] for row in rows if row["status"] == "complete" and isinstance(row[column], float)]
        if values and min(values) > 0 and max(values) >= 3 * min(values):
            set_scale("log")
    axes.set_xlabel(_label(x))
    axes.set_ylabel(_label(y))
    axes.grid(True, which="both", alpha=0.3)
    axes.legend()
    if title:
        axes.set_title(title)
    figure.tight_layout()
    Path(image_path).parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(image_path)
    plt.close(figure)
    return Path(image_path)


def _label(column):
    unit = UNITS.get(column)
    return f"{column} [{unit}]" if unit else column
