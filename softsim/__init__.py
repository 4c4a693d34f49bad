"""softsim: explicit tetrahedral FEM for elastic solids, driven by YAML scene files.

The folders follow the pipeline: ``config`` (scene schema) -> ``mesh`` (gmsh / meshio, checks,
renumbering) -> ``materials`` + ``kernels`` (Numba, per tetrahedron) -> ``integrators``
(symplectic Euler) -> ``io`` (HDF5 + XDMF).  ``simulation`` wires them together.
"""

__version__ = "0.1.0"
