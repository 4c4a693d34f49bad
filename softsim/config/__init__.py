"""Scene files: the strict schema (``schema``) and the YAML loader (``loader``).

Typical use::

    from softsim.config import load_scene
    scene = load_scene("beam.yaml", overrides=["material.youngs_modulus=2e8"])
    scene.material.youngs_modulus   # float [Pa]
    scene.time.dt                   # "auto" or float [s]

Every invalid input raises ``softsim.errors.ConfigError`` with a one-line message.
"""

from .loader import SceneLoader, apply_overrides, load_scene, parse_scene, scene_to_yaml
from .schema import (
    FixedRegion,
    Ground,
    InitialDeformation,
    Material,
    Mesh,
    Output,
    Scene,
    Section,
    Time,
    TractionRegion,
)

__all__ = [
    "FixedRegion",
    "Ground",
    "InitialDeformation",
    "Material",
    "Mesh",
    "Output",
    "Scene",
    "SceneLoader",
    "Section",
    "Time",
    "TractionRegion",
    "apply_overrides",
    "load_scene",
    "parse_scene",
    "scene_to_yaml",
]
