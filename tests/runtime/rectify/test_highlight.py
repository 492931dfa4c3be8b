"""The flash highlight's colour read from a photo (:func:`svbrdf_cli.rectify.highlight.metal_share`)."""

import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli.imageops import blur, luminance
from svbrdf_cli.rectify import highlight
from svbrdf_cli.shading import render_maps


def _photo(colour, f0, roughness, side=256, seed=3):
    rng = np.random.default_rng(seed)
    grain = blur(rng.normal(0.0, 1.0, (side, side)).astype(np.float32), 1.0)
    grain = grain / grain.std()
    maps = {"normal": np.tile(np.float32([0, 0, 1]), (side, side, 1)),
            "diffuse": (np.float32(colour) * (1.0 + 0.25 * grain)[..., None]).astype(np.float32),
            "roughness": np.full((side, side, 1), roughness, np.float32),
            "specular": np.broadcast_to(np.float32(f0), (side, side, 3)).copy()}
    lin = render_maps(maps, light=cv.FLASH_POSITION, intensity=cv.LIGHT_INTENSITY * 1.6)
    return cv.linear_to_srgb(np.clip(lin, 0.0, 1.0)).astype(np.float32)


GOLD = np.float32([1.0, 0.72, 0.25])


def test_a_highlight_in_the_materials_colour_reads_as_metal():
    f0 = 0.06 * GOLD / luminance(GOLD[None])[0]
    share = highlight.metal_share(_photo(0.12 * GOLD, f0, 0.3), cv.FLASH_POSITION[2])
    assert share.mean() > 0.9


def test_a_white_highlight_or_none_reads_as_a_dielectric():
    height = cv.FLASH_POSITION[2]
    for photo in (_photo((0.30, 0.13, 0.05), (0.04, 0.04, 0.04), 0.25),   # glossy walnut: a white highlight
                  _photo((0.5, 0.1, 0.1), (0.04, 0.04, 0.04), 0.15),      # red lacquer
                  _photo((0.30, 0.13, 0.05), (0.04, 0.04, 0.04), 1.0),    # matte: no highlight to read
                  _photo((0.3, 0.3, 0.3), 0.5 * GOLD, 0.3)):              # grey diffuse: no hue to compare
        assert highlight.metal_share(photo, height).max() < 0.05
