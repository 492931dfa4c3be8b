"""``svbrdf view``: an interactive viewer beside a texture set."""

import sys

import click


@click.command("view")
@click.argument("mapset", type=click.Path(exists=True, file_okay=False))
@click.option("--size", type=click.IntRange(128, 4096), default=2048, show_default=True,
              help="Largest canvas resolution in pixels (the canvas fills the window, up to this).")
@click.option("--open/--no-open", "open_", default=None,
              help="Open it in a browser (default: when run from a terminal).")
def view_cmd(mapset, size, open_):
    """Write MAPSET/viewer.html: the material under a light that follows the mouse.

    A self-contained page (the maps embedded, nothing fetched) rendering the
    set (native, or written by svbrdf with any preset) with the same
    Cook-Torrance model as the tool, with toggles
    for each map, 1-3x tiling and the light's intensity and height.

    \b
    Example:
      svbrdf view textures/wood
    """
    import webbrowser

    from svbrdf_cli.write.viewer import write_viewer

    path = write_viewer(mapset, size)
    click.echo(f"wrote {path}", err=True)
    if open_ if open_ is not None else sys.stdout.isatty():
        try:
            webbrowser.get().open("file://" + path)
        except webbrowser.Error:
            click.echo("no browser found: open the file by hand", err=True)
