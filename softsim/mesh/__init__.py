"""Mesh stage: a checked, positively oriented tetrahedral mesh from a scene's ``mesh`` section."""

import dataclasses
import logging
import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..errors import MeshError
from ..io.files import content_sha256
from .checks import boundary_face_slots, check_not_degenerate, orient_positively
from .quality import format_quality, quality_summary

log = logging.getLogger("softsim")


@dataclass(frozen=True)
class TetMesh:
    """A simulable tetrahedral mesh, in the user's vertex and tet order.

    points: (node_count, 3) rest positions [m], float64.
    tets: (tet_count, 4) vertex indices, int64, every rest volume positive.
    source: where it came from (shape name or file path), for messages.
    source_sha256: for a mesh file, the SHA-256 of its content when it was read (``io.files.content_sha256``),
    stored in a run file so that a resume or a sweep notices a file that changed since; else None.
    boundary_slots: None, or the boundary faces as face slots ``4 e + k`` of ``tets``
    (``checks.boundary_face_slots``), found when the mesh was checked: the model reuses them.
    """

    points: np.ndarray
    tets: np.ndarray
    source: str
    boundary_slots: Optional[np.ndarray] = None
    source_sha256: Optional[str] = None

    @property
    def node_count(self):
        return self.points.shape[0]

    @property
    def tet_count(self):
        return self.tets.shape[0]

    def quality(self):
        """Dict of tets, vertices, dihedral angle range [deg] and smallest altitude [m]."""
        return quality_summary(self.points, self.tets)


# Meshes estimated above this many tets are refused before meshing (about 10 GB of working memory).
MAX_TETS = 50_000_000


# Peak memory per tet while softsim meshes and prepares a scene [bytes]: measured 1.25 kB for a
# 169k-tet gmsh box (381 MB peak, ~170 MB of it the interpreter and libraries) and 3.4 kB for a
# 1M-tet structured beam (3285 MiB peak, ``python -m benchmarks --sections memory``).
MESH_PEAK_BYTES_PER_TET = 3500
# gmsh meshes with this many tetrahedra or more are announced before gmsh starts: it says nothing
# for minutes on a few million (2.6M: about three minutes on a 2-core EPYC).
ANNOUNCED_MESH_TETS = 500_000


def available_memory_bytes():
    """Memory the OS can give this process now [bytes] (``MemAvailable``), or None if unknown."""
    try:
        with open("/proc/meminfo") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def estimated_tet_count(spec):
    """Tets a generated shape will have at ``element_size`` (exact for structured boxes), or None for files."""
    if spec.shape == "file":
        return None
    h = spec.element_size
    if spec.shape == "box" and spec.structured:
        return 5 * int(np.prod(np.maximum(1, np.rint(np.asarray(spec.size) / h))))
    if spec.shape == "box":
        volume = float(np.prod(spec.size))
    elif spec.shape == "cylinder":
        volume = math.pi * spec.radius ** 2 * spec.length
    else:
        volume = 4.0 / 3.0 * math.pi * spec.radius ** 3
    return int(volume / (h ** 3 / (6.0 * math.sqrt(2.0))))    # regular tets of edge h


def raw_tetrahedra(spec):
    """Unchecked (points, tets) for a scene's ``mesh`` section (``softsim.config.MeshSpec``)."""
    from . import generate, read

    estimate = estimated_tet_count(spec)
    if estimate is not None and estimate > MAX_TETS:
        raise MeshError(f"mesh.element_size = {spec.element_size:g}: would make about {estimate:.3g} tetrahedra, "
                        f"more than the {MAX_TETS:.0e} softsim meshes on one machine; use a larger element_size")
    available = available_memory_bytes()
    if estimate is not None and available is not None and estimate * MESH_PEAK_BYTES_PER_TET > available:
        raise MeshError(f"mesh.element_size = {spec.element_size:g}: about {estimate:.3g} tetrahedra need "
                        f"~{estimate * MESH_PEAK_BYTES_PER_TET / 1e9:.3g} GB to mesh and set up, but only "
                        f"{available / 1e9:.3g} GB of memory are available; use a larger element_size")
    if spec.shape == "file":
        return read.read_tetrahedra(spec.file)
    if estimate >= ANNOUNCED_MESH_TETS and not (spec.shape == "box" and spec.structured):
        log.info("mesh.element_size = %g: gmsh is meshing about %.2g million tetrahedra, which takes minutes",
                 spec.element_size, estimate / 1e6)
    if spec.shape == "box" and spec.structured:
        return generate.structured_box(spec.size, spec.origin, spec.element_size)
    if spec.shape == "box":
        return generate.gmsh_box(spec.size, spec.origin, spec.element_size)
    if spec.shape == "cylinder":
        return generate.gmsh_cylinder(spec.radius, spec.length, spec.axis, spec.origin, spec.element_size)
    if spec.shape == "sphere":
        return generate.gmsh_sphere(spec.radius, spec.origin, spec.element_size)
    raise ValueError(f"unknown mesh shape {spec.shape!r}")


def checked_mesh(points, tets, source):
    """A ``TetMesh`` from raw arrays: tets oriented and checked, vertex numbering kept.

    Raises ``MeshError`` for degenerate or tangled tets; logs a warning for re-oriented tets and
    for vertices no tet uses (they stay in the output, massless and held at their initial place).
    """
    points = np.asarray(points, np.float64)
    tets = np.asarray(tets, np.int64)
    unreferenced = len(points) - len(np.unique(tets))
    if unreferenced:
        log.warning("%s: %d vertices are used by no tetrahedron; they are kept in the output but not "
                    "simulated (they stay at their initial position)", source, unreferenced)
    check_not_degenerate(points, tets, source)
    tets, reversed_count = orient_positively(points, tets)
    if reversed_count:
        log.warning("%s: re-oriented %d tetrahedra with reversed winding (negative volume)", source, reversed_count)
    boundary = boundary_face_slots(tets, source)   # refuses tangled meshes
    return TetMesh(points=points, tets=tets, source=source, boundary_slots=boundary)


def mesh_file_sha256(file):
    """``io.files.content_sha256`` of the scene's mesh file ``file``; ``MeshError`` naming the file
    (or the data file it names) that cannot be read."""
    try:
        return content_sha256(file)
    except OSError as exc:
        what = f"{exc.filename}: " if exc.filename and str(exc.filename) != str(file) else ""
        raise MeshError(f"mesh.file = '{file}': cannot be read ({what}{exc.strerror or exc})") from None


def build_mesh(spec):
    """The checked ``TetMesh`` of a scene's ``mesh`` section."""
    if spec.shape != "file":
        return checked_mesh(*raw_tetrahedra(spec), f"mesh.shape = {spec.shape}")
    # Hashed before it is read: a file changed in between then differs from its stored hash later
    # (a resume refused), never the other way round (a changed mesh taken for the one run before).
    digest = mesh_file_sha256(spec.file)
    checked = checked_mesh(*raw_tetrahedra(spec), f"mesh.file = '{spec.file}'")
    return dataclasses.replace(checked, source_sha256=digest)


__all__ = ["TetMesh", "build_mesh", "mesh_file_sha256", "checked_mesh", "raw_tetrahedra", "format_quality"]
