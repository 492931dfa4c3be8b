"""Test-time refinement: adjust the maps so that, rendered under the capture's own flash, they match the photo.

``svbrdf capture --refine N`` runs :func:`refine` on the model's (or the physical estimate's)
maps at the network's resolution, before upsampling. numpy only: the renderer and its analytic
gradient are :func:`svbrdf_cli.shading.render_with_gradient`.

**What is optimised.** Per pixel: the normal as a 2D tilt (x/z, y/z: every value is a valid
normal), the diffuse albedo as its logarithm (relative steps, never negative), roughness and
specular (F0) directly, projected back into range after each step. One global light intensity is
fitted once at the start by least squares (an exposed photo has no absolute scale) and then held.

**Against what.** The photo, compared gamma-encoded (as people and the relighting scores see it)
through a robust (Cauchy) loss: pixels the photo clipped, and their rims, say only "at least this
bright" and are left out, and a few badly explained pixels (a sparkle no smooth lobe makes, a
speck of dust) barely pull the fit. With per-pixel freedom the
diffuse alone could copy the photo exactly, so the priors decide how the residual is shared:

* **closeness to the initial maps**, relative for diffuse (a pixel may change by a fraction of
  itself), absolute for the rest: where the photo says nothing the prediction stands;
* **smoothness of roughness and specular** (squared differences of neighbours): a highlight is
  explained by a smooth lobe, not by painting its disc into the maps;
* **a dielectric prior**: specular's luminance is pulled towards :data:`svbrdf_cli.conventions.DIELECTRIC_F0`,
  and its change is grey plus at most the diffuse's own colour, that only where the pixel is a metal by
  F0's level or by the photo's highlight colour (:func:`_spec_change`: a metal looks its colour; no other
  tint is added to explain a white highlight over a coloured diffuse), and
  the map's mean luminance never goes under that dielectric F0 (:data:`SPECULAR_FLOOR`): the photo
  may shape it from pixel to pixel but not lower the whole map;
* **normals near the start's** (up, for the physical estimate) unless the photo needs them changed, and no
  change of tilt over whole regions;
* **no trend with the distance to the highlight** in the diffuse's, roughness's and F0's changes
  (:func:`_without_radial_trend`): no disc round the flash, no vignetting taken up by the diffuse; and
  no tilt pointing away from (or towards) the highlight all round it (:func:`_without_radial_tilt`): no
  bump or crater at the flash in the normals and the height integrated from them; and, once the fit is
  done, no trend across the map in x and y in the diffuse's change (:func:`_without_planar_trend`) and
  no patch where the tilt changed many times more than over the rest of the map (:func:`_even_tilt`).

**Schedule.** Coarse to fine (:data:`LEVELS`): the changes are first found on a small image,
where the smooth parts converge in few cheap steps, then upsampled and refined at the next
level. Adam steps. The result is the iterate with the lowest objective; if it fits the photo
worse than the starting maps, or anything is not finite, the starting maps are returned.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli import imageops
from svbrdf_cli.imageops import luminance
from svbrdf_cli import shading
from svbrdf_cli.rectify import highlight

#: Iterations of ``--refine`` given without a number (and of ``svbrdf capture`` without ``--refine``).
#: After the trained chain, 30 steps fit as well as 60 in half the time (``docs/benchmarks.md``): the
#: card 0.1262 against 0.1259, the 48 generated known-light captures 0.0723 against 0.0722, Des19 within
#: 0.0003 on every map; 15 steps relit those captures worse (0.0734).
DEFAULT_ITERATIONS = 30
#: The most ``--refine`` accepts.
MAX_ITERATIONS = 5000
#: Resolutions of the coarse-to-fine schedule (fractions of the working size), and the share of
#: the iterations each gets.
LEVELS = ((0.25, 0.3), (0.5, 0.3), (1.0, 0.4))
#: Encoded pixels at or above this (times the photo's clip level) were clipped by the camera.
CLIPPED = cv.CLIPPED
#: Pixels this close (a fraction of the width) to a clipped one are left out of the photo term
#: (the edge of a clipped blob is partly clipped too).
CLIP_MARGIN = 0.008
#: Width of the robust (Cauchy) loss on encoded residuals: residuals well under it count as
#: squares, residuals well over it (a sparkle the model cannot make, a speck of dust) barely pull.
ROBUST_WIDTH = 0.2
#: The scale of a "broad" tilt (:attr:`Priors.broad_tilt`), a fraction of the width.
BROAD_SIGMA = 1.0 / 16.0
#: Floor added to radiance before the 1/2.2 power (keeps its derivative finite at black).
ENCODED_FLOOR = 1e-3


@dataclasses.dataclass
class Priors:
    """Weights of the prior terms (each a mean over pixels, like the photo term).

    Chosen on the held-out relighting of ``card_blue_9lights``, Des19 and 32 generated photos
    (``python -m export.studies.refine_eval --methods physical --repeat 0 --generated 32 --prior
    NAME=VALUE`` tries a weight); a weaker ``broad_tilt`` relights the card a little better but leaves a
    disc of tilted normals round the flash on real photos.
    """

    diffuse: float = 0.05            # ((d - d0) / (d0 + 0.05))^2: relative
    #: (r - r0)^2. At 0.05 (Adam step 0.1) the card relit from its 9 photos 0.1422 -> 0.1320 and the 48
    #: generated known-light captures 0.0741 -> 0.0726, but a scratched leather's fit (henzler_train
    #: 0256/IMG_0895) tilted the normals round its clipped highlight; with the tilt's change held there
    #: (ramped in over 15 % of the side from the clipped pixels) the marks went and the card kept its gain
    #: (0.1183, 9 photos 0.1310; Des19 roughness 0.1277 -> 0.1324), yet the leather's roughness fell from
    #: 0.39 to 0.21 and its render's highlight came out far tighter than the photo's broad one.
    roughness: float = 0.5
    specular: float = 1.0            # (s - s0)^2
    normal: float = 1.02             # |tilt - tilt0|^2
    #: |(tilt - tilt0) blurred over BROAD_SIGMA|^2: no change of tilt over whole regions. The physical
    #: estimate starts flat, so its tilt is held near up; the chain's relief is kept as it read it. Pulled
    #: towards up instead (|tilt|^2 at 0.02, its blur at 10), the chain's normals lost
    #: relief under refinement (Des19 normal 0.0504 -> 0.0527, relief 0.380 -> 0.361); held at the start
    #: they keep it (0.0504, 0.382) and the card (0.1262 -> 0.1260), the known-light captures (0.0723 ->
    #: 0.0719) and Des19's relighting (0.0581 -> 0.0577) are relit better.
    broad_tilt: float = 10.0
    #: (luminance(s) - 0.04)^2: a dielectric's F0 *level*. Its colour is left to the closeness prior and
    #: to :func:`_spec_change` (grey plus the diffuse's own colour): a coloured foil or anodised metal
    #: reflects in its own colour, and a grey F0 pulled onto it whitens every highlight (the teal and
    #: gold foil scales of card_blue_9lights relit pale).
    dielectric: float = 5.0
    smooth_roughness: float = 0.5    # squared neighbour differences (at the full size)
    smooth_specular: float = 2.0


#: Adam step sizes per parameter (tilt, log diffuse, roughness, specular).
STEP = {"tilt": 0.02, "diffuse": 0.03, "roughness": 0.02, "specular": 0.005}
#: Parameters whose Adam second moment is the whole map's (per channel), not each pixel's. Per pixel,
#: Adam turns a gradient however small into a full step: the photo's gradient on the tilt changes sign
#: across the highlight's row and column, and 30 steps drew a cross there in the normals (0.13 of tilt
#: from one side to the other on a leather, repeated by ``--tileable``). Pooled, a pixel moves in
#: proportion to its gradient, at most a step: the tilt's step at most one step long, whatever its
#: direction. Held to a step in x and in y apart (a square), the steps that the highlight's slope
#: clipped were shorter along the highlight's row and column than on its diagonals, and the tilt's change
#: drew a cross there (an orange leather, henzler_train 0259/IMG_0892). Measured through ``svbrdf capture``
#: with the installed chain, square -> round: Des19 relief 0.431 -> 0.433 (the other maps unchanged), the
#: card 0.1179 -> 0.1180, from its 9 photos 0.1414 -> 0.1413, the 48 generated known-light captures
#: 0.0543 -> 0.0543.
POOLED = ("tilt",)
#: Ranges the parameters are projected into after each step.
ROUGHNESS_RANGE = (0.03, 1.0)
SPECULAR_RANGE = (0.0, 1.0)
#: The refined F0's mean luminance never goes under a common dielectric's (grey is added to every
#: pixel, so its spatial variation and tint stay). Almost every surface reflects at least that much
#: (water, 0.02, is the rare exception); a fit that lowers the whole map is explaining something else
#: (the global intensity fitted at the start, a highlight spread by relief the flat start lacks),
#: while its variation from pixel to pixel is the photo's evidence. Without a floor the fit lowered F0
#: on 27 of the 29 Des19 samples; a floor on every pixel's F0 relit the card worse (its foil scales do
#: reflect less than 0.04 in places). The fit still draws a dark F0 dot on the bundled tiles, at a grout
#: corner beside the clipped highlight (0.011 against 0.046 round it). Two ways to stop it were measured
#: through the command with the installed chain and not kept: every pixel's F0 luminance at least 0.03
#: (the dot at 0.03; the card 0.1201 -> 0.1201, from its 9 photos 0.1428 -> 0.1445, the 48 generated
#: known-light captures 0.0551 -> 0.0554), and F0's change one value per albedo class, as the
#: roughness's (:func:`_per_class` on each channel; no dot; Des19 specular 0.0579 -> 0.0572 but relief
#: 0.426 -> 0.425, the card 0.1195 -> 0.1217, from its 9 photos 0.1436 -> 0.1466).
SPECULAR_FLOOR = cv.DIELECTRIC_F0
#: Diffuse, roughness and F0 may change from pixel to pixel but not with the distance to the
#: highlight: after each step their change (the diffuse's in its logarithm: a relative change) loses its
#: trend over :data:`RADIAL_RINGS` rings round the highlight's centre (:func:`_without_radial_trend`, the
#: diffuse's ring means weighted by its albedo, :func:`_radial_weight`; the map's mean change is kept). A
#: material has no reason to be rougher, duller or darker where the flash happened to point; a fit that
#: makes it so is explaining the highlight's shape (sharper than the start's lobe, its clipped core left
#: out) or the lens's vignetting and the flash's beam, and leaves a disc round the flash, or dark edges
#: that show as a grid when the texture tiles.
RADIAL_RINGS = 16
#: The maps whose change loses its radial trend. Free of it, the fit made the diffuse's edges darker
#: than its centre by a median 10 % on the 12 real benchmark photos (the estimate's own: 4 %): the
#: lens's vignetting, which the synthetic sets do not have.
RADIAL_FREE = ("diffuse", "roughness", "specular")
TILT_LIMIT = 3.0  # 72 degrees
#: The roughness's change is one value per soft albedo class of the start's diffuse
#: (:func:`svbrdf_cli.imageops.soft_classes`), projected after each step (:func:`_per_class`), each class's
#: value read where the specular lobe makes the light (:func:`_lobe_share`). With a change per pixel, the
#: fit painted a clipped highlight's rim into the roughness: a ring of glossy and rough blotches round the
#: flash on a red lacquer, a blotch at the flash on a green leather and on the bundled tiles. A material's
#: roughness follows its albedo's classes (a tile and its grout, a wood and its varnish), not the flash.
ROUGHNESS_CLASSES = 4
#: The soft classes' memberships are raised to this power (and normalised again): a pixel of one colour
#: belongs to its own class, not a quarter to each of the others (:func:`svbrdf_cli.imageops.soft_classes`
#: gives a grey pixel next to a blue region 0.29 of the blue's classes), so a class the highlight never
#: reached does not take the change seen under it; a pixel between two colours still shares them.
CLASS_SHARPNESS = 4
#: A class's value is its lobe-weighted mean change shrunk towards none by this share of the image's pixels
#: added to its lobe's weight: a class the lobe shows over a few pixels only (or through the last of its
#: membership) keeps about no change, one it shows over 1 % of the image keeps 0.9 of its mean.
CLASS_EVIDENCE = 0.001
#: The tilt's change keeps only its detail finer than this (a Gaussian's sigma, a share of the side), after
#: each step (:func:`_only_fine`). A highlight whose shape the smooth lobe does not make (taller than wide,
#: broader, a little off) was explained by tilting the normals round the flash: on a scratched leather
#: (henzler_train 0256/IMG_0895) whose normals the chain read flat, 30 steps drew a disc of tilted
#: quadrants a quarter of the photo wide, split by a step along the highlight's row, repeated by a tiling
#: (the seam measure of ``export.studies.tiling_figure`` 0.92 -> 0.05). One photo shows relief round the
#: flash as fine detail in its highlight, and that is kept. Measured through ``svbrdf capture``
#: (``capture_eval --all-card``) without -> with: Des19 normal 0.0478 -> 0.0478, relief 0.419 -> 0.422, the
#: card 0.1187 -> 0.1195, from its 9 photos 0.1419 -> 0.1425; the 48 generated known-light captures
#: 0.0750 -> 0.0748; ``--model physical``: relief 0.081 -> 0.088, the card 0.1297 -> 0.1301. At 0.015:
#: relief 0.424, the card 0.1201. The step size instead (a quarter: the disc fainter, the step still
#: there), looser clipping of the pooled step (no step, a ring of noisy tilt instead) or a smoothness
#: prior on the change (relief 0.415, the card 0.1201 at weight 8) left the disc.
TILT_DETAIL = 0.03
#: Where the photo clipped (no photo term), the fit's change to diffuse, roughness and F0 is taken
#: from the surrounding pixels' change once the fit is done, instead of the start's values the
#: priors hold there: the change is the photo's evidence about the material (a glossier tile, a
#: brighter diffuse), and the clipped disc is the same material. Without it the bundled sample's
#: F0 showed a dark disc at the clipped highlight inside a ring that had moved (:func:`_fill_unobserved`).
#: The parameters :func:`_fill_unobserved` fills. The tilt too: held at the start's inside the clipped
#: region while the fit tilted the normals round it, it drew the region's ragged outline into every
#: relit render of the highlight. Not the roughness: its change is its albedo class's
#: (:data:`ROUGHNESS_CLASSES`), which the clipped pixels share with the rest of their class.
FILLED = ("tilt", "diffuse", "specular")


@dataclasses.dataclass
class Result:
    """What :func:`refine` returns."""
    stored: dict            # refined maps, stored encoding (HWC, roughness one channel)
    report: dict            # JSON-able: iterations, photo loss before/after, intensity, seconds


def _at(x, side):
    """(H, W, C) ``x`` at ``side``² (:func:`svbrdf_cli.imageops.resize`, bilinear up; float32)."""
    return imageops.resize(np.asarray(x, np.float32), side, up="linear")


def _robust(e):
    """Cauchy penalty of residuals ``e`` and its derivative."""
    c = ROBUST_WIDTH
    t = 1.0 + (e / c) ** 2
    return 0.5 * c * c * np.log(t), e / t


def _encode(r):
    """Radiance -> the space the photo is compared in (gamma encoded), and its derivative."""
    y = (r + ENCODED_FLOOR) ** (1.0 / cv.IMAGE_GAMMA)
    return y, y / (cv.IMAGE_GAMMA * (r + ENCODED_FLOOR))


def _unclipped(photo_lin):
    """(H, W, 1) weight: 0 at clipped pixels and within :data:`CLIP_MARGIN` of one, rising to 1 over as
    much again (Euclidean distance: a round rim, not a square kernel's staircase)."""
    import cv2

    level = cv.clip_level(cv.image_to_encoded(photo_lin))  # (a clipped highlight the exposure darkened)
    clipped = (photo_lin >= cv.image_to_linear(np.float32(CLIPPED * level))).any(-1)
    r = max(1.0, CLIP_MARGIN * photo_lin.shape[0])
    if not clipped.any():
        return np.ones(photo_lin.shape[:2] + (1,), np.float32)
    dist = cv2.distanceTransform((~clipped).astype(np.uint8), cv2.DIST_L2, 5)
    return np.clip((dist - r) / r, 0.0, 1.0)[..., None].astype(np.float32)


def _dot_flat(a, b):
    """Sum of ``a * b`` over all elements, without the product's temporary array (``einsum``: one pass on
    this thread; BLAS's dot product would wake its threads, which spin on a core a batch or the
    training run is using)."""
    return float(np.einsum("i,i->", np.ascontiguousarray(a).ravel(), np.ascontiguousarray(b).ravel()))


def _sum_sq(x):
    """Sum of the squares of ``x``."""
    return _dot_flat(x, x)


def _smoothness(x):
    """Mean over pixels of squared neighbour differences, and its gradient."""
    dx, dy = np.diff(x, axis=1), np.diff(x, axis=0)
    n = x.shape[0] * x.shape[1]
    val = (_sum_sq(dx) + _sum_sq(dy)) / n
    g = np.zeros_like(x)
    g[:, :-1] -= dx
    g[:, 1:] += dx
    g[:-1] -= dy
    g[1:] += dy
    return val, 2.0 * g / n


def _broad(x):
    return imageops.blur(x, BROAD_SIGMA * x.shape[0]).reshape(x.shape)


def _maps(p):
    return p["tilt"], np.exp(p["diffuse"]), p["roughness"], p["specular"]


class _Problem:
    """The objective at one resolution: the photo term plus the priors around the start ``init``."""

    def __init__(self, photo_lin, init, geometry, intensity, priors, full_side, weight=None):
        side = photo_lin.shape[0]
        self.weight = _unclipped(photo_lin) if weight is None else weight
        self.count = max(float(self.weight.sum()) * 3.0, 1.0)
        # each residual's weight in the photo term, per channel
        self.scaled_weight = np.ascontiguousarray(np.broadcast_to(self.weight / np.float32(self.count), photo_lin.shape))
        self.target = _encode(photo_lin)[0]
        self.init = dict(init, diffuse_lin=np.exp(init["diffuse"]))
        self.lighting = shading.Lighting(side, side, geometry.light, geometry.camera, intensity)
        self.priors = priors
        # a coarser level's neighbour differences span more of the surface: scale them to the full size's
        self.smooth_scale = (side / full_side) ** 2

    def photo_loss(self, p):
        r, _ = shading.render_with_gradient(*_maps(p), self.lighting)
        return _dot_flat(self.scaled_weight, _robust(_encode(r)[0] - self.target)[0])

    def __call__(self, p):
        """(objective, photo term, gradient dict like ``p``)."""
        pr, init = self.priors, self.init
        maps = _maps(p)
        r, backward = shading.render_with_gradient(*maps, self.lighting)
        y, dy = _encode(r)
        rho, drho = _robust(y - self.target)
        data = _dot_flat(self.scaled_weight, rho)
        g = backward(self.scaled_weight * drho * dy)
        d = maps[1]
        g["diffuse"] = g["diffuse"] * d  # through d = exp(u)
        n = float(r.shape[0] * r.shape[1])
        total = data
        d0 = init["diffuse_lin"]
        rel = (d - d0) / (d0 + 0.05)
        total += pr.diffuse * _sum_sq(rel) / (3 * n)
        g["diffuse"] += pr.diffuse * 2.0 * rel / (d0 + 0.05) * d / (3 * n)
        for key, w, ch in (("roughness", pr.roughness, 1), ("specular", pr.specular, 3), ("tilt", pr.normal, 2)):
            dv = p[key] - init[key]
            total += w * _sum_sq(dv) / (ch * n)
            g[key] += w * 2.0 * dv / (ch * n)
        if pr.broad_tilt:  # the blur is symmetric: its own adjoint
            b = _broad(p["tilt"] - init["tilt"])
            total += pr.broad_tilt * _sum_sq(b) / (2 * n)
            g["tilt"] += pr.broad_tilt * 2.0 * _broad(b) / (2 * n)
        # the dielectric prior holds F0's level (its luminance), not its colour (see Priors.dielectric)
        ds = luminance(p["specular"]) - cv.DIELECTRIC_F0
        total += pr.dielectric * _sum_sq(ds) / n
        g["specular"] += pr.dielectric * 2.0 * ds[..., None] * imageops.LUMA32 / n
        for key, w in (("roughness", pr.smooth_roughness), ("specular", pr.smooth_specular)):
            val, gs = _smoothness(p[key])
            total += w * val * self.smooth_scale
            g[key] += w * gs * self.smooth_scale
        return total, data, g


def _tint(diffuse_log):
    """(H, W, 3) colour of the diffuse with unit channel mean: the one tint F0 may take on (a metal's)."""
    d = np.exp(diffuse_log)
    return (d / np.maximum(d.mean(-1, keepdims=True), 1e-4)).astype(np.float32)


def _spec_change(change, tint, level, own=None):
    """Project a change of F0 onto ``a * grey + b * tint`` with ``b >= 0`` (per pixel, least squares): F0 may
    rise or fall, and take on the diffuse's own colour (a metal's look), but no other colour: not the
    blue that would whiten a highlight over brown wood, nor the photo's texture.

    How much of the diffuse's colour is bounded by how far the pixel is a metal: ``b`` is at most that
    share of F0's ``level`` (the start's plus this change's, luminance), the share being F0's level read
    as a metal's (:func:`svbrdf_cli.conventions.metal_weight`) or ``own`` (H, W), the share of the photo's
    highlight in the material's colour (:func:`svbrdf_cli.rectify.highlight.metal_share`), whichever is
    more. A dielectric's highlight is the flash's white, so its F0 changes in grey (a wood's F0 tinted by
    its diffuse renders pink highlights and reads as metal); a foil whose highlight the photo shows in
    its own colour may take that colour even at a dielectric's level."""
    return _TintBasis(tint).project(change, level, own)


class _TintBasis:
    """:func:`_spec_change`'s least squares for one ``tint`` (H, W, 3), its normal equations' terms made once
    (per level of :func:`refine`)."""

    def __init__(self, tint):
        self.tint = tint
        self.g12 = tint[..., 0:1] + tint[..., 1:2] + tint[..., 2:3]
        det = 3.0 * (tint[..., 0:1] ** 2 + tint[..., 1:2] ** 2 + tint[..., 2:3] ** 2) - self.g12 * self.g12
        ok = det > 1e-6  # a grey diffuse has no tint of its own
        self.inv_det = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0).astype(np.float32)

    def project(self, change, level, own=None):
        """:func:`_spec_change` of ``change``."""
        t = self.tint
        r1 = change[..., 0:1] + change[..., 1:2] + change[..., 2:3]
        r2 = change[..., 0:1] * t[..., 0:1] + change[..., 1:2] * t[..., 1:2] + change[..., 2:3] * t[..., 2:3]
        b = (3.0 * r2 - self.g12 * r1) * self.inv_det
        metal = cv.metal_weight(level)
        if own is not None:
            metal = np.maximum(metal, own)
        b = np.clip(b, 0.0, (metal * np.maximum(level, 0.0))[..., None])
        a = (r1 - b * self.g12) / 3.0
        return (a + b * t).astype(np.float32)


