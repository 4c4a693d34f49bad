"""``softsim export``: a run's frames as files any meshio / ParaView reader opens.

- ``vtu``: one ``.vtu`` per frame with the moved points and every stored field (tensors as 9
  components, row-major, which ParaView shows as a tensor), and a ``.pvd`` collection with the
  frame times, so ParaView plays them in order.
- ``xdmf``: one XDMF + HDF5 pair written by meshio's ``TimeSeriesWriter``: the rest mesh, fixed,
  and per frame the fields with ``displacement`` as point data (ParaView: Warp By Vector).
"""

import os
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from ..io.fields import FIELDS
from ..io.hdf5 import holds_run
from .results import ResultsError, open_results

FORMATS = ("vtu", "xdmf")


def frame_data(results, i):
    """``(point_data, cell_data)`` dicts of frame ``i``: every stored field, plus ``displacement``.

    Tensors are flattened to (count, 9), row-major; energies (one number per frame) are left out.
    """
    point_data, cell_data = {}, {}
    names = [name for name in results.fields if FIELDS[name].location != "frame"]
    if "displacement" not in names:
        names.append("displacement")
    for name in names:
        values = np.asarray(results.field(name, i), dtype=np.float64)
        if values.ndim == 3:
            values = values.reshape(values.shape[0], 9)
        if FIELDS[name].location == "tet":
            cell_data[name] = [values]
        else:
            point_data[name] = values
    return point_data, cell_data


def export(path, fmt, output=None, frames=None, overwrite=False):
    """Export the frames ``frames`` (see ``Results.select_frames``) of run file ``path`` as ``fmt``.

    output: for ``vtu`` a folder (default ``<stem>_vtu`` beside the run file) that gets
    ``<stem>_NNNN.vtu`` per frame and ``<stem>.pvd``, or, for a single frame, a ``.vtu`` file name;
    for ``xdmf`` the ``.xdmf`` file (default ``<stem>_export.xdmf``), its data in the ``.h5`` of the
    same name beside it.  Existing files are replaced only with ``overwrite``.  Returns the list of
    files written.
    """
    import meshio

    if fmt not in FORMATS:
        raise ResultsError(f"--format = '{fmt}': must be one of {', '.join(FORMATS)}")
    with open_results(path) as results:
        selected = results.select_frames(frames)
        stem = results.path.stem
        if fmt == "vtu":
            return _export_vtu(meshio, results, selected, output, stem, overwrite)
        return _export_xdmf(meshio, results, selected, output, stem, overwrite)


def _export_vtu(meshio, results, selected, output, stem, overwrite):
    single = output is not None and str(output).lower().endswith(".vtu")
    if output is not None and not single and Path(output).suffix and not Path(output).is_dir():
        raise ResultsError(f"-o '{output}': --format vtu writes a folder of .vtu files, or one .vtu file for "
                           f"one frame; name a folder without an extension, or a .vtu file")
    if single and len(selected) != 1:
        raise ResultsError(f"-o '{output}': a single .vtu file holds one frame, but {len(selected)} are "
                           f"selected; give a folder, or --frames N")
    if single:
        targets = [Path(output)]
        folder = targets[0].parent
    else:
        folder = Path(output) if output is not None else results.path.with_name(f"{stem}_vtu")
        targets = [folder / f"{stem}_{i:04d}.vtu" for i in selected]
    if folder.exists() and not folder.is_dir():
        raise ResultsError(f"-o '{folder}': exists and is not a folder")
    if not single:
        folder.mkdir(parents=True, exist_ok=True)
    elif not folder.is_dir():
        raise ResultsError(f"-o '{output}': folder {folder} does not exist")
    pvd = None if single else folder / f"{stem}.pvd"
    _refuse_existing([*targets, *([pvd] if pvd else [])], overwrite)
    cells = [("tetra", results.tets)]
    for target, i in zip(targets, selected):
        point_data, cell_data = frame_data(results, i)
        mesh = meshio.Mesh(results.frame_points(i), cells, point_data=point_data, cell_data=cell_data)
        meshio.write(target, mesh, file_format="vtu")
    if pvd is not None:
        entries = "".join(f'    <DataSet timestep="{float(results.times[i])!r}" file={quoteattr(t.name)}/>\n'
                          for t, i in zip(targets, selected))
        pvd.write_text('<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n  <Collection>\n'
                       f"{entries}  </Collection>\n</VTKFile>\n", encoding="utf-8")
        return [*targets, pvd]
    return targets


class _TimeSeriesWriter:
    """meshio's ``TimeSeriesWriter`` with its ``.h5`` beside the ``.xdmf`` (meshio 5.3 opens it in
    the working directory, while the XDMF refers to it by bare name, i.e. beside itself)."""

    def __new__(cls, meshio, xdmf_path):
        class Writer(meshio.xdmf.TimeSeriesWriter):
            def __enter__(self):
                import h5py

                self.h5_filename = str(Path(xdmf_path).with_suffix(".h5"))
                self.h5_file = h5py.File(self.h5_filename, "w")
                return self

        return Writer(xdmf_path)


def _export_xdmf(meshio, results, selected, output, stem, overwrite):
    target = Path(output) if output is not None else results.path.with_name(f"{stem}_export.xdmf")
    if target.suffix != ".xdmf":
        raise ResultsError(f"-o '{output}': --format xdmf writes an .xdmf file (and its .h5); use a name like "
                           f"{stem}_export.xdmf")
    if not target.parent.is_dir():
        raise ResultsError(f"-o '{output}': folder {target.parent} does not exist")
    data = target.with_suffix(".h5")
    if data.resolve() == results.path.resolve():
        raise ResultsError(f"-o '{target}': its data file {data} would replace the run file; choose another name")
    if holds_run(data):
        raise ResultsError(f"-o '{target}': its data file {data} holds another softsim run's results; choose another "
                           f"name")
    sidecar = results.path.with_suffix(".xdmf")
    if target.resolve() == sidecar.resolve():
        raise ResultsError(f"-o '{target}': is the run's own XDMF file; choose another name")
    _refuse_existing([target, data], overwrite)
    with _TimeSeriesWriter(meshio, target) as writer:
        writer.write_points_cells(results.points, [("tetra", results.tets)])
        for i in selected:
            point_data, cell_data = frame_data(results, i)
            writer.write_data(float(results.times[i]), point_data=point_data, cell_data=cell_data)
    return [target, data]


def _refuse_existing(paths, overwrite):
    if overwrite:
        return
    existing = [str(p) for p in paths if os.path.exists(p)]
    if existing:
        more = f" (and {len(existing) - 1} more)" if len(existing) > 1 else ""
        raise ResultsError(f"'{existing[0]}'{more}: exists; pass --overwrite to replace")
