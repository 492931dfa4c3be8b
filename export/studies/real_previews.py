"""``docs/figures/real_previews.png``: what each model makes of the 12 real benchmark photos.

    python -m export.studies.real_previews --model physical --model weights/swift -o docs/figures/real_previews.png

One row per photo (:func:`export.files.real_photos`: none of them is trained on): the photo as
``svbrdf capture`` crops it, then for each ``--model`` its normal, diffuse and roughness maps at 256
px (default options otherwise). It prints per photo and model the normals' relief strength (the
standard deviation of the tilt, 0 for a flat map) and the roughness's mean and spread, so relief
invented on a flat material and a roughness that cannot tell gloss from matte show as numbers too.
"""

from __future__ import annotations

import os
import tempfile

import click
import numpy as np

from export import files

MAPS = ("normal", "diffuse", "roughness")


def capture(photo, model, out, size=256):
    """The set ``svbrdf capture`` writes for ``photo`` with ``model`` into ``out``; its folder."""
    from click.testing import CliRunner

    from svbrdf_cli.cli.main import cli

    args = ["capture", photo, "-o", out, "--size", str(size), "--model", model, "--force", "--debug"]
    res = CliRunner().invoke(cli, args)
    if res.exit_code != 0:
        raise click.ClickException(f"{photo}: {res.output.strip()}")
    return os.path.join(out, os.path.splitext(os.path.basename(photo))[0])


def measures(maps):
    """(relief strength, mean roughness, roughness spread) of a set's maps as read back."""
    n = maps["normal"][..., :2].astype(np.float64) * 2 - 1
    r = maps["roughness"].astype(np.float64)
    r = r[..., 0] if r.ndim == 3 else r
    return float(n.reshape(-1, 2).std(0).mean()), float(r.mean()), float(r.std())


def _tile(img, cell):
    from PIL import Image

    img = np.repeat(img[..., None], 3, -1) if img.ndim == 2 else img[..., :3]
    return Image.fromarray((np.clip(img, 0, 1) * 255).round().astype(np.uint8)).resize((cell, cell))


def make(models, out, cell=160, log=print):
    from PIL import Image, ImageDraw

    from svbrdf_cli.imageio import read_image

    real = os.path.join(files.shared_data(None), "real")
    photos = files.real_photos(real)
    if not photos:
        raise click.ClickException(f"{real}: no real photos (the shared data is absent)")
    cols = 1 + len(models) * len(MAPS)
    top = 34
    sheet = Image.new("RGB", (cols * cell, top + len(photos) * cell), "white")
    draw = ImageDraw.Draw(sheet)
    draw.text((4, 4), "photo", fill="black")
    for m, model in enumerate(models):
        for k, name in enumerate(MAPS):
            draw.text((4 + (1 + m * len(MAPS) + k) * cell, 4 + 14 * (k == 0)),
                      (os.path.basename(model.rstrip("/")) + ": " if k == 0 else "") + name, fill="black")
    log("photo | " + " | ".join(f"{os.path.basename(m.rstrip('/'))} relief, roughness mean, spread" for m in models))
    with tempfile.TemporaryDirectory() as tmp:
        for i, photo in enumerate(photos):
            row = []
            for m, model in enumerate(models):
                folder = capture(photo, model, os.path.join(tmp, str(m)))
                maps = {name: read_image(os.path.join(folder, name + ".png")) for name in MAPS}  # read once
                row.append(measures(maps))
                for k, name in enumerate(MAPS):
                    sheet.paste(_tile(maps[name], cell), ((1 + m * len(MAPS) + k) * cell, top + i * cell))
                if m == 0:
                    shown = read_image(os.path.join(folder, "debug", "input.png"))  # the crop the model saw
            sheet.paste(_tile(shown, cell), (0, top + i * cell))
            name = os.path.relpath(photo, real)
            log(f"{name} | " + " | ".join(f"{a:.3f}, {b:.2f}, {c:.3f}" for a, b, c in row))
    sheet.save(out)
    return out


@click.command()
@click.option("--model", "models", multiple=True, default=("physical",), show_default=True,
              help="A model name or an exported folder (repeatable).")
@click.option("-o", "--out", default="docs/figures/real_previews.png", show_default=True)
def cli(models, out):
    """Draw the real benchmark photos' maps for each model and print their relief and roughness."""
    click.echo(make(models, out, log=click.echo))


if __name__ == "__main__":
    cli()
