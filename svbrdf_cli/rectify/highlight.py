"""Where the flash's highlight is in a photo: the brightest blob of its weakest channel.

A dielectric's highlight adds the flash's (white) light to every channel, while a bright coloured
texture is bright in some channels only, so the blob is read on the weakest channel rather than the
luminance (measured on card_blue_9lights, whose gold foil scales are the brightest thing in the photo
by luminance: the centre lands 0.127 from the camera's foot instead of 0.163). Used by
:mod:`svbrdf_cli.infer.geometry` (where the camera and flash were) and :mod:`svbrdf_cli.infer.physical` (what of
the highlight is left in the diffuse). :func:`metal_share` reads the highlight's colour: white (a
dielectric's) or the material's own (a metal's), for :mod:`svbrdf_cli.infer.refine`.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli.imageops import blur

#: The blob: pixels of the blurred weakest channel above this fraction of the way from its median to
#: its peak.
BLOB_LEVEL = 0.7


@dataclasses.dataclass
class Blob:
    """The highlight's blob in a photo."""
    mask: np.ndarray     # (H, W) bool: the blob's pixels
    peak: tuple          # (row, col) of its brightest blurred pixel
    centre: tuple        # (x, y) surface position: the weighted centroid (the peak where it has no weight)


def find(image):
    """The highlight's :class:`Blob` in the encoded (H, W, 3) photo ``image`` (on a matte surface: the
    brightness peak's)."""
    import cv2

    lin = cv.image_to_linear(np.asarray(image, np.float32))
    lum = np.ascontiguousarray(lin.min(-1), np.float32)
    h, w = lum.shape
    b = blur(lum, max(1.0, w / 64.0))
    peak = np.unravel_index(int(np.argmax(b)), b.shape)
    top, base = float(b[peak]), float(np.median(b))
    thr = base + BLOB_LEVEL * (top - base)
    _, labels = cv2.connectedComponents((b >= thr).astype(np.uint8))
    mask = labels == labels[peak]
    wgt = np.where(mask, b - thr, 0.0)
    p = cv.surface_positions(h, w)
    total = float(wgt.sum())
    if total <= 0:
        centre = (float(p[peak][0]), float(p[peak][1]))
    else:
        centre = (float((wgt * p[..., 0]).sum() / total), float((wgt * p[..., 1]).sum() / total))
    return Blob(mask, (int(peak[0]), int(peak[1])), centre)


#: :func:`metal_share`: the flash spot is the pixels within this many times the blob's radius (at least
#: :data:`SPOT_MIN_RADIUS` of the width) of its centre, and a hue's own level is read beyond
#: :data:`FAR_RADIUS` times that radius.
SPOT_RADIUS, SPOT_MIN_RADIUS, FAR_RADIUS = 1.5, 0.08, 3.0
#: Soft hue bins (the same hue is taken for the same material, in the spot and away from it).
HUE_BINS = 12
#: A hue says something about its highlight's colour only where its material is clearly coloured
#: (whiteness, weakest over strongest channel, away from the flash: full trust up to the first, none from
#: the second; a grey's highlight has the same colour as its diffuse whatever it is) ...
COLOURED_WHITENESS = (0.4, 0.7)
#: ... and where a white highlight of the brightness the spot adds would whiten it visibly (the
#: whiteness it would add: no evidence under the first, full from the second).
WHITENING_EVIDENCE = (0.05, 0.15)
#: The share of the highlight in the material's own colour (:func:`metal_share`) is read as a metal's from
#: the first to the second (a smoothstep). A dielectric's highlight is the flash's white (share 0); the
#: measured share also takes the errors of the flat-surface falloff the spot's added brightness is read
#: against (the flash's beam, vignetting): up to 0.36 on the real dielectric photos of
#: ``python -m export.studies.artist_check`` (orange leather, henzler_train/0259), mostly 0.4-0.9 on the
#: hues of their metals.
METAL_SHARE = (0.35, 0.65)
#: Only spot pixels the highlight makes this share of (brightness over the hue's albedo away from the flash
#: times the falloff) are read: a spot with no highlight but brighter texture or relief shading
#: says nothing about the highlight's colour.
HIGHLIGHT_SHARE = 0.5


def _hue(lin):
    """Hue angle (radians) of RGB ``lin``: unchanged by adding white."""
    return np.arctan2(np.sqrt(3.0) * (lin[..., 1] - lin[..., 2]), 2.0 * lin[..., 0] - lin[..., 1] - lin[..., 2])


