"""Reusable options and their validating callbacks."""

import click


def _vector3(ctx, param, value):
    if value is None:
        return None
    try:
        parts = [float(x) for x in value.split(",")]
    except ValueError:
        parts = []
    if len(parts) != 3:
        raise click.BadParameter(f"expected three comma-separated numbers X,Y,Z; got '{value}'.")
    return tuple(parts)


light_opt = click.option(
    "--light", callback=_vector3, default=None, metavar="X,Y,Z",
    help="Light position in surface units (the surface spans -1..1; default: the flash, 0,0,2.414).")

overwrite_opt = click.option("--overwrite", is_flag=True, help="Replace an existing output file.")
