"""Seamless maps (``svbrdf capture --tileable``): offset-and-blend, one axis at a time, the same on every map.

Along each axis in turn (columns, then rows), every map is cross-faded with a copy of itself rolled
by ``c`` lines along that axis. The weight of the original depends only on the position along that
axis: 1 in the middle, falling smoothly to 0 over a band of :data:`BAND` of the size at both ends,
where the rolled copy takes over. The rolled copy is continuous across the wrap (its first and last
lines are neighbouring lines of the original), and its own discontinuity (the original's border)
sits at line ``n - c``, which is kept inside the middle, where only the original shows. After the
columns' pass the maps wrap left to right; the rows' pass rolls along the rows only, so that stays
true, and the maps then wrap top to bottom as well. No line of a 2 x 2 tiling shows a step the
photo does not have, at the edges or inside.

* **A regular pattern is cut to whole repeats first**: where the diffuse luminance's detail repeats
  along an axis (its autocorrelation has a clear peak at a period ``p`` of at least
  :data:`MIN_REPEATS` repeats, ``docs/capture.md``), the maps are cut, round the centre, to the
  length of the whole number of periods that fits (read off the autocorrelation at that length, so
  the error does not add up) and resized back, a stretch of less than one period (normals tilted
  accordingly). Otherwise two copies cannot be in step at both ends at once, and the grout lines
  inside one band are doubled.
* **The shift** ``c`` is the one, within the allowed range, at which the diffuse map's luminance
  best matches itself (the circular autocorrelation's maximum, one FFT): a regular pattern (tiles,
  a weave) is blended with itself in step, so its grout lines are not doubled; a stochastic
  material (leather, wood, plaster) has no preferred shift and any is as good.
* **The blend keeps the texture's contrast**: two unrelated textures averaged half and half have
  0.71 of their contrast, a washed-out band. Each map's fine detail (what a blur of
  :data:`DETAIL_SIGMA` of its size leaves) is blended with weights normalised to keep its
  variance, given the correlation of the two copies' detail (1 for a pattern in step: a plain
  blend); the coarse part is blended plainly.

Normals are blended as vectors and renormalised; every map uses the same weights and shifts, so the
maps stay consistent (the engine presets' height map is then integrated periodically).
"""

from __future__ import annotations

import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli.imageops import luminance

#: Width of the cross-fade band at each end of an axis, as a fraction of the map's size.
BAND = 0.25
#: A repeat along an axis counts when the detail's autocorrelation at its period is at least this
#: (1 = identical) and rises by at least PERIOD_RISE above its lowest value at a shorter lag (a grain
#: along the axis keeps the autocorrelation high at every lag: no period).
PERIOD_CORRELATION, PERIOD_RISE = 0.4, 0.3
#: Patterns with fewer repeats than this across the map are not cut (the cut would lose too much).
MIN_REPEATS = 3
#: The detail whose contrast the blend keeps: the map less a blur of this fraction of its size.
DETAIL_SIGMA = 1.0 / 48.0


def ramp(n, band=BAND):
    """(n,) weight of the original along one axis: 1 in the middle, smoothly to 0 over ``band`` at each end."""
    d = np.minimum(np.arange(n) + 0.5, n - np.arange(n) - 0.5) / max(band * n, 1.0)
    return cv.smoothstep(d, 0.0, 1.0).astype(np.float32)


def weights(h, w, band=BAND):
    """(H, W) share of the original pixel in the result (both passes): 1 inside, 0 at every border."""
    return np.multiply.outer(ramp(h, band), ramp(w, band)).astype(np.float32)


def best_shift(lum, axis, band=BAND):
    """The roll along ``axis`` at which ``lum`` best matches itself, among those that keep the rolled
    copy's discontinuity (at ``n - shift``) where the original's weight is 1."""
    n = lum.shape[axis]
    corr = _autocorrelation(lum, axis)  # corr[c]: how well lum matches itself rolled by c
    lo, hi = int(np.ceil(band * n)) + 1, n - int(np.ceil(band * n)) - 1
    if hi <= lo:
        return n // 2
    return lo + int(np.argmax(corr[lo:hi + 1]))


def _autocorrelation(x, axis, circular=True):
    """(n,) normalised autocorrelation of the (H, W) ``x`` along ``axis`` (summed over the other):
    circular (of ``x`` rolled), or of ``x`` slid over itself, per overlapping pixel."""
    x = np.asarray(x, np.float64)
    x = x - x.mean()
    n = x.shape[axis]
    m = n if circular else 2 * n
    f = np.fft.rfft(x, n=m, axis=axis)
    corr = np.fft.irfft(f * np.conj(f), n=m, axis=axis).sum(axis=1 - axis)[:n]
    if not circular:
        corr = corr * n / (n - np.arange(n))
    return corr / max(float(corr[0]), 1e-20)


