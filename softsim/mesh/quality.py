"""Element quality measures, reported once per run in the mesh summary line."""

import numpy as np

from ..kernels.tet_shape import tet_shapes
from .checks import OUTWARD_FACES


def face_normals(points, tets):
    """Outward area vectors of the 4 faces of each tet [m^2], shape (tet_count, 4, 3)."""
    X = points[tets]
    f = X[:, OUTWARD_FACES]                                  # (m, 4, 3 corners, 3)
    return 0.5 * np.cross(f[:, :, 1] - f[:, :, 0], f[:, :, 2] - f[:, :, 0])


def altitudes(points, tets):
    """Smallest altitude of each tet [m] (3 V / largest face area), shape (tet_count,)."""
    return tet_shapes(np.ascontiguousarray(points, dtype=np.float64), tets)[0]


def dihedral_angles(points, tets):
    """The 6 interior dihedral angles of each tet [degrees], shape (tet_count, 6)."""
    n = face_normals(points, tets)
    n = n / np.linalg.norm(n, axis=2, keepdims=True)
    pairs = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    cos = np.stack([-(n[:, a] * n[:, b]).sum(axis=1) for a, b in pairs], axis=1)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def quality_summary(points, tets):
    """Dict with tets, vertices, min/max dihedral angle [deg] and smallest altitude [m]
    (``kernels.tet_shape``: one compiled pass, no per-tet temporaries of NumPy's)."""
    altitude, cos_min, cos_max = tet_shapes(np.ascontiguousarray(points, dtype=np.float64), tets)
    return {
        "tets": int(tets.shape[0]),
        "vertices": int(points.shape[0]),
        "min_dihedral_deg": float(np.degrees(np.arccos(cos_max.max()))),
        "max_dihedral_deg": float(np.degrees(np.arccos(cos_min.min()))),
        "min_altitude_m": float(altitude.min()),
    }


def format_quality(summary):
    """One line: ``6451 tets, 1746 vertices, dihedral 9.8-161.2 deg, smallest altitude 2.1e-03 m``."""
    return (f"{summary['tets']} tets, {summary['vertices']} vertices, "
            f"dihedral {summary['min_dihedral_deg']:.1f}-{summary['max_dihedral_deg']:.1f} deg, "
            f"smallest altitude {summary['min_altitude_m']:.3g} m")
