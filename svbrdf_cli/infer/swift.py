"""The trained ``swift`` chain (masks -> auxiliary renderings -> maps) on onnxruntime (no torch).

A model folder holding ``chain.onnx``, as ``python -m export.engine onnx`` writes it: one graph with
inputs ``photo`` (1, 3, H, W) encoded, ``context`` (1, 4, H, W) and ``base`` (1, 10, H, W)
(:mod:`svbrdf_cli.infer.flash_fields`), outputs ``masks`` (M_b, M_h), ``aux`` (I_bf, I_hr, I_hr²)
and ``maps`` (stored encoding, the correction of the base already applied). Its metadata holds the
training run's provenance.

**Scale.** A chain runs at the image size its run trained at (``run_size`` in its metadata, 128):
a larger photo is area-shrunk to it and the maps come back to the photo's size with the photo's own
detail in the normals and the diffuse (:func:`to_photo_size`), the normals renormalised. The chain
learned the flash spot's and the texture's size in pixels at that scale; run on Des19 at 256 instead,
the run's chain at 987k samples scored normal / diffuse / roughness / specular 0.0571 / 0.0489 /
0.2151 / 0.0742 (relief 0.276), at 128 0.0545 / 0.0406 / 0.1322 / 0.0595 (relief 0.302)
(``docs/training.md``).

Where the flash was comes from the physical estimate's fit of the photo (the foot of the flash and
its height, :func:`svbrdf_cli.infer.physical.fit_flash`), as the training's flash context comes from
the true flash moved by the error such a fit makes (``export/engine/batches.py``). The same fit
takes the flash's leftover trends off the diffuse (:func:`flatten_flash_trends`). The roughness keeps
the chain's reading where the highlight showed it and, elsewhere, takes its level per albedo class
from there (:func:`roughness_from_observed`). The diffuse's level is the geometric mean of the chain's
and the physical estimate's (:func:`level_with_estimate`).
"""

from __future__ import annotations

import json
import os
import time

import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli.imageops import luminance, shrink_longest, soft_classes
from svbrdf_cli.infer import flash_fields, tta
from svbrdf_cli.infer.chain import SWIFT_FILE as FILE
from svbrdf_cli.infer.chain import ModelError, padding, session
from svbrdf_cli.infer.upsample import GUIDED_MAPS, guide_detail, guided_upsample
OUTPUTS = {"masks": ("M_b", "M_h"), "aux": ("I_bf", "I_hr", "I_hr2")}


#: Reflected margin round the chain's input, in pixels. The chain trained on whole 128 px photos with
#: none, and its global features read the whole input, so the margin changes what it decides, metal
#: above all: with 16 px the chain read two dark grey plastics of ``paper_real`` (a phone case and a
#: speaker grille) at F0 0.5, with 32 px at 0.08, and no photo with metal in it above 0.05 with either.
#: Read as a dielectric where it guessed a metal (:func:`read_as_dielectric`), 16 px reads the real card and Des19
#: better. Measured through ``svbrdf capture`` (``capture_eval --all-card``; ``known_lights``) with the
#: run's chain at 1,235k and 2,376k samples (Des19 normal, relief, diffuse, roughness, specular; the card
#: relit from photo 00 and from each of its 9 photos; 48 generated known-light captures):
#:
#: ============================  ======  =====  ======  ======  ======  ======  ======  ======
#: chain, margin                 normal  relief diffuse rough.  spec.   card    card 9  known
#: ============================  ======  =====  ======  ======  ======  ======  ======  ======
#: 1,235k, 32                    0.0505  0.395  0.0322  0.1117  0.0577  0.1235  0.1498  0.0728
#: 1,235k, 16, F0 a dielectric's 0.0505  0.403  0.0320  0.1151  0.0580  0.1206  0.1437  0.0745
#: 2,376k, 32                    0.0484  0.399  0.0322  0.1266  0.0572  0.1260  0.1488  0.0768
#: 2,376k, 16                    0.0479  0.415  0.0317  0.1280  0.0571  0.1187  0.1420  –
#: 2,376k, 16, F0 a dielectric's 0.0479  0.415  0.0318  0.1280  0.0578  0.1187  0.1420  0.0747
#: 2,376k, 0                     0.0477  0.429  0.0317  0.1169  0.0594  0.1316  0.1495  –
#: ============================  ======  =====  ======  ======  ======  ======  ======  ======
MARGIN = 16
#: The passes the chain runs on each photo, averaged (:mod:`svbrdf_cli.infer.tta`'s quarter turns and
#: mirrors): the photo as it is and turned half round, the flash turned with it. A flat surface under
#: the flash looks the same after the turn; the chain reads the two a little differently, and their
#: mean reads better. Measured with the installed chain through ``svbrdf capture`` (``--refine 60``,
#: ``docs/training.md``, "Passes"): Des19 normal 0.0530 -> 0.0527, relief 0.351 -> 0.361, diffuse
#: 0.0364 -> 0.0361, roughness 0.1106 -> 0.1077, specular 0.0574 -> 0.0578; the card 0.1261 -> 0.1259;
#: the 48 generated known-light captures 0.0731 -> 0.0722. Mirrored passes read Des19 as well but the
#: card worse (0.1282-0.1286).
PASSES = ((0, False), (2, False))
#: Sizes (px) at which the chain reads the photo a second time, for :data:`SECOND_MAPS` only, averaged
#: with its reading at the run's size; the other maps are the run size's. A photo's relief shows at more
#: than one scale, and the chain, trained at 128 px, reads each a little differently. Measured for the
#: normals with the installed chain through ``svbrdf capture`` (``capture_eval --all-card``; 48 generated
#: known-light captures): with none, Des19 normal 0.0505, relief 0.382, the card 0.1233 (9 inputs
#: 0.1497), known lights 0.0731; with 160, 0.0505, **0.395**, 0.1235 (0.1498), 0.0728. With 96 instead:
#: relief 0.371, the card 0.1225; 192: 0.398, 0.0508, 0.1244; 160 and 192: 0.399, 0.0508, 0.1242. All
#: the maps at 128 and 160 read the card worse (0.1299 against 0.1262, an earlier runtime).
SECOND_SIZES = (160,)
#: The passes of the reading at :data:`SECOND_SIZES`: the two quarter turns, the flash turned with the
#: photo, so that the normals are the mean of four orientations at no more cost than two. The chain reads
#: relief a little differently in each orientation. Measured with the installed chain (2,376k) through
#: ``svbrdf capture`` (``capture_eval --all-card``): against :data:`PASSES` there, Des19 normal 0.0476 ->
#: 0.0474, relief 0.425 -> 0.431, the card 0.1179 -> 0.1177 (its 9 photos 0.1418 -> 0.1416), the other
#: maps unchanged. The quarter turns read at both sizes (four passes more) gave 0.0474 / 0.430 and the
#: card 0.1178, with a 12 MP capture 1.22 times as long (``farm-bench``); at the run's size alone 0.0475
#: / 0.426. Every map read on the four turns at the run's size: Des19 diffuse 0.0299, roughness 0.1174,
#: but the card 0.1200.
SECOND_PASSES = ((1, False), (3, False))
#: The maps averaged over the run size's reading and :data:`SECOND_SIZES`' (the others: the run size's).
#: Measured with the others added (as above, the normals' two readings kept): the specular, Des19 specular
#: 0.0578 -> 0.0569, diffuse 0.0303 -> 0.0301, the card 0.1177 -> 0.1176 (9 photos 0.1416), the 48
#: known-light captures and the artist check unchanged, but ``--confidence``'s specular, the agreement of
#: five turned and mirrored passes, went white on 99.8 % of the bundled sample (2.6 % grey before): not
#: kept for so little. The diffuse: Des19 0.0298 but the card 0.1187 (9 photos 0.1424); the roughness:
#: Des19 0.1151 but the card 0.1231 (9 photos 0.1467).
SECOND_MAPS = ("normal",)
#: The maps whose trend with the distance to the flash's foot is divided out (:func:`flatten_flash_trends`).
#: The specular too: on a speaker grille (``paper_real`` IMG_7381) the chain's F0 held a pale disc round
#: the flash, which the glTF preset turned into a metallic disc (mean metallic 0.117, 0.034 with F0
#: flattened) and a base colour 2.7 times brighter in the flash spot than round it (0.94). Measured through
#: ``svbrdf capture``: Des19 specular 0.0578 -> 0.0579, relighting 0.0577 -> 0.0576, the card 0.1260 ->
#: 0.1262, the 48 generated known-light captures 0.0719 -> 0.0718.
FLATTENED = ("diffuse", "specular")
#: How far round the pixels it fills :func:`fill_highlight` reaches, as a share of the width.
FILL_MARGIN = 0.01
#: The chain's highlight mask ``M_h`` (luminance) above which :func:`fill_highlight` fills the diffuse.
HIGHLIGHT_MASK = 0.15
#: ... unless the mask covers more of the image than this (a mirror-like surface: too little is left
#: to fill from; on the 34 real photos of ``export.studies.artist_check`` it covers at most 0.29).
MAX_MASK_SHARE = 0.5


