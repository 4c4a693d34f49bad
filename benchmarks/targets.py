"""The performance issue's targets, checked against the rows of one run of the suite.

    python -m benchmarks.targets benchmarks/results/results.csv [--host avx512|avx2]

``python -m benchmarks`` puts these rows first in its ``results.md`` (section ``targets``); this
command derives them again from any run's ``results.csv``.  Each row is one target at one size:
``ratio`` the value measured in that run, ``ratio_to`` what the target needs, ``note`` ``met`` or
``short`` (or why it could not be judged).  Pure Python over the rows: nothing is timed here.

The targets (float64 StVK on the structured beam, 2 threads, unless a row says otherwise):

- throughput at least 0.8 of the bandwidth bound, 3x Taichi and 2x Warp at 10k, 100k and 1M tets;
- the other material models within 1.5x StVK's cost, and float32 at least 1.6x float64;
- 2 threads at least 1.8x one thread from 100k tets;
- the cost per tet-step flat within 20 % from 10k to 2M tets: each size against the cheapest, all
  sizes timed in the same rounds (section ``sizes``; a run without it is judged from its
  throughput section);
- at most 150 bytes a tet of arrays the step touches, at 1M tets;
- a warm start-up (Numba's on-disk cache) stepping within 2 s;
- at most 10 % of a run's wall time outside the step loop at the example scenes' frame interval
  (10 ms), and a scene with no optional feature within 5 % of the bare kernel's speed, the
  once-per-frame guard included: the guard's share of the wall time;
- the peers computing the same positions (to round-off: 1e-10 of the displacement after the
  check's 1,000 steps) at speeds no more than 25 % under the issue's table for this host kind
  (AVX-512 or AVX2, as the run's ``host`` row records it): a peer slowed by a poor port proves
  nothing, a faster one takes nothing from softsim's ratio to it.
"""

import argparse
import csv
import sys

# Sizes the issue names, and how far (a factor) a beam's tet count may lie from one to count as it.
NOMINAL_SIZES = (10_000, 100_000, 1_000_000, 2_000_000)
SIZE_TOLERANCE = 1.3
# The table of peer speeds, M tet-steps/s at 10k / 100k / 1M tets: Taichi on 2 threads,
# Warp on its one (host B: AVX-512; host A: Zen 3, AVX2).
PEER_TABLE = {
    "avx512": {"taichi": {10_000: 19, 100_000: 26, 1_000_000: 30}, "warp": {10_000: 47, 100_000: 51, 1_000_000: 51}},
    "avx2": {"taichi": {10_000: 21, 100_000: 22, 1_000_000: 30}, "warp": {10_000: 25, 100_000: 25, 1_000_000: 30}},
}
PEER_SPEED_FLOOR = 0.75          # of the table's speed
SAME_ANSWER = 1e-10              # max |x_peer - x_softsim| over the largest displacement
BOUND_SHARE = 0.8
TIMES_TAICHI = 3.0
TIMES_WARP = 2.0
MODEL_COST = 1.5                 # other models' cost per tet-step over StVK's
FLOAT32_SPEEDUP = 1.6
THREAD_SPEEDUP = 1.8
THREAD_SCALING_FROM = 100_000
FLAT_COST = 1.2                  # cost per tet-step over the cheapest size's, 10k to 2M
STEP_BYTES_PER_TET = 150.0       # at 1M tets
WARM_START_SECONDS = 2.0
OUTSIDE_SHARE = 0.10             # of the wall time, frames every 10 ms
GUARD_SHARE = 0.05


def host_row(kind):
    """The row that records which host kind's peer table (``PEER_TABLE``) judges a run."""
    if kind not in PEER_TABLE:
        raise ValueError(f"host kind {kind!r}: must be one of {', '.join(PEER_TABLE)}")
    return dict(section="host", case="peer table", tets=None, runner="softsim", threads=None, rate=None,
                ratio=None, ratio_to=None, note=kind)


def host_kind(rows):
    """The host kind a run's ``host`` row records; ``avx512`` for a run without one."""
    return next((r["note"] for r in _pick(rows, "host", "peer table")), "avx512")


