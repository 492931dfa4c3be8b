"""The image operations every stage uses: luminance, resizing, blurs, push-pull fills, rings.

Images are numpy arrays, (H, W) or (H, W, C), float32 unless a function says otherwise; none of
these functions cares about the colour space (the caller's linear or encoded values go through
as they are).
"""

from __future__ import annotations

import numpy as np

from svbrdf_cli import conventions as cv

#: The Rec. 709 luminance weights (:data:`svbrdf_cli.conventions.LUMA`) as float32, for gradients.
LUMA32 = np.asarray(cv.LUMA, np.float32)


def luminance(image, dtype=np.float32):
    """Luminance of an RGB image.

    Args:
        image: (..., 3) array, linear or encoded (the weights are the same, the meaning differs).
        dtype: the weights' dtype: float32 (the runtime's) or float64 (with a float64 image: a
            float64 result from float64 weights).

    Returns:
        (...) array: ``image @ LUMA``.
    """
    return image @ (LUMA32 if dtype == np.float32 else np.asarray(cv.LUMA, dtype))


def resize(image, side, up="cubic"):
    """A square image to ``side`` x ``side``: area filter down, bicubic (``up="cubic"``) or bilinear
    (``up="linear"``) up.

    Args:
        image: (H, W) or (H, W, C) array (float32 or float64, any range).
        side: the output side in pixels.
        up: "cubic" or "linear", the filter when enlarging.

    Returns:
        ``image`` itself when it already has that size, else (side, side, C) (C = 1 for a 2-D
        image), of ``image``'s dtype.
    """
    import cv2

    if image.shape[0] == side and image.shape[1] == side:
        return image
    interp = cv2.INTER_AREA if side < image.shape[0] else {"cubic": cv2.INTER_CUBIC, "linear": cv2.INTER_LINEAR}[up]
    out = cv2.resize(np.ascontiguousarray(image), (side, side), interpolation=interp)
    return out[..., None] if out.ndim == 2 else out


