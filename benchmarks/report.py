"""Results of the suite: ``results.csv`` (every row), ``results.md`` (a table per section) and
``throughput.png`` (tet-steps/s against tets: softsim, the peers, the bandwidth bound)."""

import csv
import os
import time

from . import targets

COLUMNS = ("section", "case", "tets", "runner", "threads", "rate", "ratio", "ratio_to", "note")
HEADERS = ("case", "tets", "runner", "threads", "M tet-steps/s", "ratio", "ratio of", "note")


def _cell(value):
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:.4g}" if abs(value) < 1e-2 and value != 0 else f"{value:,.3g}" if value >= 1e4 else f"{value:.3g}"
    if isinstance(value, int):
        return f"{value:,}"
    return str(value).replace("|", "/")


def write(rows, folder, machine, quick, sections=None):
    """``results.csv``, ``results.md`` and ``throughput.png`` (with throughput rows) in ``folder``, in
    place of an earlier run's; sections: the names of the sections run, when not all (said in the
    markdown's first line)."""
    os.makedirs(folder, exist_ok=True)
    paths = [os.path.join(folder, "results.csv"), os.path.join(folder, "results.md")]
    with open(paths[0], "w", newline="") as f:
        writer = csv.DictWriter(f, COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    with open(paths[1], "w") as f:
        f.write(f"# softsim benchmarks\n\n{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {machine}"
                f"{' (--quick)' if quick else ''}{'; sections ' + ', '.join(sections) + ' only' if sections else ''}"
                f". Rates: medians of interleaved rounds in one process; "
                f"ratios: medians of per-round ratios. Regenerate: `python -m benchmarks`.\n")
        for section in dict.fromkeys(r["section"] for r in rows):
            if section == "targets":               # the targets, judged (``targets.py``)
                judged = [r for r in rows if r["section"] == section]
                f.write(f"\n## targets\n\n{targets.summary(judged)}.\n\n{targets.markdown(judged)}")
                continue
            f.write(f"\n## {section}\n\n| " + " | ".join(HEADERS) + " |\n|" + "---|" * len(HEADERS) + "\n")
            for r in rows:
                if r["section"] == section:
                    f.write("| " + " | ".join(_cell(r[c]) for c in COLUMNS[1:]) + " |\n")
    png = plot(rows, os.path.join(folder, "throughput.png"), machine)
    if png:
        paths.append(png)
    elif os.path.exists(os.path.join(folder, "throughput.png")):     # an earlier run's: not this table's
        os.remove(os.path.join(folder, "throughput.png"))
    return paths


def plot(rows, path, machine):
    """Throughput against tets (log-log); None without matplotlib or throughput rows."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    series = {}
    for r in rows:
        if r["section"] == "throughput" and r["rate"] is not None:
            series.setdefault(r["runner"], []).append((r["tets"], r["rate"]))
    if not series:
        return None
    fig, ax = plt.subplots(figsize=(7, 4.5))
    styles = {"softsim": dict(color="C0", marker="o", lw=2), "taichi": dict(color="C1", marker="s"),
              "warp": dict(color="C2", marker="^"), "stream triad / 272 B": dict(color="k", ls="--")}
    for name, points in series.items():
        points.sort()
        style = styles.get(name, dict(color="C0", marker=".", ls=":", alpha=0.6))
        label = {"taichi": "Taichi CPU (atomics)", "warp": "Warp CPU (1 thread)",
                 "stream triad / 272 B": "bandwidth bound (STREAM triad / 272 B)"}.get(name, name)
        ax.plot([p[0] for p in points], [p[1] for p in points], label=label, **style)
        if name == "stream triad / 272 B":
            ax.plot([p[0] for p in points], [0.8 * p[1] for p in points], color="k", ls=":", lw=1, label="0.8 x bound")
    ax.set_xscale("log")
    ax.set_xlabel("tets (structured beam, StVK, float64)")
    ax.set_ylabel("M tet-steps / s")
    ax.set_ylim(bottom=0)
    ax.set_title(machine, fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
