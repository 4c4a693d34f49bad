"""Writing a tetrahedral mesh to any file format meshio writes, never over a file by surprise."""

from pathlib import Path

from ..errors import MeshError
from ..io.files import describe_input, input_clash, with_data_file
from ..io.hdf5 import being_written, holds_run


# meshio formats that hold surface cells only: a tetrahedral mesh written to one is an empty file.
SURFACE_ONLY_FORMATS = {"obj", "off", "ply", "stl", "svg", "wkt"}


def check_mesh_output(output, overwrite=False, inputs=()):
    """Raise ``MeshError`` unless ``write_mesh`` may write ``output`` (checked before meshing):
    its folder exists; neither it nor, for XDMF, the ``.h5`` data file meshio writes beside it is
    one of ``inputs`` (the scene's own files) or a file a run is writing now; the ``.h5`` holds no
    run's results (``--overwrite`` or not: it names the ``.xdmf``, and meshio replaced a finished
    run's file unsaid); its extension names a format meshio knows that holds tetrahedra; and unless ``overwrite``
    neither exists."""
    folder = Path(output).resolve().parent
    if not folder.is_dir():
        raise MeshError(f"--output = '{output}': folder {folder} does not exist")
    clash = input_clash(with_data_file(output), inputs)
    if clash is not None:
        written, input_file, name = clash
        which = "is" if Path(written) == Path(output) else f"its data file '{written}' is"
        raise MeshError(f"--output = '{output}': {which} the scene's own file {describe_input(input_file, name)}, "
                        f"which meshing reads; choose another output name")
    formats = _meshio_formats(output)
    if not formats:
        raise MeshError(f"--output = '{output}': meshio writes no format by the extension "
                        f"'{''.join(Path(output).suffixes) or '(none)'}'; use one like .vtu, .msh, .xdmf or .vtk")
    if set(formats) <= SURFACE_ONLY_FORMATS:
        raise MeshError(f"--output = '{output}': {formats[0]} holds surfaces only, not tetrahedra (meshio would "
                        f"write an empty file); use a volume mesh format like .vtu, .msh, .xdmf or .vtk")
    for file in with_data_file(output):
        if being_written(file):
            raise MeshError(f"--output = '{output}': another run is writing '{file}' now; choose another output name")
        if file != Path(output) and holds_run(file):
            raise MeshError(f"--output = '{output}': meshio writes an XDMF file's data to '{file}', which holds a "
                            f"softsim run's results; choose another output name")
    if not overwrite:
        for file in with_data_file(output):
            if file.exists():
                what = "the file exists" if file == Path(output) else (
                    f"meshio writes an XDMF file's data to '{file}', which exists")
                raise MeshError(f"--output = '{output}': {what}; pass --overwrite to replace it")


def _meshio_formats(path):
    """The meshio formats of ``path``'s extension (its last suffixes, e.g. ``.vtu``, ``.vol.gz``);
    empty where meshio knows none."""
    import meshio

    suffixes = [suffix.lower() for suffix in Path(path).suffixes]
    for k in range(len(suffixes)):
        formats = meshio.extension_to_filetypes.get("".join(suffixes[k:]))
        if formats:
            return list(formats)
    return []


def write_mesh(tet_mesh, output):
    """Write ``tet_mesh`` (a ``TetMesh``) to ``output``, its format by the extension (meshio)."""
    import meshio

    try:
        meshio.write(output, meshio.Mesh(tet_mesh.points, [("tetra", tet_mesh.tets)]))
    except Exception as exc:  # meshio raises several types for unknown formats and bad paths
        raise MeshError(f"--output = '{output}': cannot write the mesh ({exc})") from None
