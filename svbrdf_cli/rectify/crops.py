"""Crop and rectify a photo to the square of surface the networks see.

Four ways, one result (:class:`Crop`: the square linear image plus a report
of what was chosen):

* :func:`auto_crop` -- the largest square around the flash highlight, or
  around the image centre when no highlight stands out;
* :func:`marker_crop` -- a printed marker sheet (:func:`marker_sheet`: a ring
  of 16 AprilTag 36h11 tags around a square window) is found with OpenCV's
  ArUco module and the window is warped to a square by a homography;
* :func:`quad_crop` -- a quadrilateral given by hand (four corners in
  pixels, any order), warped to a square;
* :func:`no_crop` -- the photo as it is (it must be square-ish: the
  networks assume a square of surface, and a non-square photo is
  centre-cropped with a warning).

Coordinates are OpenCV's: x to the right, y down, pixel centres at
integers. Images are (H, W, 3) float32, linear; nothing here changes values
except by interpolation.
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli.imageops import luminance
from svbrdf_cli.errors import SvbrdfError

log = logging.getLogger("svbrdf")


class CropError(SvbrdfError):
    """The requested crop cannot be made from this photo."""


@dataclasses.dataclass
class Crop:
    """A square crop of the photo: its linear (S, S, 3) float32 pixels and how it was made."""
    image: np.ndarray      # (S, S, 3) float32, linear
    report: dict           # JSON-able: mode, what was found, the source quad


# --------------------------------------------------------------------------
# The marker sheet
# --------------------------------------------------------------------------

#: The sheet is a grid of SHEET_CELLS x SHEET_CELLS cells; tags sit on the odd
#: cells of the outer ring of a 5 x 5 lattice (cells 1, 3, 5, 7, 9), ids 0-15
#: clockwise from the top-left; the window to photograph through is cells 2..9
#: (between the tags' inner edges).
SHEET_CELLS = 11
TAG_IDS = tuple(range(16))
_LATTICE = (1, 3, 5, 7, 9)
WINDOW_CELLS = (2, 9)


def _tag_cells():
    """Id -> (column, row) cell of the tag's top-left corner, clockwise from the top-left."""
    top = [(c, 1) for c in _LATTICE]
    right = [(9, r) for r in _LATTICE[1:]]
    bottom = [(c, 9) for c in reversed(_LATTICE[:-1])]
    left = [(1, r) for r in reversed(_LATTICE[1:-1])]
    return dict(zip(TAG_IDS, top + right + bottom + left))


def _dictionary():
    import cv2

    return cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)


def tag_centres(cell=1.0):
    """Id -> (x, y) centre of each tag on the sheet, in units of ``cell``
    (sheet edge coordinates: the sheet spans 0..SHEET_CELLS)."""
    return {i: ((c + 0.5) * cell, (r + 0.5) * cell) for i, (c, r) in _tag_cells().items()}


#: Pixels per cell of a printed sheet: the default (a 1056 px sheet) and the range ``svbrdf markers`` takes.
SHEET_CELL_PX, SHEET_CELL_PX_RANGE = 96, (24, 1000)


