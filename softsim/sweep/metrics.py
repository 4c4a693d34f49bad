"""What the sweep summary says about one run, read back from the run's HDF5 file alone.

The file is the record: a run finished in this sweep and one skipped because an earlier sweep
finished it get their summary row from the same function, so the two rows are identical.
"""

from __future__ import annotations

import math

import h5py
import numpy as np
import yaml

from ..io.hdf5 import frames_written, read_resume_state, wall_time_s

# Tip vertices: those within this fraction of the greatest distance from the held vertices.
TIP_TOLERANCE = 1e-3

METRIC_COLUMNS = ("status", "status_reason", "steps", "steps_done", "dt", "time", "wall_time_s",
                  "compile_time_s", "tet_steps_per_s", "tets", "max_displacement", "final_kinetic_energy",
                  "tip_x", "tip_y", "tip_z", "tip_displacement", "tip_dz")


# Units of the summary's columns, for plot labels.
UNITS = {"dt": "s", "time": "s", "wall_time_s": "s", "compile_time_s": "s", "tet_steps_per_s": "1/s", "max_displacement": "m",
         "final_kinetic_energy": "J", "tip_x": "m", "tip_y": "m", "tip_z": "m", "tip_displacement": "m",
         "tip_dz": "m", "material.youngs_modulus": "Pa", "material.density": "kg/m^3", "time.dt": "s",
         "mesh.element_size": "m", "time.duration": "s", "damping": "1/s"}


def tip_vertices(points, fixed):
    """Indices of the "tip": the vertices farthest from the held ones (the far end face of a beam).

    points: (n, 3) rest positions [m]; fixed: (n,) bool.  Distance is to the nearest held
    vertex; vertices within ``TIP_TOLERANCE`` of the greatest distance count.  Empty without a
    held vertex (a free body has no tip).
    """
    held = points[fixed]
    if held.shape[0] == 0 or held.shape[0] == points.shape[0]:
        return np.zeros(0, np.int64)
    distance = np.full(points.shape[0], np.inf)
    for start in range(0, held.shape[0], 256):     # (n, 256) blocks: memory stays small
        block = held[start:start + 256]
        d = np.sqrt(((points[:, None, :] - block[None, :, :]) ** 2).sum(axis=2)).min(axis=1)
        np.minimum(distance, d, out=distance)
    far = distance.max()
    return np.flatnonzero(distance >= far * (1.0 - TIP_TOLERANCE))


def lumped_masses(points, tets, density):
    """Vertex masses [kg], (n,): each tet gives a quarter of ``density x |volume|`` to each corner."""
    corners = points[tets]                                  # (m, 4, 3)
    volume = np.abs(np.linalg.det(corners[:, 1:, :] - corners[:, :1, :])) / 6.0
    mass = np.zeros(points.shape[0])
    np.add.at(mass, tets.ravel(), np.repeat(density * volume / 4.0, 4))
    return mass


def run_metrics(path):
    """The summary columns ``METRIC_COLUMNS`` of the run file ``path`` as a dict.

    steps: planned steps; steps_done: steps reached at the last complete frame; time: its simulated
    time [s]; compile_time_s: of the wall time, Numba compiling kernels its disk cache did not hold
    (``io.hdf5``: a killed session's is not known; 0 in files from before it was recorded);
    tet_steps_per_s: tets x steps_done / (wall_time_s - compile_time_s) (steps of the file's dt:
    sub-steps a ``dt_policy: substep`` run took are not counted); max_displacement: largest |x - X| [m] over
    every frame and vertex; final_kinetic_energy [J] at the last frame (lumped masses);
    tip_x/y/z: mean position [m] of the tip vertices (``tip_vertices``) at the last frame,
    tip_displacement: length of their mean displacement [m], tip_dz: its z component [m]
    (negative = down); NaN without held vertices.
    """
    with h5py.File(path, "r") as f:
        attrs = f.attrs
        points = f["mesh/points"][...]
        tets = f["mesh/tets"][...]
        fixed = f["mesh/fixed"][...]
        frames = f["frames/points"]
        frame_count = frames_written(f)
        max_displacement = 0.0
        for start in range(0, frame_count, 64):
            chunk = frames[start:min(start + 64, frame_count)]
            max_displacement = max(max_displacement, float(np.sqrt(((chunk - points) ** 2).sum(axis=2)).max()))
        final = frames[frame_count - 1] if frame_count else points
        resume_state = read_resume_state(f) or {}
        velocities = resume_state.get("velocities", np.zeros_like(points))
        steps_done = int(resume_state.get("step", 0))
        time = float(resume_state.get("time", 0.0))
        config = yaml.safe_load(str(attrs["config"]))
        row = {
            "status": str(attrs.get("status", "")),
            "status_reason": str(attrs.get("status_reason", "")),
            "steps": int(attrs.get("steps", 0)),
            "dt": float(attrs.get("dt", math.nan)),
            "wall_time_s": wall_time_s(f),
            "compile_time_s": float(attrs.get("compile_time_s", 0.0)),
        }
    density = float(config["material"]["density"])
    mass = lumped_masses(points, tets, density)
    wall = row["wall_time_s"] - row["compile_time_s"]
    row.update(
        steps_done=steps_done,
        time=time,
        tets=int(tets.shape[0]),
        tet_steps_per_s=tets.shape[0] * steps_done / wall if wall > 0 else math.nan,
        max_displacement=max_displacement,
        final_kinetic_energy=float(0.5 * (mass * (velocities ** 2).sum(axis=1)).sum()) if frame_count else 0.0,
    )
    tip = tip_vertices(points, fixed)
    if tip.size:
        position = final[tip].mean(axis=0)
        displacement = (final[tip] - points[tip]).mean(axis=0)
        row.update(tip_x=float(position[0]), tip_y=float(position[1]), tip_z=float(position[2]),
                   tip_displacement=float(np.linalg.norm(displacement)), tip_dz=float(displacement[2]))
    else:
        row.update(tip_x=math.nan, tip_y=math.nan, tip_z=math.nan, tip_displacement=math.nan, tip_dz=math.nan)
    return {column: row[column] for column in METRIC_COLUMNS}