class _Rings:
    """The rings round ``centre`` (the highlight's) at ``side``², those of :func:`svbrdf_cli.imageops.rings`, made
    once per level: each pixel's ring, where it falls between two ring centres (the piecewise-linear
    interpolation of ``np.interp``, held at the ends, as indices and fractions), and its direction away
    from the centre. :func:`_without_radial_trend` and :func:`_without_radial_tilt` use them at every step."""

    def __init__(self, side, centre, rings=RADIAL_RINGS):
        p = cv.surface_positions(side, side)
        off = np.stack([p[..., 0] - centre[0], p[..., 1] - centre[1]], -1)
        self.rho = np.hypot(off[..., 0], off[..., 1]).astype(np.float32)
        self.ring, self.centres = imageops.rings(self.rho, rings)
        self.count = np.bincount(self.ring, minlength=rings).astype(np.float64)
        self.away = (off / np.maximum(self.rho, 1e-6)[..., None]).astype(np.float32)
        c, rho = self.centres, self.rho.ravel()
        self.lower = np.clip(np.searchsorted(c, rho, "right") - 1, 0, rings - 2)
        frac = np.clip((rho - c[self.lower]) / (c[self.lower + 1] - c[self.lower]), 0.0, 1.0)
        self.frac = frac.astype(np.float32)
        # the interpolation's mean over the pixels, as weights of the ring values
        self.mean_weights = (np.bincount(self.lower, 1.0 - frac, minlength=rings) +
                             np.bincount(self.lower + 1, frac, minlength=rings)) / rho.size

    def interpolate(self, values, ok):
        """(H, W) float32: ``values`` (one per ring; those of the ``ok`` rings count) interpolated between the
        ring centres at each pixel, and its mean over the pixels."""
        if not ok.all():  # the same polyline through the rings that have pixels only
            values = np.interp(self.centres, self.centres[ok], values[ok])
        v = values.astype(np.float32)
        t = v[self.lower] + np.diff(v)[self.lower] * self.frac
        return t.reshape(self.rho.shape), float(self.mean_weights @ values)

    def weights(self, weight, channels):
        """Per channel of a map, what :func:`_without_radial_trend` weighs its ring means by: (each pixel's weight,
        flat, or None for equal weights; each ring's; the map's). ``weight``: (H, W, C) or None."""
        if weight is None:
            return [(None, self.count, float(self.count.sum()))] * channels
        out = []
        for c in range(channels):
            w = weight[..., c].ravel().astype(np.float64)
            out.append((w, np.bincount(self.ring, weights=w, minlength=len(self.centres)), max(float(w.sum()), 1e-12)))
        return out


