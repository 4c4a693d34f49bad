"""Running a sweep's runs on Dask: a local cluster of process workers or an existing scheduler.

The client validates every run and builds each distinct mesh once before anything is submitted;
each worker runs one run at a time (one Dask thread, its share of the cores as Numba threads)
and, unless the workers share the output folder, writes the HDF5 file to a local temporary
folder and sends its bytes back for the client to write.  The summary row of every run is read
from its file (``metrics.run_metrics``).

Dask is imported only here and only when a sweep runs: a plain ``pip install softsim`` works
without it, and ``import_distributed`` names the extra to install.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import math
import os
import shutil
import signal
import socket
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

from ..errors import MissingDependencyError, SimulationError, SoftsimError
from ..io.hdf5 import being_written, xdmf_path_for
from ..kernels.compile_ahead import available_cores
from .metrics import METRIC_COLUMNS, run_metrics
from .spec import Run

log = logging.getLogger("softsim")

SUMMARY_NAME = "summary"
# Status in the summary of a run the sweep never finished (Ctrl-C): as a file's would be.
NOT_FINISHED = "interrupted"
# Seconds a mesh's scatter to the workers may take before the runs carry the mesh themselves.
SCATTER_TIMEOUT_S = 120.0
# Times a run is submitted again, carrying its mesh, when Dask cancels it for one of
# ``LOST_REASONS``: at most this often.  (A run whose own worker dies Dask reschedules itself,
# until the run has killed ``distributed.scheduler.allowed-failures`` + 1 workers: KilledWorker.)
LOST_RUN_RESUBMITS = 3
# Dask's reasons for cancelling a task that mean the workers lost what it needs (its scattered
# mesh died with a worker) or all of it (a restart of the cluster); not the reasons that mean the
# client lost the scheduler or another client cancelled it.  "unknown" is how the client names a
# key the scheduler reports it no longer has, with no reason: a run that had finished on a worker
# that died while its result was being fetched, and that could not run again without the mesh
# that died with it (``Scheduler.report_on_key``).
LOST_REASONS = ("already forgotten", "lost dependencies", "scheduler-restart", "unknown")
# Seconds to wait for a scheduler to answer, and on connecting to a cluster that has no workers,
# for one to join.
CONNECT_TIMEOUT_S = 10.0
WORKER_WAIT_S = 30.0
# A sweep's runs left fail when the cluster has had no worker for this long [s], instead of
# waiting for ever (``runs_cancelled_without_workers``); it looks every WORKER_POLL_S seconds.
NO_WORKERS_TIMEOUT_S = 60.0
WORKER_POLL_S = 1.0
# A run on a worker asks the scheduler whether its sweep was stopped (Ctrl-C) at its frames, at
# most once in this many seconds; an answer not back within STOP_ASK_TIMEOUT_S is not waited for.
STOP_POLL_S = 1.0
STOP_ASK_TIMEOUT_S = 5.0
# Seconds a shared folder may take to show this machine a file a worker wrote (NFS keeps a
# "no such file" answer up to a minute); after one that never showed, the sweep waits no more.
SHARED_FILE_WAIT_S = 60.0


def import_distributed():
    """``dask.distributed``, or ``MissingDependencyError`` naming the extra that brings it."""
    try:
        import distributed
    except ImportError as exc:
        raise MissingDependencyError(
            f"softsim sweep needs Dask ({exc.name or 'distributed'} is not installed): "
            f"pip install \".[sweep]\" in softsim's source folder") from None
    return distributed


def local_layout(run_count, workers=None, cores=None):
    """``(workers, numba_threads)`` of a local cluster: workers x threads <= cores, never oversubscribed.

    By default as many single-threaded workers as there are cores (runs in parallel beat threads
    within a run for the small meshes sweeps are made of), but no more workers than runs; the
    cores left over go to each worker's Numba threads.
    """
    cores = cores or available_cores()
    if workers is None:
        workers = max(1, min(cores, run_count))
    return workers, max(1, cores // workers)


# ---------------------------------------------------------------------------------------------
# Worker side


def execute_run(scene, mesh, name, target_dir=None, numba_threads=None, stop_event=None):
    """Run one sweep run on a worker; returns a dict (never raises for a failed run).

    scene: the run's validated scene; mesh: its built ``TetMesh``; target_dir: a folder the client
    also sees (write the file there), or None (write to a local temporary folder and return the
    bytes of ``<name>.h5`` and ``<name>.xdmf`` under ``files``).  numba_threads: Numba threads
    for this run, or None to leave the worker's setting.  stop_event: the name of the sweep's
    ``distributed.Event``: once it is set, the run ends at its next frame, its file ``interrupted``
    (``stop_requested``).  The dict has ``name``, ``error`` (one line, or None), ``metrics`` (None
    if no file was written), ``numba_threads``, ``host``.
    """
    import numba

    from ..simulation import prepare, simulate

    if numba_threads:
        numba.set_num_threads(max(1, min(int(numba_threads), numba.config.NUMBA_NUM_THREADS)))
    folder = Path(target_dir) if target_dir is not None else Path(tempfile.mkdtemp(prefix="softsim-sweep-"))
    path = folder / f"{name}.h5"
    result = {"name": name, "error": None, "metrics": None, "files": None, "warnings": [],
              "numba_threads": numba.get_num_threads(), "host": socket.gethostname()}
    catcher = _ListHandler(result["warnings"])
    log.addHandler(catcher)
    try:
        try:
            simulate(prepare(scene, mesh), path, should_stop=stop_requested(stop_event) if stop_event else None)
        except SoftsimError as exc:
            result["error"] = str(exc)
        except Exception as exc:    # a bug must not stop the other runs; the file says failed too
            result["error"] = (f"{type(exc).__name__}: {exc}".splitlines() or [""])[0]
        if path.is_file():
            result["metrics"] = run_metrics(path)
            if target_dir is None:
                result["files"] = {p.name: p.read_bytes() for p in (path, xdmf_path_for(path)) if p.is_file()}
        return result
    finally:
        log.removeHandler(catcher)
        if target_dir is None:
            shutil.rmtree(folder, ignore_errors=True)


def stop_requested(event_name, every_s=None):
    """A ``should_stop()`` for ``simulation.simulate`` on a worker: whether the sweep's
    ``distributed.Event`` ``event_name`` is set, asked of the scheduler at most every ``every_s``
    seconds (``STOP_POLL_S``), the last answer given in between and where the scheduler does not
    answer within ``STOP_ASK_TIMEOUT_S``.  Never True where no Dask client is to be had (not on a
    worker)."""
    distributed = import_distributed()
    try:
        client = distributed.get_client()
    except ValueError:              # no worker, no client: nothing can ask this run to stop
        return lambda: False
    every_s = STOP_POLL_S if every_s is None else every_s
    asked = {"at": -math.inf, "set": False}

    def should_stop():
        now = time.monotonic()
        if now - asked["at"] >= every_s:
            asked["at"] = now
            try:
                asked["set"] = bool(client.sync(client.scheduler.event_is_set, name=event_name,
                                                callback_timeout=STOP_ASK_TIMEOUT_S))
            except Exception:       # the scheduler did not answer: go on, ask again later
                pass
        return asked["set"]

    return should_stop


class _ListHandler(logging.Handler):
    """Collects the messages softsim logs during a run on a worker; the client logs them with the run's name."""

    def __init__(self, messages):
        super().__init__(logging.WARNING)
        self.messages = messages

    def emit(self, record):
        self.messages.append(record.getMessage())


