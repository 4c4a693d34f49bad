"""The stress catalogue of ``softsim stability``: stiff and extreme scenes, generated in code.

Each entry is a scene mapping (the same keys as a scene file) with ``material.model`` left to the
caller, so that every scene runs once per material model.  Nothing here reads a file shipped with
the package, so the catalogue works from a wheel; the one scene with a hand-made mesh (slivers)
writes its mesh file into a folder the caller names.

Scenes (``quick`` shortens durations, never the physics):

- ``steel-cantilever``: a 1 m steel beam (E = 200 GPa, rho = 7850 kg/m^3, nu = 0.3) clamped at
  x = 0, sagging under gravity from rest, undamped (its first bending period is about 12 ms).
- ``rubber-nu0.49``, ``rubber-nu0.499``: a 20 cm rubber beam (E = 1 MPa) clamped at one end,
  sagging under gravity, undamped: near-incompressible, so the dilatational wave (and the stable
  step) is 3.6x (11x) faster (shorter) than at nu = 0.3.
- ``crushed-cube``: a 10 cm soft cube whose top face a held box pushes down to a tenth of its
  height (damped).
- ``inverted-squashed``: the cube starts mirrored and squashed, ``x = diag(1, -0.3, 1) X``.
- ``inverted-mirror``: the cube starts exactly inside out, ``x = diag(1, 1, -1) X``.
- ``fast-impact``: a rubber cube hitting a stiff ground (1e10 Pa/m) at 20 m/s, about a third of
  its dilatational wave speed (59 m/s).
- ``sliver-mesh``: a clamped rubber beam on a structured mesh whose interior vertices are moved at
  random by up to 0.45 of a cell (dihedral angles from 0.7 to 179 degrees).
- ``large-dt-substep`` / ``-refuse`` / ``-allow``: a clamped cube under gravity with a given
  ``time.dt`` of 3x the true stability limit at rest, under each ``dt_policy``.
"""

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

MODELS = ("linear", "stvk", "corotated", "neohookean")
# The names of ``catalogue``'s scenes, in its order: known before it writes a mesh or runs anything
# (``--scene`` is checked against them first).
SCENE_NAMES = ("steel-cantilever", "rubber-nu0.49", "rubber-nu0.499", "crushed-cube", "inverted-squashed",
               "inverted-mirror", "fast-impact", "sliver-mesh", "large-dt-substep", "large-dt-refuse",
               "large-dt-allow")

STEEL = {"youngs_modulus": 2.0e11, "poissons_ratio": 0.3, "density": 7850.0}
SOFT = {"youngs_modulus": 1.0e5, "poissons_ratio": 0.3, "density": 1000.0}
RUBBER = {"youngs_modulus": 1.0e6, "density": 1100.0}
CUBE = {"shape": "box", "size": [0.1, 0.1, 0.1], "element_size": 0.025, "structured": True}
# the face x = 0 of a body starting at the origin
CLAMP_X0 = {"min": [-1.0, -1.0, -1.0], "max": [1e-9, 1.0, 1.0]}
NO_GRAVITY = [0.0, 0.0, 0.0]
# The given dt of the large-dt scenes, as a multiple of the true stability limit at rest.
LARGE_DT_FACTOR = 3.0
SLIVER_AMOUNT = 0.45
SLIVER_SEED = 11


@dataclass(frozen=True)
class CatalogueScene:
    """One stress scene.

    name: short identifier (file names, table rows); description: one line for people;
    data: the scene mapping without ``material.model``; drift_caveats: why the total energy
    (kinetic + elastic + gravity) is not expected to be conserved (damping, ground, held motion),
    empty when it should be.
    """

    name: str
    description: str
    data: dict
    drift_caveats: tuple = field(default=())

    def scene_data(self, model):
        """The full scene mapping for material model ``model``."""
        data = {key: (dict(value) if isinstance(value, dict) else value) for key, value in self.data.items()}
        data["material"] = {"model": model, **self.data["material"]}
        return data