#: A clipped pixel hides the albedo only where it is white: its darkest channel at least this share of
#: the clip level (a highlight's colour is the flash's). Measured on ``paper_real`` 7F1A4436: yellow
#: paint clipped in red and green kept its colour instead of a grey veil.
WHITE_CLIP = 0.6


def fill_highlight(diffuse, image, highlight=None, masks=None):
    """The stored ``diffuse`` filled from its surroundings where the highlight hid the albedo: where
    the encoded ``image`` is clipped (at its plateau, :func:`svbrdf_cli.conventions.clip_level`) and
    where the chain's own highlight mask ``highlight`` (``M_h``, encoded) is above
    :data:`HIGHLIGHT_MASK`, with :data:`FILL_MARGIN` round them. The smooth fill takes the chain's own
    detail (:func:`svbrdf_cli.infer.physical.relative_texture`) where the photo was not clipped (the
    chain saw the grout lines through the highlight, at a wrong level), and the texture just beside
    where it was, as the physical estimate fills its own (:func:`svbrdf_cli.infer.physical.texture_beside`):
    moved from beside, the texture doubled a tiling's grout lines. ``masks``: :func:`hidden_by_highlight`'s,
    if the caller has them. Measured with the 1,235k chain and
    the carried roughness (Des19 through capture, ``--refine 60``): diffuse 0.0365 -> 0.0364, relighting
    0.0580 -> 0.0579, the card 0.1262 -> 0.1261, the generated known-light captures 0.0734 -> 0.0731.

    The photo says nothing of the albedo under a clipped highlight, and little under a bright one:
    the aux stage's highlight-removed renderings (``I_hr``, ``--debug``) hold a grey blob there on real
    photos, and the chain's diffuse kept it as a pale or dark disc (the wood, the red lacquer, the
    green leather of ``docs/figures/real_previews.png``; Des19's polished marble). Measured on Des19
    through the capture path: the clipped pixels (the chain at 1,005k samples) diffuse RMSE 0.0411 ->
    0.0370, held-out relighting 0.0591 -> 0.0575, the card 0.1526 -> 0.1509; ``M_h`` too (at 1,066k)
    0.0374 -> 0.0367, 0.0575 -> 0.0572, the card 0.1415 -> 0.1418 (above 0.3: 0.0371, 0.0573, 0.1416).
    Filling where the estimate's fitted lobe is above 0.8 of the photo instead raised the card's
    error (0.1527; above 0.5: 0.1624).

    The smooth fill averages what surrounds the hole: on the bundled tiles the grout lines that cross the
    highlight and the tiles' darker bevels make a grey diamond (its tiles 0.87 of the ring's brightness,
    saturation 0.63 against 0.67). OpenCV's frequency-selective reconstruction (``cv2.xphoto.inpaint``,
    fast mode, in CIELab) as the fill's base instead carried the grout on through it (saturation 0.67, the
    diamond mostly gone) and relit better through the command (the card 0.1199 -> 0.1178, from its 9
    photos 0.1422 -> 0.1419, the 48 generated known-light captures 0.0741 -> 0.0737, Des19 unchanged), but
    it is not kept: on a synthetic grid with a hole about 40 px across it left a dark block in the middle
    and moved the lines the chain had seen (their correlation with the true ones -0.48); its exact mode
    fills such holes but takes 2.5 s at 256 px. Filling per albedo class, the class read from the photo's
    hue (which a white highlight keeps), kept the tiles' saturation but not their brightness: the pixels
    round the hole are the bevels' and the grout's. Patches of the rest of the map (``cv2.xphoto.inpaint``,
    shift-map mode, in CIELab, on a window round the hole) in place of the fill make whole tiles of the
    right colours on the bundled sample, the diamond's core gone, and keep the grout seen under the mask;
    measured through the command and not kept: the card 0.1199 -> 0.1201 (from its 9 photos 0.1422 ->
    0.1413), Des19 unchanged but roughness 0.1277 -> 0.1270, and the 48 generated known-light captures
    0.0651 -> 0.0664 over the whole mask, 0.0663 over its clipped part only: a plausible texture in
    the wrong place costs a relighting more than a smooth average does."""
    from svbrdf_cli.imageops import fill_from_surroundings, luminance
    from svbrdf_cli.infer.physical import relative_texture, texture_beside

    mask, clipped = masks if masks is not None else hidden_by_highlight(image, highlight)
    if not mask.any():
        return diffuse
    lin = cv.albedo_to_linear(diffuse)
    # the chain's own detail where the photo still showed the albedo through the highlight; where it
    # clipped, the texture just beside
    detail = np.where(clipped, texture_beside(lin, mask), relative_texture(luminance(lin)))
    filled = fill_from_surroundings(lin, mask, detail)
    seen = mask & ~clipped
    if seen.any():  # where the photo is not the fill's colour plus white, M_h marked another material
        kept = not_white_over(np.asarray(image, np.float32), filled) * seen
        filled += kept[..., None] * (lin - filled)
    return cv.albedo_to_stored(np.clip(filled, 0.0, 1.0)).astype(np.float32)


