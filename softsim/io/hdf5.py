"""The run's HDF5 file: mesh once, frames appended as the run goes, status at the end.

Layout (a public interface):

- ``mesh/points`` (n, 3) rest positions [m], ``mesh/tets`` (m, 4), ``mesh/fixed`` (n,) bool
- ``frames/time`` (k,) [s], ``frames/points`` (k, n, 3) [m]; optional ``frames/velocities``
  (k, n, 3) [m/s]; ``frames/energy/{kinetic,elastic,gravity}`` (k,) [J]; the other optional
  fields of ``io.fields.FIELDS`` as ``frames/<name>``, (k, n, ...) per vertex or (k, m, ...) per tet
- ``state/``: the resume state of the last complete frame (``positions``, ``velocities`` (n, 3),
  the guard's ``guard_*``; attributes ``time``, ``step``, ``checksum``) in two slots ``state/a``,
  ``state/b`` written in turn; ``state`` attribute ``current`` names the newer, ``time`` and ``step``
  are its; read it with ``read_resume_state``
- root attributes: ``config``, ``dt``, ``steps``, ``wall_time_s``, ``softsim_version``,
  ``status`` (running | complete | interrupted | failed), ``status_reason``

Plain HDF5 (default ``libver``), chunked resizable datasets, flushed after every frame: a file left
by a killed run opens with plain ``h5py.File(path)`` and holds the frames written before.  An XDMF
file beside it (``out.xdmf``) lets ParaView play the frames.
"""

import os
import shutil
import signal
import time as _time
import zlib
from pathlib import Path

import h5py
import numpy as np

from .. import __version__
from ..errors import SimulationError, SoftsimError
from .fields import FIELDS
from .xdmf import write_xdmf

ENERGY_TERMS = ("kinetic", "elastic", "gravity")
STATUSES = ("running", "complete", "interrupted", "failed")
# Fields stored as frames/<name>, one array row per frame, passed to append_frame(fields=...).
_ARRAY_FIELDS = tuple(name for name, spec in FIELDS.items()
                      if spec.location in ("vertex", "tet") and name != "velocities")
# The XDMF is rewritten at most this often [s of wall time] while running, and always at the end.
XDMF_REWRITE_INTERVAL_S = 1.0
# A frame is written only if the disk has room for twice its data plus this (metadata, XDMF, status).
FREE_SPACE_MARGIN_BYTES = 4 << 20
# ``state/`` holds the resume state in two slots written in turn (see ``RunWriter.append_frame``).
STATE_SLOTS = ("a", "b")


def xdmf_path_for(path):
    """``out.h5`` -> ``out.xdmf`` (same folder)."""
    return Path(path).with_suffix(".xdmf")


def check_writable(path, overwrite=True):
    """Raise ``SimulationError`` if ``path``'s folder is missing or not writable, or if ``path``
    exists and ``overwrite`` is False (checked before any work)."""
    folder = Path(path).resolve().parent
    if not folder.is_dir():
        raise SimulationError(f"output.path = '{path}': folder {folder} does not exist")
    if not os.access(folder, os.W_OK):
        raise SimulationError(f"output.path = '{path}': folder {folder} is not writable")
    if Path(path).is_dir():
        raise SimulationError(f"output.path = '{path}': is a directory, expected a file name like out.h5")
    if not overwrite and Path(path).exists():
        raise SimulationError(f"output.path = '{path}': the file exists; pass --overwrite to replace it")
    if xdmf_path_for(path).resolve() == Path(path).resolve():
        raise SimulationError(f"output.path = '{path}': is the name of the XDMF file written beside the "
                              f"HDF5 file; use an HDF5 name like out.h5")


