"""Crop and rectify: the marker sheet, a synthetic perspective photo of it, manual quads, auto crop."""

import numpy as np
import pytest

from svbrdf_cli.rectify import crops as rectify

CELL = 64


def _textured_sheet(seed=0):
    """The sheet with a blurred random texture in its window (linear RGB)."""
    import cv2

    sheet = rectify.marker_sheet(CELL, label=False).astype(np.float32) / 255
    lo, hi = (c * CELL for c in rectify.WINDOW_CELLS)
    tex = np.random.default_rng(seed).uniform(0.1, 0.9, (hi - lo, hi - lo)).astype(np.float32)
    sheet[lo:hi, lo:hi] = cv2.GaussianBlur(tex, (0, 0), 2)
    return np.repeat(sheet[..., None], 3, -1)


def _photograph(sheet, dst, size=(1400, 1100), gain=0.4, noise=0.0, seed=0):
    """Warp the sheet so its outer corners land on ``dst``; returns (photo, homography sheet px -> photo px)."""
    import cv2

    s = sheet.shape[0]
    src = np.float32([[0, 0], [s, 0], [s, s], [0, s]]) - 0.5   # outer pixel edges, in pixel-centre coordinates
    m = cv2.getPerspectiveTransform(src, np.float32(dst))
    photo = cv2.warpPerspective(sheet, m, size, flags=cv2.INTER_LINEAR, borderValue=(0.3, 0.3, 0.3)) * gain
    if noise:
        photo = photo + np.random.default_rng(seed).normal(0, noise, photo.shape).astype(np.float32)
    return np.clip(photo, 0, 1).astype(np.float32), m


def _true_window(m):
    import cv2

    lo, hi = (c * CELL - 0.5 for c in rectify.WINDOW_CELLS)
    return cv2.perspectiveTransform(np.float32([[[lo, lo], [hi, lo], [hi, hi], [lo, hi]]]), m)[0]


@pytest.mark.parametrize("dst,noise", [
    ([[300, 200], [1150, 260], [1100, 950], [250, 900]], 0.0),        # mild keystone
    ([[200, 150], [1250, 80], [1300, 1000], [150, 900]], 0.01),       # strong tilt, noisy
    ([[1100, 200], [1150, 1000], [300, 950], [250, 150]], 0.0),       # sheet rotated 90 degrees
])
def test_marker_rectification_error_below_two_pixels(dst, noise):
    photo, m = _photograph(_textured_sheet(), dst, noise=noise)
    c = rectify.marker_crop(photo)
    assert len(c.report["tags"]) >= 12
    quad = np.array(c.report["quad"])
    # The detected window corners against the true ones (in any starting order for a rotated sheet).
    true = _true_window(m)
    err = min(np.abs(np.roll(quad, k, axis=0) - true).max() for k in range(4))
    assert err < 2.0, err
    # The rectified window looks like the texture that was printed in it.
    lo, hi = (c * CELL for c in rectify.WINDOW_CELLS)
    side = c.image.shape[0]
    assert c.image.shape == (side, side, 3) and side > 100


def test_marker_rectified_pixels_match_the_sheet():
    import cv2

    sheet = _textured_sheet(seed=3)
    photo, m = _photograph(sheet, [[300, 200], [1150, 260], [1100, 950], [250, 900]], gain=1.0)
    c = rectify.marker_crop(photo)
    lo, hi = (k * CELL for k in rectify.WINDOW_CELLS)
    ref = cv2.resize(sheet[lo:hi, lo:hi], c.image.shape[:2][::-1], interpolation=cv2.INTER_AREA)
    inner = slice(8, -8)
    assert np.abs(c.image[inner, inner] - ref[inner, inner]).mean() < 0.03


def test_too_few_markers_is_a_clear_error():
    photo = np.full((600, 800, 3), 0.4, np.float32)
    with pytest.raises(rectify.CropError, match="marker tags"):
        rectify.marker_crop(photo)


def test_the_shared_printed_sheet_is_recognised(shared_data):
    """The marker sheet in ../shared (a print of the same layout) rectifies too."""
    import cv2

    path = shared_data / "markers" / "apriltag_tag36h11_print.png"
    sheet = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE).astype(np.float32) / 255
    s = sheet.shape[0]
    photo, m = _photograph(np.repeat(sheet[..., None], 3, -1), [[300, 200], [1150, 260], [1100, 950], [250, 900]])
    c = rectify.marker_crop(photo)
    u = s / rectify.SHEET_CELLS
    lo, hi = (k * u - 0.5 for k in rectify.WINDOW_CELLS)
    true = cv2.perspectiveTransform(np.float32([[[lo, lo], [hi, lo], [hi, hi], [lo, hi]]]), m)[0]
    assert np.abs(np.array(c.report["quad"]) - true).max() < 2.0


def test_manual_corners_any_order():
    img = np.zeros((200, 300, 3), np.float32)
    img[50:150, 100:200] = 1.0
    quad = [(199.5, 149.5), (99.5, 49.5), (199.5, 49.5), (99.5, 149.5)]  # shuffled
    c = rectify.quad_crop(img, quad)
    assert c.report["quad"][0] == [99.5, 49.5]
    assert c.image.shape == (100, 100, 3)
    assert c.image[2:-2, 2:-2].min() > 0.99


@pytest.mark.parametrize("quad,match", [
    ([(0, 0), (500, 0), (500, 500), (0, 500)], "outside"),
    ([(10, 10), (20, 10), (20, 20), (10, 20)], "smaller"),
])
def test_bad_manual_corners(quad, match):
    with pytest.raises(rectify.CropError, match=match):
        rectify.quad_crop(np.zeros((200, 300, 3), np.float32), quad)


def _flash(h, w, cx, cy):
    y, x = np.mgrid[0:h, 0:w]
    lum = 0.1 + 0.8 * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * (0.05 * w) ** 2))
    return np.repeat(lum[..., None], 3, -1).astype(np.float32)


def test_auto_crop_is_the_largest_square_around_the_highlight():
    c = rectify.auto_crop(_flash(600, 900, 600, 300))
    x0, y0, side, _ = c.report["box"]
    assert c.report["anchor"] == "highlight" and side == 600 and y0 == 0
    assert abs(x0 + side / 2 - 600) < 6           # centred on the highlight
    c = rectify.auto_crop(_flash(600, 900, 850, 300))   # too close to the edge: slides as far as it can
    assert c.report["box"][0] == 300


def test_auto_crop_without_highlight_is_the_centre():
    c = rectify.auto_crop(np.full((400, 700, 3), 0.3, np.float32))
    assert c.report["anchor"] == "centre" and c.report["box"] == [150, 0, 400, 400]
