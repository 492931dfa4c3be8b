"""The bundled samples, procedural, made by this project (MIT).

    python -m export.data.sample            # rewrites examples/glazed_tiles/ and examples/glazed_tiles.jpg

``examples/glazed_tiles/`` is a map set; ``examples/glazed_tiles.jpg`` is a
flash photo of the same kind of tiles (1024 x 768, light at the lens, a
little sensor noise, sRGB JPEG) for the README's first command.

Glazed ceramic tiles in a 4 x 4 grid with rough grout, bevelled edges, a
little glaze waviness and per-tile colour variation: enough relief and gloss
to show the flash highlight and the bump shading. Deterministic (fixed seed);
numpy only.
"""

from __future__ import annotations

import argparse
import os

import numpy as np

from export.data.cc0 import normals_from_height
from svbrdf_cli.write.mapset import write_map_set

SAMPLE_DIR = os.path.join("examples", "glazed_tiles")
SAMPLE_PHOTO = os.path.join("examples", "glazed_tiles.jpg")


def glazed_tiles(size=256, tiles=4, seed=7):
    """Linear maps (HWC float32) of glazed tiles."""
    rng = np.random.default_rng(seed)
    u = (np.arange(size) + 0.5) / size * tiles
    x, y = np.meshgrid(u, u)
    fx, fy = x % 1.0, y % 1.0
    edge = np.minimum(np.minimum(fx, 1 - fx), np.minimum(fy, 1 - fy))  # distance to the tile border
    grout = edge < 0.035
    bevel = np.clip((edge - 0.035) / 0.06, 0, 1)
    ix, iy = x.astype(int), y.astype(int)
    tile_id = iy * tiles + ix
    wav = sum(np.sin(2 * np.pi * (k * x * rng.uniform(0.3, 0.8) + rng.uniform())) *
              np.sin(2 * np.pi * (k * y * rng.uniform(0.3, 0.8) + rng.uniform())) / k for k in (1, 2, 3))
    height = np.where(grout, 0.0, 0.6 + 0.4 * np.sqrt(bevel)) + 0.01 * wav
    base = np.array([0.10, 0.32, 0.42])
    tint = rng.uniform(0.8, 1.2, size=(tiles * tiles, 3))[tile_id]
    diffuse = np.where(grout[..., None], [0.35, 0.33, 0.30], base * tint)
    roughness = np.where(grout, 0.85, 0.18 + 0.05 * rng.uniform(size=tiles * tiles)[tile_id])[..., None]
    specular = np.where(grout[..., None], 0.03, 0.06) * np.ones(3)
    return {"normal": normals_from_height(height, depth=0.03), "diffuse": diffuse.astype(np.float32),
            "roughness": roughness.astype(np.float32), "specular": specular.astype(np.float32)}


def flash_photo(width=1024, height=768, tiles=6, seed=7):
    """A landscape flash photo of glazed tiles: linear RGB (H, W, 3) float32.

    The camera looks straight down at the centre with the flash at the lens
    (:data:`svbrdf_cli.conventions.FLASH_POSITION`); the image is the middle
    ``height`` rows of a square render, so the surface spans -1..1 across the
    width.
    """
    from svbrdf_cli import conventions as cv
    from svbrdf_cli.shading import render_maps

    maps = {k: v.astype(np.float64) for k, v in glazed_tiles(width, tiles, seed).items()}
    lin = render_maps(maps, light=cv.FLASH_POSITION)
    top = (width - height) // 2
    lin = lin[top:top + height]
    rng = np.random.default_rng(seed)
    lin = lin * 1.6 + rng.normal(0.0, 0.004, lin.shape) * np.sqrt(np.clip(lin, 0, None) + 0.01)  # exposure, noise
    return np.clip(lin, 0.0, 1.0).astype(np.float32)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-o", "--output", default=SAMPLE_DIR)
    ap.add_argument("--photo", default=SAMPLE_PHOTO)
    a = ap.parse_args(argv)
    write_map_set(a.output, glazed_tiles())
    print(f"wrote {a.output}")
    write_jpeg(a.photo, flash_photo())
    print(f"wrote {a.photo}")


def write_jpeg(path, linear, quality=90):
    """Linear RGB -> sRGB JPEG, the way a phone stores a photo."""
    import OpenImageIO as oiio

    from svbrdf_cli import conventions as cv

    h, w, _ = linear.shape
    spec = oiio.ImageSpec(w, h, 3, "uint8")
    spec.attribute("Compression", f"jpeg:{quality}")
    spec.attribute("oiio:ColorSpace", "sRGB")
    px = (cv.linear_to_srgb(linear) * 255 + 0.5).astype(np.uint8)
    out = oiio.ImageOutput.create(path)
    if out is None or not (out.open(path, spec) and out.write_image(px)):
        raise OSError(f"could not write {path}: {oiio.geterror()}")
    out.close()


if __name__ == "__main__":
    main()