def resize_to(image, shape):
    """(h, w, C) ``image`` bilinearly resized to ``shape`` = (H, W); returns (H, W, C)."""
    import cv2

    return cv2.resize(image, (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR).reshape(*shape, image.shape[-1])


def shrink_to(image, shape):
    """(h, w, C) ``image`` area-filtered down to ``shape`` = (H, W) (H <= h, W <= w); returns (H, W, C)."""
    import cv2

    return cv2.resize(image, (shape[1], shape[0]), interpolation=cv2.INTER_AREA).reshape(*shape, image.shape[-1])


def shrink_longest(image, size):
    """(h, w, C) ``image`` area-filtered so that its longer side is ``size`` (aspect kept); as it is when
    ``size`` is None or the image is no larger."""
    h, w = image.shape[:2]
    if not size or max(h, w) <= size:
        return image
    s = size / max(h, w)
    return shrink_to(image, (max(1, round(h * s)), max(1, round(w * s))))


def blur(image, sigma):
    """Gaussian blur of standard deviation ``sigma`` pixels, reflecting at the borders.

    Args:
        image: (H, W) or (H, W, C) array; taken as float32.
        sigma: the standard deviation in pixels.

    Returns:
        float32 array; (H, W) for an (H, W, 1) input (OpenCV drops a single channel).
    """
    import cv2

    return cv2.GaussianBlur(np.ascontiguousarray(image, np.float32), (0, 0), float(sigma),
                            borderType=cv2.BORDER_REFLECT)


def box(image, r):
    """Mean over (2r+1)^2 windows, reflecting at the borders.

    Args:
        image: (H, W, C) float32 array.
        r: the window's radius in pixels.

    Returns:
        (H, W, C) float32.
    """
    import cv2

    return cv2.boxFilter(image, -1, (2 * r + 1, 2 * r + 1), borderType=cv2.BORDER_REFLECT).reshape(image.shape)


def push_pull(values, weights, confident=1.0, until_covered=False, fallback=0.0):
    """Weighted push-pull of ``values`` by ``weights``.

    Weighted averages on a pyramid of halvings (INTER_AREA), then back up: each level keeps its own
    weighted average in proportion to its weight (fully from ``confident``) and takes the coarser
    level's elsewhere. A pixel with weight keeps its local average; one without takes the nearest
    weighted region's, smoothly.

    Args:
        values: (H, W) or (H, W, C) array.
        weights: (H, W) array in [0, 1].
        confident: the weight from which a level keeps only its own average.
        until_covered: stop the halving once every pixel of a level has some weight (a fill);
            otherwise go down to one pixel (a spread).
        fallback: the value where even the coarsest level has no weight.

    Returns:
        float32 array of ``values``' shape.
    """
    import cv2

    channels = values.ndim == 3

    def per_pixel(d):
        return d[..., None] if channels else d

    num = np.ascontiguousarray(values * per_pixel(weights), np.float32)
    den = np.ascontiguousarray(weights, np.float32)
    pyramid = [(num, den)]
    while min(den.shape) > (2 if until_covered else 1) and (not until_covered or float(den.min()) <= 0.0):
        h, w = den.shape
        size = (max(1, w // 2), max(1, h // 2))
        num = cv2.resize(num, size, interpolation=cv2.INTER_AREA).reshape(size[1], size[0], *values.shape[2:])
        den = cv2.resize(den, size, interpolation=cv2.INTER_AREA)
        pyramid.append((num, den))
    num, den = pyramid[-1]
    out = np.where(per_pixel(den) > 0, num / np.maximum(per_pixel(den), 1e-12), fallback)
    for num, den in reversed(pyramid[:-1]):
        h, w = den.shape
        up = cv2.resize(np.ascontiguousarray(out, np.float32), (w, h), interpolation=cv2.INTER_LINEAR).reshape(num.shape)
        c = np.clip(den / confident, 0.0, 1.0)
        own = np.divide(c, den, out=np.zeros_like(den), where=den > 0)  # 1 where fully confident
        out = num * per_pixel(own) + per_pixel(1.0 - c) * up  # c x its own average + (1 - c) x the coarser
    return out


def fill_from_surroundings(x, mask, detail=None):
    """Pixels of ``mask`` replaced from their surroundings by push-pull.

    A smooth fill (:func:`push_pull` of the unmasked pixels), without the radial streaks of
    boundary-marching inpainting; the mask's one-pixel halo is replaced too.

    Args:
        x: (H, W, C) array.
        mask: (H, W) bool, the pixels to replace.
        detail: (H, W) factor multiplying the fill (the photo's own relative texture), or None.

    Returns:
        (H, W, C) float32 (``x`` itself when nothing is masked).
    """
    import cv2

    if not mask.any():
        return x
    m = cv2.dilate(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)  # the halo goes too
    keep = (~m).astype(np.float32)
    if not keep.any():
        return x
    x = np.asarray(x, np.float32)
    fill = push_pull(x, keep, until_covered=True, fallback=x[~m].mean(0))
    if detail is not None:
        fill = fill * detail[..., None]
    return np.where(m[..., None], fill, x).astype(np.float32)


def rings(rho, count):
    """Equal-width rings of the distances ``rho`` out to their maximum.

    Args:
        rho: (H, W) distances (to the flash's foot).
        count: the number of rings.

    Returns:
        (ring index of each pixel, flattened, int; ring centres, (count,) float64).
    """
    edges = np.linspace(0.0, float(rho.max()) + 1e-6, count + 1)
    return np.clip(np.digitize(rho.ravel(), edges) - 1, 0, count - 1), 0.5 * (edges[:-1] + edges[1:])


def _log_colour(diffuse_lin):
    """(H*W, 3) float32 log of the linear colour (floored at 1e-3): the k-means features' start."""
    return np.log(np.maximum(diffuse_lin, 1e-3)).reshape(-1, 3).astype(np.float32)


def _seeded_kmeans(features, k, every, attempts):
    """(k, C) k-means centres of every ``every``-th row of ``features`` (``attempts`` restarts, k-means++,
    OpenCV's generator seeded so the same image gives the same classes)."""
    import cv2

    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 20, 1e-3)
    cv2.setRNGSeed(0)
    return cv2.kmeans(features[::every], k, None, crit, attempts, cv2.KMEANS_PP_CENTERS)[2]


def chroma_classes(diffuse_lin, k, apart, every=7, attempts=2, share_apart=0.0):
    """(H*W,) int class of each pixel of the linear ``diffuse_lin`` by its chromaticity alone (its log colour
    less the mean of its three channels, which a change of brightness leaves as it is): k-means (on every
    ``every``-th pixel, ``attempts`` restarts, seeded), a centre joining an earlier one's class when it is
    closer than ``apart`` (log units) or when its channels' shares of their sum differ from that one's by
    less than ``share_apart`` (a near-black channel is far apart in log units and near in share: a red
    whose blue is 0.003 or 0.006 is one colour); None when that leaves one class."""
    f = _log_colour(diffuse_lin)
    f -= f.mean(1, keepdims=True)
    centres = _seeded_kmeans(f, k, every, attempts)
    shares = np.exp(centres) / np.exp(centres).sum(1, keepdims=True)
    joined = np.arange(k)
    for i in range(1, k):
        near = np.flatnonzero((np.linalg.norm(centres[:i] - centres[i], axis=1) < apart)
                              | (np.abs(shares[:i] - shares[i]).max(1) < share_apart))
        if near.size:
            joined[i] = joined[near[0]]
    nearest = ((f[:, None, :] - centres[None]) ** 2).sum(-1).argmin(1)
    kept, classes = np.unique(joined[nearest], return_inverse=True)
    return classes if kept.size > 1 else None


def soft_classes(diffuse_lin, k, every=7, attempts=2):
    """(H*W, k) soft assignment of each pixel of the linear ``diffuse_lin`` to ``k`` classes of its log
    colour: k-means (on every ``every``-th pixel, ``attempts`` restarts, seeded), each pixel weighted by
    its squared distances to the centres over the median distance to the second nearest."""
    f = _log_colour(diffuse_lin)
    f = (f - f.mean(0)) / (float(f.std()) + 1e-6)
    centres = _seeded_kmeans(f, k, every, attempts)
    d2 = ((f[:, None, :] - centres[None]) ** 2).sum(-1)
    p = np.exp(-(d2 - d2.min(1, keepdims=True)) / max(float(np.median(np.sort(d2, 1)[:, 1])), 1e-4))
    return p / p.sum(1, keepdims=True)