# ---------------------------------------------------------------------------------------------
# Client side


@dataclass
class SweepResult:
    """Rows of the summary (one per run, in run order) and where the summary was written."""

    rows: list
    summary_paths: list
    skipped: int = 0
    cancelled: bool = False
    counts: dict = field(default_factory=dict)

    @property
    def failed(self):
        return [row for row in self.rows if row["status"] != "complete"]


def plan_runs(runs, force=False):
    """``(to_run, to_skip)``: runs whose file is complete with the same scene are skipped unless ``force``
    (for a mesh file, the same content: ``simulation.run_file_difference``; a file that does not
    record it is rerun).

    A file that is not complete (failed, interrupted, left running by a killed sweep) is
    replaced.  A complete file written for a different scene is not replaced without ``force``:
    ``SimulationError`` naming the run and the first differing key, before anything runs; nor is
    a file a run still writes (one of an earlier sweep that a cluster's worker goes on with).
    """
    import yaml

    from ..io.hdf5 import run_attributes
    from ..simulation import run_file_difference

    to_run, to_skip = [], []
    digests = {}                        # each mesh file hashed once, however many runs use it
    for run in runs:
        path = run.path
        if force or not path.exists():
            to_run.append(run)
            continue
        if path.is_dir():
            raise SimulationError(f"run {run.index + 1} ({run.name}): {path} is a directory")
        if being_written(path):
            raise SimulationError(f"run {run.index + 1} ({run.name}): {path} is open for writing by another "
                                  f"process (a run of an earlier sweep still going on a worker?); wait for it to end")
        stored = run_attributes(path)
        status = stored.get("status", "")
        if "config" not in stored:
            raise SimulationError(f"run {run.index + 1} ({run.name}): {path} exists and is not a softsim run "
                                  f"file; pass --force to replace it or choose another output folder")
        if status != "complete":
            to_run.append(run)
            continue
        try:
            difference = run_file_difference(stored, run.scene, digests)
        except (yaml.YAMLError, AttributeError):      # not a mapping: not a scene softsim wrote
            difference = "config: not a scene"
        if difference is not None:
            raise SimulationError(
                f"run {run.index + 1} ({run.name}): {path} is complete but was written for another scene "
                f"({difference}); pass --force to rerun it or choose another output folder")
        if run.scene.mesh.shape == "file" and "mesh_file_sha256" not in stored:
            to_run.append(run)          # written before softsim kept the mesh file's hash: its mesh is unknown
            continue
        to_skip.append(run)
    return to_run, to_skip