def drift_caveats(data):
    """What makes the total energy of a scene mapping change besides time-stepping error."""
    caveats = []
    if data.get("damping", 0.0) > 0.0:
        caveats.append("damped")
    if data.get("ground") is not None:
        caveats.append("ground contact")
    if any(any(component != 0.0 for component in box.get("velocity", (0, 0, 0))) for box in data.get("fixed", ())):
        caveats.append("held motion does work")
    if data.get("tractions"):
        caveats.append("tractions do work")
    return tuple(caveats)


def _entry(name, description, data):
    return CatalogueScene(name=name, description=description, data=data, drift_caveats=drift_caveats(data))


def sliver_box(size, cells, amount=SLIVER_AMOUNT, seed=SLIVER_SEED):
    """``(points, tets)`` of a structured box whose interior vertices moved at random (slivers).

    size: box extents [m] (origin at 0); cells: cell edge length [m]; amount: the largest move of
    an interior vertex along each axis, as a fraction of the cell edge.  The boundary vertices stay
    on the box faces, so regions selected on the faces still work.  The perturbation shrinks
    (by 10 % per try) until no tet inverts; fixed seed, so the mesh is always the same.
    """
    from ..mesh.generate import structured_box

    points, tets = structured_box(tuple(size), (0.0, 0.0, 0.0), cells)
    rng = np.random.default_rng(seed)
    interior = np.all((points > 1e-9) & (points < np.asarray(size) - 1e-9), axis=1)
    for _ in range(50):
        moved = points.copy()
        moved[interior] += amount * cells * rng.uniform(-1.0, 1.0, (int(interior.sum()), 3))
        X = moved[tets]
        if (np.linalg.det(X[:, 1:] - X[:, :1]) > 0).all():
            return moved, tets
        amount *= 0.9
    raise RuntimeError("could not perturb the box without inverting a tet")


def write_mesh(path, points, tets):
    """Write a tet mesh with meshio (format from the suffix); returns ``path`` as a ``Path``."""
    import meshio

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    meshio.write(str(path), meshio.Mesh(np.asarray(points, np.float64), [("tetra", np.asarray(tets, np.int64))]))
    return path


def large_dt(data):
    """``LARGE_DT_FACTOR`` x symplectic Euler's true stability limit at rest of scene mapping ``data`` [s].

    At rest every model's tangent is Hooke's law, so the limit does not depend on the model.
    """
    from ..config import parse_scene
    from ..integrators.stability import exact_stable_step
    from ..simulation import prepare

    scene = parse_scene({**data, "material": {"model": "linear", **data["material"]}})
    return LARGE_DT_FACTOR * exact_stable_step(prepare(scene).model)


