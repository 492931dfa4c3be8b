"""``svbrdf capture --confidence`` for the physical estimate: where its maps rest on what the photo shows.

The physical estimate (:mod:`svbrdf_cli.infer.physical`) runs no network, so rotated passes would all
agree (every pixel 1, the flash spot included: a confidence that says nothing). What it knows per
pixel follows from how it is made:

* **diffuse**: the photo less the fitted highlight, over the flash's shading. It is read off the
  photo where the photo is neither clipped (:data:`svbrdf_cli.conventions.CLIPPED`: no value left),
  nor dominated by the highlight (where the fitted lobe makes more than
  :data:`svbrdf_cli.infer.physical.HIGHLIGHT_SHARE` of the brightness the diffuse is filled in from
  around: confidence 0; from :data:`SHARE_RAMP` [0] it falls), nor too dark for its 8 bits
  (:data:`SIGNAL_RAMP`, encoded), and where the flash's falloff model is sure: a flash height off by
  one step of the fit's grid (15 %) changes the shading divided out little under the flash and more
  far from it (confidence 0.5 at a change of :data:`FALLOFF_HALF`).
* **roughness**: one value, read off the highlight's profile: trusted where the highlight was seen
  (its share over :data:`SEEN_RAMP`) as far as the fit explains the profile (its gain), and less for
  a lobe so broad that it has the shape of the diffuse falloff (roughness over
  :data:`BROAD_RAMP`: the fit cannot tell them apart); nowhere when the photo shows no highlight
  (the value is then the estimate's default).
* **normal** and **specular** are not measured at all (flat; a dielectric's F0), so they get no map:
  ``material.json`` names them under ``confidence.not_measured``.
"""

from __future__ import annotations

import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli.imageops import blur
from svbrdf_cli.infer import physical

#: Maps the physical estimate measures (and gets a confidence for), and those it assumes.
MEASURED = ("diffuse", "roughness")
NOT_MEASURED = {"normal": "flat: relief is not measured", "specular": "a dielectric's F0 (0.04), assumed"}
#: The highlight's share of the brightness over which the diffuse's confidence falls to 0 (at the
#: share above which the estimate fills the diffuse in).
SHARE_RAMP = (0.1, physical.HIGHLIGHT_SHARE)
#: Encoded brightness over which the diffuse's confidence rises from 0 to 1 (8-bit steps are 0.004).
SIGNAL_RAMP = (0.02, 0.1)
#: Relative change of the flash shading (for a flash height one grid step off) at which confidence is 0.5.
FALLOFF_HALF = 0.15
#: The highlight's share over which the roughness counts as seen.
SEEN_RAMP = (0.02, 0.2)
#: Roughness over which the lobe's width stops being measurable (confidence 1 below, 0 above).
BROAD_RAMP = (0.5, 0.9)


def confidence(image, geometry=None):
    """{map: (H, W) float32 in [0, 1]} for :data:`MEASURED` maps of the encoded (H, W, 3) ``image``."""
    geo = geometry or physical.Geometry()
    img = np.asarray(image, np.float32)
    h, w = img.shape[:2]
    flash = physical.fit_flash(img, geo)
    rho, fit = flash.rho, flash.fit
    shading, d = physical.shading_at(rho, fit.height, geo.height)
    lobe = physical.lobe(d, fit.height, fit.roughness) * (fit.height / geo.height) ** 2 * fit.specular
    share = lobe / np.maximum(fit.diffuse * shading + lobe, 1e-12)
    # diffuse
    clipped = (img >= physical.CLIPPED * cv.clip_level(img)).any(-1).astype(np.float32)
    near_clip = np.clip(blur(clipped, max(1.0, w / 128.0)) * 4.0, 0.0, 1.0)  # and a little round it
    step = physical.HEIGHT_GRID[3] / physical.HEIGHT_GRID[2]
    other, _ = physical.shading_at(rho, fit.height * step, geo.height)
    change = np.abs(np.log(np.maximum(other, 1e-12) / np.maximum(shading, 1e-12)))
    diffuse = ((1.0 - near_clip) * (1.0 - cv.smoothstep(share, *SHARE_RAMP)) * cv.smoothstep(img.mean(-1), *SIGNAL_RAMP)
               / (1.0 + (change / FALLOFF_HALF) ** 2))
    # roughness
    sure = float(np.clip(fit.gain, 0.0, 1.0)) * float(1.0 - cv.smoothstep(fit.roughness, *BROAD_RAMP))
    seen = cv.smoothstep(share, *SEEN_RAMP) * sure if fit.specular > 0 else np.zeros((h, w))
    return {"diffuse": np.clip(diffuse, 0, 1).astype(np.float32),
            "roughness": np.clip(seen * (1.0 - near_clip), 0, 1).astype(np.float32)}
