"""The run's HDF5 file: mesh once, frames written as the run goes, status at the end.

Layout (a public interface):

- ``mesh/points`` (n, 3) rest positions [m], ``mesh/tets`` (m, 4), ``mesh/fixed`` (n,) bool
- ``frames/time`` (k,) [s], ``frames/points`` (k, n, 3) [m]; optional ``frames/velocities``
  (k, n, 3) [m/s]; ``frames/energy/{kinetic,elastic,gravity}`` (k,) [J]; the other optional
  fields of ``io.fields.FIELDS`` as ``frames/<name>``, (k, n, ...) per vertex or (k, m, ...) per tet
- ``state/``: the resume state of the last complete frame, in two slots ``state/a`` and
  ``state/b`` written in turn: ``positions``, ``velocities`` (n, 3), the guard's ``guard_*``
  arrays, ``scalars`` (the numbers, named by its attribute ``names``) and ``header`` (one record:
  ``frames`` written, ``step``, ``time`` [s], ``wall_time_s``, ``data_crc``, ``crc``); read it
  with ``read_resume_state`` and the frame count with ``frames_written``
- root attributes: ``config``, ``dt``, ``steps``, ``wall_time_s``, ``compile_time_s`` (of the
  wall time, Numba compiling kernels, summed over the sessions of the run that ended: a killed
  session's is not known), ``softsim_version``, ``status`` (running | complete | interrupted |
  failed), ``status_reason``

Crash safety.  The file's structure (its HDF5 metadata) changes only when a run starts, resumes
or ends.  In between, the ``frames/*`` datasets hold a row for every planned frame, allocated up
front (unwritten rows are holes in a sparse file), and a frame writes only raw data: its rows and
the older ``state/`` slot, then a flush, then that slot's ``header`` (48 bytes, checksummed),
then a flush.  A kill at any moment therefore leaves a file that plain ``h5py.File(path)`` opens,
and the newest intact header says how many frames are complete; ``--resume`` goes on from
there.  While a run is going, or after it was killed, the datasets are longer than that count
(``frames_written(f)`` gives it; the XDMF lists only those frames); a run that ends, however it
ends, trims them to it.  A kill during that final trim and status write is not covered (HDF5
has no journal).  An XDMF file beside it (``out.xdmf``) lets ParaView play the frames.
"""

import contextlib
import os
import shutil
import signal
import tempfile
import threading
import time as _time
import zlib
from pathlib import Path

try:
    import fcntl
except ImportError:               # Windows: no flock, so no check for a concurrent writer
    fcntl = None

import h5py
import numpy as np

from .. import __version__
from ..errors import SimulationError, SoftsimError
from .fields import FIELDS
from .files import describe_input, input_clash
from .xdmf import write_xdmf

ENERGY_TERMS = ("kinetic", "elastic", "gravity")
STATUSES = ("running", "complete", "interrupted", "failed")
# The names a run's output may take: HDF5 under another name (``-o out.txt``) was written silently.
HDF5_SUFFIXES = (".h5", ".hdf5")
# Fields stored as frames/<name>, one array row per frame, passed to append_frame(fields=...).
_ARRAY_FIELDS = tuple(name for name, spec in FIELDS.items()
                      if spec.location in ("vertex", "tet") and name != "velocities")
# The XDMF is rewritten at most this often [s of wall time] while running, and always at the end.
XDMF_REWRITE_INTERVAL_S = 1.0
# A frame is written only if the disk has room for twice its data plus this (metadata, XDMF, status).
FREE_SPACE_MARGIN_BYTES = 4 << 20
# Rows per chunk of a frames/* dataset: as many as fit in this many bytes, at least one.
CHUNK_BYTES = 64 << 10
# ``state/`` holds the resume state in two slots written in turn (see ``RunWriter.append_frame``).
STATE_SLOTS = ("a", "b")


def xdmf_path_for(path):
    """``out.h5`` -> ``out.xdmf`` (same folder)."""
    return Path(path).with_suffix(".xdmf")


