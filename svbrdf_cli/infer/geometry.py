"""Where the camera and the flash were, from the photo itself (and its EXIF when it has one).

A phone's flash sits 1-2 cm beside the lens, so at 10-30 cm from the surface the light is not at
the camera: the mirror highlight of a flat surface appears half-way between the two feet (the
points straight under the lens and under the flash), off the image centre. What the tool knows:

* **the camera's foot**: a fronto-parallel photo's optical axis meets the surface at the photo's
  centre, so for the auto (and whole-photo) crop the foot is where the photo's centre falls in the
  crop's [-1, 1]^2 coordinates. For a marker or corner crop (rectified by a homography) the photo's
  centre says nothing, and the camera is taken to sit at the highlight (a flash at the lens).
* **the distance**: with a 35 mm-equivalent focal length in the EXIF, the crop's half-width in
  pixels over the focal length in pixels is tan(half the crop's field of view), and the height is
  its inverse in surface units (:func:`svbrdf_cli.conventions.camera_height`). Without one, the
  physical estimate's flash height (the steepness of the diffuse falloff) is used.
* **the highlight's centre** (:func:`highlight_centre`): the centroid of the brightest blob of the
  blurred photo's weakest channel (a highlight is white, texture has a colour). With equal heights the
  highlight is at the mid-point of the feet, so the flash's
  foot is ``2 * highlight - camera``, its offset from the lens bounded by :data:`MAX_FLASH_OFFSET`.

:class:`CaptureGeometry` holds the result; ``material.json`` records it under ``"geometry"``.
"""

from __future__ import annotations

import dataclasses
import math


from svbrdf_cli import conventions as cv
from svbrdf_cli.rectify import highlight

#: Half the diagonal of a 35 mm film frame (36 x 24 mm), in mm: 35 mm-equivalent focal lengths
#: are defined on the diagonal.
HALF_DIAGONAL_35MM = 0.5 * math.hypot(36.0, 24.0)
#: The flash's offset from the lens at most, as a fraction of the height (2 cm at 10 cm).
MAX_FLASH_OFFSET = 0.2
#: Heights accepted from EXIF, in surface units (a crop seeing 1.5 to 150 degrees).
HEIGHT_RANGE = (0.5, 80.0)


@dataclasses.dataclass
class CaptureGeometry:
    """Camera and flash positions in the crop's surface units (the crop spans [-1, 1]^2, z up)."""

    camera: tuple
    light: tuple
    highlight: tuple
    focal_35mm: float | None = None
    sources: dict = dataclasses.field(default_factory=dict)

    def report(self):
        """JSON-able, for ``material.json``."""
        r = lambda v: [round(float(c), 4) for c in v]  # noqa: E731
        return {"camera": r(self.camera), "light": r(self.light), "highlight": r(self.highlight),
                "focal_35mm": self.focal_35mm, "sources": dict(self.sources)}


def crop_height(focal, photo_size, crop_side):
    """Height above the surface, in surface units, of a camera with 35 mm-equivalent ``focal`` (mm)
    whose ``photo_size`` = (width, height) pixel photo holds a square crop of ``crop_side`` pixels."""
    f_px = focal * math.hypot(*photo_size) / (2.0 * HALF_DIAGONAL_35MM)
    return f_px / (0.5 * crop_side)


def camera_foot(photo_size, box):
    """The photo centre's position in the crop's surface coordinates (row 0 is y = +1).

    Args:
        photo_size: (width, height) of the photo in pixels.
        box: the crop's (x0, y0, side, side) in the same pixels.
    """
    w, h = photo_size
    x0, y0, side = box[0], box[1], box[2]
    half = 0.5 * side
    return ((0.5 * w - (x0 + half)) / half, -((0.5 * h - (y0 + half)) / half))


def highlight_centre(image):
    """(x, y) surface position of the flash highlight (or, on a matte surface, of the brightness peak):
    the centre of :func:`svbrdf_cli.rectify.highlight.find`'s blob.

    Args:
        image: (H, W, 3) encoded photo in [0, 1].
    """
    return highlight.find(image).centre


def estimate(image, height=None, focal=None, photo_size=None, box=None):
    """The capture's geometry (see the module docstring).

    Args:
        image: (H, W, 3) encoded crop, as the networks take it.
        height: the flash height to use without EXIF (the physical estimate's fit); None: the
            conventions' :data:`svbrdf_cli.conventions.CAMERA_HEIGHT`.
        focal: 35 mm-equivalent focal length (mm), or None.
        photo_size: (width, height) of the photo the crop came from, or None.
        box: the crop's (x0, y0, side, side) in the photo, or None (a rectified or unknown crop).
    """
    sources = {}
    hx, hy = highlight_centre(image)
    z = None
    if focal and photo_size and box:
        z = crop_height(focal, photo_size, box[2])
        if not HEIGHT_RANGE[0] <= z <= HEIGHT_RANGE[1]:
            z = None
        else:
            sources["height"] = "exif"
    if z is None:
        z = float(height) if height else cv.CAMERA_HEIGHT
        sources["height"] = "falloff fit" if height else "convention"
    if photo_size and box:
        cx, cy = camera_foot(photo_size, box)
        sources["camera"] = "photo centre"
        # equal heights: the highlight is half-way between the feet
        ox, oy = 2.0 * (hx - cx), 2.0 * (hy - cy)
        norm = math.hypot(ox, oy)
        limit = MAX_FLASH_OFFSET * z
        if norm > limit:
            ox, oy = ox * limit / norm, oy * limit / norm
            sources["light"] = "highlight (offset capped)"
        else:
            sources["light"] = "highlight"
        light = (cx + ox, cy + oy, z)
    else:
        cx, cy = hx, hy
        sources["camera"] = sources["light"] = "highlight (flash at the lens)"
        light = (hx, hy, z)
    return CaptureGeometry(camera=(cx, cy, z), light=light, highlight=(hx, hy), focal_35mm=focal, sources=sources)


def for_capture(image, focal, photo_shape, crop_report, found=None):
    """:func:`estimate` for one ``svbrdf capture`` job.

    Args:
        image: the network input (encoded crop).
        focal: the photo's 35 mm-equivalent focal length from its EXIF
            (:attr:`svbrdf_cli.ingest.photo.Photo.focal_35mm`), or None.
        photo_shape: the decoded photo's (height, width, ...).
        crop_report: the crop's report (:class:`svbrdf_cli.rectify.crops.Crop`): an ``auto`` or ``none`` crop
            has a ``box`` in the photo; a rectified one has none.
        found: the physical estimate's findings when the model computed it
            (:attr:`svbrdf_cli.infer.model.Model.found`: its flash height); otherwise the estimate is
            run for it.
    """
    box = crop_report.get("box") if crop_report.get("mode") in ("auto", "none") else None
    height = None
    if not focal or box is None:
        if not found or "flash_height" not in found:
            from svbrdf_cli.infer.physical import estimate as physical_estimate

            found = physical_estimate(image)[1]
        height = found["flash_height"]
    size = (int(photo_shape[1]), int(photo_shape[0]))
    return estimate(image, height=height, focal=focal, photo_size=size if box else None, box=box)
