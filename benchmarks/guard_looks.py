"""How close the guard lets the step come to the stability limit, and how often it looks.

The guard (``softsim.integrators.guard``) recomputes the stable step by Lanczos once an element's J
or stretch has moved by ``recheck_change`` since its last look: 5 % where the step is at its
sub-steps' limit, more where the last look left a margin.  This runs the stress scenes of
``softsim stability`` (``reports.catalogue``, every model) and the example scenes with the guard
as it is and with a fixed 5 %, and at every check (each frame, and every ``RECHECK_STEPS`` steps)
computes the true limit at the current state (Lanczos, ``tol`` 1e-4) to measure

    worst = max over the checks of (the step taken since the last check) / (the limit now)

and counts the guard's own looks.  A margin-aware threshold that is as safe as the fixed one gives
the same worst ratios and outcomes with fewer looks.

    python benchmarks/guard_looks.py                      # every scene, both thresholds (~10 min)
    python benchmarks/guard_looks.py crushed-cube         # catalogue scenes by name
"""

import argparse
import logging
import math
import tempfile
from pathlib import Path

from softsim import simulation
from softsim.config import load_scene, parse_scene
from softsim.errors import ConfigError, SoftsimError
from softsim.integrators import guard
from softsim.integrators.stability import exact_stable_step
from softsim.reports.catalogue import MODELS, catalogue

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ("bouncing_cube", "twisted_bar", "cantilever")


class Watch:
    """Wraps the guard's checks: the worst step / limit seen, and the guard's own looks."""

    def __init__(self):
        self.worst, self.looks = 0.0, 0
        self._plain = (guard.FrameGuard.check, guard.FrameGuard.recheck_step, guard.exact_stable_step)

    def __enter__(self):
        check, recheck, look = self._plain

        def measured(original):
            def wrapper(frame_guard, state, time):
                if state.step > 0:
                    limit = exact_stable_step(frame_guard.model, state.x, iterations=400, tol=1e-4)
                    ratio = frame_guard.dt / frame_guard.substeps / limit if limit > 0.0 else math.inf
                    self.worst = max(self.worst, ratio)
                return original(frame_guard, state, time)
            return wrapper

        def counted(*args, **kwargs):
            self.looks += 1
            return look(*args, **kwargs)

        guard.FrameGuard.check, guard.FrameGuard.recheck_step = measured(check), measured(recheck)
        guard.exact_stable_step = counted
        return self

    def __exit__(self, *exc):
        guard.FrameGuard.check, guard.FrameGuard.recheck_step, guard.exact_stable_step = self._plain
        return False


def run(scene, folder):
    """``(worst, looks, outcome)`` of one run of ``scene``."""
    with Watch() as watch:
        try:
            summary = simulation.simulate(simulation.prepare(scene), Path(folder) / "run.h5", overwrite=True)
            outcome = summary.status
        except SoftsimError as exc:
            outcome = "stopped: " + str(exc).splitlines()[0][:50]
    return watch.worst, watch.looks, outcome


def scenes(folder, names):
    for entry in catalogue(folder, quick=False):
        if entry.name.endswith("allow") or (names and entry.name not in names):
            continue            # allow: the guard does not look at the step
        for model in MODELS:
            try:
                yield f"{entry.name}/{model}", parse_scene(entry.scene_data(model), base_dir=folder)
            except ConfigError as exc:      # an inverted start for linear / stvk: nothing to run
                print(f"{entry.name + '/' + model:<30} refused: {exc}", flush=True)
    for name in () if names else EXAMPLES:
        yield name, load_scene(ROOT / "configs" / f"{name}.yaml")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help="catalogue scenes (default: all, and the examples)")
    args = parser.parse_args()
    logging.disable(logging.WARNING)
    margin_aware = guard.recheck_change
    print(f"{'scene':<30} {'worst step / limit':>19} {'looks':>13}  outcome (guard as is / fixed 5 %)")
    with tempfile.TemporaryDirectory() as folder:
        for name, scene in scenes(folder, args.names):
            results = []
            for threshold in (margin_aware, lambda margin: guard.RECHECK_CHANGE):
                guard.recheck_change = threshold
                try:
                    results.append(run(scene, folder))
                finally:
                    guard.recheck_change = margin_aware
            (worst, looks, outcome), (worst_fixed, looks_fixed, outcome_fixed) = results
            same = "" if outcome == outcome_fixed else f" / {outcome_fixed}"
            print(f"{name:<30} {worst:>9.3f} {worst_fixed:>9.3f} {looks:>6} {looks_fixed:>6}  {outcome}{same}",
                  flush=True)


if __name__ == "__main__":
    main()
