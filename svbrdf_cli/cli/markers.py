"""``svbrdf markers``: the printable sheet for ``--crop markers``."""

import click

from svbrdf_cli.cli.options import force_opt, refuse_existing
from svbrdf_cli.rectify.crops import SHEET_CELL_PX, SHEET_CELL_PX_RANGE, SHEET_CELLS


@click.command("markers")
@click.argument("output", type=click.Path(dir_okay=False))
@click.option("--cell", type=click.IntRange(*SHEET_CELL_PX_RANGE), default=SHEET_CELL_PX, show_default=True,
              help=f"Pixels per grid cell (the sheet is {SHEET_CELLS} cells wide).")
@force_opt("an existing file")
def markers_cmd(output, cell, force):
    """Write the marker sheet for --crop markers (print it, cut out the window).

    A ring of 16 AprilTag 36h11 tags around a square window. Lay the sheet on
    the material, photograph it whole with the flash on, and run
    'svbrdf capture photo.jpg --crop markers': the window is found and
    rectified to a square, however the phone was tilted.

    \b
    Example:
      svbrdf markers sheet.png && svbrdf capture shot.jpg -o out --crop markers
    """
    import numpy as np

    from svbrdf_cli.imageio import write_image
    from svbrdf_cli.rectify.crops import marker_sheet

    refuse_existing(output, force)
    sheet = marker_sheet(cell)
    write_image(output, sheet.astype(np.float32) / 255.0)
    click.echo(f"wrote {output} ({sheet.shape[1]}x{sheet.shape[0]}; print at any size, keep it flat)", err=True)
