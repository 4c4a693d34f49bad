"""The simulation model: everything about a scene that does not change during a run.

``build_model`` turns a validated scene and its checked mesh into flat arrays in the internal
(locality-renumbered) vertex order; ``initial_state`` makes the state at t = 0.  The time loop
reads a ``Model`` and updates a ``State``.
"""

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .errors import ConfigError
from .kernels.blocked import build_block_layout, faces_by_part
from .kernels.jit import CompileTimeConstant
from .kernels.rest_state import lumped_masses, rest_state, vertex_tet_csr
from .materials.models import MODEL_IDS, model_lame_parameters
from .mesh import TetMesh
from .mesh.checks import boundary_faces, faces_of_slots, renumbered_face_slots
from .mesh.reorder import renumber_for_locality

AXIS_INDEX = {"x": 0, "y": 1, "z": 2}
# Rest positions within this distance [m] of a box's faces count as inside it.
BOX_TOLERANCE = 1e-12


@dataclass(frozen=True)
class Model:
    """Rest state, material, constraints and loads, in internal vertex order (arrays: float64 unless said).

    mesh: the checked mesh in the user's order (written to the output).
    vertex_order: (n,) int64, internal vertex i is the user's vertex ``vertex_order[i]``.
    tet_order: (m,) int64, internal tet e is the user's tet ``tet_order[e]``.
    rest_points: (n, 3) [m]; tets: (m, 4) int64; Dm_inv: (m, 3, 3) [1/m]; rest_volume: (m,) [m^3].
    mass, inv_mass: (n,) [kg], [1/kg] lumped; a vertex no tet uses has mass 0, inv_mass 0 and is held.
    material_id: model id, a ``kernels.jit.CompileTimeConstant`` (the kernels it reaches compile that
    model's law alone); lam, mu: the model's Lame parameters [Pa]; lame_hooke: (lambda, mu) of Hooke's law [Pa].
    csr_offsets (n+1,), csr_slots (4m,): vertex -> (tet, corner) map.
    boundary_faces: (b, 3) outward-wound faces; boundary_area: (n,) [m^2] a third of each adjacent face.
    gravity: (3,) [m/s^2]; traction_force: (n, 3) [N] constant; external_accel: (n, 3) = gravity + traction / m
    (the step reads it only where there are tractions, ``has_tractions``; else gravity alone).
    held: (n, 3) bool; held_velocity: (n, 3) [m/s]; fixed: (n,) bool, held by the scene's ``fixed`` boxes.
    ground_stiffness [Pa/m] (None without a ground), ground_height [m], ground_friction.
    """

    mesh: TetMesh
    vertex_order: np.ndarray
    tet_order: np.ndarray
    rest_points: np.ndarray
    tets: np.ndarray
    Dm_inv: np.ndarray
    rest_volume: np.ndarray
    mass: np.ndarray
    inv_mass: np.ndarray
    material_id: int
    lam: float
    mu: float
    csr_offsets: np.ndarray
    csr_slots: np.ndarray
    boundary_faces: np.ndarray
    boundary_area: np.ndarray
    gravity: np.ndarray
    traction_force: np.ndarray
    external_accel: np.ndarray
    held: np.ndarray
    held_velocity: np.ndarray
    fixed: np.ndarray
    ground_stiffness: float | None
    ground_height: float
    ground_friction: float
    blocks: object = None     # kernels.blocked.BlockLayout: the tets in blocks for the vectorised step
    part_face_offsets: np.ndarray = None   # boundary faces by part of the block layout (kernels.blocked.faces_by_part)
    part_faces: np.ndarray = None
    precision: str = "float64"    # of the step (its blocks; the state stays float64); the model's arrays are float64

    def __post_init__(self):
        # also for a model made by ``dataclasses.replace`` with a plain int
        object.__setattr__(self, "material_id", CompileTimeConstant(self.material_id))

    @cached_property
    def has_tractions(self):
        """Whether any vertex carries a traction force; without, the step reads ``gravity`` alone,
        not ``external_accel``."""
        return bool(np.any(self.traction_force))

    @property
    def has_ground(self):
        return self.ground_stiffness is not None

    @property
    def contact_stiffness_bound(self):
        """Upper bound of each vertex's contact spring [N/m], (n,): stiffness x whole boundary area."""
        return (self.ground_stiffness or 0.0) * self.boundary_area

    def ground_arguments(self):
        """``(ground, ground_faces)`` of ``integrators.symplectic_euler.advance``: ``(None, None)``
        without a ground (with a new zeroed array for the vertices' downward face areas)."""
        if not self.has_ground:
            return None, None
        return ((self.ground_height, self.ground_stiffness, self.ground_friction, np.zeros(self.node_count)),
                (self.part_face_offsets, self.part_faces))

    @property
    def node_count(self):
        return self.rest_points.shape[0]

    @property
    def tet_count(self):
        return self.tets.shape[0]

    def to_user_order(self, a):
        """``a`` (n, ...) in internal order, re-indexed to the user's vertex order."""
        out = np.empty_like(a)
        out[self.vertex_order] = a
        return out

    def from_user_order(self, a):
        """``a`` (n, ...) in the user's vertex order, re-indexed to internal order."""
        return np.ascontiguousarray(a[self.vertex_order])


@dataclass
class State:
    """Positions x (n, 3) [m] and velocities v (n, 3) [m/s] in internal order, after ``step`` steps."""

    x: np.ndarray
    v: np.ndarray
    step: int
    held_start: np.ndarray   # (n, 3) [m] positions of held components at t = 0