def check_writable(path, overwrite=True, inputs=()):
    """Raise ``SimulationError`` unless a run can write ``path`` and its XDMF file (checked before any
    work): the name must end in an HDF5 suffix (``HDF5_SUFFIXES``), the folder must exist and take a
    new file, neither ``path`` nor its XDMF file may be one
    of ``inputs`` (the scene's own files, never written over; an XDMF mesh file's ``.h5`` data
    file too), and unless ``overwrite`` neither may exist."""
    folder = Path(path).resolve().parent
    if not folder.is_dir():
        raise SimulationError(f"output.path = '{path}': folder {folder} does not exist")
    if not os.access(folder, os.W_OK):
        raise SimulationError(f"output.path = '{path}': folder {folder} is not writable")
    if Path(path).is_dir():
        raise SimulationError(f"output.path = '{path}': is a directory, expected a file name like out.h5")
    clash = input_clash((path, xdmf_path_for(path)), inputs)
    if clash is not None:
        written, input_file, name = clash
        which = "is" if written == path else f"its XDMF file '{written}' would replace"
        raise SimulationError(f"output.path = '{path}': {which} the scene's own file "
                              f"{describe_input(input_file, name)}, which the run reads; choose another output name")
    if xdmf_path_for(path).resolve() == Path(path).resolve():
        raise SimulationError(f"output.path = '{path}': is the name of the XDMF file written beside the "
                              f"HDF5 file; use an HDF5 name like out.h5")
    if not Path(path).name.lower().endswith(HDF5_SUFFIXES):
        raise SimulationError(f"output.path = '{path}': a run writes HDF5, so the name must end in "
                              f"{' or '.join(HDF5_SUFFIXES)} (softsim export converts it to VTU or XDMF)")
    refuse_if_being_written(path)
    if not overwrite:
        attrs = run_attributes(path)
        status = attrs.get("status")
        if status == "failed":
            reason = attrs.get("status_reason") or "no reason recorded"
            raise SimulationError(f"output.path = '{path}': the file holds a run that failed ({reason}); "
                                  f"pass --overwrite to replace it (--resume goes on from its last complete frame: "
                                  f"only for a failure from outside the run, such as a full disk)")
        if status in ("running", "interrupted"):
            raise SimulationError(f"output.path = '{path}': the file holds an unfinished run (status: "
                                  f"{status}); pass --resume to continue it or --overwrite to replace it")
        _refuse_if_exists(path)
        if xdmf_path_for(path).exists():
            raise SimulationError(f"output.path = '{path}': the XDMF file {xdmf_path_for(path)} written beside "
                                  f"it exists; pass --overwrite to replace it")
    try:
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".softsim-write-check-"):
            pass
    except OSError as exc:
        raise SimulationError(f"output.path = '{path}': cannot create a file in folder {folder} "
                              f"({exc.strerror or exc})") from None


def being_written(path):
    """Whether a process has ``path`` open for writing through HDF5, which holds an exclusive
    ``flock`` on a file it writes, or a ``RunWriter`` holds one (a running softsim run, HDF5's
    locking on or off).  False where there is no ``flock`` (Windows, a file system without locks)
    or no such file."""
    if fcntl is None or not Path(path).is_file():
        return False
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        return False
    except BlockingIOError:
        return True
    except OSError:               # a file system without locks
        return False
    finally:
        os.close(fd)              # closing drops the shared lock, if taken


def refuse_if_being_written(path, resuming=False):
    """Raise ``SimulationError`` if another run is writing ``path`` now (``being_written``); the
    message names ``--resume`` when ``resuming``, else ``output.path``."""
    if not being_written(path):
        return
    if resuming:
        raise SimulationError(f"--resume: another run is writing '{path}' now; wait for it to end")
    raise SimulationError(f"output.path = '{path}': another run is writing this file now; wait for it to end "
                          f"or choose another output name")


def _refuse_if_exists(path):
    """Raise ``SimulationError`` if ``path`` exists (a run without ``--overwrite``)."""
    if Path(path).exists():
        raise SimulationError(f"output.path = '{path}': the file exists; pass --overwrite to replace it")


@contextlib.contextmanager
def _folder_locked(folder):
    """Hold an exclusive ``flock`` on ``folder`` while inside: softsim processes check and claim an
    output name in it one at a time (``_move_into_place``, ``RunWriter.reopen``).  Unguarded where
    the folder takes no lock: Windows, a folder this user cannot read, and network file systems,
    where a lock holds on one host at most, not against a run on another."""
    fd = None
    try:
        if fcntl is not None:
            try:
                fd = os.open(folder, os.O_RDONLY)
                fcntl.flock(fd, fcntl.LOCK_EX)
            except OSError:
                pass
        yield
    finally:
        if fd is not None:
            os.close(fd)            # closing drops the folder's lock


def _move_into_place(partial, path, overwrite=True):
    """Rename the finished file ``partial`` to ``path`` unless another run is writing ``path`` now
    (or, unless ``overwrite``, ``path`` exists).

    ``check_writable`` looks before any work, but two runs started together on one output both
    passed it: the later rename replaced the earlier run's file, which went on writing to a file no
    longer on disk and reported success.  The check and the rename are made here under the
    folder's lock (``_folder_locked``), and the new file is locked before the folder is released
    (``RunWriter``: HDF5's lock or the run's own), so a second run sees the first."""
    with _folder_locked(path.parent):
        refuse_if_being_written(path)
        if not overwrite:
            _refuse_if_exists(path)
        os.replace(partial, path)


