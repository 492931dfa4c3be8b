"""The physical estimate: all four maps from the photo and the flash geometry alone (numpy, no network).

What a flash photo of a flat surface tells us for free, computed rather than learned:

* **where the flash is**: a flat surface lit by a point light at the lens is brightest
  straight under it, and its brightness falls off as ``H / d^3`` around that point. A
  quadratic fitted to the blurred log-brightness finds the foot of the flash
  (:func:`flash_foot`).
* **the highlight, and from it roughness**: with light and camera at the same place, the
  mirror highlight of a flat surface sits at the same foot. The ring-averaged brightness
  around it is fitted by the diffuse falloff ``c0 s(rho)`` plus the flash highlight
  ``c1 lobe_r(rho)``, over flash heights and roughness values (:func:`fit_lobe`): the lobe's
  width gives the roughness, ``c0`` the diffuse level.
* **diffuse**: the linear photo less the highlight, divided by the shading a flat surface gets
  from the flash (``P * H / d^3``) and by ``1 - F0``. Where the material has a colour, the
  highlight is read per pixel from it (:func:`separate_by_colour`, the dichromatic model: a
  highlight adds white, which changes a pixel's whiteness but not its hue, and the whiteness
  is read on the same hue away from the flash), so glossy tiles lose their highlight while the
  matte grout between them keeps its level; on greys, the fitted lobe's share of each pixel
  is taken off as white. Pixels the highlight clipped or dominates are filled in from their
  surroundings, and any trend with the distance to the foot is divided out (for the greys on
  their own first).
* **specular**: F0 = :data:`svbrdf_cli.conventions.DIELECTRIC_F0` (a dielectric's, the great
  majority of real surfaces): from the photo alone a metal cannot be told from a dark glossy
  dielectric (``docs/benchmarks.md``).
* **normals**: flat. With the light at the lens, a tilt changes the shading only in proportion to
  the light's lateral component, and albedo texture changes it the same way: read as tilt, shading
  raised the normal error (``docs/benchmarks.md``); relief is left to ``--refine``.

**The absolute albedo level** cannot be recovered from one exposed photo (a darker surface
under a stronger flash looks the same). The estimate takes the photo, as the tool exposes
it (mean encoded brightness :data:`svbrdf_cli.conventions.AUTO_EXPOSURE_MEAN`) or as a
validation input comes, to be lit by the flash power
:data:`svbrdf_cli.conventions.FLASH_INTENSITY`: the one power that reproduces the Des19
validation inputs from their maps (a convention of the data, see ``docs/conventions.md``).

:class:`PhysicalModel` has the call interface of :class:`svbrdf_cli.infer.chain.Chain`, so
``svbrdf capture --model physical`` and the benchmarks run it like any model.
"""

from __future__ import annotations

import dataclasses
import time
import types

import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli import imageops
from svbrdf_cli.imageops import blur, fill_from_surroundings, luminance, push_pull
from svbrdf_cli.rectify import highlight

#: Bumped whenever the estimate's output changes: a network trained to refine one version
#: must be fed that version (written into exported models and checked when they load).
PHYSICAL_VERSION = "9"

#: Roughness values the lobe fit tries (the lobe's width picks one).
ROUGHNESS_GRID = np.linspace(0.08, 1.0, 47)
#: Roughness where the photo shows no highlight to measure (a matte surface, or a lobe
#: too wide to tell from the diffuse falloff).
DEFAULT_ROUGHNESS = 0.6
#: Rings of the radial profile around the flash foot.
PROFILE_RINGS = 64
#: Flash heights tried, as multiples of the assumed one (the falloff's steepness; the
#: irradiance at the foot stays the convention's, so the albedo level does not move).
HEIGHT_GRID = np.array([0.75, 0.87, 1.0, 1.15, 1.35])
#: A dielectric's lobe height over its diffuse level at most: F0 = 0.04 over an albedo
#: of at least 0.02 (the darkest common dielectrics, black leather or rubber). The bound does not
#: cost the metals a tell: without it (roughness at most 0.5) the ring profile reads no diffuse floor
#: at all on 4 of Des19's 8 metals and its gold flake and on 5 of the 9 photos labelled metal in
#: ``henzler_train``, but as well on 15 photos of its leathers, woods and paints and on 4 dark
#: dielectrics of ``paper_real`` (a phone case, a speaker grille, a mesh, IMG_7187).
MAX_LOBE_RATIO = 2.0
#: Pixels where the fitted highlight makes more than this share of the photo's
#: brightness, or that are clipped, take their diffuse from the surroundings (what is
#: left of them after the highlight is taken off is dark and grey: a hole in the diffuse).
HIGHLIGHT_SHARE = 0.8
#: Under the highlight the fill takes the photo's texture (its brightness over its neighbourhood's),
#: within this factor either way.
DETAIL_RANGE = 1.5
#: The fill under the highlight takes the photo's fine detail (:func:`_fill_with_detail`) within this
#: factor of the fill's brightness either way.
FILL_DETAIL_RANGE = 3.0
#: Under the highlight, subtracting white leaves the weakest channel at least this
#: fraction of its value (so no channel empties and the hue is kept).
SUBTRACT_FLOOR = 0.25
#: The trend :func:`flatten_radial` divides out is a polynomial of this degree in the distance (fitted
#: to the ring means, weighted by their pixel counts): a falloff or lobe mismatch is smooth in the
#: distance, a ring-to-ring change is the material's own (ring means smoothed over a few rings drew
#: concentric rings into a brushed-metal plate round a sign in its middle).
RADIAL_DEGREE = 4
#: A ring's level, for that trend, is the mean of its log-brightness between these quantiles (within
#: the ring): a material's own pattern that covers a different share of each ring (black spots on white
#: plaster, a stripe through the flash spot) is not read as a trend. With the plain mean, the spots in the
#: rings round a spotless flash spot on white plaster (paper_real IMG_7308) darkened the spot to 0.51 of
#: its ring's brightness (1.17 with these; 0.25-0.75 and 0.35-0.65 lifted a black phone's spot to 1.28
#: and 1.36, 0.1-0.9 left IMG_7308 at 0.75: ``python -m export.studies.artist_check``).
RING_QUANTILES = (0.2, 0.8)
#: Encoded values at or above this (times the photo's clip level) are clipped.
CLIPPED = cv.CLIPPED
#: The highlight left in the diffuse at the highlight's own peak (:func:`highlight_residue`) is filled:
#: a patch of the diffuse this much brighter than the diffuse round the photo's highlight blob.
RESIDUE_LEVEL = 0.2
#: ... and this much whiter than the diffuse's median (weakest over strongest channel). Without this
#: rule the brightest patch of a matte textured surface was taken too (a brick on 4 of Des19's brick
#: and cobble samples: their diffuse error rose, 0.0254 -> 0.0286 on one); the patches found on Des19
#: and the 12 real benchmark photos whitened by -0.11 to 0.19, a speckled worktop's clear-coat glint
#: by 0.44 (henzler_train IMG_0785). A grey material has no colour to whiten and is never filled.
RESIDUE_WHITENING = 0.25
#: Hue bins of the colour separation's hue-aware spreading, and the least (trust-weighted) share of
#: the image a hue must cover to be read at all.
HUE_BINS = 12
WHITENESS_MIN_SHARE = 0.002
#: The whiteness is read only where the fitted lobe's share of the brightness is under this.
READ_SHARE = 0.2
#: ... and used where it takes off more than COLOUR_RAMP[0] of a pixel's brightness (fully from
#: COLOUR_RAMP[1]): less is the photo's noise.
COLOUR_RAMP = (0.05, 0.2)
#: The whiteness is spread on a copy of at most this side.
SPREAD_SIDE = 256
#: Pixels whose (white-balanced) saturation is under this say nothing about their diffuse's colour.
MIN_SATURATION = 0.08
#: The colour separation is trusted fully for a diffuse whiteness (min over max channel) up to
#: ``WHITE_FULL`` and not at all from ``WHITE_NONE`` (greys and whites: a highlight cannot be told
#: from them by colour; the lobe's share is taken off there).
WHITE_FULL, WHITE_NONE = 0.4, 0.7
#: Encoded values at or above this have lost their colour to the sensor's range (the weakest
#: channel of a near-clipped pixel is all highlight).
NEAR_CLIPPED = 0.95
@dataclasses.dataclass
class Geometry:
    """Where the flash and camera are (surface units; the surface spans [-1, 1]^2)."""

    height: float = cv.CAMERA_HEIGHT
    intensity: float = cv.FLASH_INTENSITY
    foot: tuple | None = None      # (x, y) under the flash; None: found from the photo