class RunWriter:
    """Context manager writing one run: ``append_frame`` per frame, ``finish`` with the status.

    points (n, 3) [m], tets (m, 4), fixed (n,) bool: the mesh in the user's order.
    fields: the optional per-frame fields asked for (names of ``io.fields.FIELDS``).
    """

    def __init__(self, path, points, tets, fixed, config_yaml, dt, steps, fields=(), xdmf=True):
        self.path = Path(path)
        self.fields = tuple(fields)
        self.node_count = points.shape[0]
        self.tet_count = tets.shape[0]
        self.xdmf = xdmf
        self._xdmf_written_at = -np.inf
        self._started = _time.perf_counter()
        # The file is built under a temporary name and renamed once its mesh and empty frame
        # datasets are on disk, so ``path`` never names a file that a plain reader cannot open.
        partial = self.path.with_name(f".{self.path.name}.partial-{os.getpid()}")
        try:
            self.file = h5py.File(partial, "w")
        except OSError as exc:
            raise SimulationError(f"output.path = '{path}': cannot create the file ({exc})") from None
        _keep_metadata_until_flush(self.file)
        try:
            self._create_layout(points, tets, fixed, config_yaml, dt, steps)
            crash_point("before_rename")
            os.replace(partial, self.path)
        except BaseException as exc:
            self.file.close()
            partial.unlink(missing_ok=True)
            if isinstance(exc, OSError):
                raise SimulationError(f"output.path = '{path}': cannot write the file ({_os_reason(exc)})") from None
            raise

    def _create_layout(self, points, tets, fixed, config_yaml, dt, steps):
        """Write the mesh, the attributes and the empty frame and state datasets, then flush."""
        f = self.file
        f.attrs.update(config=config_yaml, dt=float(dt), steps=int(steps), wall_time_s=0.0,
                       softsim_version=__version__, status="running", status_reason="")
        mesh = f.create_group("mesh")
        mesh.create_dataset("points", data=np.asarray(points, np.float64))
        mesh.create_dataset("tets", data=np.asarray(tets, np.int64))
        mesh.create_dataset("fixed", data=np.asarray(fixed, np.bool_))
        frames = f.create_group("frames")
        n = self.node_count
        frames.create_dataset("points", shape=(0, n, 3), maxshape=(None, n, 3), dtype=np.float64, chunks=(1, n, 3))
        if "velocities" in self.fields:
            frames.create_dataset("velocities", shape=(0, n, 3), maxshape=(None, n, 3), dtype=np.float64,
                                  chunks=(1, n, 3))
        if "energy" in self.fields:
            energy = frames.create_group("energy")
            for term in ENERGY_TERMS:
                energy.create_dataset(term, shape=(0,), maxshape=(None,), dtype=np.float64, chunks=(1024,))
        for name in self.fields:
            if name in _ARRAY_FIELDS:
                spec = FIELDS[name]
                row = (n if spec.location == "vertex" else self.tet_count, *spec.shape)
                frames.create_dataset(name, shape=(0, *row), maxshape=(None, *row), dtype=np.float64,
                                      chunks=(1, *row))
        # Created last, so its header lies behind the others' and HDF5, which flushes metadata in
        # address order, writes its new length last: a kill inside a flush can leave the other
        # datasets a row ahead of frames/time, never behind it.
        frames.create_dataset("time", shape=(0,), maxshape=(None,), dtype=np.float64, chunks=(1024,))
        state = f.create_group("state")
        for slot in STATE_SLOTS:
            group = state.create_group(slot)
            group.create_dataset("positions", shape=(n, 3), dtype=np.float64, fillvalue=0.0)
            group.create_dataset("velocities", shape=(n, 3), dtype=np.float64, fillvalue=0.0)
            group.attrs.update(time=-1.0, step=-1, checksum=-1)
        state.attrs.update(current="", time=0.0, step=0)
        f.flush()

    @classmethod
    def reopen(cls, path, fields=(), xdmf=True):
        """``(writer, state)`` to continue the run in ``path`` from its last complete frame.

        ``state`` is a dict of ``state/``: ``positions``, ``velocities`` (n, 3) in the user's order,
        ``time``, ``step`` and any extra arrays and numbers the run stored for a resume.  Frames
        after that state (a frame cut off by a crash) are dropped; the status is ``running`` again.
        """
        self = cls.__new__(cls)
        self.path = Path(path)
        self.fields = tuple(fields)
        self.xdmf = xdmf
        self._xdmf_written_at = -np.inf
        try:
            self.file = h5py.File(self.path, "a")
        except OSError as exc:
            raise SimulationError(f"output.path = '{path}': cannot reopen the file to resume ({exc})") from None
        _keep_metadata_until_flush(self.file)
        f = self.file
        self.node_count = f["mesh/points"].shape[0]
        self.tet_count = f["mesh/tets"].shape[0]
        state = read_resume_state(f)
        if state is None:
            self.file.close()
            raise SimulationError(f"--resume: '{path}' holds no intact resume state")
        kept = int(np.searchsorted(f["frames/time"][:], float(state["time"]), side="right"))
        f["frames/time"].resize(kept, axis=0)
        self._drop_partial_frame()
        self._started = _time.perf_counter() - float(f.attrs["wall_time_s"])
        f.attrs.update(status="running", status_reason="")
        f.flush()
        return self, state

    @property
    def frame_count(self):
        return self.file["frames/time"].shape[0]

    def append_frame(self, time, step, points, velocities, energy=None, resume_state=None, fields=None):
        """Append one frame and the resume state, then flush: the file on disk changes only there.

        points, velocities: (n, 3) [m], [m/s] in the user's order; energy: dict of ENERGY_TERMS [J];
        resume_state: optional dict of further arrays (datasets) and numbers (attributes) a resume
        needs, stored with positions and velocities in the ``state/`` slot not written last time;
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

    def _write_frame(self, k, time, step, points, velocities, energy, resume_state, fields=None):
        frames = self.file["frames"]
        crash_point("frame_start", k)
        _append(frames["points"], k, points)
        crash_point("after_points", k)
        if "velocities" in self.fields:
            _append(frames["velocities"], k, velocities)
            crash_point("after_velocities", k)
        if "energy" in self.fields:
            for term in ENERGY_TERMS:
                _append(frames["energy"][term], k, energy[term])
            crash_point("after_energy", k)
        for name, value in (fields or {}).items():
            _append(frames[name], k, value)
        _append(frames["time"], k, time)
        crash_point("after_time", k)
        # The resume state: two slots, written in turn: the one written now is not the one the last flush called
        # current, so a kill before the next flush (HDF5 may put raw data on disk before the
        # metadata that describes it) leaves the current slot intact; a checksum, stored with
        # the step, tells an intact slot from a torn one.
        state = self.file["state"]
        slot_name = STATE_SLOTS[1] if state.attrs["current"] == STATE_SLOTS[0] else STATE_SLOTS[0]
        slot = state[slot_name]
        arrays = {"positions": points, "velocities": velocities}
        arrays.update({name: value for name, value in (resume_state or {}).items() if np.ndim(value) > 0})
        for name, value in arrays.items():
            value = np.asarray(value)
            if name in slot and slot[name].shape == value.shape and slot[name].dtype == value.dtype:
                slot[name][...] = value
            else:
                if name in slot:
                    del slot[name]
                slot.create_dataset(name, data=value)
        scalars = {name: value for name, value in (resume_state or {}).items() if np.ndim(value) == 0}
        slot.attrs.update(scalars)
        slot.attrs.update(time=float(time), step=int(step), checksum=state_checksum(arrays, step))
        state.attrs.update(current=slot_name, time=float(time), step=int(step))
        self.file.attrs["wall_time_s"] = _time.perf_counter() - self._started
        crash_point("before_flush", k)
        self.file.flush()
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
        write_xdmf(xdmf_path_for(self.path), self.path, self.node_count, self.tet_count,
                   self.file["frames/time"][:], point_fields=point_fields, cell_fields=cell_fields)

    def finish(self, status, reason=""):
        """Record the final ``status`` and ``reason``, rewrite the XDMF, close the file."""
        if status not in STATUSES:
            raise ValueError(f"status must be one of {STATUSES}, got {status!r}")
        if not self.file:
            return
        try:
            self._drop_partial_frame()
            crash_point("finish_before_status")
            self.file.attrs.update(status=status, status_reason=reason,
                                   wall_time_s=_time.perf_counter() - self._started)
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
                pass

    def _drop_partial_frame(self):
        """Shrink every per-frame dataset to ``frames/time``'s length (a frame cut off mid-write)."""
        k = self.frame_count
        datasets = []
        self.file["frames"].visititems(lambda name, obj: datasets.append(obj)
                                       if isinstance(obj, h5py.Dataset) else None)
        for dataset in datasets:
            if dataset.shape[0] > k:
                dataset.resize(k, axis=0)

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