def in_box(points, lo, hi):
    """Bool mask (n,) of ``points`` (n, 3) inside the closed box [lo, hi] (with BOX_TOLERANCE)."""
    lo = np.asarray(lo) - BOX_TOLERANCE
    hi = np.asarray(hi) + BOX_TOLERANCE
    return np.all((points >= lo) & (points <= hi), axis=1)


def face_areas(points, faces):
    """Areas [m^2] of triangles ``faces`` (b, 3) of ``points``."""
    p = points[faces]
    return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)


def _extent_text(points):
    """The bounding box of ``points`` (n, 3) [m] as text: ``x 0..1, y 0..0.25, z 0..0.25 m``."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    return ", ".join(f"{axis} {a:.4g}..{b:.4g}" for axis, a, b in zip("xyz", lo, hi)) + " m"


def build_model(scene, mesh):
    """The ``Model`` of a validated scene (``softsim.config.Scene``) on its checked ``mesh``."""
    points, tets, vertex_order, tet_order = renumber_for_locality(mesh.points, mesh.tets)
    n = points.shape[0]
    material = scene.material
    Dm_inv, rest_volume = rest_state(points, tets)
    mass = lumped_masses(tets, rest_volume, material.density, n)
    lam, mu = model_lame_parameters(material.model, material.youngs_modulus, material.poissons_ratio)
    offsets, slots = vertex_tet_csr(tets, n)

    if mesh.boundary_slots is not None:      # found when the mesh was checked
        faces, face_tets = faces_of_slots(tets, renumbered_face_slots(mesh.boundary_slots, tet_order), with_tets=True)
    else:
        faces, face_tets = boundary_faces(tets, mesh.source, with_tets=True)
    areas = face_areas(points, faces)
    boundary_area = np.zeros(n)
    np.add.at(boundary_area, faces.ravel(), np.repeat(areas / 3.0, 3))

    traction_force = np.zeros((n, 3))
    for index, load in enumerate(scene.tractions):
        on_face = in_box(points, load.min, load.max)[faces].all(axis=1)
        if not on_face.any():
            raise ConfigError(f"tractions[{index}]: the box min = {list(load.min)}, max = {list(load.max)} holds no "
                              f"boundary face (all three corners inside) of the mesh, which spans "
                              f"{_extent_text(points)}; a traction box must hold at least one")
        np.add.at(traction_force, faces[on_face].ravel(),
                  np.repeat(areas[on_face] / 3.0, 3)[:, None] * np.asarray(load.traction))
    gravity = np.asarray(scene.gravity, dtype=np.float64)

    held = np.zeros((n, 3), dtype=np.bool_)
    held_velocity = np.zeros((n, 3))
    for index, box in enumerate(scene.fixed):
        inside = in_box(points, box.min, box.max)
        if not inside.any():
            raise ConfigError(f"fixed[{index}]: the box min = {list(box.min)}, max = {list(box.max)} holds no vertex of "
                              f"the mesh, which spans {_extent_text(points)}; a fixed box must hold at least one")
        for axis in box.axes:
            k = AXIS_INDEX[axis]
            held[inside, k] = True
            held_velocity[inside, k] = box.velocity[k]

    fixed = held.any(axis=1)
    unreferenced = mass == 0.0
    held[unreferenced] = True          # massless: no force acts on them, they stay where they start
    held_velocity[unreferenced] = 0.0
    inv_mass = np.where(unreferenced, 0.0, 1.0 / np.where(unreferenced, 1.0, mass))
    external_accel = gravity[None, :] + traction_force * inv_mass[:, None]

    ground = scene.ground
    blocks = build_block_layout(tets, Dm_inv, rest_volume, n, dtype=np.dtype(scene.precision),
                                model=MODEL_IDS[material.model])
    part_face_offsets, part_faces = faces_by_part(faces, face_tets, blocks.part_offsets)
    return Model(
        mesh=mesh, vertex_order=vertex_order, tet_order=tet_order, rest_points=points, tets=tets, Dm_inv=Dm_inv,
        rest_volume=rest_volume, mass=mass, inv_mass=inv_mass, material_id=MODEL_IDS[material.model],
        lam=float(lam), mu=float(mu), csr_offsets=offsets, csr_slots=slots, boundary_faces=faces,
        boundary_area=boundary_area, gravity=gravity, traction_force=traction_force,
        external_accel=np.ascontiguousarray(external_accel), held=held, held_velocity=held_velocity, fixed=fixed,
        ground_stiffness=float(ground.stiffness) if ground is not None else None,
        ground_height=float(ground.height) if ground is not None else 0.0,
        ground_friction=float(ground.friction) if ground is not None else 0.0,
        blocks=blocks, part_face_offsets=part_face_offsets, part_faces=part_faces,
        precision=scene.precision,
    )


def initial_state(scene, model):
    """State at t = 0: ``x = A X + b``; ``v = v0 + omega x (x - c)`` with c the centre of mass.

    Held components start at ``A X + b`` too and move with their prescribed velocity.
    """
    A = np.asarray(scene.initial_deformation.matrix, dtype=np.float64)
    b = np.asarray(scene.initial_deformation.translation, dtype=np.float64)
    x = model.rest_points @ A.T + b
    centroid = (model.mass[:, None] * x).sum(axis=0) / model.mass.sum()
    omega = np.asarray(scene.angular_velocity, dtype=np.float64)
    v = np.asarray(scene.initial_velocity, dtype=np.float64) + np.cross(omega, x - centroid)
    v = np.where(model.held, model.held_velocity, v)
    return State(x=np.ascontiguousarray(x), v=np.ascontiguousarray(v), step=0, held_start=x.copy())