def summary_columns(runs):
    """The columns of the summary of ``runs`` (``summary_row``'s keys), known before any run:
    run, name, file, each swept key, then ``METRIC_COLUMNS``."""
    return ["run", "name", "file", *(runs[0].parameters if runs else ()), *METRIC_COLUMNS]


def summary_row(run, metrics=None, error=None):
    """One summary row: run number, name, file, each swept key's value, then ``METRIC_COLUMNS``."""
    row = {"run": run.index + 1, "name": run.name, "file": run.path.name}
    for key, value in run.parameters.items():
        row[key] = value if isinstance(value, (int, float, str, bool)) else str(value)
    if metrics is None:
        metrics = {column: math.nan for column in METRIC_COLUMNS}
        metrics.update(status="failed", status_reason=error or "no output file was written")
    elif error and metrics["status"] == "running":     # a crash the file could not record
        metrics = dict(metrics, status="failed", status_reason=error)
    row.update(metrics)
    return row


def write_summary(rows, output_dir):
    """Write ``summary.csv`` (and ``summary.parquet`` if pyarrow is importable); returns their paths."""
    import csv

    output_dir = Path(output_dir)
    columns = list(dict.fromkeys(column for row in rows for column in row))
    csv_path = output_dir / f"{SUMMARY_NAME}.csv"
    part = csv_path.with_name(f".{csv_path.name}.part")
    with open(part, "w", newline="") as stream:
        writer = csv.DictWriter(stream, fieldnames=columns, restval="")
        writer.writeheader()
        for row in rows:
            writer.writerow({key: _csv_value(value) for key, value in row.items()})
    os.replace(part, csv_path)
    paths = [csv_path]
    try:
        import pyarrow
        import pyarrow.parquet
    except ImportError:
        return paths
    table = pyarrow.Table.from_pylist([{column: row.get(column) for column in columns} for row in rows])
    parquet_path = output_dir / f"{SUMMARY_NAME}.parquet"
    pyarrow.parquet.write_table(table, parquet_path)
    paths.append(parquet_path)
    return paths


def _csv_value(value):
    if isinstance(value, float):
        return "" if math.isnan(value) else repr(value)
    return value


def _write_files(files, output_dir):
    """Write the bytes a worker sent back; each file appears whole (written aside, then renamed)."""
    for name, data in files.items():
        target = Path(output_dir) / name
        part = target.with_name(f".{name}.part")
        part.write_bytes(data)
        os.replace(part, target)


def build_meshes(runs):
    """Each distinct ``mesh`` section's ``TetMesh``, built once: ``{mesh key: mesh}``, and each run's key.

    A mesh that cannot be built is a ``SoftsimError`` naming the first run that uses it.
    """
    from ..mesh import build_mesh

    meshes, keys = {}, {}
    for run in runs:
        key = run.scene.mesh.model_dump_json()
        keys[run.index] = key
        if key not in meshes:
            try:
                meshes[key] = build_mesh(run.scene.mesh)
            except SoftsimError as exc:
                raise type(exc)(f"run {run.index + 1} ({run.name}): {exc}") from None
    return meshes, keys