def _without_radial_trend(change, radial, weight=None):
    """``change`` (H, W, C) less its ring means' departure from its mean, interpolated between ring
    centres (so no ring edge shows): what is left varies from pixel to pixel, not with the distance.

    ``weight`` (H, W, C), when given, weights each pixel in its ring's mean and in the map's (the
    diffuse's start albedo, :func:`_radial_weight`); the trend is still taken off every pixel alike. It
    may also be :meth:`_Rings.weights`' list, made once for many changes."""
    channels = change.shape[-1]
    weights = weight if isinstance(weight, list) else radial.weights(weight, channels)
    out = np.empty_like(change)
    for c, (w, n, total) in enumerate(weights):
        v = change[..., c]
        sums = np.bincount(radial.ring, weights=v.ravel() if w is None else v.ravel() * w,
                           minlength=len(radial.centres))
        ok = n > 0
        trend = np.where(ok, sums / np.where(ok, n, 1.0), 0.0) - float(sums.sum()) / total
        t, mean = radial.interpolate(trend, ok)
        out[..., c] = v - (t - np.float32(mean))  # (interpolated, the trend's own mean is not quite 0)
    return out


def _radial_weight(key, params):
    """The weight of each pixel in the ring means of ``key``'s change (:func:`_without_radial_trend`), at the
    start ``params``: the diffuse's linear albedo for the diffuse's change, None (equal) for the others.

    The diffuse's change is relative (its logarithm), and a dark pixel's moves far for little cost (the
    closeness prior is relative only above its 0.05, and a dark pixel makes a small part of the photo's
    brightness). On white plaster with black spots all round a spotless flash spot, the fit took the spots'
    logarithm down by about 1.1 and the plaster's by 0.16; with equal weights the spotted rings' means read
    the spots' share as a trend, and taking it off lifted the plaster in those rings by up to 0.26 over the
    plaster at the spot (0.75 of its brightness in the written base colour). Weighted by the albedo, a ring's
    mean is the relative change of its mean albedo: a disc or vignetting, alike on every pixel, moves it as
    much as the plain mean, and a dark pattern's change barely does (the plaster's brightness at the spot:
    0.90). What it lets through is a trend in the dark pixels' own change: there, the spots' went from -0.8
    in the inner spotted rings to -3 at the edge, black either way (4 % and 0.4 % of the plaster's albedo)."""
    return np.exp(params["diffuse"]) if key == "diffuse" else None