def surface_grid(h, w):
    """(x, y) surface positions of an (h, w) image's pixels: two (h, w) float32 arrays."""
    p = cv.surface_positions(h, w)
    return p[..., 0].astype(np.float32), p[..., 1].astype(np.float32)


#: Larger photos are shrunk to this side before the flash's foot is fitted.
FOOT_SIDE = 256


def flash_foot(lum, x, y, limit=0.8):
    """(x, y) of the point under the flash: the peak of a quadratic fitted to the blurred log-brightness.

    Args:
        lum: (H, W) linear brightness.
        x: (H, W) surface x of the pixels (:func:`surface_grid`).
        y: (H, W) surface y of the pixels.
        limit: the foot is kept within +-``limit`` (a fit on a surface with no
            visible falloff can wander).
    """
    h, w = lum.shape
    if max(h, w) > FOOT_SIDE:  # the fit is of a smooth falloff: a small copy holds all of it (and a
        import cv2             # blur of a tenth of 2048 px would cost seconds)

        small = cv2.resize(np.ascontiguousarray(lum, np.float32), (FOOT_SIDE, FOOT_SIDE), interpolation=cv2.INTER_AREA)
        return flash_foot(small, *surface_grid(FOOT_SIDE, FOOT_SIDE), limit=limit)
    b = blur(np.maximum(lum, 1e-6), max(h, w) / 10.0)
    step = max(1, min(h, w) // 48)
    xs, ys, z = x[::step, ::step].ravel(), y[::step, ::step].ravel(), np.log(b[::step, ::step]).ravel()
    a = np.stack([np.ones_like(xs), xs, ys, xs * xs + ys * ys], 1).astype(np.float64)
    coef, *_ = np.linalg.lstsq(a, z.astype(np.float64), rcond=None)
    c = coef[3]
    if c >= -1e-3:  # no falloff peak: brightest blurred pixel
        i = np.unravel_index(int(np.argmax(b)), b.shape)
        return float(np.clip(x[i], -limit, limit)), float(np.clip(y[i], -limit, limit))
    return float(np.clip(-coef[1] / (2 * c), -limit, limit)), float(np.clip(-coef[2] / (2 * c), -limit, limit))


def lobe(d, height, roughness):
    """Specular radiance per unit F0 and flash power of a flat surface, light at the lens.

    n.h = n.l = n.v = H / d and v.h = 1 (so Fresnel is F0): ``pi * D * G/(4 nl nv) * nl / d^2``.
    """
    from svbrdf_cli.shading import ndf_ggx, visibility_smith_schlick

    cos = height / d
    a = cv.roughness_to_alpha(np.asarray(roughness, np.float64))
    return np.pi * ndf_ggx(cos, a) * visibility_smith_schlick(cos, cos, a) * 0.25 * cos / (d * d)


@dataclasses.dataclass
class Lobe:
    """The lobe fit's result (:func:`fit_lobe`); levels are at the flash power ``geo.intensity``."""
    roughness: float
    diffuse: float       # flash power x mean diffuse luminance (the profile's floor)
    specular: float      # flash power x F0
    height: float        # the flash height whose falloff fits best
    gain: float          # fraction of the flat-profile residual the fit explains


def ring_profile(lum, clipped, rho):
    """Ring-averaged ``lum`` around the flash foot: (radii, means, pixel counts) of usable rings."""
    ring, centres = imageops.rings(rho, PROFILE_RINGS)
    good = ~clipped.ravel()
    n = np.bincount(ring[good], minlength=PROFILE_RINGS).astype(np.float64)
    total = np.bincount(ring, minlength=PROFILE_RINGS).astype(np.float64)
    s = np.bincount(ring[good], weights=lum.ravel()[good].astype(np.float64), minlength=PROFILE_RINGS)
    use = (n >= 4) & (n >= 0.5 * np.maximum(total, 1))
    return centres[use], s[use] / np.maximum(n[use], 1), n[use]


def shading_at(rho, height, ref_height):
    """Flat-surface diffuse shading per unit albedo and flash power at radius ``rho`` from the foot,
    for a flash at ``height`` that gives the foot the irradiance of one at ``ref_height``."""
    d = np.sqrt(rho * rho + height * height)
    return height / d ** 3 * (height / ref_height) ** 2, d


def lobe_terms(rho, prof, wts, geo):
    """Every (height, roughness) pair of :data:`HEIGHT_GRID` x :data:`ROUGHNESS_GRID` at once, at the ring
    profile ``(rho, prof, wts)`` (:func:`ring_profile`): ``heights`` (H,), the flat surface's falloff ``s``
    (H, 1, N), the lobe ``g`` (H, R, N), the ring weights ``w`` (1, 1, N), the sums ``sss = sum w s s`` and
    ``sy = sum w s prof``, and the unconstrained 2x2 least squares ``prof = m0 s + m1 g``
    (``m0``, ``m1``: (H, R)), which every hypothesis about the profile starts from."""
    heights = geo.height * HEIGHT_GRID
    sh, dd = shading_at(rho[None, :], heights[:, None], geo.height)
    s = sh[:, None, :]
    g = lobe(dd[:, None, :], heights[:, None, None], ROUGHNESS_GRID[None, :, None]) * (heights[:, None, None] / geo.height) ** 2
    w = wts[None, None, :]
    sss, sgg, ssg = (w * s * s).sum(-1), (w * g * g).sum(-1), (w * s * g).sum(-1)
    sy, gy = (w * s * prof).sum(-1), (w * g * prof).sum(-1)
    det = np.maximum(sss * sgg - ssg * ssg, 1e-30)
    return types.SimpleNamespace(heights=heights, s=s, g=g, w=w, sss=sss, sy=sy,
                                 m0=(sgg * sy - ssg * gy) / det, m1=(sss * gy - ssg * sy) / det)


def fit_lobe(lum, clipped, rho, geo):
    """Fit the ring-averaged brightness around the foot with a flat surface's diffuse falloff plus its
    flash highlight, over :data:`HEIGHT_GRID` x :data:`ROUGHNESS_GRID`.

    The surface is a dielectric, whose lobe is at most :data:`MAX_LOBE_RATIO` times its diffuse
    (F0 = 0.04 over an albedo of at least 0.02: without that bound a broad lobe and a flatter
    falloff explain the same profile, and the fit hands the whole photo to the lobe). The photo's exposure
    is not assumed: the lobe's
    height is fitted, only the diffuse level is read at the convention's flash power.
    """
    P = geo.intensity
    rho, prof, wts = ring_profile(lum, clipped, rho)
    if len(rho) < 6:
        return Lobe(DEFAULT_ROUGHNESS, float(np.median(lum / (geo.height ** -2))), cv.DIELECTRIC_F0 * P,
                    geo.height, 0.0)
    base = float((wts * prof).sum() / wts.sum())
    res_flat = float((wts * (prof - base) ** 2).sum())
    t = lobe_terms(rho, prof, wts, geo)
    heights, s, g, w, m0, m1 = t.heights, t.s, t.g, t.w, t.m0, t.m1
    sss, sy = t.sss, t.sy
    # dielectric: 0 <= c1 <= MAX_LOBE_RATIO * c0 (its F0 is 0.04, its albedo at least half that)
    k = MAX_LOBE_RATIO
    sk = s + k * g
    edge = np.maximum((w * sk * prof).sum(-1) / (w * sk * sk).sum(-1), 0.0)  # on c1 = k c0
    c0_only = np.maximum(sy / sss, 0.0)                                       # on c1 = 0
    inside = (m1 >= 0) & (m1 <= k * m0)
    c0 = np.where(inside, m0, np.where(m1 > k * m0, edge, c0_only))
    c1 = np.where(inside, m1, np.where(m1 > k * m0, k * edge, 0.0))
    res_d = (w * (prof - c0[..., None] * s - c1[..., None] * g) ** 2).sum(-1)
    i = np.unravel_index(int(np.argmin(res_d)), res_d.shape)
    res, r, h = float(res_d[i]), float(ROUGHNESS_GRID[i[1]]), float(heights[i[0]])
    return Lobe(r, float(c0[i]), float(c1[i]), h, 1.0 - res / max(res_flat, 1e-20))


#: :func:`planar_trend`: the trend's degree in x and y, the pixels it is fitted on (every n-th of each row
#: and column), its reweighting rounds, and the residual (in robust standard deviations) beyond which a
#: pixel stops counting (Tukey's biweight).
PLANAR_DEGREE = 2
PLANAR_EVERY = 2
PLANAR_ROUNDS = 5
PLANAR_REACH = 4.685


def planar_trend(logl, classes=None):
    """(H, W) float64 trend in x and y of the (H, W) map ``logl`` (a log-brightness), its mean 0; None when
    too few pixels are left to fit it.

    A polynomial of :data:`PLANAR_DEGREE` in the surface's x and y plus a level for each class (``classes``,
    (H*W,) int, of :func:`svbrdf_cli.imageops.chroma_classes`; None: one level), fitted robustly (iteratively
    reweighted, Tukey's biweight on the residuals over their median absolute deviation), so that a
    material's own pattern and its colours are not read as the trend."""
    h, w = logl.shape
    x, y = (g.astype(np.float64) for g in surface_grid(h, w))
    powers = [(i, d - i) for d in range(1, PLANAR_DEGREE + 1) for i in range(d + 1)]
    terms = np.stack([x ** i * y ** j for i, j in powers], -1).reshape(-1, len(powers))
    cls = np.zeros(h * w, np.int64) if classes is None else np.asarray(classes)
    k = int(cls.max()) + 1
    pick = np.zeros((h, w), bool)
    pick[::PLANAR_EVERY, ::PLANAR_EVERY] = True
    pick = pick.ravel()
    design = np.concatenate([np.eye(k)[cls[pick]], terms[pick]], 1)
    target = np.asarray(logl, np.float64).ravel()[pick]
    wt = np.ones(target.shape)
    for _ in range(PLANAR_ROUNDS):  # the weighted normal equations: the same least-norm fit, 20x faster
        dw = design.T * wt
        coef = np.linalg.lstsq(dw @ design, dw @ target, rcond=None)[0]
        res = target - design @ coef
        scale = 1.4826 * float(np.median(np.abs(res))) + 1e-6
        u = res / (PLANAR_REACH * scale)
        wt = np.where(np.abs(u) < 1, (1 - u * u) ** 2, 0.0)
        if wt.sum() < design.shape[1] * 4:
            return None
    trend = terms @ coef[k:]
    return (trend - trend.mean()).reshape(h, w)


def flatten_radial(diffuse, rho, rings=PROFILE_RINGS // 2, weights=None, classes=None):
    """Divide out what is left of the flash in the diffuse: its log-brightness as a function of the
    distance to the foot (each ring's trimmed mean, :data:`RING_QUANTILES`), smoothed, relative to the
    whole image's.

    An albedo has no reason to brighten or darken with the distance to where the flash happened to
    point, so any such trend is the model's mismatch (a highlight sharper than the fitted lobe, a
    falloff steeper than the fitted height) and is removed; the mean level is kept.

    ``weights`` (H, W) in [0, 1], when given, restrict both the trend and its removal to a class of
    pixels (in proportion): e.g. the greys, whose highlight was taken off by the lobe's share.

    ``classes`` (H*W,) int, when given (:func:`svbrdf_cli.imageops.chroma_classes`): the trend is fitted to
    each class's ring levels at once, with a level of each class's own (:func:`_class_trend`), so that a
    class which covers more of the rings near the foot than far from it (a pale grout line through the
    flash spot) is not read as a trend.
    """
    logl = np.log(np.maximum(luminance(diffuse), 1e-5)).ravel().astype(np.float64)
    ring, centres = imageops.rings(rho, rings)
    wt = np.ones(logl.shape) if weights is None else np.asarray(weights, np.float64).ravel()
    fitted = None if classes is None else _class_trend(logl, ring, wt, centres, classes)
    if fitted is None:
        n = np.bincount(ring, weights=wt, minlength=rings)
        if weights is not None:
            n = np.where(n >= RING_MIN, n, 0.0)  # a ring with a few such pixels says nothing
        mean = _ring_midmeans(logl, ring, wt, rings)
        mean = np.where(n > 0, mean, np.nan)
        valid = ~np.isnan(mean)
        if valid.sum() < 3:
            return diffuse
        mean = np.interp(centres, centres[valid], mean[valid])
        # a smooth trend only: ring-to-ring changes are the material's own (a sign, a tile)
        t = centres / max(float(centres[-1]), 1e-6)
        smooth = np.polyval(np.polyfit(t, mean, RADIAL_DEGREE, w=np.sqrt(np.maximum(n, 0.0))), t)
    else:
        smooth, n = fitted
    level = float((n * smooth).sum() / n.sum())
    trend = np.interp(rho.ravel(), centres, smooth - level).reshape(rho.shape)
    if weights is not None:
        trend = trend * weights
    return (diffuse * np.exp(-trend)[..., None]).astype(np.float32)


#: :func:`flatten_radial`: a ring of a class (or of the pixels ``weights`` picks) counts in the trend's fit
#: only with at least this weight of pixels in it.
RING_MIN = 4.0


def _class_trend(logl, ring, wt, centres, classes):
    """(the smooth trend at the ring ``centres`` less any constant, each ring's weight), or None with too few
    rings to fit it (:func:`flatten_radial` then fits one level for all): the polynomial of
    :data:`RADIAL_DEGREE` in the distance, without its constant, plus one level per class, fitted by weighted
    least squares to each class's ring levels (:func:`_ring_midmeans` of ``logl`` within the class, weighted
    by its pixels, :data:`RING_MIN` at least), so that what differs between the classes is their own."""
    count = centres.size
    t = centres / max(float(centres[-1]), 1e-6)
    powers = t[:, None] ** np.arange(1, RADIAL_DEGREE + 1)
    k = int(classes.max()) + 1
    onehot = np.eye(k)
    rows, levels, n_fit = [], [], []
    for c in range(k):
        m = classes == c
        n = np.bincount(ring[m], weights=wt[m], minlength=count)
        mean = _ring_midmeans(logl[m], ring[m], wt[m], count)
        for r in np.flatnonzero(n >= RING_MIN):
            rows.append(np.concatenate([onehot[c], powers[r]]))
            levels.append(mean[r])
            n_fit.append(n[r])
    if len(rows) < k + RADIAL_DEGREE + 1:
        return None
    w = np.sqrt(np.asarray(n_fit))
    coef = np.linalg.lstsq(np.asarray(rows) * w[:, None], np.asarray(levels) * w, rcond=None)[0]
    return powers @ coef[k:], np.bincount(ring, weights=wt, minlength=count)


def _ring_midmeans(values, ring, weights, count):
    """(count,) per ring (``ring``: each value's ring index), the weighted mean of ``values`` between their
    weighted quantiles :data:`RING_QUANTILES` within the ring (NaN where a ring has no weight)."""
    order = np.lexsort((values, ring))
    v, r, wt = values[order], ring[order], weights[order]
    total = np.bincount(r, weights=wt, minlength=count)
    start = np.concatenate([[0.0], np.cumsum(total)[:-1]])
    before = np.cumsum(wt) - wt - start[r]  # weight below each value within its ring
    q = before / np.maximum(total[r], 1e-12)
    lo, hi = RING_QUANTILES
    keep = wt * ((q + wt / np.maximum(total[r], 1e-12) > lo) & (q < hi))
    n = np.bincount(r, weights=keep, minlength=count)
    out = np.bincount(r, weights=v * keep, minlength=count) / np.maximum(n, 1e-12)
    return np.where(n > 0, out, np.nan)


def _channel_min_max(x):
    """Weakest and strongest channel of (H, W, 3) ``x`` (faster than ``.min(-1)`` / ``.max(-1)``)."""
    return (np.minimum(np.minimum(x[..., 0], x[..., 1]), x[..., 2]),
            np.maximum(np.maximum(x[..., 0], x[..., 1]), x[..., 2]))


def _hue(x):
    """Hue angle (radians) of RGB ``x``: unchanged by adding white."""
    return np.arctan2(np.sqrt(3.0) * (x[..., 1] - x[..., 2]), 2.0 * x[..., 0] - x[..., 1] - x[..., 2])


def separate_by_colour(lin, share, tint, unreliable, reference=None):
    """The diffuse part of each pixel by the dichromatic reflection model, and how far to trust it.

    A dielectric's highlight adds the flash's colour (``tint``) to the diffuse colour: in a
    white-balanced pixel it raises every channel by the same amount. So the pixel less its weakest
    channel keeps the diffuse's hue and chroma exactly (a "specular-free" image); what the highlight
    hides is only the diffuse's **whiteness** ``w`` (weakest over strongest channel). ``w`` is a
    property of the material, not of the lighting: it is read where the highlight is weak and
    spread, averaged within hue (so a blue tile takes a blue tile's, not its green neighbour's),
    to the pixels under the highlight. Each pixel's diffuse is then its specular-free colour plus
    the white that gives it that whiteness, and never more than the pixel itself.

    This reads the highlight per pixel, so glossy tiles lose theirs while the matte grout between
    them keeps its colour (the lobe's share, one smooth function of the distance, cannot tell the
    two apart). Greys and whites carry no such evidence: the trust (second output) falls to 0 for
    whiteness from :data:`WHITE_FULL` to :data:`WHITE_NONE`, where too few pixels of the hue are
    seen outside the highlight, and where the pixel is ``unreliable`` (near-clipped).

    Args:
        lin: (H, W, 3) linear photo.
        share: (H, W) the fitted lobe's share of each pixel's brightness (0 far from the highlight).
        tint: the highlight's colour (RGB, unit luminance).
        unreliable: (H, W) bool, pixels whose colour is lost (near-clipped).
        reference: (H, W, 3) what the whiteness is read from (default ``lin``): the photo less the
            lobe's share, so that the weak highlight where it is read does not whiten it.

    Returns:
        ((H, W, 3) linear diffuse part of each pixel, (H, W) trust in [0, 1]).
    """
    import cv2

    ln = np.asarray(lin, np.float32) / tint
    lo, hi = _channel_min_max(ln)
    spread = hi - lo
    whiteness = lo / np.maximum(hi, 1e-6)
    if reference is not None:
        rlo, rhi = _channel_min_max(np.asarray(reference, np.float32) / tint)
        read = np.clip(rlo / np.maximum(rhi, 1e-6), 0.0, 1.0)
    else:
        read = whiteness
    coloured = spread > MIN_SATURATION * hi
    trust_px = (np.clip(1.0 - share / READ_SHARE, 0.0, 1.0) ** 2 * coloured * ~unreliable).astype(np.float32)
    hue = _hue(ln).astype(np.float32)

    def member(k):  # soft hue bins
        m = np.maximum(np.cos(hue - np.float32(2.0 * np.pi * k / HUE_BINS - np.pi)), np.float32(0.0))
        m *= m
        return m * m

    # per hue bin, the whiteness of the trusted pixels spread to every pixel; a bin seen too little
    # outside the highlight (under WHITENESS_MIN_SHARE of the image) gives nothing
    # (on at most a SPREAD_SIDE² copy: the spread is coarse, and the estimate runs at the output size)
    h, wd = lo.shape
    f = min(1.0, SPREAD_SIDE / max(h, wd))
    small = (max(1, round(wd * f)), max(1, round(h * f)))

    def down(x):
        return cv2.resize(np.ascontiguousarray(x, np.float32), small, interpolation=cv2.INTER_AREA) if f < 1 else x

    def up(x):
        return cv2.resize(x, (wd, h), interpolation=cv2.INTER_LINEAR) if f < 1 else x

    w = np.zeros(lo.shape, np.float32)
    seen = np.zeros(lo.shape, np.float32)
    total = np.zeros(lo.shape, np.float32)
    for k in range(HUE_BINS):
        m = member(k)
        total += m
        wt = m * trust_px
        if float(wt.mean()) < WHITENESS_MIN_SHARE:
            continue
        w += m * up(push_pull(down(read * wt) / np.maximum(down(wt), 1e-12), down(wt), confident=0.05))
        seen += m
    w = np.where(seen > 1e-6, w / np.maximum(seen, 1e-6), 1.0)
    seen = np.clip(seen / np.maximum(total, 1e-6), 0.0, 1.0)
    w = np.clip(np.minimum(w, whiteness), 0.0, WHITE_NONE)  # a highlight only whitens a pixel
    diffuse = (ln - lo[..., None]) + (w * spread / (1.0 - w))[..., None]
    diffuse = np.clip(diffuse, 0.0, ln) * tint
    trust = np.clip((WHITE_NONE - w) / (WHITE_NONE - WHITE_FULL), 0.0, 1.0) * seen * coloured * ~unreliable
    return diffuse.astype(np.float32), trust.astype(np.float32)


def highlight_residue(diffuse, blob):
    """(H, W) bool: the highlight left in ``diffuse`` at the photo's highlight (``blob``:
    :func:`svbrdf_cli.rectify.highlight.find`): the bright connected patch of the diffuse that holds the blob's
    peak, stands :data:`RESIDUE_LEVEL` above the level of the diffuse round the blob and is whiter
    than the material elsewhere by :data:`RESIDUE_WHITENING` (weakest over strongest channel). A highlight
    sharper than the fitted lobe (a clear coat over a rough base: two lobes where the fit has one) keeps
    its peak after the lobe's share is taken off; an albedo has no reason to be brightest exactly where
    the flash is reflected."""
    import cv2

    h, w = diffuse.shape[:2]
    none = np.zeros((h, w), bool)
    k = max(3, (w // 16) | 1)
    area = cv2.dilate(blob.mask.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))).astype(bool)
    if area.all() or not area[blob.peak]:
        return none
    ld = blur(luminance(diffuse), max(1.0, w / 256.0))  # not single noisy pixels
    around = push_pull(ld, (~area).astype(np.float32), until_covered=True, fallback=float(ld.mean()))
    bright = area & (ld > (1.0 + RESIDUE_LEVEL) * around)
    _, labels = cv2.connectedComponents(bright.astype(np.uint8))
    if labels[blob.peak] == 0:
        return none
    spot = labels == labels[blob.peak]
    # a highlight adds the flash's white: the patch must be clearly whiter than the material is
    # elsewhere (a bright brick or a pale fleck under the flash keeps its own colour and is left)
    lo, hi = _channel_min_max(diffuse)
    whiteness = lo / np.maximum(hi, 1e-6)
    if float(whiteness[spot].mean() - np.median(whiteness)) < RESIDUE_WHITENING:
        return none
    return cv2.dilate(spot.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))).astype(bool)