def repeat_length(lum, axis):
    """The length, along ``axis``, of the whole number of repeats of a regular pattern in the (H, W)
    ``lum`` that fits its size, or None for a pattern that does not repeat (see the module docstring)."""
    n = lum.shape[axis]
    x = np.asarray(lum, np.float64)
    detail = x - _blur_wrap(x[..., None], DETAIL_SIGMA * max(x.shape))[..., 0]
    r = _autocorrelation(detail, axis, circular=False)
    lo, hi = max(2, n // 64), n // MIN_REPEATS
    if hi <= lo + 2:
        return None
    lowest = np.minimum.accumulate(r[:hi + 1])
    peaks = [p for p in range(lo, hi) if r[p] >= r[p - 1] and r[p] >= r[p + 1]
             and r[p] >= PERIOD_CORRELATION and r[p] - lowest[p] >= PERIOD_RISE]
    if not peaks:
        return None
    p = max(peaks, key=lambda q: r[q])
    k = n // p
    # the k-th repeat, read where the autocorrelation peaks near k p (an error in p does not add up)
    a, b = max(p, k * p - k), min(n - 1, k * p + k)
    return a + int(np.argmax(r[a:b + 1]))


def whole_repeats(maps, lum):
    """Cut ``maps`` round their centre to whole repeats of their pattern along each axis and resize
    them back (see the module docstring); returns (maps, (rows, columns) kept)."""
    from svbrdf_cli.imageops import resize_to

    h, w = lum.shape
    ly = repeat_length(lum, 0) or h
    lx = repeat_length(lum, 1) or w
    if (ly, lx) == (h, w):
        return maps, (h, w)
    y0, x0 = (h - ly) // 2, (w - lx) // 2
    out = {}
    for k, v in maps.items():
        cut = np.ascontiguousarray(np.asarray(v, np.float32)[y0:y0 + ly, x0:x0 + lx])
        big = resize_to(cut, (h, w))
        if k == "normal":  # the surface stretched by w / lx and h / ly: its slopes shrink by as much
            big = cv.normalize(big * np.float32([lx / w, ly / h, 1.0])).astype(np.float32)
        out[k] = big
    return out, (ly, lx)


def _blur_wrap(x, sigma):
    """Gaussian blur of an (H, W, C) array, wrapping at the borders (in the frequency domain)."""
    h, w = x.shape[:2]
    fy, fx = np.fft.fftfreq(h)[:, None], np.fft.rfftfreq(w)[None, :]
    g = np.exp(-2.0 * (np.pi * sigma) ** 2 * (fy * fy + fx * fx))
    return np.fft.irfft2(np.fft.rfft2(x, axes=(0, 1)) * g[..., None], s=(h, w), axes=(0, 1))


def _blend_axis(v, shift, axis, band):
    """One pass: ``v`` (H, W, C) cross-faded along ``axis`` with itself rolled by ``shift``."""
    n = v.shape[axis]
    a = ramp(n, band).astype(np.float64)
    a = a[:, None, None] if axis == 0 else a[None, :, None]
    x = np.asarray(v, np.float64)
    s = np.roll(x, -shift, axis=axis)  # s[i] = x[i + shift]
    coarse = _blur_wrap(x, DETAIL_SIGMA * max(x.shape[:2]))
    cs = np.roll(coarse, -shift, axis=axis)
    dx, ds = x - coarse, s - cs
    var = float((dx * dx).sum())
    rho = float((dx * ds).sum()) / var if var > 1e-12 else 1.0  # (the two copies have the same variance)
    rho = min(max(rho, 0.0), 1.0)
    norm = np.sqrt(a * a + (1.0 - a) ** 2 + 2.0 * a * (1.0 - a) * rho)
    return a * coarse + (1.0 - a) * cs + (a * dx + (1.0 - a) * ds) / norm


def make_tileable(maps, band=BAND, report=None):
    """Linear maps (HWC) -> the same maps, seamless when tiled (see the module docstring). ``report``,
    a dict, receives what was done: the shifts and, for a regular pattern, the part kept."""
    h, w = next(iter(maps.values())).shape[:2]
    lum = luminance(np.asarray(maps["diffuse"], np.float64), np.float64) if "diffuse" in maps else np.zeros((h, w))
    maps, kept = whole_repeats(maps, lum)
    if kept != (h, w):
        lum = luminance(np.asarray(maps["diffuse"], np.float64), np.float64)
    cx = best_shift(lum, 1, band)
    cy = best_shift(_blend_axis(lum[..., None], cx, 1, band)[..., 0], 0, band)
    if report is not None:
        report.update({"method": "offset and blend, columns then rows", "band": band, "shift": [int(cy), int(cx)],
                       "whole_repeats": None if kept == (h, w) else {"rows": int(kept[0]), "columns": int(kept[1])}})
    out = {}
    for k, v in maps.items():
        x = _blend_axis(_blend_axis(np.asarray(v, np.float64), cx, 1, band), cy, 0, band)
        if k == "normal":
            out[k] = cv.normalize(x).astype(np.float32)
        else:
            lo, hi = float(np.min(v)), float(np.max(v))  # a blend stays within the map's own range
            out[k] = np.clip(x, lo, hi).astype(np.float32)
    return out


def wrap_ratio(img):
    """Mean absolute difference across the wrap (last column against the first, last row against the
    first) over the mean difference between neighbouring interior columns and rows: about 1 for a
    seamless map."""
    x = np.asarray(img, np.float64)
    wrap = (np.abs(x[:, -1] - x[:, 0]).mean() + np.abs(x[-1] - x[0]).mean()) / 2
    inner = (np.abs(np.diff(x, axis=1)).mean() + np.abs(np.diff(x, axis=0)).mean()) / 2
    return float(wrap / max(inner, 1e-12))


def line_steps(img, axis):
    """(2n - 1,) how much a 2 x 2 tiling of ``img`` changes from each line to the next along ``axis``
    (0: row to row): the absolute mean change over the line, averaged over channels. A seam is a line
    whose whole length steps the same way: it stands out here while texture averages away."""
    x = np.asarray(img, np.float64)
    x = x[..., None] if x.ndim == 2 else x
    t = np.tile(x, (2, 2, 1))
    return np.abs(np.diff(t, axis=axis).mean(axis=1 - axis)).mean(-1)