def marker_sheet(cell_px=SHEET_CELL_PX, label=True):
    """The printable sheet: (S, S) uint8, white paper, black tags.

    ``cell_px`` pixels a cell: the default 96 gives a 1056 px sheet, 8.9 cm
    wide at 300 dpi. Print it at any scale; the window (7 of the 11 cells)
    is the patch of surface that becomes the texture.
    """
    import cv2

    size = SHEET_CELLS * cell_px
    sheet = np.full((size, size), 255, np.uint8)
    d = _dictionary()
    for i, (c, r) in _tag_cells().items():
        tag = cv2.aruco.generateImageMarker(d, i, cell_px)
        sheet[r * cell_px:(r + 1) * cell_px, c * cell_px:(c + 1) * cell_px] = tag
    lo, hi = WINDOW_CELLS[0] * cell_px, WINDOW_CELLS[1] * cell_px
    # A thin frame marks the window (cut it out, or lay the sheet's window over the material).
    cv2.rectangle(sheet, (lo, lo), (hi - 1, hi - 1), 160, max(1, cell_px // 48))
    if label:
        cv2.putText(sheet, "svbrdf markers: cut out the window, lay it on the surface", (cell_px, cell_px // 2 + 6),
                    cv2.FONT_HERSHEY_SIMPLEX, cell_px / 160, 0, max(1, cell_px // 64), cv2.LINE_AA)
        cv2.arrowedLine(sheet, (cell_px * 2 + cell_px // 2, int(cell_px * 1.9)), (cell_px * 2 + cell_px // 2, int(cell_px * 1.1)),
                        0, max(1, cell_px // 32), tipLength=0.3)  # "up" for the photographer
    return sheet


def detect_markers(gray):
    """Find the sheet's tags: id -> (4, 2) corners in pixels (float64)."""
    import cv2

    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.ArucoDetector(_dictionary(), params)
    corners, ids, _ = detector.detectMarkers(gray)
    if ids is None:
        return {}
    return {int(i): c.reshape(4, 2).astype(np.float64) for i, c in zip(ids.ravel(), corners) if int(i) in TAG_IDS}


def _quad_centre(q):
    """Intersection of a quadrilateral's diagonals: the image of the square's centre under any homography."""
    p1, p2, p3, p4 = q
    d1, d2 = p3 - p1, p4 - p2
    a = np.array([d1, -d2]).T
    t = np.linalg.solve(a, p2 - p1)[0]
    return p1 + t * d1


def sheet_homography(found):
    """Homography sheet (cell units) -> photo pixels from detected tags (at least 4)."""
    import cv2

    if len(found) < 4:
        raise CropError(f"found {len(found)} of the 16 marker tags; at least 4 must be visible and sharp")
    centres = tag_centres()
    # Tag centres (the diagonals' intersection) do not depend on which corner
    # a detector reports first, so sheets printed in any rotation work.
    src = np.array([centres[i] for i in sorted(found)], np.float64)
    dst = np.array([_quad_centre(found[i]) for i in sorted(found)], np.float64)
    h, inliers = cv2.findHomography(src, dst, cv2.RANSAC if len(found) > 4 else 0, 3.0)
    if h is None:
        raise CropError("the marker tags found do not form a plane; photograph the whole sheet, flat")
    return h


def window_quad(h):
    """The window's corners in the photo (TL, TR, BR, BL), from the sheet homography."""
    lo, hi = WINDOW_CELLS
    sq = np.array([[lo, lo, 1], [hi, lo, 1], [hi, hi, 1], [lo, hi, 1]], np.float64)
    p = sq @ h.T
    return p[:, :2] / p[:, 2:]


# --------------------------------------------------------------------------
# Warping
# --------------------------------------------------------------------------

def order_quad(quad):
    """Four points in any order -> top-left, top-right, bottom-right, bottom-left."""
    q = np.asarray(quad, np.float64).reshape(4, 2)
    c = q.mean(0)
    ang = np.arctan2(q[:, 1] - c[1], q[:, 0] - c[0])
    q = q[np.argsort(ang)]                     # clockwise on screen (y down), starting anywhere
    start = np.argmin(q.sum(1))                # top-left: smallest x + y
    return np.roll(q, -start, axis=0)


def _side(quad):
    q = np.asarray(quad)
    sides = np.linalg.norm(q - np.roll(q, -1, axis=0), axis=1)
    return max(2, int(round(sides.max())))


def warp_quad(image, quad, side=None):
    """Warp the quadrilateral ``quad`` (TL, TR, BR, BL) of ``image`` to a ``side`` x ``side`` square.

    ``side`` defaults to the quad's longest edge (no detail is thrown away).
    Pixel centres map to pixel centres: corner k of the quad is the outer
    corner of the square's corner pixel.
    """
    import cv2

    side = side or _side(quad)
    src = np.asarray(quad, np.float32).reshape(4, 2)
    # Quad corners are continuous positions; OpenCV's pixel centres are integers.
    dst = np.array([[-0.5, -0.5], [side - 0.5, -0.5], [side - 0.5, side - 0.5], [-0.5, side - 0.5]], np.float32)
    m = cv2.getPerspectiveTransform(src, dst)
    return cv2.warpPerspective(np.ascontiguousarray(image, np.float32), m, (side, side),
                               flags=cv2.INTER_AREA if side < _side(quad) / 1.5 else cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_REPLICATE)


def _check_inside(quad, shape, what):
    h, w = shape[:2]
    q = np.asarray(quad)
    if (q[:, 0] < -1).any() or (q[:, 0] > w).any() or (q[:, 1] < -1).any() or (q[:, 1] > h).any():
        raise CropError(f"{what} reaches outside the {w}x{h} photo")
    # Convex, non-degenerate, same winding everywhere.
    def cross(a, b):
        return a[0] * b[1] - a[1] * b[0]

    z = [cross(q[(i + 1) % 4] - q[i], q[(i + 2) % 4] - q[(i + 1) % 4]) for i in range(4)]
    if not (all(v > 0 for v in z) or all(v < 0 for v in z)):
        raise CropError(f"{what} is not a convex quadrilateral")
    if _side(q) < 16:
        raise CropError(f"{what} is smaller than 16 pixels")


# --------------------------------------------------------------------------
# The four modes
# --------------------------------------------------------------------------

def find_highlight(image):
    """Where the flash highlight is: ((x, y) in pixels, strength), or None.

    The photo's luminance, downscaled and blurred over ~3 % of its size; the
    highlight is the centroid of the region within 10 % of the peak, if the
    peak is at least 1.6 times the median (a flash on a matte surface still
    makes one through the 1/d^2 falloff).
    """
    import cv2

    lum = luminance(image)
    h, w = lum.shape
    scale = 256.0 / max(h, w)
    small = cv2.resize(lum, (max(1, round(w * scale)), max(1, round(h * scale))), interpolation=cv2.INTER_AREA)
    small = cv2.GaussianBlur(small, (0, 0), 0.03 * max(small.shape))
    med = float(np.median(small))
    peak = float(small.max())
    if med <= 0 or peak < 1.6 * med:
        return None
    ys, xs = np.nonzero(small >= 0.9 * peak)
    x, y = xs.mean(), ys.mean()
    return (float((x + 0.5) / scale - 0.5), float((y + 0.5) / scale - 0.5)), peak / med


#: A brightness peak counts as the flash's highlight (for the warning that it is near the crop's edge)
#: when it is at least this many times the median: on the 77 henzler_train photos, the matte fabrics'
#: peaks (the flash's falloff, or a lighter patch of the pattern) are 1.6-2.1 times the median, the
#: glossy materials' (wood, leather, paint, metal, stone) 2.9-560 times.
REAL_HIGHLIGHT = 2.5


def auto_crop(image):
    """The largest square of the photo, as close to centred on the flash highlight as it fits.

    Without a clear highlight (diffuse light, flash off) it is the centre
    square.
    """
    h, w = image.shape[:2]
    side = min(h, w)
    hl = find_highlight(image)
    if hl is None:
        cx, cy, anchor, strength = (w - 1) / 2, (h - 1) / 2, "centre", None
    else:
        (cx, cy), strength = hl
        anchor = "highlight"
    x0 = int(round(np.clip(cx + 0.5 - side / 2, 0, w - side)))
    y0 = int(round(np.clip(cy + 0.5 - side / 2, 0, h - side)))
    # Where the highlight lands in the crop, as a fraction of its size from the centre.
    off = None if hl is None else [round((cx + 0.5 - x0) / side - 0.5, 3), round((cy + 0.5 - y0) / side - 0.5, 3)]
    report = {"mode": "auto", "anchor": anchor, "box": [x0, y0, side, side],
              "highlight": None if hl is None else [round(cx, 1), round(cy, 1)],
              "highlight_strength": None if strength is None else round(strength, 2),
              "highlight_offset": off}
    if off is not None and max(abs(v) for v in off) > 0.3 and strength >= REAL_HIGHLIGHT:
        log.warning("the flash highlight is near the edge of the crop (offset %s): hold the phone parallel "
                    "to the surface, or use --corners/--crop markers", off)
    return Crop(np.ascontiguousarray(image[y0:y0 + side, x0:x0 + side]), report)


def marker_crop(image):
    """Rectify the window of a photographed :func:`marker_sheet`."""
    lum = luminance(image)
    gray = (np.clip(lum / max(np.percentile(lum, 99), 1e-6), 0, 1) ** (1 / cv.IMAGE_GAMMA) * 255).astype(np.uint8)
    found = detect_markers(gray)
    try:
        hom = sheet_homography(found)
    except CropError as e:
        raise CropError(f"{e}. Print the sheet with 'svbrdf markers sheet.png', or use --crop auto or --corners") from None
    quad = window_quad(hom)
    _check_inside(quad, image.shape, "the marker window")
    # Reprojection error of the tag centres, in pixels: how well the sheet fits one plane.
    centres = tag_centres()
    src = np.array([[*centres[i], 1.0] for i in sorted(found)])
    pred = src @ hom.T
    pred = pred[:, :2] / pred[:, 2:]
    obs = np.array([_quad_centre(found[i]) for i in sorted(found)])
    err = float(np.sqrt(((pred - obs) ** 2).sum(1)).max())
    return Crop(warp_quad(image, quad), {"mode": "markers", "tags": sorted(found), "quad": np.round(quad, 2).tolist(),
                                         "max_tag_error_px": round(err, 3)})


def quad_crop(image, corners):
    """Warp a hand-given quadrilateral (4 corners, any order) to a square."""
    quad = order_quad(corners)
    _check_inside(quad, image.shape, "the --corners quadrilateral")
    return Crop(warp_quad(image, quad), {"mode": "corners", "quad": np.round(quad, 2).tolist()})


def no_crop(image):
    """The photo as it is; a non-square photo is centre-cropped to a square (with a warning)."""
    h, w = image.shape[:2]
    side = min(h, w)
    if h != w:
        log.warning("--crop none on a %dx%d photo: centre-cropping to %dx%d (the maps are square)", w, h, side, side)
    x0, y0 = (w - side) // 2, (h - side) // 2
    return Crop(np.ascontiguousarray(image[y0:y0 + side, x0:x0 + side]),
                {"mode": "none", "box": [x0, y0, side, side]})


CROP_MODES = ("auto", "markers", "none")


def crop(image, mode="auto", corners=None):
    """Dispatch: ``corners`` (8 numbers or 4 points) wins over ``mode``."""
    if corners is not None:
        return quad_crop(image, corners)
    if mode == "auto":
        return auto_crop(image)
    if mode == "markers":
        return marker_crop(image)
    if mode == "none":
        return no_crop(image)
    raise ValueError(f"unknown crop mode {mode!r}; choose one of {', '.join(CROP_MODES)}")