def relative_texture(lum):
    """(H, W) brightness over its neighbourhood's (1/64 of the width), within :data:`DETAIL_RANGE`: the
    texture a fill is multiplied by so that it is not a flat, textureless blot."""
    w = lum.shape[1]
    return np.clip(lum / np.maximum(blur(lum, max(1.0, w / 64.0)), 1e-6), 1.0 / DETAIL_RANGE, DETAIL_RANGE)


def _fill_with_detail(diffuse, bad, lum, to_albedo, blind):
    """``diffuse`` with its ``bad`` pixels (those the highlight dominates) filled from their surroundings,
    keeping the photo's own fine detail there.

    The highlight *adds* a smooth white to the photo, so the photo's high-pass (its brightness less its
    blur over 1/64 of the width: the lobe is smooth at that scale) is the albedo's detail in absolute
    terms: ``lum - blur(lum)`` over ``to_albedo`` (the flash's shading times its power: photo units ->
    albedo) is added, as a factor of the fill's brightness (within :data:`FILL_DETAIL_RANGE`), to the
    push-pull fill. A factor of the photo's relative texture (``lum / blur(lum)``) would divide that
    detail by the highlight's brightness over the diffuse's: 6 to 40 times too little under a highlight.
    Where the photo has no detail (``blind``: clipped), the detail of the diffuse just beside the clipped
    region is moved onto it (:func:`texture_beside`), not a smooth blot."""
    if not bad.any():
        return diffuse
    import cv2

    w = lum.shape[1]
    filled = fill_from_surroundings(diffuse, bad)
    level = np.maximum(luminance(filled), 1e-6)
    detail = (lum - blur(lum, max(1.0, w / 64.0))) / np.maximum(to_albedo, 1e-6)
    factor = np.clip(1.0 + detail / level, 1.0 / FILL_DETAIL_RANGE, FILL_DETAIL_RANGE).astype(np.float32)
    factor = _no_more_detail_than_around(factor, diffuse, bad, w)
    blind = blind & bad
    if blind.any():
        k = max(3, (w // 128) | 1)
        blind = cv2.dilate(blind.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))).astype(bool)
        beside = texture_beside(np.where(blind[..., None], filled, filled * factor[..., None]), blind)
        factor = np.where(blind, beside, factor)
    return (filled * np.where((filled != diffuse).any(-1), factor, 1.0)[..., None]).astype(np.float32)


