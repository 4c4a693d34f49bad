"""``softsim mesh``: mesh a scene's solid and write it (any format meshio writes, e.g. .vtu)."""

import logging

import click

from softsim.config import load_scene
from softsim.mesh import build_mesh, format_quality
from softsim.mesh.write import check_mesh_output, write_mesh

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
    scene_config = load_scene(scene, overrides)
    check_mesh_output(output, overwrite, (scene, scene_config.mesh.file))   # before meshing: a bad path costs no work
    tet_mesh = build_mesh(scene_config.mesh)
    log.info("mesh: %s", format_quality(tet_mesh.quality()))
    write_mesh(tet_mesh, output)
    click.echo(f"{output}: {tet_mesh.tet_count} tets, {tet_mesh.node_count} vertices")