def nominal_size(tets):
    """The issue's size (``NOMINAL_SIZES``) a beam of ``tets`` tets stands for, or None."""
    if not tets:
        return None
    for size in NOMINAL_SIZES:
        if size / SIZE_TOLERANCE <= tets <= size * SIZE_TOLERANCE:
            return size
    return None


def _number(value):
    return None if value in (None, "") else float(value)


def _row(case, tets, value, need, met, note=""):
    verdict = "not measured" if value is None else "met" if met else "short"
    return dict(section="targets", case=case, tets=tets, runner="softsim", threads=None,
                rate=None, ratio=None if value is None else float(f"{value:.4g}"), ratio_to=need,
                note=verdict + (f": {note}" if note else ""))


def _at_least(case, tets, value, need):
    return _row(case, tets, value, f">= {need:g}", value is not None and value >= need)


def _at_most(case, tets, value, need, note=""):
    return _row(case, tets, value, f"<= {need:g}", value is not None and value <= need, note)


def _pick(rows, section, case=None, runner=None):
    return [r for r in rows if r["section"] == section and (case is None or r["case"] == case)
            and (runner is None or r["runner"] == runner)]


def _throughput_targets(rows, host):
    by_size = {}
    for r in _pick(rows, "throughput"):
        size = nominal_size(r["tets"])
        if size in (10_000, 100_000, 1_000_000):
            by_size.setdefault(size, {})[r["case"]] = r
    out = []
    for size, found in sorted(by_size.items()):
        soft = found.get("softsim", {})
        tets = soft.get("tets")
        out.append(_at_least("softsim / bandwidth bound", tets, _number(soft.get("ratio")), BOUND_SHARE))
        for peer, need in (("taichi", TIMES_TAICHI), ("warp", TIMES_WARP)):
            if peer not in found:
                out.append(_row(f"softsim / {peer}", tets, None, f">= {need:g}", False, "the peer did not run"))
                continue
            out.append(_at_least(f"softsim / {peer}", tets, _number(found[peer]["ratio"]), need))
            rate, table = _number(found[peer]["rate"]), PEER_TABLE[host][peer][size]
            out.append(_row(f"{peer} speed against the issue's table", tets, rate / table,
                            f">= {PEER_SPEED_FLOOR:g} of {table}", rate / table >= PEER_SPEED_FLOOR,
                            f"{rate:.1f} M tet-steps/s"))
    return out


def _flat_cost_targets(rows):
    """From the ``sizes`` section (every size interleaved; its ratios are per-round medians against
    the cheapest), or in a run without it, from the throughput section's softsim rates."""
    sizes = [r for r in _pick(rows, "sizes", "softsim") if _number(r["rate"])]
    source = sizes or [r for r in _pick(rows, "throughput", "softsim") if _number(r["rate"])]
    if not source:
        return []
    cost = {r["tets"]: 1e3 / _number(r["rate"]) for r in source}
    cheapest = min(cost, key=cost.get)
    against = ({r["tets"]: _number(r["ratio"]) for r in sizes} if sizes
               else {tets: cost[tets] / cost[cheapest] for tets in cost})
    note = f"the cheapest: {cheapest:,} tets, {cost[cheapest]:.2f} ns"
    note += "; all sizes interleaved" if sizes else "; sizes timed one after another"
    if not {10_000, 2_000_000} <= {nominal_size(t) for t in cost}:
        note += "; the run does not span 10k to 2M tets"
    return [_at_most("cost per tet-step against the cheapest size", tets, against[tets], FLAT_COST, note)
            for tets in sorted(cost)]


def _same_answer_targets(rows):
    out = []
    for r in _pick(rows, "check", "same answer"):
        value = _number(r["ratio"])
        out.append(_row(f"{r['runner']}'s positions against softsim's", r["tets"], value, f"<= {SAME_ANSWER:g}",
                        value is not None and value <= SAME_ANSWER, "" if value is not None else r["note"]))
    return out


