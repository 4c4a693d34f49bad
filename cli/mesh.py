"""``softsim mesh``: mesh a scene's solid and write it (any format meshio writes, e.g. .vtu)."""

import logging
from pathlib import Path

import click

from softsim.config import load_scene
from softsim.errors import SoftsimError
from softsim.mesh import build_mesh, format_quality

from .options import scene_argument, set_option

log = logging.getLogger("softsim")


@click.command()
@scene_argument
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False, path_type=str),
              help="Mesh file to write; the format follows the extension (.vtu, .msh, .xdmf, ...).")
@click.option("--overwrite", is_flag=True, help="Replace an existing mesh file.")
@set_option
def mesh(scene, output, overwrite, overrides):
    """Mesh the solid of SCENE and write it to OUTPUT without simulating.

    \b
    Examples:
      softsim mesh configs/cantilever.yaml -o beam.vtu
      softsim mesh configs/cantilever.yaml -o fine.vtu --set mesh.element_size=0.01
    """
    import meshio

    scene_config = load_scene(scene, overrides)
    folder = Path(output).resolve().parent
    if not folder.is_dir():   # before meshing: a bad path costs no work
        raise SoftsimError(f"--output = '{output}': folder {folder} does not exist")
    for name in (scene, scene_config.mesh.file):
        if name and Path(name).resolve() == Path(output).resolve():
            raise SoftsimError(f"--output = '{output}': is the scene's own file '{name}', which meshing reads; "
                               f"choose another output name")
    if Path(output).exists() and not overwrite:
        raise SoftsimError(f"--output = '{output}': the file exists; pass --overwrite to replace it")
    tet_mesh = build_mesh(scene_config.mesh)
    log.info("mesh: %s", format_quality(tet_mesh.quality()))
    try:
        meshio.write(output, meshio.Mesh(tet_mesh.points, [("tetra", tet_mesh.tets)]))
    except Exception as exc:  # meshio raises several types for unknown formats and bad paths
        raise SoftsimError(f"--output = '{output}': cannot write the mesh ({exc})") from None
    click.echo(f"{output}: {tet_mesh.tet_count} tets, {tet_mesh.node_count} vertices")