def scatter_meshes(client, meshes, timeout=None):
    """Each mesh of ``meshes`` ({key: mesh}) sent to a worker once: {key: future}, for the runs to take.

    A scatter that has not finished after ``timeout`` seconds (``SCATTER_TIMEOUT_S``) is given up,
    with a warning, and that mesh is returned itself: each run using it then carries it in its task,
    which is slower but still runs.  (``Client.scatter``'s own ``timeout`` bounds only the wait for a
    worker.  A scatter was once seen to hang here, on a local cluster whose previous sweep had been
    cancelled, the workers idle; scatters hanging in tests are dask/distributed#4907.)
    """
    timeout = SCATTER_TIMEOUT_S if timeout is None else timeout
    scattered = {}
    for key, mesh in meshes.items():
        try:
            scattered[key] = client.sync(functools.partial(client.scatter, mesh, hash=False, asynchronous=True),
                                         callback_timeout=timeout)
        except (TimeoutError, asyncio.TimeoutError):     # the same class from Python 3.11 on
            log.warning("sending a mesh to the workers took over %g s; the runs carry it themselves", timeout)
            scattered[key] = mesh
    return scattered


def _remove_run_files(path):
    """Remove a run's file ``path`` and the ``.xdmf`` beside it, where they are."""
    for stale in (path, xdmf_path_for(path)):
        stale.unlink(missing_ok=True)


def _appears(path, wait_s):
    """Whether ``path`` is a file, or becomes one within ``wait_s`` seconds; each look lists its
    folder first, which makes a network file system look again."""
    deadline = time.monotonic() + wait_s
    while True:
        with contextlib.suppress(OSError):
            os.listdir(path.parent)
        if path.is_file():
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.5)


@contextlib.contextmanager
def _sigint_ignored_in_children():
    """While inside, SIGINT is ignored, so worker processes started now ignore Ctrl-C.

    Ctrl-C on a terminal goes to every process of the foreground group; the client alone
    should handle it (cancel, then stop the workers).  An ignored signal stays ignored in a
    child, and Python leaves it so.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def local_cluster_config():
    """The Dask settings of a local cluster.  Its nannies restart a worker that dies.  Dask's
    cluster object also closes a nanny whose worker has not come back ``lost-worker-timeout`` after
    a worker of its name died (meant for clusters of batch jobs), checking only then, not whether
    the worker died and came back meanwhile: with every worker killed twice, 15 s apart (the
    default timeout), it closed both nannies while their workers restarted, and the sweep waited
    for a worker, for ever (a test, on a loaded host, once in 5-8 runs of its module).  Here the
    nannies alone restart workers; where none is left, ``runs_cancelled_without_workers`` ends
    the sweep."""
    return {"distributed.deploy.lost-worker-timeout": "365 days"}


@contextlib.contextmanager
def local_client(workers, numba_threads):
    """A ``distributed.Client`` on a new local cluster of ``workers`` single-threaded process workers.

    Each worker gets ``NUMBA_NUM_THREADS=numba_threads`` in its environment and the preload
    ``worker_setup``, which makes Numba read it again before its threads start.  One Dask thread
    per worker: Numba's ``workqueue`` threading layer aborts when two threads of one process run
    parallel code at once.
    """
    distributed = import_distributed()
    import dask

    with dask.config.set(local_cluster_config()), _local_cluster(distributed, workers, numba_threads) as cluster:
        with distributed.Client(cluster) as client:
            yield client


@contextlib.contextmanager
def _local_cluster(distributed, workers, numba_threads):
    """``local_client``'s cluster."""
    with _sigint_ignored_in_children():
        cluster = distributed.LocalCluster(
            n_workers=workers, threads_per_worker=1, processes=True, silence_logs=logging.CRITICAL,
            env={"NUMBA_NUM_THREADS": str(int(numba_threads))}, preload=[f"{__package__}.worker_setup"],
            # No dashboard; the scheduler's small HTTP server on a free port, not 8787.
            dashboard_address=":0", scheduler_kwargs={"dashboard": False})
    try:
        yield cluster
    finally:
        cluster.close()


@contextlib.contextmanager
def remote_client(address, worker_wait_s=None):
    """A ``distributed.Client`` connected to the scheduler at ``address`` (``tcp://host:port``)
    that has a worker: one that has none is waited for ``worker_wait_s`` (``WORKER_WAIT_S``) to
    get one.  ``SimulationError``, one line, where nothing answers at ``address``, it is not an
    address, or no worker came."""
    distributed = import_distributed()
    worker_wait_s = WORKER_WAIT_S if worker_wait_s is None else worker_wait_s
    # Dask's own warnings (a result gathered again after a worker died) say nothing softsim's
    # summary does not, in Dask's terms: a local cluster silences them too (``silence_logs``)
    # (Dask's logging configuration gives ``distributed.client`` a level and a handler of its own.)
    dask_logs = [logging.getLogger(name) for name in ("distributed", "distributed.client")]
    levels = [dask_log.level for dask_log in dask_logs]
    for dask_log in dask_logs:
        dask_log.setLevel(logging.ERROR)
    try:
        with _connected(distributed, address, worker_wait_s) as client:
            yield client
    finally:
        for dask_log, level in zip(dask_logs, levels):
            dask_log.setLevel(level)