#: :func:`not_white_over`: the colour residual (a share of the photo's colour) up to which a pixel is the
#: fill's colour plus white, and from which it is not (smoothstep between).
WHITE_OVER_FILL = (0.08, 0.2)


def not_white_over(image, fill):
    """(H, W) in [0, 1]: how far each pixel of the encoded ``image`` is from being the linear ``fill``'s colour
    plus white (the nearest ``a * fill + b``, a, b >= 0, per pixel; the residual's length over the photo's,
    read through :data:`WHITE_OVER_FILL`).

    A dielectric's highlight adds the flash's white to its own colour, so the photo under it is the albedo's
    colour plus white; :func:`fill_highlight` replaces the chain's diffuse there by the albedo round it. Where
    the photo's colour is not that, the chain's highlight mask ``M_h`` marked a material of its own: the gold
    foil snowflake of ``paper_real`` real_cards-red_0 (its residual over the red paper's fill 0.28 against
    0.01 for a white highlight on that paper), which the fill painted red. There the chain's diffuse is kept.
    Measured through ``svbrdf capture``: the card 0.1189 -> 0.1179 (9 photos 0.1419 -> 0.1418), Des19
    unchanged (specular 0.0579 -> 0.0578), the 48 generated known-light captures unchanged (0.0543 as shot,
    0.0568 colocated: their highlights are all white over the albedo), ``export.studies.artist_check``'s
    counts unchanged (only the metal photos' spots move: the red card's fine detail 0.73 -> 0.70)."""
    from svbrdf_cli.imageops import blur

    p = blur(cv.image_to_linear(np.asarray(image, np.float32)), 1.0).astype(np.float64)
    f = np.asarray(fill, np.float64)
    ff, fs, pf, ps = (f * f).sum(-1), f.sum(-1), (p * f).sum(-1), p.sum(-1)
    det = 3.0 * ff - fs * fs  # the normal equations of [f, 1] against p
    safe = np.maximum(det, 1e-12)
    a = np.where(det > 1e-12, (3.0 * pf - fs * ps) / safe, 0.0)
    b = np.where(det > 1e-12, (ff * ps - fs * pf) / safe, ps / 3.0)
    a, b = np.where(b < 0, np.maximum(pf / np.maximum(ff, 1e-12), 0.0), a), np.maximum(b, 0.0)
    a, b = np.maximum(a, 0.0), np.where(a < 0, ps / 3.0, b)
    r = p - a[..., None] * f - b[..., None]
    rel = np.sqrt((r * r).sum(-1)) / np.maximum(np.sqrt((p * p).sum(-1)), 1e-6)
    return cv.smoothstep(rel, *WHITE_OVER_FILL).astype(np.float32)


#: A clipped pixel hides the albedo only within :data:`CLIPPED_REACH` of the width of where the chain's
#: highlight mask ``M_h`` is above this (when :func:`hidden_by_highlight` has the mask): a white albedo the
#: camera clipped with no highlight on it is at least as bright as the clip level, and the fill from its
#: darker surroundings made it a dark hole (a honeycomb's white grout round the flash, a pale stone under a
#: strong flash: 32 % and 78 % of the photo filled, relit at 0.241 and 0.062 against the floor's 0.153 and
#: 0.041). On the real photos of ``export.studies.artist_check`` every clipped highlight lies within it
#: (the chain's ``M_h`` 0.05-0.73 at its median there); the pixels left out are paint and foil the chain
#: reads as albedo (``paper_real`` 7F1A4436, IMG_7303, IMG_7364). Measured through the capture on the 48
#: generated known-light captures: 0.0601 -> 0.0551 (worse than the floor on 9, from 13; with 0.02,
#: 0.0571; with 0.1, 0.0550), Des19 diffuse 0.0311 -> 0.0312, the card unchanged (0.1201, 9 photos 0.1428).
CLIPPED_NEAR_HIGHLIGHT = 0.05
#: See :data:`CLIPPED_NEAR_HIGHLIGHT`; a share of the width.
CLIPPED_REACH = 0.02


