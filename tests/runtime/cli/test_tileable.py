"""``svbrdf capture --tileable``: a 2 x 2 tiling of the maps shows no seam, inside the tile or at its
edges, and a regular pattern is not doubled."""

import json

import numpy as np

from svbrdf_cli.imageio import read_image, write_image
from svbrdf_cli.imageops import luminance
from svbrdf_cli.write.tiling import line_steps

from .clitools import run


def _flash(h, w, x, y):
    return np.exp(-((x - w / 2) ** 2 + (y - h / 2) ** 2) / (2 * (0.12 * w) ** 2))[..., None]


def _leather(path, n=512, seed=3):
    """A stochastic material (grain at several scales, a trend across it) under a flash."""
    import cv2

    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:n, 0:n]
    grain = sum(cv2.GaussianBlur(rng.standard_normal((n, n)).astype(np.float32), (0, 0), s) * s
                for s in (1.0, 3.0, 9.0))
    grain = (grain - grain.mean()) / grain.std()
    trend = 1.0 + 0.8 * x / n - 0.5 * y / n  # the hide darker towards one corner: the map does not wrap
    base = (0.3 * trend + 0.05 * grain)[..., None] * np.float32([1.0, 0.75, 0.55])
    write_image(path, np.clip(base + 0.35 * _flash(n, n, x, y), 0, 1).astype(np.float32))
    return path


def _tiles(path, n=512, period=74, grout=5, seed=4):
    """A regular pattern whose period does not divide the photo: glazed tiles of random colours."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:n, 0:n]
    colours = rng.uniform(0.25, 0.6, (n // period + 2, n // period + 2, 3)) * np.float32([0.4, 0.8, 0.9])
    img = colours[y // period, x // period]
    line = ((x % period) < grout) | ((y % period) < grout)
    img[line] = 0.12
    write_image(path, np.clip(img + 0.3 * _flash(n, n, x, y), 0, 1).astype(np.float32))
    return path


def _steps_max(img):
    return max(float(line_steps(img, a).max()) for a in (0, 1))


def _interior_steps_max(img):
    x = np.asarray(img, np.float64)
    return max(float(np.abs(np.diff(x, axis=a).mean(axis=1 - a)).mean(-1).max()) for a in (0, 1))


# Both tests check the tiling machinery on drawn photos, so they run the physical estimate, whose maps
# follow the photo: the default chain fills the diffuse under the highlight from beside it, which on
# these drawings adds steps and doubled grout lines of its own (its real-photo tiling:
# python -m export.studies.tiling_figure).
MODEL = ("--model", "physical")


def test_a_2x2_tiling_has_no_seam_inside_or_at_the_edges(tmp_path):
    photo = _leather(tmp_path / "leather.png")
    for flag in ((), ("--tileable",)):
        code, out = run("capture", photo, "-o", tmp_path / ("t" if flag else "p"), "--size", 256, *flag, *MODEL)
        assert code == 0, out
    for m in ("diffuse", "specular", "roughness", "normal"):
        plain = read_image(tmp_path / "p" / "leather" / f"{m}.png")
        tiled = read_image(tmp_path / "t" / "leather" / f"{m}.png")
        # no line of the 2 x 2 tiling steps more than the photo's own largest line-to-line step
        # (the old cross-fade left a step at 3/4 of the tile, 2-5 times it)
        assert _steps_max(tiled) <= 1.25 * max(_interior_steps_max(plain), 1.5 / 255), m


def test_a_regular_pattern_stays_in_step(tmp_path):
    photo = _tiles(tmp_path / "tiles.png")
    code, out = run("capture", photo, "-o", tmp_path / "t", "--size", 256, "--tileable", *MODEL)
    assert code == 0, out
    rec = json.loads((tmp_path / "t" / "tiles" / "material.json").read_text())
    assert rec["tileable"] is True and rec["tiling"]["whole_repeats"] is not None
    lum = luminance(read_image(tmp_path / "t" / "tiles" / "diffuse.png"))
    for axis in (0, 1):
        profile = np.tile(lum, (2, 2)).mean(axis=axis)  # grout lines: dips of the line means
        lo, hi = np.percentile(profile, 2), np.percentile(profile, 60)
        level = (profile - lo) / (hi - lo)  # 0: a grout line's, 1: the tiles'
        dips = [i for i in range(1, len(profile) - 1) if profile[i] <= profile[i - 1] and profile[i] < profile[i + 1]]
        # a grout line seen through a half-and-half blend is a dip half as deep: a doubled line (the old
        # cross-fade had 6 and 12 of them along the two axes of this tiling; the grid's own are at ~0)
        ghosts = [i for i in dips if 0.3 < level[i] < 0.65]
        assert not ghosts, (axis, ghosts)
