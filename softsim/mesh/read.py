"""Reading a tetrahedral mesh from any file format meshio understands."""

import contextlib
import io

import numpy as np

from ..errors import MeshError

_VOLUME_CELLS = {"tetra", "tetra10", "hexahedron", "hexahedron20", "hexahedron27", "wedge", "wedge15",
                 "pyramid", "pyramid13", "polyhedron"}


def read_tetrahedra(path):
    """``(points (n, 3) float64 [m], tets (m, 4) int64)`` of the linear tets in mesh file ``path``.

    Lower-dimensional cells (surface triangles, lines, vertices) are ignored; other volume cells
    (hexahedra, quadratic tets, ...) are refused rather than silently dropped.
    """
    import meshio

    said = io.StringIO()
    try:
        # meshio prints its own complaints, and calls sys.exit(1) when no reader fits the file
        with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
            mesh = meshio.read(path)
    except (Exception, SystemExit) as exc:
        text = "" if isinstance(exc, SystemExit) else str(exc).strip()
        printed = " ".join(line.strip() for line in said.getvalue().splitlines() if line.strip())
        reason = text.splitlines()[0] if text else (printed or type(exc).__name__)
        raise MeshError(f"mesh.file = '{path}': cannot be read as a mesh by meshio ({reason})") from None
    points = np.asarray(mesh.points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise MeshError(f"mesh.file = '{path}': points must be 3D, got shape {points.shape}")
    blocks = [np.asarray(c.data, dtype=np.int64) for c in mesh.cells if c.type == "tetra"]
    others = sorted({c.type for c in mesh.cells if c.type in _VOLUME_CELLS and c.type != "tetra"})
    if others:
        raise MeshError(f"mesh.file = '{path}': has {', '.join(others)} cells; softsim simulates linear tetrahedra only")
    if not blocks or sum(len(b) for b in blocks) == 0:
        found = sorted({c.type for c in mesh.cells}) or ["no cells"]
        raise MeshError(f"mesh.file = '{path}': has no tetrahedra (found: {', '.join(found)})")
    tets = np.concatenate(blocks).reshape(-1, 4)
    if tets.min() < 0 or tets.max() >= points.shape[0]:
        raise MeshError(f"mesh.file = '{path}': tetrahedra refer to vertices outside 0..{points.shape[0] - 1}")
    if not np.isfinite(points).all():
        raise MeshError(f"mesh.file = '{path}': vertex coordinates must be finite numbers")
    return points, tets