def hidden_by_highlight(image, highlight=None):
    """(hidden, clipped): (H, W) masks of the encoded ``image`` where the highlight hid the albedo
    (:func:`fill_highlight` fills them) and, among them, where the photo clipped (white at its plateau,
    :func:`svbrdf_cli.conventions.clip_level`; with the chain's mask ``highlight``, only near where it reads
    a highlight: :data:`CLIPPED_NEAR_HIGHLIGHT`), each with :data:`FILL_MARGIN` round it."""
    import cv2

    from svbrdf_cli.imageops import luminance
    from svbrdf_cli.infer.physical import CLIPPED

    img = np.asarray(image, np.float32)
    level = cv.clip_level(img)
    # at the plateau an exposure darkened, and white: a saturated colour clipped in one or two channels
    # (yellow paint) is the albedo, not a highlight
    clipped = (img >= CLIPPED * level).any(-1) & (img.min(-1) >= WHITE_CLIP * level)

    def grow(m, reach=FILL_MARGIN):
        k = max(3, int(reach * img.shape[1]) | 1)
        return cv2.dilate(m.astype(np.uint8), np.ones((k, k), np.uint8)).astype(bool)

    mask = clipped.copy()
    if highlight is not None:
        h_lum = luminance(np.asarray(highlight, np.float32))
        clipped &= grow(h_lum > CLIPPED_NEAR_HIGHLIGHT, CLIPPED_REACH)
        marked = h_lum > HIGHLIGHT_MASK
        mask = clipped | marked if marked.mean() <= MAX_MASK_SHARE else clipped.copy()
    return grow(mask), grow(clipped)


#: :func:`flatten_flash_trends`: the diffuse's colours (k-means on its chromaticity) ...
TREND_CLASSES = 3
#: ... of which two closer than this (log units) are one, ...
TREND_CLASSES_APART = 0.25
#: ... as are two whose channels' shares of their sum differ by less than this.
TREND_SHARES_APART = 0.08


def flatten_flash_trends(stored, rho, names=("diffuse", "roughness")):
    """The maps of ``names`` among the diffuse, the specular and the roughness (stored maps) with any trend
    in the distance ``rho`` to the flash's foot divided out (:func:`svbrdf_cli.infer.physical.flatten_radial`,
    the physical estimate's last step), their mean level kept.

    None has a reason to change with where the flash happened to point; the chain leaves such
    trends where it reads the highlight's surroundings differently from the rest (a pale or dark
    spot in the diffuse, a glossier blob in the roughness, seen on real photos). Measured on Des19
    through the capture path (the run's chain at 987k samples): diffuse RMSE 0.0444 -> 0.0403,
    roughness 0.1222 -> 0.1200, held-out relighting 0.0617 -> 0.0582, the card's relighting
    0.1449 -> 0.1416.

    The trend is fitted with a level for each of the diffuse's colours (:func:`svbrdf_cli.imageops.chroma_classes`,
    :data:`TREND_CLASSES`): read from all the pixels at once, a material's own pattern that covers more of
    the rings near the foot than far from it was read as the flash's and divided out. On ``paper_real``
    IMG_6830 the flash fell beside a pale yellow grout line between blue tiles, and the spot came out at
    0.66 of its ring's brightness (0.83 before the step). Measured through ``svbrdf capture`` with the
    installed chain, one level for all -> one per colour: ``export.studies.artist_check``, the flash spot's
    brightness within 0.8-1.25 of its ring's on 30 -> 32 of the 34 photos (IMG_6830 0.66 -> 0.87, IMG_7279
    0.79 -> 0.82) and its fine detail at least half the ring's on 31 -> 32 (the card 0.48 -> 0.52); the
    48 generated known-light captures (``known_lights``) 0.0551 -> 0.0541, worse than the floor on 9 -> 7;
    the card 0.1201 -> 0.1195, from its 9 photos 0.1428 -> 0.1436; Des19 (``capture_eval --all-card``)
    unchanged but specular 0.0578 -> 0.0579. With 4 colours, joined under 0.15 apart: fine detail 33, brightness
    31 of 34, known lights 0.0543, the card 0.1194 (9 photos 0.1431), Des19 diffuse 0.0313 and roughness
    0.1279. In the physical estimate's own last step
    (:func:`svbrdf_cli.infer.physical.estimate`) it was measured and not kept: ``--model physical`` Des19
    diffuse 0.0350 -> 0.0358, the card 0.1292 -> 0.1288, from its 9 photos 0.1613 -> 0.1624, the spot's
    brightness in bounds on 29 -> 28 of 34 photos; the default's diffuse (whose level is halfway to the
    estimate's) 0.0312 -> 0.0313."""
    from svbrdf_cli.imageops import chroma_classes
    from svbrdf_cli.infer.physical import flatten_radial

    albedos = [k for k in ("diffuse", "specular") if k in names]
    classes = chroma_classes(cv.albedo_to_linear(stored["diffuse"]), TREND_CLASSES, TREND_CLASSES_APART,
                             share_apart=TREND_SHARES_APART) if albedos else None
    out = {}
    for k in albedos:  # the albedos, in linear units
        flat = flatten_radial(cv.albedo_to_linear(stored[k]), rho, classes=classes)
        if k == "diffuse":
            flat = flatten_planar(flat, classes)
        out[k] = cv.albedo_to_stored(np.clip(flat, 0.0, 1.0)).astype(np.float32)
    if "roughness" in names:
        r = np.repeat(stored["roughness"], 3, -1)
        out["roughness"] = np.clip(flatten_radial(r, rho)[..., :1], 0.0, 1.0).astype(np.float32)
    return out


def flatten_planar(diffuse, classes=None):
    """(H, W, 3) linear ``diffuse`` with its whole-map trend in x and y divided out, its mean level kept.

    :func:`svbrdf_cli.infer.physical.flatten_radial` divides out a trend round the flash's foot as the
    physical fit places it; where that foot is off (a photo's dark edge pulls it, vignetting adds to it),
    a bowl or a tilt across the map is left: on the orange leather ``henzler_train`` IMG_0892, column
    means 1.12 / 0.92 / 1.15 from left to right and a dark disc in the middle. A flat material's albedo
    has neither. The trend is :func:`svbrdf_cli.infer.physical.planar_trend`'s of the log-brightness, a level
    for each colour class (``classes`` of :func:`svbrdf_cli.imageops.chroma_classes`, or one level).
    Measured through ``svbrdf capture``: Des19 diffuse 0.0313 -> 0.0303, roughness 0.1277 -> 0.1269, the card
    0.1187 -> 0.1189 (9 photos 0.1426 -> 0.1419), ``export.studies.artist_check``'s counts unchanged. Tried
    and not kept: this step alone, without the radial one (the flash spot's brightness within bounds on 32
    -> 29 of 34 photos); the chromaticity's trends taken off too, per channel (the card 0.1193-0.1195, Des19
    level)."""
    from svbrdf_cli.infer.physical import planar_trend

    h, w = diffuse.shape[:2]
    trend = planar_trend(np.log(np.maximum(luminance(diffuse), 1e-5)), classes)
    if trend is None:
        return diffuse
    return (diffuse * np.exp(-trend).reshape(h, w, 1)).astype(np.float32)


