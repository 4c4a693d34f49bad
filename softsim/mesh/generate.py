"""Tetrahedral meshes of the scene's primitive solids.

``box``, ``cylinder`` and ``sphere`` are meshed by gmsh's Python API (OpenCASCADE geometry,
no GUI) into linear tetrahedra of target edge length ``element_size``; ``structured_box`` builds
a hex grid cut into 5 tets per cell with alternating parity, with no gmsh at all.
"""

import re
import threading

import numpy as np

from ..errors import MeshError, MissingDependencyError
from ..kernels.rest_state import signed_volumes

# Debian / Ubuntu packages providing the shared libraries the gmsh wheel loads even headless.
GMSH_SYSTEM_PACKAGES = "libglu1-mesa libgl1 libxcursor1 libxinerama1 libxft2 libxrender1"

_gmsh_lock = threading.Lock()   # gmsh keeps global state: one model at a time per process


def import_gmsh():
    """Import the gmsh module, or raise ``MissingDependencyError`` naming the missing library."""
    try:
        import gmsh
    except OSError as exc:  # the wheel's libgmsh.so could not load a system library
        match = re.search(r"(lib[\w.+-]+\.so[\w.]*)", str(exc))
        library = match.group(1) if match else str(exc).splitlines()[0]
        raise MissingDependencyError(
            f"gmsh cannot load the system library {library}; install it, e.g. "
            f"'apt-get install {GMSH_SYSTEM_PACKAGES}'"
        ) from None
    except ImportError as exc:
        raise MissingDependencyError(f"gmsh is not importable ({exc}); reinstall softsim with pip") from None
    return gmsh


def _gmsh_tetrahedra(add_geometry, element_size, solid, smallest):
    """Run gmsh on the solid that ``add_geometry(occ)`` creates; return (points, tets) arrays.

    solid: what it is, for messages ("cylinder of radius 0.01 m, length 0.3 m"); smallest: its
    smallest dimension [m].  gmsh's own failures (an element far larger than the solid, a
    geometry OpenCASCADE cannot build) become a ``MeshError`` naming the scene's keys.
    """
    gmsh = import_gmsh()
    with _gmsh_lock:
        gmsh.initialize(interruptible=False)   # no signal handler: works off the main thread
        try:
            gmsh.option.setNumber("General.Terminal", 0)
            gmsh.option.setNumber("General.Verbosity", 0)
            gmsh.model.add("softsim")
            try:
                add_geometry(gmsh.model.occ)
                gmsh.model.occ.synchronize()
            except Exception as exc:           # gmsh raises plain Exception with its last error
                raise MeshError(f"mesh: gmsh cannot build the {solid} ({_gmsh_reason(exc)})") from None
            gmsh.option.setNumber("Mesh.MeshSizeMin", 0.5 * element_size)
            gmsh.option.setNumber("Mesh.MeshSizeMax", element_size)
            gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
            gmsh.option.setNumber("Mesh.Optimize", 1)
            try:
                gmsh.model.mesh.generate(3)
            except Exception as exc:
                hint = (f"use an element_size below its smallest dimension, {smallest:g} m"
                        if element_size >= smallest else "try a smaller element_size")
                raise MeshError(f"mesh.element_size = {element_size:g}: gmsh cannot mesh the {solid} with it "
                                f"({_gmsh_reason(exc)}); {hint}") from None
            node_tags, coords, _ = gmsh.model.mesh.getNodes()
            types, _, element_nodes = gmsh.model.mesh.getElements(dim=3)
        finally:
            gmsh.finalize()
    tet_type = 4   # gmsh's 4-node tetrahedron
    if tet_type not in list(types):
        raise MeshError("gmsh produced no tetrahedra; try a smaller mesh.element_size")
    tag_to_index = np.full(int(node_tags.max()) + 1, -1, dtype=np.int64)
    tag_to_index[node_tags.astype(np.int64)] = np.arange(len(node_tags))
    tets = tag_to_index[np.asarray(element_nodes[list(types).index(tet_type)], dtype=np.int64)].reshape(-1, 4)
    points = np.asarray(coords, dtype=np.float64).reshape(-1, 3)
    return points, tets


