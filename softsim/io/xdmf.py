"""XDMF sidecar that lets ParaView open a softsim HDF5 run as an animation.

The XDMF holds no numbers, only pointers into the HDF5 file (layout fixed by the HDF5 writer):

    mesh/tets        (m, 4)    int64    tetrahedra, 0-based vertex indices
    frames/time      (k,)      float64  simulation time of each frame [s]
    frames/points    (k, n, 3) float64  deformed vertex positions per frame [m]
    frames/<field>   (k, n, ...) or (k, m, ...) float64  optional per-frame point / cell data

It is a Temporal Collection with one Uniform grid per frame; each grid's geometry and attributes
are HyperSlabs picking frame ``i`` out of the ``frames/*`` datasets, so the points move.  This is
the structure ``vtkXdmfReader`` (what ParaView uses for ``.xdmf``) reads.
"""

from __future__ import annotations

import os
from xml.sax.saxutils import escape

_QUOTE = {'"': "&quot;"}
_ATTRIBUTE_TYPES = {(): "Scalar", (3,): "Vector", (3, 3): "Tensor"}


def write_xdmf(
    xdmf_path,
    h5_path,
    node_count: int,
    tet_count: int,
    times,
    point_fields=(),
    cell_fields=(),
    rows=None,
) -> None:
    """Write (atomically replace) ``xdmf_path`` describing the first ``len(times)`` frames.

    Args:
        xdmf_path: the ``.xdmf`` file to write.
        h5_path: the run's HDF5 file; referenced relative to the XDMF's directory.
        node_count: n, number of mesh vertices.
        tet_count: m, number of tetrahedra.
        times: frame times [s], length k; frame ``i`` is labelled ``times[i]``.  Only these k
            frames are described, even if the HDF5 datasets already hold more rows.
        point_fields: ``(attribute_name, dataset_path)`` pairs for per-vertex vectors stored as
            (k, n, 3) float64, e.g. ``("velocity", "frames/velocities")``, or
            ``(attribute_name, dataset_path, component_shape)`` triples as for ``cell_fields``.
        cell_fields: ``(attribute_name, dataset_path, component_shape)`` triples for per-tet
            data stored as (k, m, *component_shape) float64; component_shape is ``()`` (Scalar),
            ``(3,)`` (Vector) or ``(3, 3)`` (Tensor).
        rows: the number of rows the ``frames/*`` datasets hold (default k); a running file's
            datasets hold a row for every planned frame.

    The new file appears via ``os.replace``, so a reader never sees a half-written XDMF.
    """
    xdmf_dir = os.path.dirname(os.path.abspath(xdmf_path))
    h5_ref = os.path.relpath(os.path.abspath(h5_path), xdmf_dir).replace(os.sep, "/")
    times = [float(t) for t in times]
    k, n, m = len(times), int(node_count), int(tet_count)
    rows = k if rows is None else int(rows)

    def slab(indent, dataset, shape, start, count, number_type="Float"):
        """HyperSlab DataItem: rows start..start+count-1 of an HDF5 dataset of shape `shape`."""
        rank, dims = len(shape), " ".join(str(d) for d in shape)
        corner, stride = " ".join([str(start)] + ["0"] * (rank - 1)), " ".join(["1"] * rank)
        counts = " ".join([str(count)] + [str(d) for d in shape[1:]])
        return (
            f'{indent}<DataItem ItemType="HyperSlab" Dimensions="{counts}" Type="HyperSlab">\n'
            f'{indent}  <DataItem Dimensions="3 {rank}" Format="XML">'
            f"{corner} {stride} {counts}</DataItem>\n"
            f'{indent}  <DataItem Dimensions="{dims}" NumberType="{number_type}" Precision="8" '
            f'Format="HDF">{escape(h5_ref)}:/{escape(dataset)}</DataItem>\n'
            f"{indent}</DataItem>\n"
        )

    def frame_slab(indent, dataset, per_frame_shape, i):
        """Frame i of a (rows, *per_frame_shape) float64 dataset."""
        return slab(indent, dataset, (rows, *per_frame_shape), i, 1)

    def attribute(name, center, kind, dataset, per_frame_shape, i):
        name = escape(name, _QUOTE)
        return (
            f'      <Attribute Name="{name}" Center="{center}" AttributeType="{kind}">\n'
            + frame_slab("        ", dataset, per_frame_shape, i)
            + "      </Attribute>\n"
        )

    parts = [
        '<?xml version="1.0" ?>\n',
        '<Xdmf Version="3.0">\n',
        "<Domain>\n",
        '  <Grid Name="frames" GridType="Collection" CollectionType="Temporal">\n',
    ]
    for i, t in enumerate(times):
        parts += [
            f'    <Grid Name="frame_{i}" GridType="Uniform">\n',
            f'      <Time Value="{t!r}"/>\n',
            f'      <Topology TopologyType="Tetrahedron" NumberOfElements="{m}">\n',
            # The whole of mesh/tets, but as a HyperSlab: that switches off vtkXdmfReader's grid
            # cache, which is keyed on file paths only (stale after a rerun into the same file)
            # and, for a HyperSlab geometry, logs an error on every frame.
            slab("        ", "mesh/tets", (m, 4), 0, m, number_type="Int"),
            "      </Topology>\n",
            '      <Geometry GeometryType="XYZ">\n',
            frame_slab("        ", "frames/points", (n, 3), i),
            "      </Geometry>\n",
        ]
        for name, dataset, *shape in point_fields:
            shape = tuple(shape[0]) if shape else (3,)
            if shape not in _ATTRIBUTE_TYPES:
                raise ValueError(f"point field {name!r}: unsupported component shape {shape}")
            parts.append(attribute(name, "Node", _ATTRIBUTE_TYPES[shape], dataset, (n, *shape), i))
        for name, dataset, shape in cell_fields:
            shape = tuple(shape)
            if shape not in _ATTRIBUTE_TYPES:
                raise ValueError(f"cell field {name!r}: unsupported component shape {shape}")
            parts.append(attribute(name, "Cell", _ATTRIBUTE_TYPES[shape], dataset, (m, *shape), i))
        parts.append("    </Grid>\n")
    parts += ["  </Grid>\n", "</Domain>\n", "</Xdmf>\n"]

    tmp_path = f"{xdmf_path}.{os.getpid()}.tmp"
    try:
        with open(tmp_path, "w", encoding="utf-8") as f:
            f.write("".join(parts))
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp_path, xdmf_path)
    except BaseException:
        if os.path.exists(tmp_path):
            os.remove(tmp_path)
        raise
