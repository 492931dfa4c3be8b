"""Where the flash's highlight is in a photo: the brightest blob of its weakest channel.

A dielectric's highlight adds the flash's (white) light to every channel, while a bright coloured
texture is bright in some channels only, so the blob is read on the weakest channel rather than the
luminance (measured on card_blue_9lights, whose gold foil scales are the brightest thing in the photo
by luminance: the centre lands 0.127 from the camera's foot instead of 0.163). Used by
:mod:`svbrdf_cli.infer.geometry` (where the camera and flash were) and :mod:`svbrdf_cli.infer.physical` (what of
the highlight is left in the diffuse).
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
