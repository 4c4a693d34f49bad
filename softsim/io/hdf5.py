"""The run's HDF5 file: mesh once, frames appended as the run goes, status at the end.

Layout (a public interface):

- ``mesh/points`` (n, 3) rest positions [m], ``mesh/tets`` (m, 4), ``mesh/fixed`` (n,) bool
- ``frames/time`` (k,) [s], ``frames/points`` (k, n, 3) [m]; optional ``frames/velocities``
  (k, n, 3) [m/s]; ``frames/energy/{kinetic,elastic,gravity}`` (k,) [J]; the other optional
  fields of ``io.fields.FIELDS`` as ``frames/<name>``, (k, n, ...) per vertex or (k, m, ...) per tet
- ``state/``: ``positions``, ``velocities``, ``time``, ``step`` of the last complete frame
- root attributes: ``config``, ``dt``, ``steps``, ``wall_time_s``, ``softsim_version``,
  ``status`` (running | complete | interrupted | failed), ``status_reason``

Plain HDF5 (default ``libver``), chunked resizable datasets, flushed after every frame: a file left
by a killed run opens with plain ``h5py.File(path)`` and holds the frames written before.  An XDMF
file beside it (``out.xdmf``) lets ParaView play the frames.
"""

import os
import time as _time
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
        try:
            self.file = h5py.File(self.path, "w")
        except OSError as exc:
            raise SimulationError(f"output.path = '{path}': cannot create the file ({exc})") from None
        f = self.file
        f.attrs.update(config=config_yaml, dt=float(dt), steps=int(steps), wall_time_s=0.0,
                       softsim_version=__version__, status="running", status_reason="")
        mesh = f.create_group("mesh")
        mesh.create_dataset("points", data=np.asarray(points, np.float64))
        mesh.create_dataset("tets", data=np.asarray(tets, np.int64))
        mesh.create_dataset("fixed", data=np.asarray(fixed, np.bool_))
        frames = f.create_group("frames")
        n = self.node_count
        frames.create_dataset("time", shape=(0,), maxshape=(None,), dtype=np.float64, chunks=(1024,))
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
        state = f.create_group("state")
        state.create_dataset("positions", shape=(n, 3), dtype=np.float64)
        state.create_dataset("velocities", shape=(n, 3), dtype=np.float64)
        state.attrs.update(time=0.0, step=0)
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
        f = self.file
        self.node_count = f["mesh/points"].shape[0]
        self.tet_count = f["mesh/tets"].shape[0]
        state_group = f["state"]
        state = {name: dataset[...] for name, dataset in state_group.items()}
        state.update({name: value for name, value in state_group.attrs.items()})
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
        """Append one frame and the resume state, then flush.

        points, velocities: (n, 3) [m], [m/s] in the user's order; energy: dict of ENERGY_TERMS [J];
        resume_state: optional dict of further arrays (stored as ``state/`` datasets) and numbers
        (``state/`` attributes) a resume needs; fields: ``{name: array}`` of the other fields asked
        for (``frames/<name>``), vertex fields in the user's vertex order, tet fields in ``mesh/tets`` order.
        ``frames/time`` grows last of the frame datasets, so its length counts only frames whose data
        is in place; ``state/`` is written after it.
        """
        frames = self.file["frames"]
        k = self.frame_count
        _append(frames["points"], k, points)
        if "velocities" in self.fields:
            _append(frames["velocities"], k, velocities)
        if "energy" in self.fields:
            for term in ENERGY_TERMS:
                _append(frames["energy"][term], k, energy[term])
        for name, value in (fields or {}).items():
            _append(frames[name], k, value)
        _append(frames["time"], k, time)
        # The resume state follows only a complete frame (never ahead of frames/time).
        state = self.file["state"]
        state["positions"][...] = points
        state["velocities"][...] = velocities
        for name, value in (resume_state or {}).items():
            if np.ndim(value) == 0:
                state.attrs[name] = value
            elif name in state:
                state[name][...] = value
            else:
                state.create_dataset(name, data=value)
        state.attrs.update(time=float(time), step=int(step))
        self.file.attrs["wall_time_s"] = _time.perf_counter() - self._started
        self.file.flush()
        now = _time.perf_counter()
        if now - self._xdmf_written_at >= XDMF_REWRITE_INTERVAL_S:
            self._write_xdmf()
            self._xdmf_written_at = now

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
        self._drop_partial_frame()
        self.file.attrs.update(status=status, status_reason=reason,
                               wall_time_s=_time.perf_counter() - self._started)
        self.file.flush()
        self._write_xdmf()
        self.file.close()

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


def _append(dataset, k, value):
    """Grow ``dataset`` along axis 0 to ``k + 1`` and write ``value`` at row ``k``."""
    dataset.resize(k + 1, axis=0)
    dataset[k] = value