def _lock_unless_locked(path):
    """An open descriptor of ``path`` holding an exclusive ``flock`` on it, so that ``being_written``
    sees the run, where HDF5 holds none (``HDF5_USE_FILE_LOCKING=FALSE``, common on cluster file
    systems); None where HDF5 holds it already, or there are no locks.  Release with ``_unlock``."""
    if fcntl is None:
        return None
    fd = os.open(path, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:                 # BlockingIOError: HDF5's own lock; else a file system without locks
        os.close(fd)
        return None
    return fd


def _unlock(fd):
    if fd is not None:
        os.close(fd)                # closing drops the lock


def _same_mesh(f, points, tets):
    """Whether the open run file ``f`` holds the mesh ``points`` (n, 3), ``tets`` (m, 4), exactly."""
    stored_points, stored_tets = f["mesh/points"], f["mesh/tets"]
    return (stored_points.shape == np.shape(points) and stored_tets.shape == np.shape(tets)
            and np.array_equal(stored_points[()], points) and np.array_equal(stored_tets[()], tets))


# The root attributes that tell what run a file holds and what it was made from.
RUN_ATTRIBUTES = ("config", "status", "status_reason", "mesh_file_sha256")


def run_attributes(path):
    """The root attributes of the HDF5 file ``path`` that tell what run it holds (``RUN_ATTRIBUTES``,
    as str), those it has; empty where there is no such file or it is no HDF5 file."""
    try:
        with h5py.File(path, "r", locking=False) as f:
            return attributes_of(f)
    except OSError:
        return {}


def attributes_of(f):
    """``run_attributes`` of the open HDF5 file ``f``."""
    return {key: str(f.attrs[key]) for key in RUN_ATTRIBUTES if key in f.attrs}


def holds_run(path):
    """Whether ``path`` is an HDF5 file that ``softsim run`` wrote (its ``config`` and ``status``
    attributes), finished or not: a file another command never writes over, ``--overwrite`` or not."""
    return {"config", "status"} <= run_attributes(path).keys()


class RunWriter:
    """Context manager writing one run: ``append_frame`` per frame, ``finish`` with the status.

    points (n, 3) [m], tets (m, 4), fixed (n,) bool: the mesh in the user's order.
    fields: the optional per-frame fields asked for (names of ``io.fields.FIELDS``).
    frames: the planned number of frames, allocated up front (more grow the datasets, a structure
    change that a kill during its flush could tear).
    resume_template: a dict shaped like the ``resume_state`` every frame will pass (arrays and
    numbers a resume needs besides positions and velocities); its slots are made up front.
    started: the ``time.perf_counter()`` reading the run's wall time counts from (default: now),
    the start of the caller's work, so that the compiling before the file is made (counted in
    ``compile_time_s``) is counted in ``wall_time_s`` too.
    overwrite: whether the file may replace one at ``path``, checked as it is renamed into place
    (``_move_into_place``); a file another run is writing is never replaced.
    attributes: further root attributes that tell what the run was made from (``mesh_file_sha256``).
    """

    def __init__(self, path, points, tets, fixed, config_yaml, dt, steps, fields=(), xdmf=True, frames=1,
                 resume_template=None, started=None, overwrite=True, attributes=None):
        self.path = Path(path)
        self.fields = tuple(fields)
        self.node_count = points.shape[0]
        self.tet_count = tets.shape[0]
        self.xdmf = xdmf
        self._xdmf_written_at = -np.inf
        self._started = _time.perf_counter() if started is None else started
        self.frame_count = 0
        self._last_slot = None
        self.compile_time_s = 0.0        # this session's compiling [s], kept up to date by the caller
        self._compile_before = 0.0       # earlier sessions' (a resumed run)
        # The file is built under a temporary name and renamed once its mesh and empty frame
        # datasets are on disk, so ``path`` never names a file that a plain reader cannot open.
        partial = self.path.with_name(f".{self.path.name}.partial-{os.getpid()}-{threading.get_native_id()}")
        try:
            self.file = h5py.File(partial, "w")
        except OSError as exc:
            raise SimulationError(f"output.path = '{path}': cannot create the file ({exc})") from None
        self._lock = _lock_unless_locked(partial)
        try:
            self._create_layout(points, tets, fixed, config_yaml, dt, steps, max(1, int(frames)),
                                resume_template or {}, attributes or {})
            _keep_metadata_until_flush(self.file)
            crash_point("before_rename")
            _move_into_place(partial, self.path, overwrite)
            self._open_datasets()
        except BaseException as exc:
            self.file.close()
            _unlock(self._lock)
            partial.unlink(missing_ok=True)
            if isinstance(exc, OSError):
                raise SimulationError(f"output.path = '{path}': cannot write the file ({_os_reason(exc)})") from None
            raise

    def _create_layout(self, points, tets, fixed, config_yaml, dt, steps, frames, resume_template, attributes):
        """Write the mesh, the attributes, the frame datasets (``frames`` rows, allocated) and the
        state slots, then flush."""
        f = self.file
        f.attrs.update(config=config_yaml, dt=float(dt), steps=int(steps), wall_time_s=0.0, compile_time_s=0.0,
                       softsim_version=__version__, status="running", status_reason="", **attributes)
        mesh = f.create_group("mesh")
        mesh.create_dataset("points", data=np.asarray(points, np.float64))
        mesh.create_dataset("tets", data=np.asarray(tets, np.int64))
        mesh.create_dataset("fixed", data=np.asarray(fixed, np.bool_))
        group = f.create_group("frames")
        n = self.node_count
        _frame_dataset(group, "time", frames, ())
        _frame_dataset(group, "points", frames, (n, 3))
        if "velocities" in self.fields:
            _frame_dataset(group, "velocities", frames, (n, 3))
        if "energy" in self.fields:
            energy = group.create_group("energy")
            for term in ENERGY_TERMS:
                _frame_dataset(energy, term, frames, ())
        for name in self.fields:
            if name in _ARRAY_FIELDS:
                spec = FIELDS[name]
                _frame_dataset(group, name, frames, (n if spec.location == "vertex" else self.tet_count, *spec.shape))
        template = {"positions": np.zeros((n, 3)), "velocities": np.zeros((n, 3)), **resume_template}
        arrays = {name: value for name, value in template.items() if np.ndim(value) > 0}
        scalars = sorted(name for name, value in template.items() if np.ndim(value) == 0)
        state = f.create_group("state")
        for slot_name in STATE_SLOTS:
            slot = state.create_group(slot_name)
            for name, value in arrays.items():
                # Created with data, so their storage is allocated now and a frame only overwrites it.
                slot.create_dataset(name, data=np.zeros(np.shape(value), np.float64))
            slot.create_dataset("scalars", data=np.zeros(len(scalars), np.float64)).attrs["names"] = scalars
            slot.create_dataset("header", data=_header(0, -1, 0.0, 0.0, 0))
        f.flush()

    @classmethod
    def reopen(cls, path, fields=(), xdmf=True, frames=1, started=None, needs=(), mesh=None, attributes=None):
        """``(writer, state)`` to continue the run in ``path`` from its last complete frame.

        ``state`` is a dict of ``state/``: ``positions``, ``velocities`` (n, 3) in the user's order,
        ``time``, ``step`` and any extra arrays and numbers the run stored for a resume.  Rows
        after that state (a frame cut off by a crash) are written over; the datasets get rows for
        ``frames`` frames again; the status is ``running`` again.  started: as for a new writer,
        this session's start; the stored wall time goes on from it.  needs: names the state must
        hold (``require_resume_names``), checked before anything in the file changes.  mesh:
        ``(points, tets)`` of the run going on, in the user's order, refused unless equal to the
        file's ``mesh/`` (a mesh file edited, or gmsh meshing the scene otherwise, since).
        attributes: as for a new writer, recorded once the checks pass (a file from a softsim that
        did not record them gets them).
        """
        self = cls.__new__(cls)
        self.path = Path(path)
        self.fields = tuple(fields)
        self.xdmf = xdmf
        self._xdmf_written_at = -np.inf
        with _folder_locked(self.path.parent):     # against a new run renaming its file into place
            refuse_if_being_written(path, resuming=True)
            try:
                self.file = h5py.File(self.path, "a")
            except OSError as exc:
                raise SimulationError(f"output.path = '{path}': cannot reopen the file to resume ({exc})") from None
            self._lock = _lock_unless_locked(self.path)
        f = self.file
        self.node_count = f["mesh/points"].shape[0]
        self.tet_count = f["mesh/tets"].shape[0]
        try:
            newest = _newest_slot(f, check_data=True)
            if newest is None:
                raise SimulationError(f"--resume: '{path}' holds no intact resume state")
            require_resume_names(path, newest[1], needs)
            if mesh is not None and not _same_mesh(f, *mesh):
                raise SimulationError(f"--resume: the mesh differs from the one '{path}' was written with (its "
                                      f"file edited, or meshed by another gmsh since); resuming it would splice two "
                                      f"different runs")
        except SimulationError:
            self.file.close()
            _unlock(self._lock)
            raise
        self._last_slot, state = newest
        self.frame_count = int(state["frames"])
        self._started = (_time.perf_counter() if started is None else started) - float(state["wall_time_s"])
        self.compile_time_s = 0.0
        self._compile_before = float(f.attrs.get("compile_time_s", 0.0))
        for dataset in _frame_datasets(f):
            if dataset.shape[0] < frames:
                dataset.resize(frames, axis=0)
        f.attrs.update(status="running", status_reason="", **(attributes or {}))
        f.flush()
        _keep_metadata_until_flush(f)
        self._open_datasets()
        return self, state

    def append_frame(self, time, step, points, velocities, energy=None, resume_state=None, fields=None):
        """Write one frame and the resume state: raw data only, then flush, then the state's
        header, then flush (see the module's note on crash safety).

        points, velocities: (n, 3) [m], [m/s] in the user's order; energy: dict of ENERGY_TERMS [J];
        resume_state: optional dict of further arrays and numbers a resume needs, with the names
        and shapes of the writer's ``resume_template``, stored with positions and velocities in the
        ``state/`` slot not written last time;
        fields: ``{name: array}`` of the other fields asked for (``frames/<name>``), vertex fields in
        the user's vertex order, tet fields in ``mesh/tets`` order.
        """
        k = self.frame_count
        # HDF5 cannot be trusted after a failed write (its error paths may even crash), so a disk
        # about to fill up stops the run before the frame, while the status can still be written.
        arrays = [points, velocities, *(fields or {}).values(), *(resume_state or {}).values()]
        needed = 2 * sum(np.asarray(a).nbytes for a in arrays) + FREE_SPACE_MARGIN_BYTES
        free = free_bytes(self.path)
        if free < needed:
            raise SimulationError(f"output.path = '{self.path}': the disk is full ({free / 1e6:.3g} MB free, "
                                  f"frame {k} needs {needed / 1e6:.3g} MB); the {k} frames before it are kept")
        try:
            self._write_frame(k, time, step, points, velocities, energy, resume_state, fields)
        except OSError as exc:     # e.g. the disk is full: the frames before k stay readable
            raise SimulationError(f"output.path = '{self.path}': writing frame {k} at t = {time:.6g} s "
                                  f"failed ({_os_reason(exc)})") from None
        now = _time.perf_counter()
        if now - self._xdmf_written_at >= XDMF_REWRITE_INTERVAL_S:
            crash_point("before_xdmf", k)
            self._write_xdmf()
            self._xdmf_written_at = now

    def _open_datasets(self):
        """Keep the handles a frame writes through (an h5py lookup by name costs ~50 us)."""
        self._rows = {dataset.name.removeprefix("/frames/"): _LowLevelDataset(dataset)
                      for dataset in _frame_datasets(self.file)}
        self._slots = {name: {member: _LowLevelDataset(dataset)
                              for member, dataset in _members(self.file["state"][name]).items()}
                       for name in STATE_SLOTS}
        self._scalar_names = list(self._slots[STATE_SLOTS[0]]["scalars"].dataset.attrs["names"])
        self._array_names = {name for name in self._slots[STATE_SLOTS[0]] if name not in ("scalars", "header")}

    def _write_frame(self, k, time, step, points, velocities, energy, resume_state, fields=None):
        rows = self._rows
        if k >= rows["time"].shape[0]:          # more frames than planned: grow (structure change)
            for dataset in rows.values():
                dataset.resize(max(2 * k, k + 1))
        template = {"positions": points, "velocities": velocities, **(resume_state or {})}
        if set(template) != self._array_names | set(self._scalar_names):
            raise ValueError(f"resume_state names {sorted(template)} differ from the writer's "
                             f"{sorted(self._array_names | set(self._scalar_names))}")
        crash_point("frame_start", k)
        rows["points"].write_row(k, points)
        crash_point("after_points", k)
        if "velocities" in self.fields:
            rows["velocities"].write_row(k, velocities)
            crash_point("after_velocities", k)
        if "energy" in self.fields:
            for term in ENERGY_TERMS:
                rows[f"energy/{term}"].write_row(k, energy[term])
            crash_point("after_energy", k)
        for name, value in (fields or {}).items():
            rows[name].write_row(k, value)
        rows["time"].write_row(k, time)
        crash_point("after_time", k)
        # The resume state goes to the slot the newest header is not in, so that slot stays intact
        # whatever happens to this one; its header, written after a flush, makes the frame count.
        slot_name = STATE_SLOTS[1] if self._last_slot == STATE_SLOTS[0] else STATE_SLOTS[0]
        slot = self._slots[slot_name]
        arrays = {name: template[name] for name in self._array_names}
        scalars = np.array([float(template[name]) for name in self._scalar_names], np.float64)
        for name, value in arrays.items():
            slot[name].write_whole(value)
        slot["scalars"].write_whole(scalars)
        crash_point("before_flush", k)
        self.file.flush()
        crash_point("before_commit", k)
        wall = _time.perf_counter() - self._started
        slot["header"].write_whole(_header(k + 1, step, time, wall, state_checksum(arrays, scalars, step)))
        self.file.flush()
        self._last_slot = slot_name
        self.frame_count = k + 1
        crash_point("after_flush", k)

    def _write_xdmf(self):
        if not self.xdmf:
            return
        point_fields = [("velocity", "frames/velocities")] if "velocities" in self.fields else []
        cell_fields = []
        for name in self.fields:
            spec = FIELDS[name]
            if name in _ARRAY_FIELDS:
                target = point_fields if spec.location == "vertex" else cell_fields
                target.append((spec.xdmf_name, f"frames/{name}", spec.shape))
        times = self.file["frames/time"]
        write_xdmf(xdmf_path_for(self.path), self.path, self.node_count, self.tet_count,
                   times[:self.frame_count], point_fields=point_fields, cell_fields=cell_fields,
                   rows=times.shape[0])

    def finish(self, status, reason=""):
        """Trim the frame datasets to the frames written, record the final ``status`` and
        ``reason``, rewrite the XDMF, close the file."""
        if status not in STATUSES:
            raise ValueError(f"status must be one of {STATUSES}, got {status!r}")
        if not self.file:
            return
        trimmed = False
        try:
            for dataset in self._rows.values():
                if dataset.shape[0] != self.frame_count:
                    dataset.resize(self.frame_count)
                    trimmed = True
            crash_point("finish_before_status")
            self.file.attrs.update(status=status, status_reason=reason,
                                   wall_time_s=_time.perf_counter() - self._started,
                                   compile_time_s=self._compile_before + self.compile_time_s)
            self.file.flush()
            crash_point("finish_after_flush")
            self._write_xdmf()
        except OSError:
            # The disk refused even the status: the file keeps the status of its last flush
            # ("running"), never "complete", and the error that brought us here is reported.
            if status == "complete":
                raise SimulationError(f"output.path = '{self.path}': could not record the final status") from None
        finally:
            try:
                self.file.close()
            except OSError:
                trimmed = False
            _unlock(self._lock)
        if trimmed:
            _compact(self.path)

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if self.file:
            if exc_type is None:
                self.finish("complete")
            elif issubclass(exc_type, KeyboardInterrupt):
                self.finish("interrupted", "interrupted by the user")
            elif issubclass(exc_type, SoftsimError):
                self.finish("failed", str(exc).splitlines()[0])
            else:
                self.finish("failed", f"{exc_type.__name__}: {exc}".splitlines()[0])
        return False


def _frame_dataset(group, name, frames, row_shape):
    """A ``(frames, *row_shape)`` float64 dataset, resizable along axis 0, every chunk allocated
    now (so writing a row changes no metadata, and nothing is written there yet: rows never written
    are holes of a sparse file and read as zeros).

    A chunk holds as many rows as fit in ``CHUNK_BYTES`` (at least one): few chunks to index,
    and a flush rewrites at most that much of a chunk already partly written."""
    row_bytes = 8 * int(np.prod(row_shape, dtype=np.int64))
    dcpl = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
    dcpl.set_chunk((max(1, CHUNK_BYTES // row_bytes), *row_shape))
    dcpl.set_alloc_time(h5py.h5d.ALLOC_TIME_EARLY)
    dcpl.set_fill_time(h5py.h5d.FILL_TIME_NEVER)
    space = h5py.h5s.create_simple((frames, *row_shape), (h5py.h5s.UNLIMITED, *row_shape))
    h5py.h5d.create(group.id, name.encode(), h5py.h5t.IEEE_F64LE, space, dcpl=dcpl)
    return group[name]


class _LowLevelDataset:
    """A ``frames/*`` or ``state/*`` dataset written through h5py's low-level calls, its shape, type
    and HDF5 dataspaces made once.

    A frame writes 8-20 datasets.  ``Dataset.__setitem__`` spends about 0.15 ms a call building its
    selection in Python (2-3 ms a frame, more than the step of the small example scenes took), and
    even ``Dataset.shape`` takes 26 us (a new dataspace object each time): at 500 vertices a third
    of the writer's time went to ``shape`` and to the dataspaces' bookkeeping."""

    def __init__(self, dataset):
        self.dataset = dataset
        self.name = dataset.name
        self.dtype = dataset.dtype
        self._memory_type = h5py.h5t.py_create(self.dtype)     # of the values write_whole passes
        self._read_shape()

    def _read_shape(self):
        self.shape = self.dataset.shape
        self._file_space = self.dataset.id.get_space()
        self._row_space = h5py.h5s.create_simple((1, *self.shape[1:])) if self.shape else None

    def resize(self, rows):
        """Change the number of rows (axis 0)."""
        self.dataset.resize(rows, axis=0)
        self._read_shape()

    def write_row(self, k, value):
        """``dataset[k] = value`` for a ``frames/*`` dataset (HDF5 converts the float64 values to
        its type).  Raises ``ValueError`` where ``value`` (cast to float64, leading axes of length 1
        dropped) is not one row's shape, ``IndexError`` where row ``k`` does not exist (HDF5 itself
        need not refuse it)."""
        if not 0 <= k < self.shape[0]:
            raise IndexError(f"{self.name}: row {k} of {self.shape[0]}")
        row_shape = self.shape[1:]
        value = np.asarray(value, dtype=np.float64, order="C")
        while value.ndim > len(row_shape) and value.shape[0] == 1:
            value = value.reshape(value.shape[1:])
        if value.shape != row_shape:
            raise ValueError(f"{self.name}: a row of shape {row_shape}, got {value.shape}")
        self._file_space.select_hyperslab((k, *(0 for _ in row_shape)), (1, *row_shape))
        self.dataset.id.write(self._row_space, self._file_space, value, h5py.h5t.NATIVE_DOUBLE)

    def write_whole(self, value):
        """``dataset[...] = value`` for a dataset of ``value``'s shape, its values cast to the
        dataset's type."""
        value = np.asarray(value, dtype=self.dtype, order="C")
        if value.shape != self.shape:
            raise ValueError(f"{self.name}: shape {self.shape}, got {value.shape}")
        self.dataset.id.write(h5py.h5s.ALL, h5py.h5s.ALL, value, self._memory_type)


def _compact(path):
    """Rewrite a trimmed run file without the space its unwritten rows held (still allocated,
    though holes on disk, after a trim), under a hidden name, then rename it over ``path``: a kill
    meanwhile leaves ``path`` as it was.  Best effort: on an OSError the file stays as it is."""
    path = Path(path)
    compact = path.with_name(f".{path.name}.compact-{os.getpid()}")
    try:
        with h5py.File(path, "r") as src, h5py.File(compact, "w") as dst:
            dst.attrs.update(src.attrs)
            for name in src:
                src.copy(src[name], dst, name=name)
        os.replace(compact, path)
    except OSError:
        compact.unlink(missing_ok=True)


def _members(group):
    """``{name: member}`` of an h5py group, read by name.

    Never ``group.items()`` / ``group.values()``: those iterators hold h5py's global lock between
    members, so one left suspended (a read that raised half-way, its traceback kept) stops every
    other thread's h5py call, object clean-up included: a Dask worker's event loop, say.
    """
    return {name: group[name] for name in group}


def _frame_datasets(f):
    """Every dataset under ``frames/`` (one row per frame)."""
    found = []
    f["frames"].visititems(lambda name, obj: found.append(obj) if isinstance(obj, h5py.Dataset) else None)
    return found


def _keep_metadata_until_flush(file):
    """Stop HDF5's metadata cache from writing entries out to make room between flushes, so the
    file's metadata on disk changes only at ``flush`` (the cache grows instead: a few kB)."""
    config = file.id.get_mdc_config()
    config.evictions_enabled = False
    config.incr_mode = config.flash_incr_mode = config.decr_mode = 0     # H5C_*_off
    file.id.set_mdc_config(config)


HEADER_DTYPE = np.dtype([("frames", "<i8"), ("step", "<i8"), ("time", "<f8"), ("wall_time_s", "<f8"),
                         ("data_crc", "<i8"), ("crc", "<i8")])


def _header(frames, step, time, wall_time_s, data_crc):
    """One ``state/<slot>/header`` record; ``crc`` is the CRC-32 of the fields before it."""
    record = np.zeros((), HEADER_DTYPE)
    record["frames"], record["step"], record["time"] = frames, step, time
    record["wall_time_s"], record["data_crc"] = wall_time_s, data_crc
    record["crc"] = _header_crc(record)
    return record


def _header_crc(record):
    return zlib.crc32(record.tobytes()[:HEADER_DTYPE.fields["crc"][1]])


def state_checksum(arrays, scalars, step):
    """CRC-32 of a resume state: its arrays' bytes in name order, its numbers and its step."""
    crc = zlib.crc32(str(int(step)).encode())
    for name in sorted(arrays):
        crc = zlib.crc32(np.ascontiguousarray(arrays[name], dtype=np.float64).tobytes(), crc)
    return zlib.crc32(np.ascontiguousarray(scalars, dtype=np.float64).tobytes(), crc)


def _newest_slot(f, check_data):
    """``(slot name, state dict)`` of the newest slot whose header is intact (and, with
    ``check_data``, whose arrays match it), or None.  The dict holds the header's fields and, with
    ``check_data``, the arrays and the named numbers."""
    found = []
    for slot_name in STATE_SLOTS:
        slot = f["state"].get(slot_name)
        if slot is None or "header" not in slot:
            continue
        record = slot["header"][()]
        if int(record["frames"]) < 1 or int(record["crc"]) != _header_crc(record):
            continue
        state = {name: record[name].item() for name in ("frames", "step", "time", "wall_time_s")}
        if check_data:
            arrays = {name: slot[name][...] for name in slot if name not in ("scalars", "header")}
            scalars = slot["scalars"][...]
            if int(record["data_crc"]) != state_checksum(arrays, scalars, state["step"]):
                continue
            state.update(arrays)
            state.update(zip(slot["scalars"].attrs["names"], scalars.tolist()))
        found.append((state["frames"], slot_name, state))
    if not found:
        return None
    _, slot_name, state = max(found, key=lambda item: item[0])
    return slot_name, state


def require_resume_names(path, state, needs):
    """Raise ``SimulationError`` unless the resume ``state`` read from run file ``path`` holds every
    name of ``needs``: a file of an earlier softsim whose run kept fewer numbers cannot go on the
    same way."""
    missing = [name for name in needs if name not in state]
    if missing:
        raise SimulationError(f"--resume: '{path}' was written by an earlier softsim, whose resume state "
                              f"lacks {', '.join(missing)}; start the run again with --overwrite")


def read_resume_state(f):
    """The newest intact resume state in an open run file, as a dict of its arrays (``positions``,
    ``velocities`` (n, 3) in the user's order, ...) and numbers (``frames`` written, ``time``,
    ``step``, ``wall_time_s``, ...); None if no slot is intact."""
    newest = _newest_slot(f, check_data=True)
    return None if newest is None else newest[1]


def frames_written(f):
    """How many frames of an open run file are complete: rows ``0 .. frames_written(f) - 1`` of
    every ``frames/*`` dataset (a file from a run that ended is trimmed to exactly these)."""
    if "state" not in f or not any(isinstance(f["state"][name], h5py.Group) and "header" in f["state"][name]
                                   for name in f["state"]):
        return f["frames/time"].shape[0] if "frames/time" in f else 0     # written before the headers
    newest = _newest_slot(f, check_data=False)
    return 0 if newest is None else int(newest[1]["frames"])


def wall_time_s(f):
    """Wall time [s] an open run file took so far: the root attribute once the run has ended, the
    newest intact resume header while it is running or after it was killed."""
    if str(f.attrs.get("status", "")) != "running":
        return float(f.attrs.get("wall_time_s", float("nan")))
    newest = _newest_slot(f, check_data=False) if "state" in f else None
    return float(newest[1]["wall_time_s"]) if newest is not None else float(f.attrs.get("wall_time_s", float("nan")))


def free_bytes(path):
    """Bytes free for this user on the file system holding ``path``: statvfs of the file itself
    where it exists (a link leads to the file system of its target), else of its folder.  A frame
    asks once; resolving the path first took 60 us of its 1-1.4 ms, the statvfs 5."""
    try:
        return shutil.disk_usage(path).free
    except FileNotFoundError:
        return shutil.disk_usage(Path(path).resolve().parent).free


def _os_reason(exc):
    """``No space left on device`` from an ``OSError`` raised by the OS or by HDF5 (one line)."""
    reason = exc.strerror or str(exc)
    return reason.strip().splitlines()[0] if reason.strip() else type(exc).__name__


# Test-only crash hook: SOFTSIM_CRASH_AT="after_points:3" kills this process with SIGKILL at that
# point of the writer (at frame 3; without ":N", at the first time the point is reached), so the
# crash tests can land on the worst instants every time.  Unset, it costs one dict lookup.
_CRASH_AT = os.environ.get("SOFTSIM_CRASH_AT", "")


def crash_point(name, frame=None):
    """SIGKILL this process here if ``SOFTSIM_CRASH_AT`` names this point (and frame)."""
    if not _CRASH_AT:
        return
    point, _, at_frame = _CRASH_AT.partition(":")
    if point == name and (not at_frame or frame is None or int(at_frame) == frame):
        os.kill(os.getpid(), signal.SIGKILL)