#: :func:`roughness_from_observed`: albedo classes, and the scale (a share of the width) below which
#: the chain's own roughness is kept everywhere.
ROUGHNESS_CLASSES = 6
ROUGHNESS_DETAIL = 1 / 32


def observed_share(highlight):
    """(H, W) in [0, 1]: how much the photo shows of the specular lobe at each pixel, from the chain's
    highlight mask ``M_h`` (1 where it is at least half its peak, smoothed over 4 % of the width); None
    when the photo shows no highlight."""
    import cv2

    from svbrdf_cli.imageops import luminance

    h = luminance(np.asarray(highlight, np.float32))
    peak = float(np.percentile(h, 99.5))
    if peak < 0.05:
        return None
    return cv2.GaussianBlur(np.clip(h / (0.5 * peak), 0.0, 1.0), (0, 0), 0.04 * h.shape[1])


def roughness_from_observed(roughness, diffuse, highlight):
    """The chain's stored ``roughness`` with its level set, away from the highlight, from where the
    highlight showed: per albedo class of the ``diffuse`` (k-means of its log colour, soft), the mean
    roughness the chain gave where :func:`observed_share` is high; its detail finer than
    :data:`ROUGHNESS_DETAIL` of the width is kept.

    One flash photo shows the roughness only where the specular lobe reaches; elsewhere the chain reads
    the flash's falloff instead (glossy where the photo is dark, rough where it is well lit: the wood
    of ``docs/figures/real_previews.png``). A material's roughness follows its albedo's classes (wood
    and its varnish, tile and grout), not the flash, so the level seen under the highlight is carried
    to the pixels of the same class."""
    import cv2

    o = observed_share(highlight)
    if o is None:
        return roughness
    r = np.asarray(roughness, np.float32)[..., 0]
    p = soft_classes(cv.albedo_to_linear(diffuse), ROUGHNESS_CLASSES)
    seen = o.ravel()[:, None] * p
    mass = seen.sum(0)
    overall = float((o * r).sum() / max(float(o.sum()), 1e-6))
    level = np.where(mass > 1e-3 * o.size, (seen * r.ravel()[:, None]).sum(0) / np.maximum(mass, 1e-9), overall)
    carried = (p @ level).reshape(r.shape).astype(np.float32)
    sigma = ROUGHNESS_DETAIL * r.shape[1]
    low = cv2.GaussianBlur(r, (0, 0), sigma) - cv2.GaussianBlur(carried, (0, 0), sigma)
    return np.clip(r - (1.0 - o) * low, 0.0, 1.0)[..., None].astype(np.float32)


#: :func:`level_with_estimate`: the weight of the physical estimate's level in the diffuse's (the
#: chain's own: 1 - this), a geometric mean per channel.
ESTIMATE_LEVEL = 0.5


def estimate_weight(flash_height):
    """The physical estimate's weight in :func:`level_with_estimate` for the fitted ``flash_height``:
    :data:`ESTIMATE_LEVEL`, or 0 where the fit sits at the top of its grid
    (:data:`svbrdf_cli.infer.physical.HEIGHT_GRID`).

    The estimate divides the photo by the fall-off of its fitted height; at the grid's top it reads the
    flattest fall-off it may, and its level comes out darkest. On Des19's 21 dielectrics the 10 fitted
    there read 0.84 stops too dark by the estimate and 0.26 by the chain (fitted at the bottom: 0.06 too
    dark and 0.38 too bright). Measured through the command with the installed chain (``capture_eval
    --all-card``, ``known_lights``): Des19's diffuse 0.0321 -> 0.0308, every other map, the card (0.1199;
    9 photos 0.1422 -> 0.1423) and the 48 generated known-light captures (0.0651 -> 0.0652;
    ``--colocated`` 0.0669 -> 0.0670) unchanged. The weight falling all the way from 1 at the grid's
    bottom took Des19 to 0.0300 but the generated captures to 0.0670: there the chain's level is the
    better one at the bottom too."""
    from svbrdf_cli.infer.physical import HEIGHT_GRID

    return 0.0 if flash_height >= TOP_OF_GRID * HEIGHT_GRID[-1] * cv.CAMERA_HEIGHT else ESTIMATE_LEVEL


#: :func:`estimate_weight`: a fitted height at least this share of the grid's top is at the top (the fit
#: reports it rounded).
TOP_OF_GRID = 0.999


def estimate_diffuse(image, size=None):
    """The physical estimate's stored diffuse (:func:`svbrdf_cli.infer.physical.estimate`) of the encoded
    ``image`` area-shrunk to ``size`` first (None: as it is)."""
    from svbrdf_cli.infer import physical

    return physical.estimate(shrink_longest(np.asarray(image, np.float32), size))[0]["diffuse"]


