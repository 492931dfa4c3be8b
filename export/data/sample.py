"""The bundled sample map set ``examples/glazed_tiles``: procedural, made by this project (MIT).

    python -m export.data.sample            # rewrites examples/glazed_tiles/

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
from svbrdf_cli.mapset import write_map_set

SAMPLE_DIR = os.path.join("examples", "glazed_tiles")


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


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-o", "--output", default=SAMPLE_DIR)
    a = ap.parse_args(argv)
    write_map_set(a.output, glazed_tiles())
    print(f"wrote {a.output}")


if __name__ == "__main__":
    main()