def spot_distances(image):
    """(each pixel's distance to the centre of the encoded ``image``'s brightest blob (:func:`find`), (H, W);
    the blob's radius, at least :data:`SPOT_MIN_RADIUS` of the width), in surface units."""
    blob = find(image)
    h, w = blob.mask.shape
    p = cv.surface_positions(h, w)
    rho = np.hypot(p[..., 0] - blob.centre[0], p[..., 1] - blob.centre[1])
    return rho, max(np.sqrt(blob.mask.sum() / np.pi), SPOT_MIN_RADIUS * w) * 2.0 / w


def metal_share(image, height, valid=None):
    """(H, W) in [0, 1]: how far each pixel's material reflects the flash in its own colour (a metal's
    highlight), read from the photo's flash spot, per hue.

    A dielectric's highlight adds the flash's white to its diffuse colour: under the flash a coloured
    material gets whiter (its weakest channel rises towards its strongest). A metal's highlight is its own
    colour: it gets brighter but no whiter. For each hue (:data:`HUE_BINS`, soft bins), the spot's pixels
    are compared with the same hue away from the flash: ``s``, the share of a spot pixel's brightness the
    highlight adds (its brightness over the hue's albedo away from the flash times a flat surface's
    falloff ``height / d^3``; only pixels where it is over :data:`HIGHLIGHT_SHARE` are read), and
    ``s_white``, the share of white that makes the pixel as white as it is
    (from the hue's whiteness away from the flash). ``1 - s_white / s`` is the share of the highlight in the
    material's colour; :data:`METAL_SHARE` reads it as metal or not, trusted only for clearly coloured hues
    (:data:`COLOURED_WHITENESS`) that a white highlight would visibly whiten (:data:`WHITENING_EVIDENCE`).
    Spread to every pixel of the hue, in or out of the spot; 0 where the photo says nothing.

    Args:
        image: (H, W, 3) encoded photo in [0, 1].
        height: the flash's height above the surface (surface units).
        valid: (H, W) bool, pixels whose colour can be read (default: all but near-clipped ones).
    """
    img = np.asarray(image, np.float32)
    lin = cv.image_to_linear(img).astype(np.float64)
    h, w = lin.shape[:2]
    out = np.zeros((h, w), np.float32)
    if valid is None:
        valid = (img < 0.95 * cv.clip_level(img)).all(-1)
    rho, radius = spot_distances(img)
    d = np.sqrt(rho * rho + height * height)
    falloff = height / d ** 3
    lo, hi = lin.min(-1), lin.max(-1)
    lum = np.maximum(lin @ np.asarray(cv.LUMA), 1e-9)
    white = lo / np.maximum(hi, 1e-9)
    strongest = hi / lum
    spot = (rho < SPOT_RADIUS * radius) & valid
    far = (rho > FAR_RADIUS * radius) & valid
    hue = _hue(lin)
    got = np.zeros((h, w))
    total = np.zeros((h, w))
    for k in range(HUE_BINS):
        m = np.maximum(np.cos(hue - (2.0 * np.pi * k / HUE_BINS - np.pi)), 0.0) ** 4
        total += m
        mf, ms = m * far, m * spot
        if mf.sum() < 1e-3 * h * w or ms.sum() < 3e-4 * h * w:  # (a hue seen too little to read)
            continue
        w_far = float((white * mf).sum() / mf.sum())
        c_far = float((strongest * mf).sum() / mf.sum())
        albedo = float((lum / falloff * mf).sum() / mf.sum())
        s = np.clip(1.0 - albedo * falloff / lum, 0.0, 1.0)
        ms = ms * (s > HIGHLIGHT_SHARE)  # where the highlight makes most of the pixel: what texture does not
        if ms.sum() < 3e-4 * h * w:
            continue
        # a white share t makes white = (w_far c (1 - t) + t) / (c (1 - t) + t): solved for t
        dw = white - w_far
        s_white = np.clip(c_far * dw / np.maximum(c_far * dw + 1.0 - white, 1e-9), 0.0, 1.0)
        would = (w_far * c_far * (1.0 - s) + s) / np.maximum(c_far * (1.0 - s) + s, 1e-9) - w_far
        ws = ms * s
        if ws.sum() <= 0:
            continue
        share = 1.0 - float((s_white * ws).sum()) / float((s * ws).sum())
        evidence = cv.smoothstep(float((would * ms).sum() / ms.sum()), *WHITENING_EVIDENCE)
        trust = 1.0 - cv.smoothstep(w_far, *COLOURED_WHITENESS)
        got += m * float(cv.smoothstep(share, *METAL_SHARE) * evidence * trust)
    out[:] = got / np.maximum(total, 1e-9)
    return out