def _thread_targets(rows):
    return [_at_least(f"{r['case']} against 1 thread", r["tets"], _number(r["ratio"]), THREAD_SPEEDUP)
            for r in _pick(rows, "threads")
            if _number(r["ratio"]) is not None and r["tets"] >= THREAD_SCALING_FROM / SIZE_TOLERANCE]


def _model_targets(rows):
    out = [_at_most(f"{r['case']} cost against stvk", r["tets"], _number(r["ratio"]), MODEL_COST)
           for r in _pick(rows, "models") if r["case"] != "stvk"]
    out += [_at_least(f"{r['case'].split()[0]} float32 speed against float64", r["tets"], _number(r["ratio"]),
                      FLOAT32_SPEEDUP)
            for r in _pick(rows, "precision") if r["case"].endswith("float32")]
    return out


def _run_targets(rows):
    out = [_at_most("bytes a tet of the arrays the step touches", r["tets"], _number(r["ratio"]), STEP_BYTES_PER_TET)
           for r in _pick(rows, "memory", "arrays the step touches") if nominal_size(r["tets"]) == 1_000_000]
    out += [_at_most("seconds to the first step, warm cache", r["tets"], _number(r["ratio"]), WARM_START_SECONDS)
            for r in _pick(rows, "startup", "warm (on-disk cache)")]
    out += [_at_most("share of a run outside the step loop, frames every 10 ms", r["tets"], _number(r["ratio"]),
                     OUTSIDE_SHARE)
            for r in _pick(rows, "overhead", "outside kernels, frames every 10 ms")]
    out += [_at_most("a bare scene's slowdown from the kernel's speed (the guard's share), frames every 10 ms",
                     r["tets"], _number(r["ratio"]), GUARD_SHARE)
            for r in _pick(rows, "overhead", "guard, frames every 10 ms")]
    return out


def targets(rows, host=None):
    """The ``targets`` rows (the suite's row format) judged from ``rows`` of one run (``suite``'s,
    or read back from ``results.csv``); ``host``: which host kind's row of the issue's peer table
    applies (``PEER_TABLE``), by default the one the run recorded (``host_kind``).  A target whose
    section did not run gives no row."""
    host = host or host_kind(rows)
    return (_same_answer_targets(rows) + _throughput_targets(rows, host) + _flat_cost_targets(rows)
            + _thread_targets(rows) + _model_targets(rows) + _run_targets(rows))


def summary(target_rows):
    """One line: how many targets were met, and the cases of those short."""
    short = [r["case"] + ("" if r["tets"] is None else f" at {int(r['tets']):,} tets")
             for r in target_rows if r["note"].startswith("short")]
    met = sum(r["note"].startswith("met") for r in target_rows)
    return f"targets: {met} met, {len(short)} short" + (f" ({'; '.join(short)})" if short else "")


def read_rows(path):
    """The rows of a ``results.csv``, numbers as numbers."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    for r in rows:
        r["tets"] = int(r["tets"]) if r["tets"] else None
        for key in ("rate", "ratio"):
            r[key] = _number(r[key])
    return rows


def markdown(target_rows):
    """The rows as a markdown table: target, tets, measured, needed, verdict."""
    lines = ["| target | tets | measured | needed | verdict |", "|---|---|---|---|---|"]
    for r in target_rows:
        value = "" if r["ratio"] is None else f"{r['ratio']:.3g}"
        tets = "" if r["tets"] is None else f"{int(r['tets']):,}"
        lines.append(f"| {r['case']} | {tets} | {value} | {r['ratio_to']} | {r['note']} |")
    return "\n".join(lines) + "\n"


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m benchmarks.targets", description=__doc__.split("\n\n")[0])
    parser.add_argument("csv", help="a results.csv written by python -m benchmarks")
    parser.add_argument("--host", choices=list(PEER_TABLE),
                        help="judge the peers by this host kind's row of the issue's table (default: the run's)")
    args = parser.parse_args(argv)
    judged = targets(read_rows(args.csv), args.host)
    sys.stdout.write(markdown(judged) + "\n" + summary(judged) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