def catalogue(mesh_dir, quick=False):
    """The stress scenes, a list of ``CatalogueScene``; mesh files are written into ``mesh_dir``.

    quick: shorter simulated times (each run well under a second once compiled) instead of
    several oscillation periods (each run seconds).
    """
    mesh_dir = Path(mesh_dir)
    scenes = []

    beam_period = 0.0123          # first bending period of the steel beam [s] (Euler-Bernoulli)
    scenes.append(_entry(
        "steel-cantilever", "1 m steel beam clamped at x = 0, sagging under gravity (undamped)",
        {"mesh": {"shape": "box", "size": [1.0, 0.1, 0.1], "element_size": 0.05, "structured": True},
         "material": dict(STEEL), "fixed": [CLAMP_X0],
         "time": {"duration": (0.5 if quick else 2.0) * beam_period},
         "output": {"frame_interval": beam_period / 20, "fields": ["energy"]}}))

    for nu in (0.49, 0.499):
        scenes.append(_entry(
            f"rubber-nu{nu:g}", f"20 cm rubber beam (E = 1 MPa, nu = {nu:g}) clamped at one end, sagging (undamped)",
            {"mesh": {"shape": "box", "size": [0.2, 0.05, 0.05], "element_size": 0.025, "structured": True},
             "material": {**RUBBER, "poissons_ratio": nu}, "fixed": [CLAMP_X0],
             "time": {"duration": 0.05 if quick else 0.3},
             "output": {"frame_interval": 0.005, "fields": ["energy"]}}))

    crush_time = 0.5
    scenes.append(_entry(
        "crushed-cube", "10 cm cube pushed by a held box to a tenth of its height",
        {"mesh": dict(CUBE), "material": dict(SOFT), "gravity": NO_GRAVITY, "damping": 5.0,
         "fixed": [{"min": [-1, -1, -1e-6], "max": [1, 1, 1e-6]},
                   {"min": [-1, -1, 0.1 - 1e-6], "max": [1, 1, 1], "velocity": [0, 0, -0.09 / crush_time]}],
         "time": {"duration": crush_time}, "output": {"frame_interval": crush_time / 20, "fields": ["energy"]}}))

    for name, matrix, what in (("inverted-squashed", [[1, 0, 0], [0, -0.3, 0], [0, 0, 1]], "mirrored and squashed"),
                               ("inverted-mirror", [[1, 0, 0], [0, 1, 0], [0, 0, -1]], "exactly inside out")):
        scenes.append(_entry(
            name, f"10 cm cube starting {what} (damped, no gravity)",
            {"mesh": dict(CUBE), "material": dict(SOFT), "gravity": NO_GRAVITY, "damping": 20.0,
             "initial_deformation": {"matrix": matrix},
             "time": {"duration": 0.25 if quick else 0.5}, "output": {"frame_interval": 0.025, "fields": ["energy"]}}))

    scenes.append(_entry(
        "fast-impact", "10 cm rubber cube hitting a stiff ground (1e10 Pa/m) at 20 m/s",
        {"mesh": dict(CUBE), "material": {**RUBBER, "poissons_ratio": 0.45},
         "initial_deformation": {"translation": [0.0, 0.0, 0.01]}, "initial_velocity": [0.0, 0.0, -20.0],
         "ground": {"height": 0.0, "stiffness": 1.0e10},
         "time": {"duration": 0.008 if quick else 0.02}, "output": {"frame_interval": 0.0005, "fields": ["energy"]}}))

    size = (0.2, 0.05, 0.05)
    slivers = write_mesh(mesh_dir / "sliver-beam.vtu", *sliver_box(size, 0.025))
    scenes.append(_entry(
        "sliver-mesh", f"20 cm rubber beam on a mesh with slivers (interior vertices moved by up to "
                       f"{SLIVER_AMOUNT:g} of a cell), clamped, sagging (undamped)",
        {"mesh": {"shape": "file", "file": str(slivers.resolve())},
         "material": {**RUBBER, "poissons_ratio": 0.45}, "fixed": [CLAMP_X0],
         "time": {"duration": 0.05 if quick else 0.3}, "output": {"frame_interval": 0.005, "fields": ["energy"]}}))

    base = {"mesh": dict(CUBE), "material": dict(SOFT),
            "fixed": [{"min": [-1, -1, -1e-6], "max": [1, 1, 1e-6]}],
            "time": {"duration": 0.1 if quick else 0.5},
            "output": {"frame_interval": 0.01, "fields": ["energy"]}}
    dt = float(f"{large_dt(base):.3g}")
    for policy in ("substep", "refuse", "allow"):
        data = dict(base)
        data["time"] = {**base["time"], "dt": dt, "dt_policy": policy}
        scenes.append(_entry(
            f"large-dt-{policy}", f"cube clamped at its base under gravity, dt = {dt:g} s "
                                  f"({LARGE_DT_FACTOR:g}x the stability limit), dt_policy: {policy}", data))
    return scenes


__all__ = ["MODELS", "SCENE_NAMES", "CatalogueScene", "catalogue", "drift_caveats", "large_dt", "sliver_box", "write_mesh"]
