"""``softsim run``: simulate a scene and write its frames to HDF5 (+ XDMF for ParaView)."""

import contextlib
import logging
import math
import signal
import sys

import click

from softsim.config import load_scene
from softsim.io.hdf5 import check_writable
from softsim.mesh import format_quality
from softsim.simulation import check_resumable, check_run_cost, prepare, safe_step_basis, simulate

from .launch import EXIT_INTERRUPTED
from .options import scene_argument, set_option

log = logging.getLogger("softsim")


def _progress_bar(total_steps):
    """A tqdm bar on a terminal's stderr, or None when stderr is not a TTY."""
    if not sys.stderr.isatty():
        return None
    from tqdm import tqdm

    return tqdm(total=total_steps, unit="step", file=sys.stderr, leave=False, dynamic_ncols=True)


# The summary line names the compile time when it is at least this [s].
COMPILE_NOTE_S = 0.5


@contextlib.contextmanager
def stop_on_signals():
    """While inside, Ctrl-C and SIGTERM ask the run to stop after the current frame.

    Yields a callable telling whether a stop was asked; a second Ctrl-C stops at once.
    """
    asked = []

    def handler(signum, frame):
        if asked and signum == signal.SIGINT:
            raise KeyboardInterrupt
        asked.append(signum)

    try:
        previous = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    except ValueError:          # not the main thread: signals stay as they are
        yield lambda: False
        return
    try:
        yield lambda: bool(asked)
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


@click.command()
@scene_argument
@click.option("-o", "--output", type=click.Path(path_type=str), default=None,
              help="Output HDF5 file (default: the scene's output.path).")
@click.option("--overwrite", is_flag=True, help="Replace an existing output file.")
@click.option("--resume", is_flag=True,
              help="Continue an interrupted or crashed run in the output file from its last complete frame.")
@click.option("-y", "--yes", is_flag=True,
              help="Start even if the run is estimated to take over an hour or to outgrow the free disk.")
@set_option
def run(scene, output, overwrite, resume, yes, overrides):
    """Simulate SCENE (a YAML scene file) and write its frames to an HDF5 file.

    \b
    Examples:
      softsim run configs/cantilever.yaml
      softsim run configs/cantilever.yaml -o stiff.h5 --set material.youngs_modulus=2e11
    """
    scene_config = load_scene(scene, overrides)
    if output is not None:   # the stored config says where the run really went
        scene_config = scene_config.model_copy(
            update={"output": scene_config.output.model_copy(update={"path": output})})
    if resume and overwrite:
        raise click.UsageError("--resume and --overwrite exclude each other")
    if resume:
        frames, time = check_resumable(scene_config, scene_config.output.path)
        log.info("resuming %s from t = %.6g s, its last complete frame (%d kept)", scene_config.output.path, time,
                 frames)
    else:
        inputs = (scene,) + ((scene_config.mesh.file,) if scene_config.mesh.file else ())
        check_writable(scene_config.output.path, overwrite, inputs)   # before meshing: a bad path costs no work
    prepared = prepare(scene_config, resuming=resume, compile_in_helper=True)
    log.info("mesh: %s", format_quality(prepared.mesh.quality()))
    plan = prepared.plan
    given = "" if prepared.substeps == 1 else f" (time.dt split into {prepared.substeps} sub-steps, dt_policy: substep)"
    safe = (f"safe step {prepared.safe_dt:.4g} s ({safe_step_basis(scene_config.time)})"
            if math.isfinite(prepared.safe_dt) else "no step limit (nothing moves but held vertices)")
    log.info("dt = %.4g s%s, %s, %d steps, %d frames", plan.dt, given, safe, plan.total_steps, len(plan.frame_steps))
    for problem in check_run_cost(prepared, scene_config.output.path, confirmed=yes):
        log.warning("%s (--yes given)", problem)
    bar = _progress_bar(plan.total_steps)
    update = None if bar is None else (lambda done, total: bar.update(done - bar.n))
    try:
        with stop_on_signals() as should_stop:
            summary = simulate(prepared, scene_config.output.path, update, should_stop, resume=resume,
                               overwrite=overwrite)
    finally:
        if bar is not None:
            bar.close()
    compiling = (f" ({summary.compile_time_s:.1f} s of it compiling the kernels, once: later runs load them from "
                 f"the cache)" if summary.compile_time_s >= COMPILE_NOTE_S else "")
    steps = f"{summary.steps}" if summary.status == "complete" else f"{summary.step} of {summary.steps}"
    click.echo(f"{summary.path}: {steps} steps, dt {summary.dt:.4g} s, {summary.frames} frames, "
               f"wall {summary.wall_time_s:.2f} s{' this session' if resume else ''}{compiling}, "
               f"{summary.tet_steps_per_s / 1e6:.3g} M tet-steps/s")
    if summary.status == "interrupted":
        click.echo(f"softsim: interrupted at t = {summary.time:.6g} s; {summary.frames} frames kept in "
                   f"{summary.path} (status: interrupted)", err=True)
        sys.exit(EXIT_INTERRUPTED)
