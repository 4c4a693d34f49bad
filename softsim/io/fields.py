"""The optional per-frame output fields: where they live, their shape and unit (a public interface).

``output.fields`` names them; ``RunWriter`` stores each as ``frames/<dataset>`` with one row per
frame, the XDMF sidecar shows them in ParaView, and ``softsim info / export / render`` read them.
Vertex fields are in the user's vertex order, tet fields in the user's tet order (``mesh/tets``).
"""

from dataclasses import dataclass


@dataclass(frozen=True)
class FieldSpec:
    """One output field.

    name: the name in ``output.fields``; location: ``vertex``, ``tet`` or ``frame`` (one value per
    frame); shape: the shape per vertex / tet / frame; unit: SI unit (``-`` dimensionless);
    datasets: the HDF5 datasets under ``frames/``; xdmf_name: the attribute name in the XDMF.
    """

    name: str
    location: str
    shape: tuple
    unit: str
    description: str
    datasets: tuple
    xdmf_name: str = ""


FIELDS = {spec.name: spec for spec in (
    FieldSpec("velocities", "vertex", (3,), "m/s", "vertex velocity v", ("velocities",), "velocity"),
    FieldSpec("displacement", "vertex", (3,), "m", "x - X, from the rest position", ("displacement",),
              "displacement"),
    FieldSpec("speed", "vertex", (), "m/s", "|v|", ("speed",), "speed"),
    FieldSpec("strain", "tet", (3, 3), "-", "Green strain 1/2 (F^T F - I); small strain 1/2 (F + F^T) - I "
              "for linear", ("strain",), "strain"),
    FieldSpec("stress", "tet", (3, 3), "Pa", "Cauchy stress P F^T / J (linear: P)", ("stress",), "stress"),
    FieldSpec("pressure", "tet", (), "Pa", "-tr(stress)/3, positive in compression", ("pressure",), "pressure"),
    FieldSpec("deviatoric_stress", "tet", (3, 3), "Pa", "stress + pressure I (trace free)",
              ("deviatoric_stress",), "deviatoric_stress"),
    FieldSpec("von_mises", "tet", (), "Pa", "sqrt(3/2 s:s), s the deviatoric stress", ("von_mises",),
              "von_mises"),
    FieldSpec("J", "tet", (), "-", "det F, volume ratio", ("J",), "J"),
    FieldSpec("energy", "frame", (), "J", "kinetic, elastic and gravitational energy",
              ("energy/kinetic", "energy/elastic", "energy/gravity")),
)}

VERTEX_FIELDS = tuple(name for name, spec in FIELDS.items() if spec.location == "vertex")
TET_FIELDS = tuple(name for name, spec in FIELDS.items() if spec.location == "tet")