def _without_radial_tilt(tilt, radial):
    """``tilt`` (H, W, 2) less its ring means' component along the direction away from the highlight
    (``radial``'s centre), interpolated between ring centres: a tilt that points away from (or towards) the
    flash all round it is a bump (or a crater) under the highlight, which integrates into the height map; a
    relief's tilts point every way round any point."""
    away = radial.away
    along = tilt[..., 0] * away[..., 0] + tilt[..., 1] * away[..., 1]
    ok = radial.count > 0
    sums = np.bincount(radial.ring, weights=along.ravel(), minlength=len(radial.centres))
    t, _ = radial.interpolate(np.where(ok, sums / np.where(ok, radial.count, 1.0), 0.0), ok)
    return (tilt - t[..., None] * away).astype(np.float32)


def _only_fine(change):
    """The tilt's ``change`` (H, W, 2) less its blur over :data:`TILT_DETAIL` of the side: its relief finer than
    the highlight."""
    low = imageops.blur(change, TILT_DETAIL * change.shape[0]).reshape(change.shape)
    return (change - low).astype(np.float32)


def _lobe_share(p, lighting, weight):
    """(H, W) share of each pixel's rendered light that is the specular lobe's, at the maps ``p`` (0 where the
    photo ``weight`` is 0: clipped): where the photo tells the roughness."""
    t, d, r, s = _maps(p)
    total, _ = shading.render_with_gradient(t, d, r, s, lighting)
    lobe, _ = shading.render_with_gradient(t, np.zeros_like(d), r, s, lighting)
    share = luminance(lobe) / np.maximum(luminance(total), 1e-6)
    return (np.clip(share, 0.0, 1.0) * weight[..., 0]).astype(np.float32)


