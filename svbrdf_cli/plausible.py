"""Results that cannot be right stop the file with an error naming it, instead of becoming a set.

A damaged file can decode to pixels that pass every decoder (a grey fill where data was missing, a
near-black frame) and a fit or a network then turns them into a confident, constant texture set.
These checks look at what the pipeline made of the photo:

* :func:`check_exposure`: the automatic exposure at its limit (a photo so dark or so bright that no
  gain within :data:`EXPOSURE_LIMIT` stops brings it to the networks' level);
* :func:`check_noise`: a photo that is mostly noise as large as its light (misplaced data);
* :func:`check_crop`: a crop that is perfectly uniform while the photo is not (what a decoder's fill
  of missing data looks like; a real photo's noise never is);
* :func:`check_maps`: maps constant over the whole set, or a black diffuse map, from a photo that is
  neither constant nor black; a fitted value (the physical estimate's ``found``) that is not finite
  or out of its range.
"""

from __future__ import annotations

import math

import numpy as np

from svbrdf_cli.errors import SvbrdfError

#: The automatic exposure searches within ± this many stops (:func:`svbrdf_cli.pipeline.auto_exposure_gain`).
EXPOSURE_LIMIT = 12.0
#: Standard deviation under which an image (0-1 units) counts as constant: under a 16-bit step.
CONSTANT = 1.0 / 65535.0
#: The physical estimate's fit gain (fraction of the flat profile's residual explained) lies in
#: [0, 1]; this much either side is rounding.
FIT_GAIN_SLACK = 1e-3


class ImplausibleError(SvbrdfError):
    """A photo's result that cannot be right."""


def _std(a, most=65536):
    flat = np.asarray(a, np.float32).reshape(-1, a.shape[-1] if a.ndim == 3 else 1)
    flat = flat[:: max(1, len(flat) // most)].astype(np.float64)  # (float32 sums make a constant's std 1e-5)
    return float(flat.std(0).max()) if len(flat) else 0.0


def check_exposure(path, gain_ev):
    if not math.isfinite(gain_ev) or abs(gain_ev) >= EXPOSURE_LIMIT - 0.05:
        dark = not math.isfinite(gain_ev) or gain_ev > 0
        raise ImplausibleError(
            f"Could not expose '{path}': the photo is {'almost black' if dark else 'almost white'} where it is "
            f"cropped (it would need {'more' if dark else 'less'} than {'+' if dark else '-'}{EXPOSURE_LIMIT:g} "
            "stops); the file may be damaged. Take or copy it again.")


def check_crop(path, photo, crop):
    if _std(crop) <= CONSTANT < _std(photo):
        raise ImplausibleError(f"Could not use '{path}': the cropped region is perfectly uniform while the photo "
                               "is not (what a decoder's fill of missing data looks like); the file may be damaged. "
                               "Copy or export it again.")


#: Noise test (:func:`check_noise`): blocks per side, the neighbour correlation under which a block
#: is noise, and the spread (standard deviation over mean) over which that noise is no sensor's.
NOISE_BLOCKS, NOISE_CORRELATION, NOISE_SPREAD = 8, 0.2, 0.25


def check_noise(path, linear, side=1024):
    """Refuse a photo that is mostly noise of the photo's own amplitude: in more than half of an
    8 x 8 grid of blocks (of its central ``side`` x ``side`` pixels at most), neighbouring pixels are
    unrelated (correlation under :data:`NOISE_CORRELATION`) while varying by more than
    :data:`NOISE_SPREAD` of the block's mean. What a damaged file's misplaced data decodes to; a
    real photo's sensor noise is far smaller than its light."""
    h, w = linear.shape[:2]
    y0, x0 = max(0, (h - side) // 2), max(0, (w - side) // 2)
    lum = np.asarray(linear[y0:y0 + side, x0:x0 + side], np.float32).mean(-1)
    bh, bw = lum.shape[0] // NOISE_BLOCKS, lum.shape[1] // NOISE_BLOCKS
    if bh < 4 or bw < 4:
        return
    noisy = 0
    for by in range(NOISE_BLOCKS):
        for bx in range(NOISE_BLOCKS):
            b = lum[by * bh:(by + 1) * bh, bx * bw:(bx + 1) * bw].astype(np.float64)
            mean, std = float(b.mean()), float(b.std())
            if std <= NOISE_SPREAD * max(mean, 1e-6):
                continue
            a, c = b[:, :-1].ravel() - b.mean(), b[:, 1:].ravel() - b.mean()
            d, e = b[:-1].ravel() - b.mean(), b[1:].ravel() - b.mean()
            corr = max(float(a @ c) / max(float(np.sqrt((a @ a) * (c @ c))), 1e-20),
                       float(d @ e) / max(float(np.sqrt((d @ d) * (e @ e))), 1e-20))
            noisy += corr < NOISE_CORRELATION
    if noisy > NOISE_BLOCKS ** 2 // 2:
        raise ImplausibleError(f"Could not use '{path}': {noisy} of its {NOISE_BLOCKS ** 2} regions are noise, not "
                               "a picture (neighbouring pixels are unrelated); the file is damaged. Copy or export "
                               "it again.")


def check_maps(path, photo, stored, found=None):
    """``photo``: the encoded network input; ``stored``: the maps as written; ``found``: the physical
    estimate's fitted values, if it ran."""
    for key in ("fit_gain", "flash_height", "roughness", "flash_intensity"):
        v = (found or {}).get(key)
        if isinstance(v, (int, float)) and not math.isfinite(v):
            raise ImplausibleError(f"Could not fit '{path}': the fitted {key.replace('_', ' ')} is {v}; the "
                                   "photo cannot be right. Take or copy it again.")
    g = (found or {}).get("fit_gain")
    if isinstance(g, (int, float)) and not -FIT_GAIN_SLACK <= g <= 1 + FIT_GAIN_SLACK:
        raise ImplausibleError(f"Could not fit '{path}': the fit's gain is {g:g}, outside [0, 1]; the photo cannot "
                               "be right. Take or copy it again.")
    if _std(photo) <= CONSTANT or float(np.max(photo)) <= 0:
        return  # a constant photo may give constant maps
    if all(_std(v) <= CONSTANT for v in stored.values()):
        raise ImplausibleError(f"Could not use '{path}': every map came out constant from a photo that is not; "
                               "the file may be damaged. Take or copy it again.")
    if float(np.max(stored["diffuse"])) <= 1.0 / 255.0:
        raise ImplausibleError(f"Could not use '{path}': the diffuse map came out black everywhere; the photo "
                               "may be damaged or far too dark. Take or copy it again.")
