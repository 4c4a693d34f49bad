"""Options shared by several commands."""

import click

scene_argument = click.argument("scene", type=click.Path(dir_okay=False, path_type=str))

set_option = click.option(
    "--set", "overrides", multiple=True, metavar="KEY=VALUE",
    help="Override a scene value, e.g. --set material.youngs_modulus=2e8 (repeatable).",
)