@contextlib.contextmanager
def _connected(distributed, address, worker_wait_s):
    """``remote_client``'s client, connected and with a worker."""
    try:
        client = distributed.Client(address, timeout=f"{CONNECT_TIMEOUT_S}s")
    except (OSError, TimeoutError, ValueError) as exc:
        reason = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise SimulationError(f"--scheduler {address}: cannot connect ({reason}); is a Dask scheduler running "
                              f"there (dask scheduler), and is the address tcp://HOST:PORT?") from None
    with client:
        if not client.nthreads():
            try:
                client.wait_for_workers(1, timeout=worker_wait_s)
            except (TimeoutError, asyncio.TimeoutError):
                raise SimulationError(f"--scheduler {address}: the cluster has no workers (none joined in "
                                      f"{worker_wait_s:g} s); start some with: dask worker {address}") from None
        yield client


@contextlib.contextmanager
def runs_cancelled_without_workers(client, futures):
    """Within: a thread asks the scheduler every ``WORKER_POLL_S`` seconds whether its cluster has
    a worker, and once it has had none for ``NO_WORKERS_TIMEOUT_S`` seconds cancels the
    runs of ``futures`` (a mapping whose keys are the runs' futures, read then) not yet done.
    Yields the set of the futures it cancelled.  Dask itself would wait for a worker for ever: a
    local cluster's scheduler could be told not to (``no-workers-timeout``), but a scheduler given
    by its address is not the sweep's to configure, and this serves both."""
    cancelled = set()
    stopped = threading.Event()

    def watch():
        since = None
        while not stopped.wait(WORKER_POLL_S):
            try:
                has_workers = bool(client.nthreads())
            except Exception:       # the client or its scheduler is gone: Dask cancels the runs itself
                return
            now = time.monotonic()
            if has_workers or since is None:
                since = None if has_workers else now
            elif now - since >= NO_WORKERS_TIMEOUT_S:
                left = [future for future in futures.copy() if not future.done()]
                cancelled.update(left)
                client.cancel(left)

    thread = threading.Thread(target=watch, name="softsim-sweep-workers", daemon=True)
    thread.start()
    try:
        yield cancelled
    finally:
        stopped.set()
        thread.join()