def level_with_estimate(diffuse, image, size=None, weight=ESTIMATE_LEVEL, estimate=None):
    """The stored ``diffuse`` scaled, per channel, to the weighted geometric mean of its own mean
    linear level and the physical estimate's (:func:`svbrdf_cli.infer.physical.estimate` of the encoded
    ``image``, area-shrunk to ``size`` first): the chain's pattern and colour ratios kept.

    The chain reads the albedo's level from the photo with what it learned of the bank's materials,
    how much of a rough sheen is diffuse and how much specular: on Des19 through ``svbrdf capture``
    its diffuse is off by a factor per sample (rough tiles 3.3 times too bright, a glossy purple
    0.5 times too dark), and with the best scale per sample its RMSE would be 0.0138 against 0.0355.
    The estimate reads the level from the photo less its fitted lobe, and errs differently. Measured
    with the installed chain (1,235k samples) through the command (``capture_eval --all-card``): with
    the estimate's weight 0, 0.5, 0.75 and 1 Des19's diffuse 0.0355, 0.0322, 0.0317, 0.0318, the card
    relit from photo 00 0.1257, 0.1233, 0.1224, 0.1217; with weights 0, 0.5 and 1, the card relit from
    each of its 9 photos 0.1511, 0.1497, 0.1486 and the 48 generated known-light captures
    (``known_lights``, the bank's own kind of material) the other way, 0.0711, 0.0731, 0.0756. Half and
    half: the real card and the artist materials gain, the bank's kind loses least. ``estimate``: the
    estimate's diffuse (:func:`estimate_diffuse`) if the caller has it.

    The caller sets ``weight`` by the fitted flash height (:func:`estimate_weight`)."""
    if estimate is None:
        estimate = estimate_diffuse(image, size)
    est = cv.albedo_to_linear(np.asarray(estimate, np.float32)).reshape(-1, 3).mean(0)
    lin = cv.albedo_to_linear(np.asarray(diffuse, np.float32))
    own = lin.reshape(-1, 3).mean(0)
    target = np.exp((1.0 - weight) * np.log(own + 1e-4) + weight * np.log(est + 1e-4))
    scaled = lin * (target / np.maximum(own, 1e-6)).astype(np.float32)
    return cv.albedo_to_stored(np.clip(scaled, 0.0, 1.0)).astype(np.float32)


#: :func:`read_as_dielectric` scales the estimate to the chain's level when at least this share of the map
#: is read as a dielectric (else the estimate's own level: too little of the chain's to read it from).
ESTIMATE_AT_CHAIN_LEVEL = 0.1


def read_as_dielectric(stored, estimate):
    """The stored maps ``stored`` read as a dielectric's where the chain guessed a metal: its F0's
    brightness (luminance, linear) at most :data:`svbrdf_cli.conventions.DIELECTRIC_MAX_F0`, its colour
    kept, and its diffuse there the physical estimate's ``estimate`` (stored, any size), blended in as
    the F0 rises through the band where a metal's begins (:func:`svbrdf_cli.conventions.metal_weight`):
    the chain's diffuse under a metal's F0 is black, the photo's light given to the specular.

    One auto-exposed photo does not tell a dark grey metal from a dark dielectric (a photo's level is
    the exposure's), and the chain's F0 above a dielectric's range is its guess between them, which
    turned with the input's margin and size: on the two dark grey plastics of ``paper_real`` (a phone
    case, a speaker grille) 0.09-0.52 and 0.04-0.53 over margins of 16 and 32 px and sizes of 96-192 px,
    read as metal by the engine presets; on the 7 real photos with metal in them (foil, gilding, bronze, a
    metal sheet) it never rose above 0.05, and on Des19's metals through the capture 0.04-0.09. Read as a
    dielectric, no photo comes out metal from the chain's guess; ``--refine`` still lets F0 take a
    metal's colour where the photo's highlight has the material's. Without this step, the installed
    chain through the command: Des19 diffuse 0.0312 -> 0.0309, specular 0.0579 -> 0.0571, the card
    unchanged, but the phone case and the speaker grille at mean metallic 0.795 and 0.966 (25 of 27
    dielectrics clean). The run's 3,913k state reads 23_MetalPlating's F0 at 0.41 (true 0.38; the
    installed chain 0.18) and 38_GoldFlake's still at 0.04; keeping its F0 where above 0.2-0.3 scored
    Des19 specular 0.0579, against 0.0576 with the step.

    The estimate comes in at the chain's level: times, per channel, the ratio of the chain's diffuse to
    the estimate's over the pixels read as a dielectric (when they are at least
    :data:`ESTIMATE_AT_CHAIN_LEVEL` of the map). At its own level the estimate drew a bright blob where the
    chain guessed a metal on the dark mesh of ``paper_real`` flash_19 (its flash spot 0.76 of the ring's
    brightness -> 1.00; IMG_7187 0.83 -> 0.93; ``export.studies.artist_check``). Measured through the command:
    Des19 diffuse 0.0319 -> 0.0321 (its metals, whose true diffuse is black, and a leather), the card and
    the 48 generated known-light captures unchanged (0.1195, 9 photos 0.1425; 0.0748)."""
    import cv2

    from svbrdf_cli.imageops import luminance

    lin = cv.albedo_to_linear(np.asarray(stored["specular"], np.float32))
    level = luminance(lin)[..., None]
    if not (level > cv.DIELECTRIC_MAX_F0).any():
        return {}
    over = level > cv.DIELECTRIC_MAX_F0
    lowered = cv.albedo_to_stored(lin * (np.float32(cv.DIELECTRIC_MAX_F0) / np.maximum(level, 1e-6)))
    f0 = np.where(over, lowered, np.asarray(stored["specular"], np.float32))
    h, w = lin.shape[:2]
    est = np.asarray(estimate, np.float32)
    if est.shape[:2] != (h, w):
        est = cv2.resize(est, (w, h), interpolation=cv2.INTER_LINEAR)
    t = cv.metal_weight(level).astype(np.float32)
    keep = 1.0 - t
    if float(keep.mean()) >= ESTIMATE_AT_CHAIN_LEVEL:  # the estimate at the chain's level (per channel)
        d_lin = cv.albedo_to_linear(np.asarray(stored["diffuse"], np.float32))
        e_lin = cv.albedo_to_linear(est)
        ratio = (d_lin * keep).sum((0, 1)) / np.maximum((e_lin * keep).sum((0, 1)), 1e-6)
        est = cv.albedo_to_stored(np.clip(e_lin * ratio.astype(np.float32), 0.0, 1.0)).astype(np.float32)
    diffuse = np.asarray(stored["diffuse"], np.float32) * keep + est * t
    return {"specular": f0.astype(np.float32), "diffuse": diffuse.astype(np.float32)}


