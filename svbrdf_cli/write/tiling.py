"""Seamless maps (``svbrdf capture --tileable``): offset-and-blend, the same operation on every map.

Each map is cross-faded with itself shifted by about half its size: the shifted copy wraps without a
seam (its left and right edges are neighbouring columns of the original, cut where the diffuse map's
neighbouring columns differ least, so a regular pattern is not cut along an edge), and its own seam
(the original's edges, now in its middle) falls where the original is kept. Near the borders, over a band of
:data:`BAND` of the size, the result fades from the original (inside) to the shifted copy (at the
edges), so the wrap is continuous and the centre is the photo's own. Normals are blended as vectors
and renormalised; every map uses the same weights, so they stay consistent.

Measured on the benchmark's 12 real photos (``docs/capture.md``): the mean absolute difference
across the wrap falls from several times the difference between neighbouring interior columns to
within it. A stochastic material (wood, leather, plaster) tiles without a visible repeat; a regular
one (tiles, weave) shows a doubled pattern inside the band, where the two copies disagree.
"""

from __future__ import annotations

import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli.imageops import luminance

#: Width of the cross-fade band at each border, as a fraction of the map's size.
BAND = 0.25


def weights(h, w, band=BAND):
    """(H, W) weight of the original: 1 inside, falling smoothly to 0 at every border over ``band``."""
    def ramp(n):
        d = np.minimum(np.arange(n) + 0.5, n - np.arange(n) - 0.5) / max(band * n, 1.0)
        t = np.clip(d, 0.0, 1.0)
        return t * t * (3.0 - 2.0 * t)  # smoothstep
    return np.minimum.outer(ramp(h), ramp(w)).astype(np.float32)


def _cut(lum, axis):
    """Where, in the middle half along ``axis``, neighbouring lines of ``lum`` differ least: the shifted
    copy's edges are the two lines on either side of it, so that is where the wrap is smoothest."""
    d = np.abs(np.diff(lum, axis=axis)).mean(axis=1 - axis)  # d[i]: line i against line i + 1
    n = lum.shape[axis]
    lo, hi = n // 4, 3 * n // 4
    return lo + int(np.argmin(d[lo:hi])) + 1


def make_tileable(maps, band=BAND):
    """Linear maps (HWC) -> the same maps, seamless when tiled (see the module docstring)."""
    h, w = next(iter(maps.values())).shape[:2]
    a = weights(h, w, band)[..., None]
    lum = luminance(np.asarray(maps["diffuse"], np.float64), np.float64) if "diffuse" in maps else np.zeros((h, w))
    cy, cx = _cut(lum, 0), _cut(lum, 1)  # the copy starts at (cy, cx): its edges are a smooth cut
    out = {}
    for k, v in maps.items():
        shifted = np.roll(v, (-cy, -cx), axis=(0, 1))
        mixed = a * v + (1.0 - a) * shifted
        out[k] = cv.normalize(mixed).astype(np.float32) if k == "normal" else mixed.astype(np.float32)
    return out


def wrap_ratio(img):
    """Mean absolute difference across the wrap (last column against the first, last row against the
    first) over the mean difference between neighbouring interior columns and rows: about 1 for a
    seamless map."""
    x = np.asarray(img, np.float64)
    wrap = (np.abs(x[:, -1] - x[:, 0]).mean() + np.abs(x[-1] - x[0]).mean()) / 2
    inner = (np.abs(np.diff(x, axis=1)).mean() + np.abs(np.diff(x, axis=0)).mean()) / 2
    return float(wrap / max(inner, 1e-12))