def _class_basis(diffuse_log, share):
    """(soft classes (H*W, k), each pixel's weight in its classes' values (H*W, k): its lobe ``share`` times its
    membership, over the class's sum of those plus :data:`CLASS_EVIDENCE`) for :func:`_per_class`, made once
    per level."""
    classes = imageops.soft_classes(np.exp(diffuse_log), ROUGHNESS_CLASSES) ** CLASS_SHARPNESS
    classes = (classes / classes.sum(1, keepdims=True)).astype(np.float32)
    seen = share.reshape(-1, 1) * classes
    read = seen / (seen.sum(0) + CLASS_EVIDENCE * share.size)
    return classes, read.astype(np.float32)


def _per_class(change, basis):
    """The roughness's ``change`` (H, W, 1) as one value per albedo class (soft): each class's value the
    mean of the change where the lobe makes the light (``basis``: :func:`_class_basis`); a class the lobe
    barely reaches keeps about none."""
    classes, read = basis
    values = read.T @ change.reshape(-1)
    return (classes @ values).reshape(change.shape).astype(np.float32)


#: The optimisation's parameters, each from its stored map (:func:`parameters`) and back (:func:`_stored`).
PARAMETERS = ("tilt", "diffuse", "roughness", "specular")

#: The darkest linear diffuse albedo the parameters hold (its logarithm's floor).
DIFFUSE_FLOOR = 1e-4