def _gmsh_reason(exc):
    """gmsh's error message, on one line."""
    return " ".join(str(exc).split()) or type(exc).__name__


def _metres(values):
    return "[" + ", ".join(f"{v:g}" for v in values) + "] m"


def gmsh_box(size, origin, element_size):
    """Unstructured tets of the box ``[origin, origin + size]`` [m]."""
    return _gmsh_tetrahedra(lambda occ: occ.addBox(*origin, *size), element_size,
                            f"box of size {_metres(size)} at origin {_metres(origin)}", min(size))


_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


def gmsh_cylinder(radius, length, axis, origin, element_size):
    """Tets of a cylinder [m]: first end face centred at ``origin``, extending ``length`` along ``axis``."""
    direction = np.asarray(_AXES[axis]) * length
    return _gmsh_tetrahedra(lambda occ: occ.addCylinder(*origin, *direction, radius), element_size,
                            f"cylinder of radius {radius:g} m and length {length:g} m at origin {_metres(origin)}",
                            min(2.0 * radius, length))


def gmsh_sphere(radius, origin, element_size):
    """Tets of a ball of ``radius`` [m] centred at ``origin``."""
    return _gmsh_tetrahedra(lambda occ: occ.addSphere(*origin, radius), element_size,
                            f"sphere of radius {radius:g} m at origin {_metres(origin)}", 2.0 * radius)


# Corners of a unit hex cell as (i, j, k) offsets, numbered i + 2 j + 4 k.
_CORNERS = np.array([[i, j, k] for k in (0, 1) for j in (0, 1) for i in (0, 1)])
# Five tets of a cell whose corner 0 is "even": four corner tets and the central one.
_FIVE_TETS_EVEN = np.array([[0, 1, 2, 4], [3, 1, 2, 7], [5, 1, 4, 7], [6, 2, 4, 7], [1, 2, 4, 7]])
# The same split mirrored in x (corner index i + 2j + 4k -> (1 - i) + 2j + 4k).
_FIVE_TETS_ODD = _FIVE_TETS_EVEN ^ 1


def structured_box(size, origin, element_size):
    """Hex grid of about ``element_size`` cells, 5 positively oriented tets each, alternating split.

    Neighbouring cells use mirrored splits so their shared faces match and no split direction is
    preferred across the body.  Returns (points (n, 3) [m], tets (m, 4) int64).
    """
    size = np.asarray(size, dtype=np.float64)
    cells = np.maximum(1, np.rint(size / element_size).astype(np.int64))
    nx, ny, nz = cells
    axes = [np.linspace(origin[d], origin[d] + size[d], cells[d] + 1) for d in range(3)]
    gx, gy, gz = np.meshgrid(*axes, indexing="ij")
    points = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=1)

    def node(i, j, k):
        return (i * (ny + 1) + j) * (nz + 1) + k

    ci, cj, ck = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    ci, cj, ck = ci.ravel(), cj.ravel(), ck.ravel()
    corner_nodes = node(ci[:, None] + _CORNERS[:, 0], cj[:, None] + _CORNERS[:, 1], ck[:, None] + _CORNERS[:, 2])
    odd = ((ci + cj + ck) % 2 == 1)[:, None, None]
    local = np.where(odd, _FIVE_TETS_ODD[None], _FIVE_TETS_EVEN[None])        # (cells, 5, 4)
    tets = np.take_along_axis(corner_nodes[:, None, :], local, axis=2).reshape(-1, 4)
    # Fix the winding of the (mirrored) tets so every rest volume is positive.
    negative = signed_volumes(points, tets) < 0
    tets[negative] = tets[negative][:, [0, 2, 1, 3]]
    return points, tets.astype(np.int64)