def _unit_normals(n):
    """Stored normals of the (H, W, 3) vectors ``n`` (a sum or a resampling of unit normals), kept in
    the upper hemisphere."""
    n = np.array(n, np.float32)
    n[..., 2] = np.maximum(n[..., 2], 1e-3)
    return cv.encode_normals(cv.normalize(n)).astype(np.float32)


#: The maps :func:`to_photo_size` brings from the chain's run size to the photo's with the photo's own detail
#: (:func:`svbrdf_cli.infer.upsample.guided_upsample`, as the capture brings every model's maps to the output
#: size); the others are bicubic. The chain runs at 128 px and the photo it reads is 256 px: bicubic, its
#: diffuse held about a third of the true albedo's fine detail on the generated known-light captures, and a
#: speckled granite relit at 0.158 against the floor's 0.094. Measured with the installed chain through
#: ``svbrdf capture`` (``capture_eval --all-card``: Des19 normal, relief, diffuse; the card from photo 00 and
#: from each of its 9 photos) and on the 48 generated known-light captures (``known_lights``):
#:
#: ====================  ======  =====  ======  ======  ======  ======
#: guided                normal  relief diffuse card    card 9  known
#: ====================  ======  =====  ======  ======  ======  ======
#: none                  0.0478  0.422  0.0308  0.1199  0.1423  0.0652
#: diffuse               0.0478  0.421  0.0311  0.1200  0.1426  0.0614
#: normal and diffuse    0.0476  0.426  0.0311  0.1201  0.1428  0.0601
#: ====================  ======  =====  ======  ======  ======  ======
#:
#: Roughness and specular unchanged. The photo's detail costs Des19's diffuse a little (its foam, gold flake
#: and leathers show relief and glints there, not albedo) and the card's clipped flash spot keeps less of the
#: ring's fine detail (0.51 -> 0.48: the ring gains the photo's detail, the clipped spot has none to gain).
GUIDED = GUIDED_MAPS


def to_photo_size(maps, small, photo):
    """The chain's ``maps`` (stored encoding, at the size of ``small``, the encoded photo it read) at the
    size of the encoded ``photo``: :data:`GUIDED` by the photo's luminance (a square photo), the others
    and any map of a photo that is not square bicubic; clipped to [0, 1], float32."""
    import cv2

    from svbrdf_cli.imageops import luminance

    full, low = photo.shape[:2], small.shape[:2]
    if low == full:
        return {n: np.ascontiguousarray(v, np.float32).reshape(full + (-1,)) for n, v in maps.items()}
    square = full[0] == full[1] and low[0] == low[1]
    guide = None
    if square and any(n in GUIDED for n in maps):
        g_low, g_high = luminance(small), luminance(photo)
        guide = (g_low, g_high, guide_detail(g_low, g_high))  # once for every guided map
    out = {}
    for n, v in maps.items():
        v = np.ascontiguousarray(v, np.float32)
        if guide is not None and n in GUIDED:
            up = guided_upsample(v, guide[0], guide[1], detail=guide[2])
        else:
            up = cv2.resize(v, (full[1], full[0]), interpolation=cv2.INTER_CUBIC)
        out[n] = np.clip(up, 0.0, 1.0).astype(np.float32).reshape(full + (-1,))
    return out


def is_swift(folder):
    """Whether ``folder`` holds a swift chain (else a folder of per-stage networks)."""
    return os.path.isfile(os.path.join(folder, FILE))