def parameters(stored, keys=PARAMETERS):
    """Stored maps -> optimisation parameters (those of ``keys``)."""
    out = {}
    if "tilt" in keys:
        out["tilt"] = shading.normal_to_tilt(cv.decode_normals(stored["normal"]), TILT_LIMIT)
    if "diffuse" in keys:
        out["diffuse"] = np.log(np.clip(cv.albedo_to_linear(stored["diffuse"]), DIFFUSE_FLOOR, 1.0)).astype(np.float32)
    if "roughness" in keys:
        out["roughness"] = np.clip(stored["roughness"][..., :1], *ROUGHNESS_RANGE).astype(np.float32)
    if "specular" in keys:
        out["specular"] = np.clip(cv.albedo_to_linear(stored["specular"]), *SPECULAR_RANGE).astype(np.float32)
    return out


def _stored(p):
    """Optimisation parameters (any of :data:`PARAMETERS`) -> stored maps in [0, 1], float32."""
    out = {}
    if "tilt" in p:
        out["normal"] = cv.encode_normals(shading.tilt_to_normal(p["tilt"]))
    if "diffuse" in p:
        out["diffuse"] = cv.albedo_to_stored(np.exp(p["diffuse"]))
    if "roughness" in p:
        out["roughness"] = p["roughness"]
    if "specular" in p:
        out["specular"] = cv.albedo_to_stored(p["specular"])
    return {k: np.clip(v, 0.0, 1.0).astype(np.float32, copy=False) for k, v in out.items()}


#: Each parameter's range (:func:`_project`).
RANGES = {"tilt": (-TILT_LIMIT, TILT_LIMIT), "diffuse": (float(np.log(DIFFUSE_FLOOR)), 0.0), "roughness": ROUGHNESS_RANGE,
          "specular": SPECULAR_RANGE}


def _project(p):
    """Each of the parameters ``p`` holds (any of :data:`PARAMETERS`) into its range (:data:`RANGES`), in place of
    the dict's."""
    for k in p:
        p[k] = np.clip(p[k], *RANGES[k])
    if SPECULAR_FLOOR and "specular" in p:  # grey added to every pixel when the map's mean luminance is under the floor
        short = SPECULAR_FLOOR - float((luminance(p["specular"])).mean())
        if short > 0:
            p["specular"] = np.clip(p["specular"] + np.float32(short), *SPECULAR_RANGE)


def fit_intensity(photo_lin, params, geometry, weight=None):
    """The light intensity that best reproduces the photo from ``params`` (least squares, unclipped pixels;
    ``weight``: :func:`_unclipped` of the photo when the caller has it already)."""
    side = photo_lin.shape[0]
    light = shading.Lighting(side, side, geometry.light, geometry.camera, 1.0)
    r, _ = shading.render_with_gradient(*_maps(params), light)
    ok = np.broadcast_to((_unclipped(photo_lin) if weight is None else weight) > 0, r.shape)
    num, den = float((r[ok] * photo_lin[ok]).sum()), float((r[ok] ** 2).sum())
    return num / den if den > 0 else cv.FLASH_INTENSITY


