"""Time-step choice: a stable step estimate and the plan of steps and frames."""

import logging
import math
from dataclasses import dataclass

from ..errors import ConfigError
from ..materials.lame import lame_parameters

log = logging.getLogger("softsim")

# dt: auto is the larger of two steps, both below symplectic Euler's limit 2 / omega_max at rest:
#
# - AUTO_SAFETY x the nodal-bound step (simulation.stable_dt_estimate), a rigorous lower bound of
#   the limit (measured 1.01-1.93x below it).  The 0.8 leaves room for what happens between two
#   re-checks of the eigenvalue limit (a body released from an inverted or flattened start changes
#   its tangent stiffness within a few steps; 1.0 blew up there).  On its own this left the limit
#   1.48-2.41x above auto: over 2x on gmsh meshes and slivers, where the bound is loose.
# - AUTO_EIGEN_SAFETY x the eigenvalue limit itself (stability.exact_stable_step, Lanczos), when
#   the run is long enough to pay for it (AUTO_EIGEN_MIN_STEPS).  0.6 keeps auto at or below what
#   the nodal step gave on structured meshes (0.8 / 1.19 = 0.67x the limit), where the hard starts
#   of tests/test_guard.py are tuned: released from inverted, flattened or crushed starts
#   (neohookean, corotated; structured and gmsh cubes), steps of 0.5 and 0.6x the rest limit
#   finished or were stopped cleanly by the guard in the same scenes, 0.7x blew up a mirrored and
#   squashed neohookean cube that 0.6x brings back.
#
# So auto lies between 0.6 and 0.8x the limit at rest: the measured limit is 1.25-1.67x auto.
AUTO_SAFETY = 0.8
AUTO_EIGEN_SAFETY = 0.6
# The eigenvalue limit is computed for dt: auto only when the run takes at least this many steps at
# the nodal-bound step: Lanczos takes 8-33 operator applications (2 force evaluations each) on the
# example and catalogue scenes, 0.01-0.1 s below 5k tets (the cost of 30-160 steps) and 0.85 s for
# 33 at 100k gmsh tets (about 220 steps), a few percent of such a run.  (Its Gram-Schmidt dot
# products once went through OpenBLAS, whose threads spun against Numba's on a busy 2-core machine:
# 9 s for the same estimate; they are serial jitted loops now, 0.30 s at 98k structured tets.)
AUTO_EIGEN_MIN_STEPS = 1000
# Most operator applications for that estimate; not converged by then, Lanczos returns the Ritz
# value plus its residual, an upper estimate of lambda_max (a smaller, still safe, step).
AUTO_EIGEN_ITERATIONS = 100


def dilatational_wave_speed(youngs_modulus, poissons_ratio, density):
    """``c_p = sqrt((lambda + 2 mu) / rho)`` [m/s], the fastest wave of linear elasticity."""
    lam, mu = lame_parameters(youngs_modulus, poissons_ratio)
    return math.sqrt((lam + 2.0 * mu) / density)


# Plans beyond these are refused before anything runs (they could not finish or fit on disk).
MAX_FRAMES = 1_000_000
MAX_STEPS = 1e12


@dataclass(frozen=True)
class TimePlan:
    """Steps and frames of a run: frame ``j`` is written after ``frame_steps[j]`` steps."""

    dt: float                 # [s]
    total_steps: int
    frame_steps: tuple        # step counts at which frames are written, starting with 0

    @property
    def frame_times(self):
        return tuple(s * self.dt for s in self.frame_steps)


def plan_time(duration, frame_interval, dt=None, max_dt=None, step_text=None):
    """A ``TimePlan`` for ``duration`` [s] with a frame every ``frame_interval`` [s].

    With ``max_dt`` (``auto``, ``exact``), dt is the largest step not above ``max_dt`` that fits a
    whole number of times into ``frame_interval`` (into ``duration``, where that is shorter: one
    frame at the end).  With a given ``dt``, frames fall on the nearest whole number of steps to
    ``frame_interval``, with a warning where that moves them (``step_text`` names the step there,
    default ``time.dt = <dt> s``).  The last frame is at the end of the run, ``total_steps * dt >=
    duration``.
    """
    frames = duration / frame_interval
    if not frames <= MAX_FRAMES:
        raise ConfigError(f"output.frame_interval = {frame_interval:g}: with time.duration = {duration:g} s that is "
                          f"{frames:.3g} frames; at most {MAX_FRAMES:.0e} are allowed")
    if dt is None:
        interval = min(frame_interval, duration)
        steps_per_frame = max(1, math.ceil(interval / max_dt - 1e-9))
        dt = interval / steps_per_frame
    else:
        steps_per_frame = max(1, round(frame_interval / dt))
        if abs(steps_per_frame * dt - frame_interval) > 1e-9 * frame_interval and frame_interval < duration:
            log.warning("%s does not fit output.frame_interval = %g s a whole number of times: "
                        "frames come every %d steps, %.6g s", step_text or f"time.dt = {dt:g} s", frame_interval,
                        steps_per_frame, steps_per_frame * dt)
    if not duration / dt <= MAX_STEPS:
        raise ConfigError(f"time.duration = {duration:g}: with dt = {dt:.3g} s that is {duration / dt:.3g} steps; "
                          f"at most {MAX_STEPS:.0e} are allowed")
    total_steps = max(1, math.ceil(duration / dt - 1e-9))
    frame_steps = list(range(0, total_steps + 1, steps_per_frame))
    if frame_steps[-1] != total_steps:
        frame_steps.append(total_steps)
    return TimePlan(dt=float(dt), total_steps=total_steps, frame_steps=tuple(frame_steps))
