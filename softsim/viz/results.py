"""Read a run's HDF5 file for looking at it: mesh, frames, fields, status (read-only, lazily).

``open_results(path)`` checks that ``path`` is a softsim output file and returns ``Results``; frames
and fields are read one frame at a time, so files larger than memory can be summarised.  A file that
a run is still writing opens too (HDF5 file locking is off for reading; only the frames that
``io.hdf5.frames_written`` counts are used).
"""

import re
from pathlib import Path

import numpy as np
import yaml

from ..errors import SoftsimError
from ..io.fields import FIELDS
from ..io.hdf5 import frames_written


class ResultsError(SoftsimError):
    """A results file cannot be read, or a field / frame asked for is not in it."""


class Results:
    """An open softsim output file.  Use as a context manager, or call ``close``.

    points (n, 3) [m] rest positions; tets (m, 4); times (k,) [s]; attrs: the root attributes;
    scene: the stored scene as a dict; fields: names of the optional fields stored (``FIELDS``).
    """

    def __init__(self, path, file):
        self.path = Path(path)
        self.file = file
        self.attrs = {key: _plain(file.attrs[key]) for key in file.attrs}   # not .items(): see io.hdf5._members
        self.points = file["mesh/points"][:]
        self.tets = file["mesh/tets"][:]
        self.times = file["frames/time"][:frames_written(file)]
        try:
            self.scene = yaml.safe_load(self.attrs.get("config", "")) or {}
        except yaml.YAMLError:
            self.scene = {}
        self.fields = tuple(name for name, spec in FIELDS.items() if spec.datasets[0] in file["frames"])

    @property
    def frame_count(self):
        return len(self.times)

    @property
    def node_count(self):
        return self.points.shape[0]

    @property
    def tet_count(self):
        return self.tets.shape[0]

    def frame_points(self, i):
        """Positions (n, 3) [m] of frame ``i``."""
        return self.file["frames/points"][self.check_frame(i)]

    def field(self, name, i):
        """Field ``name`` at frame ``i``: (n, ...) or (m, ...) float64, or a float for ``energy/*``.

        ``displacement`` and ``speed`` are derived from ``frames/points`` / ``frames/velocities``
        when the run did not store them.
        """
        i = self.check_frame(i)
        if name == "displacement" and "displacement" not in self.fields:
            return self.frame_points(i) - self.points
        if name == "speed" and "speed" not in self.fields and "velocities" in self.fields:
            return np.linalg.norm(self.file["frames/velocities"][i], axis=1)
        if name not in self.available_fields():
            raise ResultsError(f"field '{name}': not in {self.path} (it has: "
                               f"{', '.join(self.available_fields()) or 'no fields'}); "
                               f"add it to output.fields and run again")
        return self.file["frames"][name][i]

    def available_fields(self):
        """Names ``field`` accepts: the stored array fields, ``energy/<term>``, and the derived ones."""
        names = []
        for name in self.fields:
            names += list(FIELDS[name].datasets) if name == "energy" else [name]
        if "displacement" not in names:
            names.append("displacement")
        if "speed" not in names and "velocities" in self.fields:
            names.append("speed")
        return names

    def energy(self):
        """``{term: (k,) [J]}`` of the recorded energies, or ``{}`` when the run did not record them."""
        if "energy" not in self.fields:
            return {}
        k = self.frame_count
        return {dataset.split("/")[1]: self.file["frames"][dataset][:k] for dataset in FIELDS["energy"].datasets}

    def check_frame(self, i):
        """``i`` as a non-negative frame index (negative counts from the end), or ``ResultsError``."""
        k = self.frame_count
        if not isinstance(i, (int, np.integer)) or not -k <= i < k:
            raise ResultsError(f"frame {i}: out of range; {self.path} has {k} frames (0 to {k - 1}, "
                               f"or -1 for the last)")
        return int(i) % k

    def select_frames(self, spec):
        """Frame indices of ``spec``: None (all), an int, or a slice text ``start:stop:step`` / ``N``."""
        k = self.frame_count
        if spec is None or spec == "":
            return list(range(k))
        if isinstance(spec, (int, np.integer)):
            return [self.check_frame(spec)]
        text = str(spec).strip()
        if re.fullmatch(r"-?\d+", text):
            return [self.check_frame(int(text))]
        match = re.fullmatch(r"(-?\d*):(-?\d*)(?::(-?\d*))?", text)
        if not match:
            raise ResultsError(f"--frames = '{spec}': expected N or start:stop[:step], e.g. 0:100:10")
        start, stop, step = (int(g) if g else None for g in match.groups())
        if step == 0:
            raise ResultsError(f"--frames = '{spec}': the step must not be 0")
        frames = list(range(k))[slice(start, stop, step)]
        if not frames:
            raise ResultsError(f"--frames = '{spec}': selects no frame of the {k} in {self.path}")
        return frames

    def close(self):
        self.file.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def open_results(path, allow_empty=False):
    """Open the softsim output file ``path`` for reading; ``ResultsError`` naming what is wrong,
    a file without a complete frame among them unless ``allow_empty`` (a run that failed in its
    first frame has its status and reason, and nothing else, to show)."""
    import h5py

    path = Path(path)
    if not path.is_file():
        raise ResultsError(f"'{path}': no such file")
    try:
        file = h5py.File(path, "r", locking=False)
    except OSError:
        raise ResultsError(f"'{path}': not an HDF5 file (expected the .h5 file softsim run writes)") from None
    missing = [name for name in ("mesh/points", "mesh/tets", "frames/time", "frames/points") if name not in file]
    if missing:
        file.close()
        raise ResultsError(f"'{path}': not a softsim output file (no {', '.join(missing)})")
    results = Results(path, file)
    if results.frame_count == 0 and not allow_empty:
        status, reason = results.attrs.get("status"), results.attrs.get("status_reason")
        results.close()
        if status in (None, "running"):
            raise ResultsError(f"'{path}': holds no frames yet")
        raise ResultsError(f"'{path}': holds no frames (status: {status}{f', {reason}' if reason else ''})")
    return results


def _plain(value):
    """An HDF5 attribute as a plain Python value (str, int, float)."""
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.generic):
        return value.item()
    return value