def run_sweep(runs, output_dir, client, shared_dir=False, force=False, numba_threads=None,
              progress: Optional[Callable] = None):
    """Run ``runs`` (from ``spec.expand_sweep``) on ``client``; returns a ``SweepResult``.

    client: a ``distributed.Client`` (None will do when every run is already complete).
    output_dir: where run files and the summary go (it must exist).  shared_dir: the workers see
    ``output_dir`` at the same path and write there directly; otherwise each result's bytes come
    back through Dask.  force: rerun runs whose file is complete.  numba_threads: Numba threads
    per run (None: the workers' own setting).  progress: called as ``progress(done, failed,
    running, total)`` after each run finishes (``done`` counts skipped runs).

    Runs whose file is complete with the same scene are skipped; every other run is (re)run, and
    one that fails (the blow-up guard, a ``SoftsimError``, a bug, a run that kills its workers)
    does not stop the others.  A run Dask cancels because the workers lost its mesh (or all was
    lost in a restart of the cluster) is submitted again, carrying its mesh, up to
    ``LOST_RUN_RESUBMITS`` times; one whose own worker died Dask reruns itself.  With
    ``shared_dir``, a run whose file this machine does not see where the worker wrote it fails.
    On ``KeyboardInterrupt`` the runs not started are cancelled and those running are asked to
    stop at their next frame (``stop_requested``; Dask cannot stop a task), the summary of what
    finished is written, and the interrupt goes on.
    """
    output_dir = Path(output_dir).absolute()
    to_run, to_skip = plan_runs(runs, force)
    meshes, mesh_keys = build_meshes(to_run)
    rows = {run.index: summary_row(run, run_metrics(run.path)) for run in to_skip}
    total = len(runs)
    done = len(rows)
    failed = sum(row["status"] != "complete" for row in rows.values())
    slots = max(1, sum(client.nthreads().values())) if to_run else 1
    futures = {}
    result = SweepResult(rows=[], summary_paths=[], skipped=len(to_skip))
    if progress is not None:
        progress(done, failed, min(slots, len(to_run)), total)
    try:
        distributed = import_distributed() if to_run else None
        mesh_futures = scatter_meshes(client, meshes)
        target = str(output_dir) if shared_dir else None
        resubmits = dict.fromkeys((run.index for run in to_run), 0)
        shared_file_wait_s = SHARED_FILE_WAIT_S
        stop_event = f"softsim-sweep-stop-{os.urandom(8).hex()}"

        def submit(run, mesh):
            future = client.submit(execute_run, run.scene, mesh, run.name, target, numba_threads, stop_event,
                                   key=f"softsim-run-{run.index}-{os.urandom(4).hex()}", pure=False, retries=0)
            futures[future] = run
            return future

        for run in to_run:
            if shared_dir:              # the worker replaces it there: a file left here must not pass for its
                _remove_run_files(run.path)
            submit(run, mesh_futures[mesh_keys[run.index]])
        finished = distributed.as_completed(list(futures)) if futures else ()
        watching = runs_cancelled_without_workers(client, futures) if futures else contextlib.nullcontext(set())
        with watching as without_workers:
            for future in finished:
                run = futures.pop(future)   # released once read: a run's bytes leave the worker's memory
                try:
                    outcome = future.result()
                    future.release()
                    error = outcome["error"]
                    for message in outcome["warnings"]:
                        log.warning("run %d (%s): %s", run.index + 1, run.name, message)
                    if outcome["files"]:
                        _write_files(outcome["files"], output_dir)
                    metrics = outcome["metrics"]
                    if shared_dir and metrics is not None and not _appears(run.path, shared_file_wait_s):
                        shared_file_wait_s = 0.0    # not shared: the next runs' files need no waiting for
                        error, metrics = (f"the worker on {outcome['host']} wrote {run.path}, but this machine does "
                                          f"not see it there: --shared-dir must be a folder this machine and every "
                                          f"worker see at the same path"), None
                except distributed.client.FutureCancelledError as exc:
                    lost = exc.reason in LOST_REASONS and client.status == "running" and future not in without_workers
                    if lost and resubmits[run.index] < LOST_RUN_RESUBMITS:
                        resubmits[run.index] += 1
                        # carrying its mesh: no scatter while workers come and go, none to lose again
                        finished.add(submit(run, meshes[mesh_keys[run.index]]))
                        continue
                    if future in without_workers:
                        error = (f"no Dask worker was left to run it for {NO_WORKERS_TIMEOUT_S:g} s (they died and "
                                 f"none came back)")
                    elif lost:
                        error = f"lost {resubmits[run.index] + 1} times with a worker that died"
                    else:
                        error = f"cancelled by Dask ({exc.reason})"
                    metrics = None
                except distributed.KilledWorker:   # the run's process died on every worker that tried it
                    error, metrics = ("the worker process running it died, on every try (out of memory, or a crash: "
                                      "see the workers' logs)"), None
                except Exception as exc:    # the result could not come back
                    error, metrics = (f"{type(exc).__name__}: {exc}".splitlines() or [""])[0], None
                if metrics is None and not being_written(run.path):   # an older file would contradict the summary
                    _remove_run_files(run.path)
                row = rows[run.index] = summary_row(run, metrics, error)
                done += 1
                failed += row["status"] != "complete"
                if progress is not None:
                    progress(done, failed, min(slots, total - done), total)
    except KeyboardInterrupt:
        result.cancelled = True
        if futures:         # the runs already started stop at their next frame: Dask cannot stop a task
            with contextlib.suppress(Exception):      # a scheduler gone must not hide the interrupt
                client.sync(client.scheduler.event_set, name=stop_event, callback_timeout=STOP_ASK_TIMEOUT_S)
        client.cancel(list(futures), force=True)
        raise
    finally:
        for run in runs:
            if run.index not in rows:
                rows[run.index] = summary_row(run, None, "the sweep was cancelled before this run finished")
                rows[run.index]["status"] = NOT_FINISHED
        result.rows = [rows[index] for index in sorted(rows)]
        result.summary_paths = write_summary(result.rows, output_dir)
        result.counts = {status: sum(row["status"] == status for row in result.rows)
                         for status in ("complete", "failed", "interrupted", "running")}
    return result