class SwiftModel:
    """``chain.onnx`` as a :class:`svbrdf_cli.infer.model.Model`."""

    #: Runs at the network size: the capture upsamples its maps.
    any_size = False

    def __init__(self, folder, threads=0):
        self.folder = os.fspath(folder)
        path = os.path.join(self.folder, FILE)
        self.session = session(path, threads)
        meta = self.session.get_modelmeta().custom_metadata_map
        if meta.get("conventions") != cv.CONVENTIONS_VERSION:
            raise ModelError(f"'{path}' was made for conventions version {meta.get('conventions')!r}, "
                             f"this tool uses {cv.CONVENTIONS_VERSION!r}; re-export it (python -m export.engine onnx).")
        names = {i.name for i in self.session.get_inputs()}
        if names != {"photo", "context", "base"}:
            raise ModelError(f"'{path}' takes {', '.join(sorted(names))}, not a swift chain's photo, context "
                             "and base; re-export it (python -m export.engine onnx).")
        self.multiple = int(meta.get("size_multiple", "32"))
        self.run_size = int(meta["run_size"]) if meta.get("run_size") else None
        self.provenance = json.loads(meta.get("provenance", "{}"))
        self.tier = meta.get("tier", "swift")
        #: "photo": the chain reads F0 at the photo's flash level, as the diffuse (the capture scales both
        #: to the photo as shot); "absolute": the material's F0, kept as it is.
        self.specular_level = meta.get("specular_level", "absolute")
        if self.specular_level not in cv.SPECULAR_LEVELS:
            raise ModelError(f"'{path}' reads F0 at {self.specular_level!r}, which this tool does not know "
                             f"({', '.join(cv.SPECULAR_LEVELS)}); update svbrdf or re-export it.")
        self.timings = {}
        self.found = self.fit = None
        self.passes, self.second_passes = PASSES, SECOND_PASSES

    @property
    def used(self):
        """Itself (a :class:`svbrdf_cli.infer.model.Model`)."""
        return self

    def describe(self):
        """What ``material.json`` records: the folder, the flash found, how much training is behind it."""
        p = self.provenance
        return {"tier": self.tier, "folder": os.path.abspath(self.folder), "found": self.found,
                "trained": {k: p[k] for k in ("samples", "cpu_hours", "step") if k in p},
                "specular_level": self.specular_level}

    def flash(self, image):
        """The flash position (3,) in surface units, from the physical estimate's fit of ``image``
        (kept as ``self.fit``)."""
        from svbrdf_cli.infer import physical

        fit = self.fit = physical.fit_flash(image)
        self.found = {"flash_foot": [round(fit.foot[0], 4), round(fit.foot[1], 4)],
                      "flash_height": round(fit.fit.height, 4)}
        foot = self.found["flash_foot"]
        return np.array([foot[0], foot[1], self.found["flash_height"]], np.float64)

    def __call__(self, image):
        """(H, W, 3) encoded photo -> the maps (stored encoding) and the masks and auxiliary
        renderings (encoded images) for ``--debug``: :meth:`network`'s, the diffuse filled where the
        highlight hid it (:func:`fill_highlight`) and the flash's trends taken off it
        (:func:`flatten_flash_trends`), the roughness carried from where the highlight showed
        (:func:`roughness_from_observed`), read as a dielectric's where the chain guessed a metal
        (:func:`read_as_dielectric`), the diffuse's level halfway to the physical estimate's
        (:func:`level_with_estimate`); ``hidden``: where the highlight hid the albedo but the photo
        did not clip (:func:`hidden_by_highlight`); ``clipped``: where it clipped, given the texture beside at the
        output size (:func:`svbrdf_cli.infer.physical.texture_beside_clipped`); ``spot``: the flash's spot beyond those, where the
        photo's fine detail the diffuse lacks is given to it at the output size
        (:func:`svbrdf_cli.infer.physical.spot_weight`)."""
        out = self.network(image)
        t0 = time.perf_counter()
        hidden, clipped = masks = hidden_by_highlight(image, out["M_h"])
        out["diffuse"] = fill_highlight(out["diffuse"], image, masks=masks)
        out["hidden"] = hidden & ~clipped
        out["clipped"] = clipped
        from svbrdf_cli.infer.physical import spot_weight

        out["spot"] = spot_weight(image, hidden)  # (hidden: the clipped pixels too)
        out.update(flatten_flash_trends(out, self.fit.rho, FLATTENED))
        out["roughness"] = roughness_from_observed(out["roughness"], out["diffuse"], out["M_h"])
        estimate = estimate_diffuse(image, self.run_size)
        out.update(read_as_dielectric(out, estimate))
        out["diffuse"] = level_with_estimate(out["diffuse"], image, self.run_size,
                                             weight=estimate_weight(self.found["flash_height"]), estimate=estimate)
        self.timings["physics"] = time.perf_counter() - t0
        return out

    def forward(self, feeds):
        """The graph's ``masks``, ``aux`` and ``maps`` (numpy, (1, C, H, W)) for its three inputs."""
        return self.session.run(["masks", "aux", "maps"], feeds)

    def network(self, image):
        """The chain's own outputs for an (H, W, 3) encoded photo, at the photo's size: its maps and
        extras at the run's size, its :data:`SECOND_MAPS` averaged with those it reads at :data:`SECOND_SIZES`
        (the normals as unit vectors)."""
        img = np.asarray(image, dtype=np.float32)
        if img.ndim != 3 or img.shape[-1] != 3:
            raise ValueError(f"expected an (H, W, 3) image, got shape {img.shape}")
        t0 = time.perf_counter()
        light = self.flash(img)  # on the whole photo: surface units do not depend on the size
        t1 = time.perf_counter()
        out = self.run_at(img, light, self.run_size)
        if self.run_size and max(img.shape[:2]) > self.run_size:
            reads = [out] + [self.run_at(img, light, s, SECOND_MAPS, self.second_passes) for s in SECOND_SIZES]
            for name in SECOND_MAPS:
                if name == "normal":
                    out[name] = _unit_normals(sum(cv.decode_normals(r[name]) for r in reads))
                else:
                    out[name] = sum(r[name] for r in reads) / np.float32(len(reads))
        self.timings = {"physical": t1 - t0, "chain": time.perf_counter() - t1}
        return out

    def run_at(self, img, light, size, names=None, passes=None):
        """The chain's outputs for the encoded photo ``img`` with its flash at ``light``, run with the
        photo area-shrunk to ``size`` (None or larger than the photo: as it is) on ``passes`` (None:
        ``self.passes``, :data:`PASSES`; (quarter turns, mirror) pairs), averaged and
        brought back to the photo's size (:func:`to_photo_size`): the maps of ``names`` only, or every map and the masks and
        auxiliary renderings (None)."""
        import cv2

        full = img.shape[:2]
        photo, img = img, shrink_longest(img, size)
        h, w = img.shape[:2]
        passes = self.passes if passes is None else passes

        def run(k, mirror):  # one pass, brought back to the photo's orientation (a quarter turn swaps h and w)
            seen, at = tta.transform_image(img, k, mirror), tta.transform_point(light, k, mirror)
            sh, sw = seen.shape[:2]
            m, pad, mode = padding(sh, sw, self.multiple, MARGIN)

            def feed(x):
                return np.ascontiguousarray(np.pad(x, pad, mode=mode).transpose(2, 0, 1)[None], dtype=np.float32)

            def own(x):  # the margin off, (sh, sw, C)
                return x[0].transpose(1, 2, 0)[m:m + sh, m:m + sw]

            masks, aux, maps = self.forward({"photo": feed(seen), "context": feed(flash_fields.context(at, sh, sw)),
                                             "base": feed(flash_fields.base(seen, at))})
            res = tta.untransform_maps(dict(zip(cv.MAP_NAMES, np.split(own(maps), [3, 6, 7], axis=-1))), k, mirror)
            res["extra"] = tta.untransform_image(np.concatenate([own(masks), own(aux)], -1), k, mirror)
            return res

        total = None
        for k, mirror in passes:
            res = run(k, mirror)
            total = res if total is None else {n: total[n] + res[n] for n in total}
        mean = {n: v / np.float32(len(passes)) for n, v in total.items()}

        out = to_photo_size({n: mean[n] for n in (names or cv.MAP_NAMES)}, img, photo)
        if "normal" in out and ((h, w) != full or len(passes) > 1):  # resized or averaged: unit vectors again
            out["normal"] = _unit_normals(cv.decode_normals(out["normal"]))
        if names:
            return out
        extra = np.ascontiguousarray(mean["extra"], np.float32)
        if (h, w) != full:
            extra = np.clip(cv2.resize(extra, (full[1], full[0]), interpolation=cv2.INTER_LINEAR), 0.0, 1.0)
        extra = extra.reshape(full + (-1,))
        names = OUTPUTS["masks"] + OUTPUTS["aux"]
        out.update({name: extra[..., 3 * i:3 * i + 3] for i, name in enumerate(names)})
        return out