def _keep_metadata_until_flush(file):
    """Stop HDF5's metadata cache from writing entries out to make room between flushes, so the
    file on disk changes only at ``flush`` (the cache grows instead: a few kB per frame at most)."""
    config = file.id.get_mdc_config()
    config.evictions_enabled = False
    config.incr_mode = config.flash_incr_mode = config.decr_mode = 0     # H5C_*_off
    file.id.set_mdc_config(config)


def state_checksum(arrays, step):
    """CRC-32 of a resume state: its arrays' bytes, in name order, and its step."""
    crc = zlib.crc32(str(int(step)).encode())
    for name in sorted(arrays):
        crc = zlib.crc32(np.ascontiguousarray(arrays[name], dtype=np.float64).tobytes(), crc)
    return crc


def read_resume_state(f):
    """The newest intact resume state in an open run file, as a dict of its arrays (``positions``,
    ``velocities`` (n, 3) in the user's order, ...) and numbers (``time``, ``step``, ...); None if
    no slot is intact.  The current slot is tried first, then the other one."""
    state = f["state"]
    current = str(state.attrs.get("current", ""))
    order = sorted(STATE_SLOTS, key=lambda slot: slot != current)
    for slot_name in order:
        slot = state[slot_name]
        step = int(slot.attrs.get("step", -1))
        if step < 0:
            continue
        arrays = {name: dataset[...] for name, dataset in slot.items()}
        if int(slot.attrs.get("checksum", -1)) == state_checksum(arrays, step):
            return {**arrays, **{name: value for name, value in slot.attrs.items() if name != "checksum"}}
    return None


def free_bytes(path):
    """Bytes free for this user on the file system holding ``path`` (statvfs: microseconds)."""
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


def _append(dataset, k, value):
    """Grow ``dataset`` along axis 0 to ``k + 1`` and write ``value`` at row ``k``."""
    dataset.resize(k + 1, axis=0)
    dataset[k] = value