def _without_planar_trend(start, p):
    """``p`` with the trend in x and y of its diffuse's change from ``start`` (in the logarithm, the mean of the
    channels: :func:`svbrdf_cli.infer.physical.planar_trend`, a level per colour class of the start's diffuse)
    taken off every channel alike; the change's mean is kept.

    The change loses its trend round the highlight at every step (:func:`_without_radial_trend`), but a trend
    centred elsewhere is left: a lens darkens a photo's corners round its own centre, and the fit put that
    into the diffuse as a bowl. Measured on the 12 real benchmark photos of ``export.studies.artist_check``
    (the base colour's log-brightness within 0.35 of the centre less beyond 0.9, median of its size):
    0.073 -> 0.036 (the orange leathers ``henzler_train`` IMG_0892 -0.16 -> -0.03 and IMG_0882 -0.16 ->
    -0.01). Through ``svbrdf capture`` (``capture_eval --all-card``): Des19 diffuse 0.0303 -> 0.0301, the rest
    unchanged; the card 0.1177 -> 0.1179, from its 9 photos 0.1416 -> 0.1414; ``--model physical`` diffuse
    0.0350 -> 0.0345, the card 0.1292 -> 0.1293 (9 photos 0.1613 -> 0.1612); the 48 generated known-light
    captures 0.0543 as shot (worse than the floor on 5 -> 6), 0.0568 colocated (3); the artist check's counts
    unchanged. Taking the trend off the whole refined diffuse instead (not only the change): Des19 diffuse
    0.0299, the benchmark photos 0.013, but the spot of two ``paper_real`` photos moved towards the bounds
    (IMG_7202 1.13 -> 1.25, IMG_7381 0.95 -> 1.10): their bright centre is the material's."""
    from svbrdf_cli.imageops import chroma_classes
    from svbrdf_cli.infer.physical import planar_trend
    from svbrdf_cli.infer.swift import TREND_CLASSES, TREND_CLASSES_APART, TREND_SHARES_APART

    classes = chroma_classes(np.exp(start["diffuse"]), TREND_CLASSES, TREND_CLASSES_APART,
                             share_apart=TREND_SHARES_APART)
    trend = planar_trend((p["diffuse"] - start["diffuse"]).mean(-1), classes)
    if trend is None:
        return p
    out = dict(p)
    lo, hi = RANGES["diffuse"]
    out["diffuse"] = np.clip(p["diffuse"] - trend[..., None].astype(np.float32), lo, hi)
    return out


#: The tilt's change is nowhere stronger than this many times its median strength over the map (its RMS over
#: :data:`TILT_EVEN_SIGMA` of the side, :func:`_even_tilt`), once the fit is done. The photo tells the tilt
#: most where the highlight is, and there the fit changed it most: a patch of relief inside the flash's spot
#: on a material whose relief is the same all over (a blotch of tilted normals on an orange and a green
#: leather, henzler_train 0259/IMG_0892 and luo2024 IMG_6970, repeated by a tiling), the rest of the map
#: as the start had it. Measured through ``svbrdf capture`` with the installed chain (``capture_eval
#: --all-card``, ``known_lights``), none -> 3, 2, 1.5: Des19 normal 0.0474 -> 0.0473 for each, relief
#: 0.433 -> 0.435, 0.436, 0.436, the other maps unchanged; the card 0.1180 -> 0.1180, 0.1180, 0.1179, from
#: its 9 photos 0.1413 -> 0.1413, 0.1411, 0.1409; the 48 generated known-light captures 0.0543 -> 0.0544,
#: 0.0544, 0.0545; ``--model physical``'s relief 0.105 -> 0.106 (at 2). The artist check's counts unchanged.
TILT_EVEN = 2.0
#: See :data:`TILT_EVEN`; a share of the side.
TILT_EVEN_SIGMA = 1 / 16


def _even_tilt(start, p):
    """``p`` with the tilt's change from ``start`` scaled down where its local strength is over :data:`TILT_EVEN`
    times its median over the map."""
    change = p["tilt"] - start["tilt"]
    side = change.shape[0]
    local = np.sqrt(np.maximum(imageops.blur((change * change).sum(-1), TILT_EVEN_SIGMA * side), 0.0)) + 1e-9
    factor = np.minimum(1.0, TILT_EVEN * float(np.median(local)) / local)
    return dict(p, tilt=(start["tilt"] + change * factor[..., None]).astype(np.float32))


def _fill_unobserved(start, p, unobserved, radial):
    """``p`` with its change from ``start`` (:data:`FILLED`: tilt, diffuse, roughness, F0) at the ``unobserved`` pixels (the
    photo clipped them) taken from their surroundings' change (:func:`svbrdf_cli.imageops.fill_from_surroundings`),
    those of :data:`RADIAL_FREE` then freed of any radial trend again (``radial``: :class:`_Rings`). The photo
    term is per pixel, so the fill leaves it as it is; see :data:`FILLED`."""
    if not unobserved.any() or unobserved.all():
        return p
    out = dict(p)
    for k in FILLED:
        change = imageops.fill_from_surroundings(p[k] - start[k], unobserved)
        if k in RADIAL_FREE:
            change = _without_radial_trend(change, radial, _radial_weight(k, start))
        elif k == "tilt":
            change = _without_radial_tilt(change, radial)
        out[k] = (start[k] + change).astype(np.float32)
    _project(out)
    return out