def _no_more_detail_than_around(factor, diffuse, bad, w):
    """``factor`` (a relative detail, 1 = none) scaled down inside ``bad`` to no more detail (RMS) than
    the ``diffuse``'s own relative texture just round ``bad``: the highlight's own sensor noise, 6 to 40
    times the diffuse's there, is not the material's."""
    import cv2

    k = max(3, (w // 32) | 1)
    around = cv2.dilate(bad.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))).astype(bool) & ~bad
    if around.sum() > 16:
        ld = luminance(diffuse)
        own = ld / np.maximum(blur(ld, max(1.0, w / 64.0)), 1e-6) - 1.0
        have, want = float(np.sqrt(np.mean((factor[bad] - 1.0) ** 2))), float(np.sqrt(np.mean(own[around] ** 2)))
        if have > want:
            factor = 1.0 + (factor - 1.0) * np.float32(want / have)
    return factor


def photo_detail_under_highlight(diffuse, image, hidden):
    """The stored ``diffuse`` with its detail finer than 1/64 of the width, inside ``hidden`` (a (h, w)
    mask at any size: where the highlight hid the albedo but did not clip), taken from the encoded photo
    ``image`` of the same size, as :func:`_fill_with_detail` takes it for the estimate.

    A model fills the diffuse under the highlight from round it at its own resolution, and ``--refine``
    fits the photo's fine detail into the diffuse where the photo shows the diffuse: round the
    highlight, not under it. There the maps held 0.4 of the fine detail of a ring round the flash
    spot, a smooth blot (``export.studies.artist_check``). Yet the highlight *adds* a smooth lobe: the
    photo's high-pass there is the albedo's detail times the flash's shading, which is read round the
    spot (the photo's local level over the diffuse's) and carried into it. No more detail than the
    diffuse has round the spot is added."""
    diffuse = np.asarray(diffuse, np.float32)
    h, w = diffuse.shape[:2]
    bad = mask_at(hidden, h, w)
    if not bad.any() or bad.all():
        return diffuse
    # on the hidden pixels' bounding box and an eighth of the width round it (their surroundings)
    rows, cols = np.flatnonzero(bad.any(1)), np.flatnonzero(bad.any(0))
    pad = max(8, w // 8)
    y0, y1 = max(0, rows[0] - pad), min(h, rows[-1] + 1 + pad)
    x0, x1 = max(0, cols[0] - pad), min(w, cols[-1] + 1 + pad)
    out = diffuse.copy()
    out[y0:y1, x0:x1] = _photo_detail(diffuse[y0:y1, x0:x1], np.asarray(image, np.float32)[y0:y1, x0:x1],
                                      bad[y0:y1, x0:x1], w)
    return out


#: :func:`photo_detail_in_spot`: the flash's spot gets the photo's detail fully out to this many times the
#: radius of the photo's brightest blob (:func:`svbrdf_cli.rectify.highlight.spot_distances`), none from the
#: second.
SPOT_DETAIL_RADII = (1.5, 2.5)
#: :func:`photo_detail_in_spot` compares logarithms of brightness plus this (linear): a dark pixel's sensor
#: noise is not multiplied into detail.
LOG_FLOOR = 0.01


def spot_weight(image, hidden):
    """(H, W) float32 in [0, 1]: where :func:`photo_detail_in_spot` gives the diffuse the encoded ``image``'s
    detail: the flash's spot (:data:`SPOT_DETAIL_RADII`), fading out over its rim, and not where the highlight
    hid the albedo or the photo clipped (``hidden``, (H, W) bool: those have their own fill), nor within
    1/64 of the width of them."""
    rho, radius = highlight.spot_distances(image)
    rho, w = rho / radius, rho.shape[1]
    inner, outer = SPOT_DETAIL_RADII
    weight = np.clip((outer - rho) / (outer - inner), 0.0, 1.0)
    if np.any(hidden):
        free = 1.0 - np.clip(blur(np.asarray(hidden, np.float32), max(1.0, w / 64.0)) * 3.0, 0.0, 1.0)
        weight = weight * np.where(hidden, 0.0, free)
    return weight.astype(np.float32)


def photo_detail_in_spot(diffuse, image, weight):
    """The stored ``diffuse`` given, times ``weight`` ((H, W) at any size: :func:`spot_weight`), the encoded photo
    ``image``'s relative detail finer than 1/64 of the width that it lacks: its log brightness's high-pass
    less the diffuse's own, within :data:`DETAIL_RANGE` either way.

    Under the flash's centre a network's diffuse came out smoother than round it even where the photo
    shows no highlight: on white plaster with black spots (``paper_real`` IMG_7308) the chain's diffuse
    kept 0.37 of the ring's fine detail in the spot where the photo has 0.60, the runtime's fill 0.32, and
    guided upsampling, which follows the map's own contrast, adds none where it has none. Where the
    diffuse has an edge the photo has too (a spot's rim), the two high-passes cancel: the edge is kept as
    the diffuse draws it, not rebuilt from a blur."""
    import cv2

    diffuse = np.asarray(diffuse, np.float32)
    h, w = diffuse.shape[:2]
    wt = np.asarray(weight, np.float32)
    if wt.shape != (h, w):
        wt = cv2.resize(wt, (w, h), interpolation=cv2.INTER_LINEAR)
    rows, cols = np.flatnonzero((wt > 0).any(1)), np.flatnonzero((wt > 0).any(0))
    if not rows.size:
        return diffuse
    sigma = max(1.0, w / 64.0)
    # on a window round the spot: its rim, the band beyond it as wide, and the blur's reach
    rim = np.sqrt((wt > 0).sum() / np.pi) - np.sqrt((wt >= 0.99).sum() / np.pi)
    pad = int(np.ceil(max(rim, 2.0) + 3.0 * sigma)) + 1
    win = (slice(max(0, rows[0] - pad), min(h, rows[-1] + 1 + pad)), slice(max(0, cols[0] - pad), min(w, cols[-1] + 1 + pad)))
    wt = wt[win]
    d = cv.albedo_to_linear(diffuse[win])
    lp = np.log(luminance(cv.image_to_linear(np.asarray(image, np.float32)[win])) + LOG_FLOOR)
    ld = np.log(luminance(d) + LOG_FLOOR)
    limit = np.log(DETAIL_RANGE)
    own = ld - blur(ld, sigma)
    missing = wt * np.clip((lp - blur(lp, sigma)) - own, -limit, limit)
    missing *= np.float32(_share_within_around(own, missing, wt))
    given = cv.albedo_to_stored(np.clip(d * np.exp(missing)[..., None], 0.0, 1.0)).astype(np.float32)
    out = diffuse.copy()
    out[win] = np.where((wt > 0)[..., None], given, diffuse[win])
    return out


#: :func:`_share_within_around` tries these shares of the photo's detail, the largest first.
SPOT_DETAIL_SHARES = (1.0, 0.75, 0.5, 0.25, 0.0)


def _share_within_around(own, added, weight):
    """The largest share (of :data:`SPOT_DETAIL_SHARES`) of ``added`` that leaves the log diffuse's fine detail
    ``own`` (both (H, W)) where ``weight`` is full no stronger than ``own`` is in a band beyond where
    ``weight`` ends, as wide as its rim: the flash's spot is given the detail its surroundings have, no
    more. Strength is the median absolute detail, which a spot's edge does not sway. A fabric's sheen
    under the flash, no highlight to the chain, is fine detail in the photo that the diffuse round it
    does not have: without this, a patch of noise on the purple fabric henzler_train IMG_0807."""
    import cv2

    full, support = weight >= 0.99, weight > 0
    if not full.any():
        return 1.0
    rim = np.sqrt(support.sum() / np.pi) - np.sqrt(full.sum() / np.pi)
    beyond = cv2.distanceTransform((~support).astype(np.uint8), cv2.DIST_L2, 5)
    band = ~support & (beyond <= max(rim, 2.0))
    if band.sum() < 16:
        return 1.0
    target = float(np.median(np.abs(own[band])))
    return next((s for s in SPOT_DETAIL_SHARES if float(np.median(np.abs(own[full] + s * added[full]))) <= target), 0.0)


def _photo_detail(diffuse, image, bad, w):
    """:func:`photo_detail_under_highlight` on a window of the maps (``w``: the whole map's width)."""
    d = cv.albedo_to_linear(diffuse)
    sigma = max(1.0, w / 64.0)
    lum = luminance(cv.image_to_linear(image))
    ld = luminance(d)
    low_lum, low_d = blur(lum, sigma), blur(ld, sigma)
    # photo units -> albedo (the flash's shading and power), read where the highlight did not reach
    shade = fill_from_surroundings((low_lum / np.maximum(low_d, 1e-6))[..., None], bad)[..., 0]
    low = blur(d, sigma)
    factor = 1.0 + (lum - low_lum) / np.maximum(shade * luminance(low), 1e-6)
    factor = np.clip(factor, 1.0 / FILL_DETAIL_RANGE, FILL_DETAIL_RANGE).astype(np.float32)
    factor = _no_more_detail_than_around(factor, d, bad, w)
    out = cv.albedo_to_stored(np.clip(low * factor[..., None], 0.0, 1.0)).astype(np.float32)
    return np.where(bad[..., None], out, diffuse)


def mask_at(mask, h, w):
    """The (any size) bool ``mask`` at (``h``, ``w``), nearest neighbour."""
    import cv2

    return cv2.resize(np.asarray(mask, np.uint8), (w, h), interpolation=cv2.INTER_NEAREST).astype(bool)


def _moved_beside(texture, spot):
    """``texture`` (H, W) moved sideways onto ``spot`` from just beside it (past its columns' span)."""
    cols = np.flatnonzero(spot.any(0))
    return np.roll(texture, int(cols[-1] - cols[0]) + 3, axis=1).astype(np.float32)


def texture_beside(diffuse, spot):
    """(H, W) relative texture (:func:`relative_texture`) of ``diffuse`` just beside ``spot``, moved onto it."""
    return _moved_beside(relative_texture(luminance(diffuse)), spot)


def texture_beside_clipped(diffuse, clipped):
    """The stored ``diffuse`` with, where the photo clipped (``clipped``: an (h, w) mask at any size), its
    own fine detail (finer than 1/64 of the width) replaced by the detail just beside the clipped pixels
    (:func:`texture_beside`), at the diffuse's size, over a rim that fades in over 1/256 of the width.

    A clipped photo says nothing of the albedo: a model fills it at its own size (the texture beside at
    128 px, :func:`svbrdf_cli.infer.swift.fill_highlight`), and brought to the output size that fill is a
    smooth disc: on the speckled phone back ``paper_real`` IMG_7202 0.40 of the ring's fine detail at
    1024 px. :func:`photo_detail_under_highlight` has no detail to take there: this is the clone stamp an
    artist would use. The level under the detail is kept. The texture moves sideways only: the work is done
    on the clipped pixels' rows and as many as the blurs reach round them, across the whole width."""
    diffuse = np.asarray(diffuse, np.float32)
    h, w = diffuse.shape[:2]
    bad = mask_at(clipped, h, w)
    if not bad.any() or bad.all():
        return diffuse
    rows = np.flatnonzero(bad.any(1))
    pad = int(4 * max(1.0, w / 64.0)) + 2  # OpenCV's Gaussian reaches 4 sigma
    band = slice(max(0, rows[0] - pad), min(h, rows[-1] + 1 + pad))
    lin = cv.albedo_to_linear(diffuse[band])
    inside = bad[band]
    own = relative_texture(luminance(lin))
    wt = np.clip(blur(inside.astype(np.float32), max(1.0, w / 256.0)) * 2.0 - 1.0, 0.0, 1.0) * inside
    factor = 1.0 + wt * (_moved_beside(own, inside) / own - 1.0)
    out = diffuse.copy()
    out[band] = cv.albedo_to_stored(np.clip(lin * factor[..., None], 0.0, 1.0))
    return out


def _residue_spot(img, diffuse):
    """:func:`highlight_residue` of the estimate's ``diffuse`` at the encoded photo ``img``'s highlight, found on
    a copy of at most :data:`FOOT_SIDE` px (like the flash's foot: the blob and the patch are broad shapes, and
    at the output size the blur, dilation and push-pull cost seconds) and brought back to full size."""
    import cv2

    h, w = diffuse.shape[:2]
    if max(h, w) <= FOOT_SIDE:
        return highlight_residue(diffuse, highlight.find(img))

    def small(x):
        return cv2.resize(np.ascontiguousarray(x, np.float32), (FOOT_SIDE, FOOT_SIDE), interpolation=cv2.INTER_AREA)

    spot = highlight_residue(small(diffuse), highlight.find(small(img)))
    return mask_at(spot, h, w)


@dataclasses.dataclass
class FlashFit:
    """The flash as a photo shows it (:func:`fit_flash`): the linear photo and its luminance, the foot of
    the flash, each pixel's distance from it (surface units) and the highlight lobe fitted there."""

    lin: np.ndarray
    lum: np.ndarray
    foot: tuple
    rho: np.ndarray
    fit: object


def fit_flash(image, geo=None):
    """Where the flash was and the highlight it made, from the encoded (H, W, 3) ``image`` (what the
    estimate, its confidence and the trained chain's flash context start from)."""
    geo = geo or Geometry()
    img = np.asarray(image, np.float32)
    lin = cv.image_to_linear(img).astype(np.float32)
    lum = luminance(lin)
    x, y = surface_grid(*img.shape[:2])
    foot = geo.foot if geo.foot is not None else flash_foot(lum, x, y)
    rho = np.sqrt((x - foot[0]) ** 2 + (y - foot[1]) ** 2)
    # The lobe fit leaves out only what clipped at the camera's white: a plateau the exposure moved down
    # stays in it as a lower bound. Measured, leaving it out too broadens the fitted lobe on real
    # data: Des19 as svbrdf capture exposes it, roughness 0.2038 against 0.1905; +2 EV clipped 0.2655
    # against 0.2119; card_blue relight 0.151 against 0.146 (on a constructed photo it would help).
    fit = fit_lobe(lum, (img >= CLIPPED).any(-1), rho, geo)
    return FlashFit(lin, lum, foot, rho, fit)


def estimate(image, geo=None, with_fit=False):
    """The physical estimate of one photo.

    Args:
        image: (H, W, 3) encoded photo in [0, 1] (as the networks take it).
        geo: :class:`Geometry` (default: the conventions' flash, foot found from the photo).
        with_fit: also return the encoded image of a flat surface of uniform albedo under the
            fitted flash (what the fit explains of the photo; ``--debug`` writes it).

    Returns:
        (dict of stored-encoding maps (HWC, roughness one channel), dict of what was found:
        foot, flash height, roughness, F0, fit gain[, the fitted image]).
    """
    geo = geo or Geometry()
    img = np.asarray(image, np.float32)
    h, w = img.shape[:2]
    level = cv.clip_level(img)  # a clipped highlight darkened by the exposure is clipped all the same
    clipped = (img >= CLIPPED * level).any(-1)
    flash = fit_flash(img, geo)
    lin, lum, foot, rho, fit = flash.lin, flash.lum, flash.foot, flash.rho, flash.fit
    shading, d = shading_at(rho, fit.height, geo.height)
    spec = lobe(d, fit.height, fit.roughness).astype(np.float32) * (fit.height / geo.height) ** 2
    spec_rad = fit.specular * spec  # luminance of the lobe
    f0 = np.full(3, cv.DIELECTRIC_F0, np.float32)
    # Diffuse: the photo less the fitted highlight's share of each pixel, over the flash shading. The
    # share (lobe over the fitted flat-surface profile), not the lobe's absolute radiance, is taken
    # off: where the highlight is brighter or sharper than fitted, the photo's texture is kept at the
    # diffuse level instead of a hole or a residual disc.
    model = fit.diffuse * shading + spec_rad
    # (the BRDF's diffuse term is d (1 - F0) / pi: the energy the specular reflects is not diffused)
    keep = np.maximum(1.0 - f0, 0.05)
    # The highlight is the flash's colour (white): the fitted lobe's share of
    # each pixel's brightness is taken off every channel (at most 1 - SUBTRACT_FLOOR of the weakest,
    # so the hue stays the photo's) rather than the pixel being scaled, which would leave the
    # highlight's whiteness in the diffuse (a pale disc, and greyer colours).
    share = (spec_rad / np.maximum(model, 1e-6))[..., None]
    tint = f0 / max(float(luminance(f0[None])[0]), 1e-6)  # the highlight's colour: white
    white = np.minimum(share * lum[..., None], (1.0 - SUBTRACT_FLOOR) * (lin / tint).min(-1, keepdims=True))
    base = lin - white * tint
    bad = clipped | (share[..., 0] > HIGHLIGHT_SHARE)  # what is left there is mostly the highlight's
    blind = clipped  # the photo has no detail there either
    grey = None
    if fit.specular > 0:
        # where the diffuse has a colour, the highlight is read per pixel from it (glossy tiles lose
        # theirs, the matte grout keeps its own); the lobe's smooth share elsewhere
        near = _channel_min_max(img)[1] >= NEAR_CLIPPED * level
        by_colour, coloured = separate_by_colour(lin, share[..., 0], tint, near, reference=base)
        # only where the colour says there is a highlight (a ramp, so no edge shows), near the flash
        taken = 1.0 - luminance(by_colour) / np.maximum(lum, 1e-6)
        trust = (coloured * np.clip((taken - COLOUR_RAMP[0]) / (COLOUR_RAMP[1] - COLOUR_RAMP[0]), 0.0, 1.0)
                 * np.clip(share[..., 0] / 0.02, 0.0, 1.0))
        # a pixel the highlight dominates keeps too little of its colour to read: filled from around it
        dominated = (trust > 0.5) & (luminance(by_colour) < (1.0 - HIGHLIGHT_SHARE) * lum)
        base = trust[..., None] * by_colour + (1.0 - trust[..., None]) * base
        blind = clipped | (near & (share[..., 0] > 0.05))
        bad = blind | dominated | ((share[..., 0] > HIGHLIGHT_SHARE) & (trust < 0.5))
        grey = 1.0 - coloured  # (filled pixels included: they take their surroundings' level)
    to_albedo = geo.intensity * shading * float(keep.mean())
    diffuse = base / (geo.intensity * shading[..., None]) / keep
    diffuse = _fill_with_detail(np.clip(diffuse, 0.0, None).astype(np.float32), bad, lum, to_albedo, blind)
    spot = _residue_spot(img, diffuse)  # what the lobe did not take off at the highlight's peak (a sharper one)
    if spot.any():
        diffuse = fill_from_surroundings(diffuse, spot, texture_beside(diffuse, spot))
    if grey is not None and 0.02 < float(grey.mean()) < 0.98:  # the greys' own trend first (their highlight was
        diffuse = flatten_radial(diffuse, rho, weights=grey)  # taken off by the lobe's share, the rest's by colour)
    diffuse = flatten_radial(diffuse, rho)
    diffuse = np.clip(np.nan_to_num(diffuse, nan=0.0, posinf=1.0), 0.0, 1.0).astype(np.float32)
    normal = np.concatenate([np.zeros((h, w, 2), np.float32), np.ones((h, w, 1), np.float32)], -1)  # flat
    stored = {"normal": cv.encode_normals(normal).astype(np.float32),
              "diffuse": cv.albedo_to_stored(diffuse).astype(np.float32),
              "roughness": np.full((h, w, 1), fit.roughness, np.float32),
              "specular": np.broadcast_to(cv.albedo_to_stored(f0), (h, w, 3)).astype(np.float32)}
    # what the fit saw, for --debug: the flat surface of uniform albedo under the fitted flash
    fitted = cv.image_to_encoded(np.repeat(model[..., None], 3, -1)).astype(np.float32)
    found = {"flash_foot": [round(foot[0], 4), round(foot[1], 4)], "flash_height": round(fit.height, 4),
             "roughness": round(fit.roughness, 4), "f0": [round(float(v), 4) for v in f0],
             "fit_gain": round(float(fit.gain), 4), "flash_intensity": geo.intensity}
    return (stored, found, fitted) if with_fit else (stored, found)


def network_input(image):
    """The estimate as a refining network takes it.

    Args:
        image: (H, W, 3) float32 encoded photo in [0, 1].

    Returns:
        ((H, W, 10) float32 stored maps stacked in :data:`svbrdf_cli.conventions.MAP_NAMES` order
        (normal 3, diffuse 3, roughness 1, specular 3), the estimate's findings (:func:`estimate`)).
    """
    stored, found = estimate(image)
    return np.concatenate([stored[k] for k in cv.MAP_NAMES], -1), found


#: The ``--model`` name of the physical estimate (it needs no model file).
NAME = "physical"


class PhysicalModel:
    """``--model physical``: :func:`estimate` as a :class:`svbrdf_cli.infer.model.Model`."""

    tier = NAME
    stages = ()
    #: Runs at any image size (the capture runs it again at the output size instead of upsampling).
    any_size = True

    def __init__(self, geometry=None):
        self.geometry = geometry
        self.timings = {}
        self.found = {}

    @property
    def used(self):
        """Itself (a :class:`svbrdf_cli.infer.model.Model`)."""
        return self

    def describe(self):
        """What ``material.json`` records: the method and what the estimate found."""
        return {"tier": self.tier, "method": "physical estimate (svbrdf_cli.infer.physical)", "found": self.found}

    def __call__(self, image):
        """Stored maps of the encoded (H, W, 3) photo ``image``, and the fitted flash image (``flash_fit``)."""
        t0 = time.perf_counter()
        stored, self.found, fitted = estimate(image, self.geometry, with_fit=True)
        self.timings = {"physical": time.perf_counter() - t0}
        return {**stored, "flash_fit": fitted}
