"""``docs/figures/tiling.png``: a 2 x 2 tiling of ``svbrdf capture --tileable`` maps of a leather, a
wood and the bundled glazed tiles (diffuse, normal, specular), and the seam measure of each map.

    python -m export.studies.tiling_figure -o docs/figures/tiling.png

The leather and the wood are real phone photos of the shared data (henzler_train 0256/IMG_0895 and
2032/IMG_9438), the tiles the bundled sample. For every map it prints the largest line-to-line step
of the 2 x 2 tiling (rows and columns, :func:`svbrdf_cli.write.tiling.line_steps`) over the largest
step inside the map made without ``--tileable``: at most about 1 where the tiling adds no seam.
"""

from __future__ import annotations

import os
import tempfile

import click
import numpy as np

from export import files

PHOTOS = (("leather", "henzler_train/0256/IMG_0895.JPG"), ("wood", "henzler_train/2032/IMG_9438.JPG"),
          ("glazed tiles", None))
MAPS = ("diffuse", "normal", "specular")


def _interior_step(x):
    x = np.asarray(x, np.float64)
    x = x[..., None] if x.ndim == 2 else x
    return max(float(np.abs(np.diff(x, axis=a).mean(axis=1 - a)).mean(-1).max()) for a in (0, 1))


def make(out, cell=360):
    """Capture each photo with and without ``--tileable``, write the figure to ``out``; returns
    {(material, map): seam measure}."""
    from click.testing import CliRunner
    from PIL import Image, ImageDraw

    from svbrdf_cli.cli.main import cli
    from svbrdf_cli.imageio import read_image
    from svbrdf_cli.write.tiling import line_steps

    sample = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))),
                          "examples", "glazed_tiles.jpg")
    real = os.path.join(files.shared_data(), "real")
    rows, measures = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        for label, rel in PHOTOS:
            photo = sample if rel is None else os.path.join(real, rel)
            stem = os.path.splitext(os.path.basename(photo))[0]
            for flag in ("", "--tileable"):
                args = ["capture", photo, "-o", os.path.join(tmp, flag or "plain"), "-q", "--no-preview"]
                r = CliRunner().invoke(cli, args + ([flag] if flag else []), catch_exceptions=False)
                if r.exit_code:
                    raise click.ClickException(r.output)
            cells = []
            for m in MAPS:
                plain = read_image(os.path.join(tmp, "plain", stem, f"{m}.png"))
                tiled = read_image(os.path.join(tmp, "--tileable", stem, f"{m}.png"))
                step = max(float(line_steps(tiled, a).max()) for a in (0, 1))
                measures[(label, m)] = step / max(_interior_step(plain), 1.5 / 255)
                t = np.tile(np.atleast_3d(tiled), (2, 2, 1))
                t = np.repeat(t, 3, -1) if t.shape[-1] == 1 else t
                img = Image.fromarray((np.clip(t, 0, 1) * 255 + 0.5).astype(np.uint8)).resize((cell, cell), Image.LANCZOS)
                ImageDraw.Draw(img).text((6, 4), f"{label}: {m}, 2 x 2", fill=(255, 255, 255))
                cells.append(np.asarray(img))
            rows.append(np.concatenate([np.pad(c, ((3, 3), (3, 3), (0, 0)), constant_values=255) for c in cells], 1))
    Image.fromarray(np.concatenate(rows, 0)).save(out, optimize=True)
    return measures


@click.command()
@click.option("-o", "--out", default="docs/figures/tiling.png", show_default=True)
def main(out):
    """Write the tiling figure and print each map's seam measure."""
    for (label, m), v in make(out).items():
        click.echo(f"{label:13s} {m:9s} largest step of the 2 x 2 tiling / largest inside the plain map: {v:.2f}")


if __name__ == "__main__":
    main()