def refine(image, stored, geometry, iterations=DEFAULT_ITERATIONS, priors=None, progress=None):
    """Refine ``stored`` maps against the encoded photo ``image`` lit as ``geometry`` says.

    Args:
        image: (S, S, 3) encoded photo in [0, 1] (the network input).
        stored: dict of (S, S, C) stored-encoding maps (the model's output).
        geometry: a :class:`svbrdf_cli.infer.geometry.CaptureGeometry`.
        iterations: Adam steps in all, over the levels of :data:`LEVELS`.
        priors: :class:`Priors` (default weights when None).
        progress: optional callable ``progress(steps_done)`` called after each step.

    Returns:
        :class:`Result`.
    """
    t0 = time.perf_counter()
    priors = priors or Priors()
    photo = cv.image_to_linear(np.asarray(image, np.float32)).astype(np.float32)
    side = photo.shape[0]
    start = parameters({k: np.asarray(v, np.float32) for k, v in stored.items()})
    # in the ranges every step is held to, as the written maps are (:func:`transfer` holds them there): a
    # chain's F0 under the floor raised before the light's fit and the loss to beat, not at the first step
    # (F0 0 on a varnished wood: 0.04 added at once doubled the photo's loss, and the start was kept)
    _project(start)
    weight = _unclipped(photo)  # (once: the intensity's fit and the full-size problem share it)
    intensity = fit_intensity(photo, start, geometry, weight)
    own = highlight.metal_share(image, geometry.light[2])[..., None]  # the photo's coloured highlights
    full = _Problem(photo, start, geometry, intensity, priors, side, weight)
    loss_before = full.photo_loss(start)
    delta = None
    best, best_total, best_data = start, None, loss_before
    done = 0
    plan = [(max(8, int(round(side * f))), int(round(iterations * share))) for f, share in LEVELS]
    plan[-1] = (side, iterations - sum(n for _, n in plan[:-1]))
    for s, steps in plan:
        init = {k: _at(v, s) for k, v in start.items()}
        # a coarser level's weight is the full size's averaged (INTER_AREA): fractional at the clipped region's
        # edge, not a mask of its own whose staircase of coarse pixels the finer levels inherit
        prob = full if s == side else _Problem(_at(photo, s), init, geometry, intensity, priors, side,
                                               weight=_at(full.weight, s))
        delta = {k: np.zeros_like(v) for k, v in init.items()} if delta is None else \
            {k: _at(v, s) for k, v in delta.items()}
        tint = _TintBasis(_tint(init["diffuse"]))
        own_s = _at(own, s)[..., 0]
        radial = _Rings(s, geometry.highlight[:2])
        weights = {k: radial.weights(_radial_weight(k, init), init[k].shape[-1]) for k in RADIAL_FREE}
        basis = _class_basis(init["diffuse"], _lobe_share(init, prob.lighting, prob.weight))
        m1 = {k: np.zeros_like(v) for k, v in delta.items()}
        m2 = {k: np.zeros((1, 1, v.shape[-1]) if k in POOLED else v.shape, np.float32) for k, v in delta.items()}
        for i in range(1, steps + 1):
            p = {k: init[k] + delta[k] for k in delta}
            _project(p)
            total, data, g = prob(p)
            if not np.isfinite(total):
                break
            if s == side and (best_total is None or total < best_total):
                best, best_total, best_data = p, total, data
            for k in delta:
                m1[k] *= 0.9
                m1[k] += 0.1 * g[k]
                g2 = g[k] * g[k]
                if k in POOLED:  # one second moment per channel for the whole map
                    g2 = g2.mean((0, 1), keepdims=True)
                m2[k] *= 0.999
                m2[k] += 0.001 * g2
                step = m1[k] / (np.sqrt(m2[k] * np.float32(1.0 / (1 - 0.999 ** i))) + np.float32(1e-12))
                step *= np.float32(1.0 / (1 - 0.9 ** i))
                if k in POOLED:  # (a pixel whose gradient is many times the map's typical one: one step at most)
                    step /= np.maximum(np.sqrt((step * step).sum(-1, keepdims=True)), np.float32(1.0))
                step *= np.float32(STEP[k])
                delta[k] -= step
            delta["specular"] = tint.project(delta["specular"], luminance(init["specular"] + delta["specular"]), own_s)
            for k in RADIAL_FREE:
                delta[k] = _without_radial_trend(delta[k], radial, weights[k])
            delta["roughness"] = _per_class(delta["roughness"], basis)
            delta["tilt"] = _only_fine(_without_radial_tilt(delta["tilt"], radial))
            done += 1
            if progress:
                progress(done)
        # the change, projected, is what the next level starts from
        p = {k: init[k] + delta[k] for k in delta}
        _project(p)
        delta = {k: p[k] - init[k] for k in delta}
    if delta is not None and plan[-1][1] > 0:
        p = {k: start[k] + delta[k] for k in delta}
        _project(p)
        total, data, _ = full(p)
        if np.isfinite(total) and (best_total is None or total < best_total):
            best, best_data = p, data
    # (radial: the last level's, at full size)
    best = _fill_unobserved(start, best, full.weight[..., 0] <= 0, radial)
    best = _without_planar_trend(start, best)
    best = _even_tilt(start, best)
    out = _stored(best)
    ok = all(np.isfinite(v).all() for v in out.values()) and best_data <= loss_before
    if not ok:
        out, best_data = _stored(start), loss_before
    out["roughness"] = out["roughness"][..., :1]
    report = {"iterations": int(done), "levels": [s for s, _ in plan], "intensity": round(float(intensity), 4),
              "photo_loss_before": round(loss_before, 5), "photo_loss_after": round(float(best_data), 5),
              "kept_start": not ok, "seconds": round(time.perf_counter() - t0, 3)}
    return Result(out, report)


def transfer(start, refined, target):
    """The refinement's change, ``refined`` less ``start`` in the optimisation's parameters, added to
    ``target``: the same photo's maps at another size (the model's maps upsampled, or the physical
    estimate computed at the output size), so the change reaches the output without blurring it.

    Args:
        start: stored-encoding maps at the working size, before :func:`refine`.
        refined: the same after it.
        target: stored-encoding maps at the output size.

    Returns:
        stored-encoding maps at the output size (roughness one channel).
    """
    a, b = (parameters({k: np.asarray(v, np.float32) for k, v in m.items()}) for m in (start, refined))
    side = target["normal"].shape[0]
    others = ("tilt", "roughness", "specular")
    p = parameters({k: np.asarray(target[k], np.float32) for k in ("normal", "roughness", "specular")}, others)
    for k in others:
        p[k] += _at(b[k] - a[k], side)
    _project(p)
    out = _stored(p)
    out["roughness"] = out["roughness"][..., :1]
    # the diffuse's change multiplies its linear albedo by exp(change), so its stored (gamma-encoded) value
    # by exp(change / gamma), within the same floor and 1: the same maps as through the logarithm, in
    # three passes over the output-size map instead of seven
    floor = np.float32(DIFFUSE_FLOOR ** (1.0 / cv.ALBEDO_GAMMA))
    factor = np.exp(_at(b["diffuse"] - a["diffuse"], side) * np.float32(1.0 / cv.ALBEDO_GAMMA))
    out["diffuse"] = np.clip(np.clip(np.asarray(target["diffuse"], np.float32), floor, 1.0) * factor, floor, 1.0)
    return out

