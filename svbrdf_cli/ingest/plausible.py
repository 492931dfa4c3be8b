"""Results that cannot be right stop the file with an error naming it, instead of becoming a set.

A damaged file can decode to pixels that pass every decoder (a grey fill where data was missing, a
near-black frame) and a fit or a network then turns them into a confident, constant texture set.
These checks look at what the pipeline made of the photo:

* :func:`check_exposure`: the automatic exposure at its limit (a photo so dark or so bright that no
  gain within :data:`EXPOSURE_LIMIT` stops brings it to the networks' level);
* :func:`check_crop`: a crop that is perfectly uniform while the photo is not (what a decoder's fill
  of missing data looks like; a real photo's noise never is);
* :func:`check_maps`: maps constant over the whole set, or a black diffuse map, from a photo that is
  neither constant nor black; a fitted value (the physical estimate's ``found``) that is not finite
  out of its range (the gain checked on photos that are not uniform).
"""

from __future__ import annotations

import math

import numpy as np

from svbrdf_cli.errors import SvbrdfError

#: The automatic exposure searches within ± this many stops (:func:`svbrdf_cli.run.pipeline.auto_exposure_gain`).
EXPOSURE_LIMIT = 12.0
#: Standard deviation under which an image (0-1 units) counts as constant: under a 16-bit step.
CONSTANT = 1.0 / 65535.0
#: The physical estimate's fit gain (1 - the fit's residual / the flat profile's) is at most 1 (this
#: much over is rounding). It is negative where the flash's falloff explains a photo worse than no
#: falloff (a synthetic marker sheet lit evenly: -100); under FIT_GAIN_LOWEST the fit is no answer.
FIT_GAIN_SLACK, FIT_GAIN_LOWEST = 1e-3, -1e3
#: A photo whose brightness varies by less than this fraction of its mean is uniform (its fit's gain
#: is undefined: the flat profile's residual is ~0).
UNIFORM = 0.01


class ImplausibleError(SvbrdfError):
    """A photo's result that cannot be right."""


def _std(a, most=65536):
    flat = np.asarray(a, np.float32).reshape(-1, a.shape[-1] if a.ndim == 3 else 1)
    flat = flat[:: max(1, len(flat) // most)].astype(np.float64)  # (float32 sums make a constant's std 1e-5)
    return float(flat.std(0).max()) if len(flat) else 0.0


def check_exposure(path, gain_ev):
    """Refuse a photo the auto exposure had to push to its limit (``gain_ev`` stops): black or white where cropped."""
    if not math.isfinite(gain_ev) or abs(gain_ev) >= EXPOSURE_LIMIT - 0.05:
        dark = not math.isfinite(gain_ev) or gain_ev > 0
        raise ImplausibleError(
            f"Could not expose '{path}': the photo is {'almost black' if dark else 'almost white'} where it is "
            f"cropped (it would need {'more' if dark else 'less'} than {'+' if dark else '-'}{EXPOSURE_LIMIT:g} "
            "stops); the file may be damaged. Take or copy it again.")


def check_crop(path, photo, crop):
    """Refuse a crop that is perfectly uniform where the (H, W, 3) linear ``photo`` is not."""
    if _std(crop) <= CONSTANT < _std(photo):
        raise ImplausibleError(f"Could not use '{path}': the cropped region is perfectly uniform while the photo "
                               "is not (what a decoder's fill of missing data looks like); the file may be damaged. "
                               "Copy or export it again.")


def check_maps(path, photo, stored, found=None):
    """``photo``: the encoded network input; ``stored``: the maps as written; ``found``: the physical
    estimate's fitted values, if it ran."""
    for key in ("fit_gain", "flash_height", "roughness", "flash_intensity"):
        v = (found or {}).get(key)
        if isinstance(v, (int, float)) and not math.isfinite(v):
            raise ImplausibleError(f"Could not fit '{path}': the fitted {key.replace('_', ' ')} is {v}; the "
                                   "photo cannot be right. Take or copy it again.")
    mean = float(np.mean(photo))
    if _std(photo) <= max(CONSTANT, UNIFORM * mean) or mean <= 0:
        return  # a uniform photo may give constant maps, and its flat profile leaves the fit's gain undefined
    g = (found or {}).get("fit_gain")
    if isinstance(g, (int, float)) and not FIT_GAIN_LOWEST <= g <= 1 + FIT_GAIN_SLACK:
        raise ImplausibleError(f"Could not fit '{path}': the fit's gain is {g:g}, outside [{FIT_GAIN_LOWEST:g}, 1]; "
                               "the photo cannot be right. Take or copy it again.")
    if all(_std(v) <= CONSTANT for v in stored.values()):
        raise ImplausibleError(f"Could not use '{path}': every map came out constant from a photo that is not; "
                               "the file may be damaged. Take or copy it again.")
    if float(np.max(stored["diffuse"])) <= 1.0 / 255.0:
        raise ImplausibleError(f"Could not use '{path}': the diffuse map came out black everywhere; the photo "
                               "may be damaged or far too dark. Take or copy it again.")
