"""``svbrdf render``: relight a map set under a point light."""

import click

from svbrdf_cli.cli.options import force_opt, light_opt, refuse_existing
from svbrdf_cli.cli.values import positive, stops


@click.command("render")
@click.argument("maps", type=click.Path(file_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Image to write (.png, .tif, .exr).")
@light_opt
@click.option("--intensity", type=float, callback=positive, default=None,
              help="Light intensity (default: the conventions' flash intensity).")
@click.option("--exposure", type=float, callback=stops, default=0.0, show_default=True,
              help="Exposure change in stops.")
@force_opt("an existing image")
def render_cmd(maps, output, light, intensity, exposure, force):
    """Relight a texture set: native (normal/diffuse/roughness/specular.png) or
    written by svbrdf with any preset (read through its texture_set.json).

    Renders the maps as a flat surface under a point light with the same
    Cook-Torrance model the networks were trained with, and writes the
    gamma-encoded image. With no --light the light sits at the camera, like a
    phone flash.

    \b
    Examples:
      svbrdf render out/wood -o wood_flash.png
      svbrdf render out/wood -o wood_side.png --light 1.5,0,1 --exposure 1
    """
    from svbrdf_cli import conventions as cv
    from svbrdf_cli.imageio import write_image
    from svbrdf_cli.write.readback import read_any_set
    from svbrdf_cli.shading import render_maps

    refuse_existing(output, force)
    m = read_any_set(maps)
    kwargs = {"light": light or cv.FLASH_POSITION}
    kwargs["intensity"] = (intensity if intensity is not None else cv.LIGHT_INTENSITY) * 2.0 ** exposure
    img = cv.image_to_encoded(render_maps(m, **kwargs))
    write_image(output, img)
    click.echo(f"wrote {output} ({img.shape[1]}x{img.shape[0]})", err=True)
