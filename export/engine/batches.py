"""One training batch, made on the fly in torch from the material bank.

Every step draws ``B`` bank materials and for each: a random window (zoom, any rotation, a mirror;
normals turned with the pixels), a deeper or shallower relief, a glossier roughness, a tint and
brightness change of the diffuse, then a photograph under a sampled camera and flash with the simulator's exposure, white balance, vignetting, blur,
noise, tone curve and JPEG (:mod:`export.data.simulate`), exposed as ``svbrdf capture`` exposes a photo
(:func:`as_the_runtime_exposes`). Only what the stage being trained needs
is rendered:

* ``masks``: ``M_b`` and ``M_h`` (paper Eqs. 10-11, :mod:`export.render.targets`);
* ``aux``: ``I_bf`` (Eq. 4) and ``I_hr``, ``I_hr2`` (Eqs. 5-8) by :func:`highlight_removed_fast`;
* ``maps``: the maps in their stored encoding, the diffuse at the conventions' flash level.

Every batch also holds the photo, the flash context and the base estimate (:mod:`export.engine.flash`).
All randomness comes from one ``torch.Generator``: its state fixes the rest of a run's batches.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from export.data import augment, simulate
from export.engine import bank as bank_mod
from export.engine import flash
from export.render import targets as render_targets
from export.render.brdf import fresnel_schlick, ndf_ggx, render_maps, surface_positions, visibility_smith_schlick
from svbrdf_cli import conventions as cv

#: Window width range as a fraction of a bank material (256² -> 128²: 0.5 is 1:1).
SCALE = (0.3, 1.0)
#: Range of the factor on the normals' tilt (:func:`relief_scale`).
RELIEF_SCALE = (0.3, 1.2)
#: Range of the factor on the roughness (:func:`gloss_scale`).
GLOSS_SCALE = (0.6, 1.0)
#: Lights of the highlight-removed renderings' specular part, and the size it is rendered at.
AUX_SPECULAR_LIGHTS = 12
AUX_SPECULAR_SIZE = 32
#: Spread of the flash position the context and base are computed from (see :func:`estimated_flash`).
FLASH_XY_ERROR = 0.03
FLASH_HEIGHT_ERROR = 0.1
STAGE_TARGETS = {"masks": ("M_b", "M_h"), "aux": ("I_bf", "I_hr", "I_hr2"), "maps": ()}


def materials(bank, g, batch, size, index=None):
    """(B, C, size, size) linear maps: random windows of random bank materials (or those at
    ``index``), tinted."""
    idx = torch.randint(0, len(bank), (batch,), generator=g) if index is None else index
    maps = augment.random_geometry(bank.stored(idx), g, size, scale=SCALE)
    maps = tint(bank_mod.linearize(relief_scale(maps, g)), g)
    maps["roughness"] = gloss_scale(maps["roughness"], g, keep=bank.scanned[idx]).clamp(0.02, 1.0)
    return {k: maps[k].contiguous() for k in cv.MAP_NAMES}


def relief_scale(maps, g, low=RELIEF_SCALE[0], high=RELIEF_SCALE[1]):
    """The same material with shallower or deeper relief: every normal's tilt (x, y) times one factor
    per sample, log-uniform in [low, high] (normals renormalised by :func:`export.engine.bank.linearize`).
    The bank's materials are steeper than real ones (mean |(n_x, n_y)| 0.28 procedural, 0.19 CC0,
    0.14 on Des19's ground truth); this spreads them over flat to steep, so the relief a network
    predicts has to be read from the photo."""
    b = maps["normal"].shape[0]
    k = bank_mod.log_uniform(g, b, low, high).reshape(-1, 1, 1, 1)
    n = maps["normal"]
    return {**maps, "normal": torch.cat([n[:, :2] * k, n[:, 2:]], 1)}


def gloss_scale(roughness, g, low=GLOSS_SCALE[0], high=GLOSS_SCALE[1], keep=None):
    """The same material glossier: its roughness times one factor per sample, log-uniform in
    [low, high], except the samples ``keep`` (a (B,) bool tensor) marks: the scanned materials.

    The procedural materials are rougher than real ones (median of the materials' mean roughness 0.68,
    against 0.52 for the CC0 scans; Des19's ground truth 0.40), and where a photo shows no highlight
    the chain falls back on that prior: its roughness came out 0.06 above the truth on Des19 (mean
    0.458 against 0.395). Applied to every material, the factor overshot (mean 0.362 after 100k
    samples) and worsened Des19's relighting (0.0571 -> 0.0596 from the roughness alone)."""
    b = roughness.shape[0]
    k = bank_mod.log_uniform(g, b, low, high)
    if keep is not None:
        k = torch.where(keep.reshape(-1), torch.ones_like(k), k)
    return roughness * k.reshape(-1, 1, 1, 1).to(roughness)


def tint(maps, g, hue=0.05, saturation=(0.8, 1.5), brightness=0.3):
    """:func:`export.data.augment.jitter_colour`'s change of the diffuse (and of a coloured specular,
    a metal's) as one 3x3 matrix per sample, 5x cheaper than going through HSV: a turn of ``hue`` of a
    full turn at most about the grey axis, a saturation factor, a brightness factor; the diffuse kept
    at most :data:`export.data.augment.MAX_ALBEDO`, the specular in [0, 1], a grey specular untouched."""
    d = maps["diffuse"]
    b = d.shape[0]

    def draw(lo, hi):
        return lo + torch.rand(b, generator=g) * (hi - lo)

    angle = draw(-hue, hue) * 2 * math.pi
    sat, gain = draw(*saturation), draw(1 - brightness, 1 + brightness)
    k = torch.full((3,), 3 ** -0.5)
    cross = torch.tensor([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    eye, outer = torch.eye(3), torch.outer(k, k)
    c, s = angle.cos()[:, None, None], angle.sin()[:, None, None]
    rotation = c * eye + s * cross + (1 - c) * outer           # Rodrigues, about (1, 1, 1)
    grey = torch.full((3, 3), 1 / 3)
    saturate = grey + sat[:, None, None] * (eye - grey)
    m = gain[:, None, None] * saturate @ rotation               # (B, 3, 3)

    def apply(x, top):
        return torch.einsum("bij,bjhw->bihw", m.to(x), x).clamp(0.0, top)

    out = dict(maps)
    out["diffuse"] = apply(d, augment.MAX_ALBEDO)
    spec = maps["specular"]
    metal = (spec.amax(1, keepdim=True) - spec.amin(1, keepdim=True)) > 0.02
    out["specular"] = torch.where(metal, apply(spec, 1.0), spec)
    return out


#: The most of a photo lit at a fixed flash power that may clip (any channel of its linear render at
#: white, before white balance, noise and the tone curve): a brighter one is
#: exposed down to it, as a phone's exposure would. Uncapped, that half of the photos clipped up to 92 %
#: of their pixels (p90 0.41 on fresh procedural materials); Des19's inputs clip at most 12.6 %, the
#: real flash photos 1.2 % at p90.
MAX_CLIPPED_SHARE = 0.1


def highlight_cap(unit):
    """(B,) the largest intensity at which at most :data:`MAX_CLIPPED_SHARE` of a (B, 3, H, W)
    unit-intensity render's pixels reach white in any channel."""
    top = unit.amax(1).flatten(1).float()
    q = torch.quantile(top, 1.0 - MAX_CLIPPED_SHARE, dim=1).to(unit.dtype)
    return 1.0 / q.clamp_min(1e-8)


def photograph(maps, capture, g, cap=True):
    """The simulated photo of a batch (:func:`export.data.simulate.photograph`'s camera model, with
    one render and auto exposure on a subsample; unlike it, with ``cap`` a fixed power is lowered to
    :func:`highlight_cap`): ``photo``, the clean ``linear`` flash image, ``intensity`` (B,)."""
    d = maps["diffuse"]
    cam, light = capture["camera"].to(d), capture["light"].to(d)
    unit = render_maps(maps, light=light, camera=cam, intensity=1.0)
    sub = unit[..., ::4, ::4]
    intensity = render_targets.exposure_of(sub, capture["exposure"].to(d), iterations=20)
    power = capture["power"].to(d)
    if cap:
        power = torch.where(power > 0, torch.minimum(power, highlight_cap(sub)), power)
    intensity = torch.where(power > 0, power, intensity)
    linear = unit * intensity.reshape(-1, 1, 1, 1)
    p = surface_positions(d.shape[-2], d.shape[-1], d)
    r2 = (p[:, :2] ** 2).sum(1, keepdim=True) / (2 * cv.SURFACE_HALF_SIZE ** 2)
    col = capture["vignetting"].to(d).reshape(-1, 1, 1, 1)
    x = linear * (1 - col * r2) * capture["wb"].to(d).reshape(-1, 3, 1, 1)
    x = simulate.gaussian_blur(x, capture["blur"].to(d) * (d.shape[-1] / 256))
    shot = capture["shot_noise"].to(d).reshape(-1, 1, 1, 1)
    read = capture["read_noise"].to(d).reshape(-1, 1, 1, 1)
    x = x + (shot * x.clamp_min(0) + read * read).sqrt() * torch.randn(x.shape, generator=g, dtype=x.dtype)
    photo = simulate.tone_curve(x.clamp(0.0, 1.0), capture["tone"], capture["contrast"])
    photo = simulate.jpeg((photo * 255).round() / 255, capture["jpeg"])
    return {"photo": photo, "linear": linear, "intensity": intensity}


def runtime_gain(photo, iterations=30):
    """(B,) the gain ``svbrdf capture``'s auto exposure gives each encoded (B, 3, H, W) ``photo``
    (:func:`svbrdf_cli.infer.exposure.auto_exposure_gain`, batched in torch): the bisection in stops, within
    :data:`svbrdf_cli.ingest.plausible.EXPOSURE_LIMIT`, that brings the encoded mean of the photo read back
    as linear (gamma 2.2) to :data:`svbrdf_cli.conventions.AUTO_EXPOSURE_MEAN`, on every other pixel."""
    from svbrdf_cli.ingest.plausible import EXPOSURE_LIMIT

    sub = cv.image_to_linear(photo)[..., ::2, ::2]
    lo = torch.full((photo.shape[0],), -EXPOSURE_LIMIT, dtype=photo.dtype)
    hi = torch.full_like(lo, EXPOSURE_LIMIT)
    for _ in range(iterations):
        mid = (lo + hi) / 2
        dark = cv.image_to_encoded(sub * (2.0 ** mid).reshape(-1, 1, 1, 1)).mean((1, 2, 3)) < cv.AUTO_EXPOSURE_MEAN
        lo, hi = torch.where(dark, mid, lo), torch.where(dark, hi, mid)
    return 2.0 ** ((lo + hi) / 2)


def as_the_runtime_exposes(shot):
    """``shot`` (:func:`photograph`'s) exposed as ``svbrdf capture`` exposes a photo before the networks
    see it: the encoded photo read back as linear, times :func:`runtime_gain`, clipped and encoded again. A
    photo the camera clipped and the runtime then darkens holds its clipped highlight as a grey plateau,
    which a photo fed as shot never shows. The clean ``linear`` image and the ``intensity`` take the same
    gain, so every target rendered from them (and the maps' flash level) reads the photo the networks see."""
    gain = runtime_gain(shot["photo"])
    return {"photo": cv.image_to_encoded(cv.image_to_linear(shot["photo"]) * gain.reshape(-1, 1, 1, 1)),
            "linear": shot["linear"] * gain.to(shot["linear"]).reshape(-1, 1, 1, 1),
            "intensity": shot["intensity"] * gain.to(shot["intensity"])}


def _light_disc(camera, count, like):
    disc = torch.as_tensor(cv.aux_light_positions(count, height=0.0), dtype=like.dtype)
    cam = camera.to(like).reshape(-1, 1, 3)
    lights = cam + disc
    power = cv.aux_light_intensities(lights - cam * cam.new_tensor([1.0, 1.0, 0.0]), 1.0, height=cam[..., 2])
    return lights, power  # (B, K, 3), (B, K)


def _flat_terms(size, lights, camera, dtype):
    """Per-light fields of a flat surface: irradiance (unit power), n.l, n.v, n.h, v.h; (B, K, 1, S, S).
    Vector components are kept apart (sums over a 3-long axis are slow on CPU)."""
    p = torch.from_numpy(cv.surface_positions(size, size)).to(dtype)
    px, py = p[..., 0], p[..., 1]  # (S, S); the surface is z = 0
    lx, ly, lz = (lights[..., i, None, None] for i in range(3))  # (B, K, 1, 1)
    tx, ty = lx - px, ly - py
    dist2 = tx * tx + ty * ty + lz * lz
    inv = dist2.rsqrt()
    cam = camera.to(dtype)
    vx, vy, vz = (cam[:, i, None, None, None] - (px if i == 0 else py if i == 1 else 0.0) for i in range(3))
    vinv = (vx * vx + vy * vy + vz * vz).rsqrt()
    vx, vy, vz = vx * vinv, vy * vinv, vz * vinv  # (B, 1, S, S)
    hx, hy, hz = tx * inv + vx, ty * inv + vy, lz * inv + vz
    hinv = (hx * hx + hy * hy + hz * hz).rsqrt()
    nl = lz * inv
    nh = hz * hinv
    vh = (vx * hx + vy * hy + vz * hz) * hinv
    irr = nl.clamp_min(0.0) / dist2
    return tuple(t.unsqueeze(2) for t in (irr, nl.expand_as(irr), vz.expand_as(irr), nh, vh))


def highlight_removed_fast(maps, camera, intensity, lights=AUX_SPECULAR_LIGHTS, size=AUX_SPECULAR_SIZE):
    """(I_hr, I_hr^2): the flash image under a disc of lights round the camera with a flat normal
    (paper Eqs. 5-8, :func:`export.render.targets.highlight_removed`'s lights, powers and per-light
    clipping), made cheap:

    * the diffuse part at full size: the albedo times the disc's mean irradiance (a smooth field,
      from every light at 32², upsampled);
    * the specular part, with what clipping each light's rendering to 1 takes off, from ``lights``
      of the disc at ``size``² (maps averaged down), upsampled.

    Args:
        maps: dict of linear maps (B, C, H, W).
        camera: (B, 3) positions; intensity: (B,) the photo's flash intensity.
    """
    d = maps["diffuse"]
    b, _, h, w = d.shape
    scale = intensity.to(d).reshape(-1, 1, 1, 1, 1)
    lt, power = _light_disc(camera, cv.AUX_LIGHT_COUNT, d)
    irr = _flat_terms(32, lt, camera, d.dtype)[0]
    mean_irr = (irr * power[..., None, None, None]).mean(1)  # (B, 1, 32, 32)
    mean_irr = F.interpolate(mean_irr, size=(h, w), mode="bilinear", align_corners=False)
    diffuse_part = d * (1 - maps["specular"]) * mean_irr * scale[:, 0]
    pick = torch.linspace(0, cv.AUX_LIGHT_COUNT - 1, lights).round().long()
    lt, power = lt[:, pick], power[:, pick]
    irr, nl, nv, nh, vh = _flat_terms(size, lt, camera, d.dtype)
    irr = irr * power[..., None, None, None] * scale  # (B, K, 1, s, s)
    small = {k: F.adaptive_avg_pool2d(maps[k], size).unsqueeze(1) for k in cv.MAP_NAMES}
    diff_k = small["diffuse"] * (1 - small["specular"]) * irr
    fresnel = fresnel_schlick(vh, small["specular"])
    out = []
    for rough in (small["roughness"], torch.full_like(small["roughness"], cv.AUX_HIGH_ROUGHNESS)):
        alpha = cv.roughness_to_alpha(rough)
        spec_k = ndf_ggx(nh, alpha) * visibility_smith_schlick(nl, nv, alpha) * (0.25 * math.pi) * irr * fresnel
        rest = ((diff_k + spec_k).clamp(0.0, 1.0) - diff_k).mean(1)  # (B, 3, s, s)
        rest = F.interpolate(rest, size=(h, w), mode="bilinear", align_corners=False)
        out.append(cv.image_to_encoded(diffuse_part + rest))
    return out[0], out[1]


def estimated_flash(light, g):
    """The flash position as a capture would estimate it (from the highlight and the EXIF field of
    view): the true one moved by ``FLASH_XY_ERROR`` flash heights across and ``FLASH_HEIGHT_ERROR``
    (log) in height, so the networks do not rely on an exactness the runtime does not have."""
    n = light.shape[0]
    xy = torch.randn(n, 2, generator=g) * FLASH_XY_ERROR * light[:, 2:3]
    z = light[:, 2:3] * (torch.randn(n, 1, generator=g) * FLASH_HEIGHT_ERROR).exp()
    return torch.cat([light[:, :2] + xy, z], 1)


#: Where the flash the context and base are computed from comes from (:func:`context_flash`).
FLASH_CONTEXTS = ("jitter", "fit")


def fitted_flash(photo):
    """(B, 3) the flash position ``svbrdf capture`` reads from each encoded (B, 3, H, W) ``photo`` without
    EXIF: the foot and the height of :func:`svbrdf_cli.infer.physical.fit_flash` (the height one of its
    grid's, :data:`svbrdf_cli.infer.physical.HEIGHT_GRID`), as :class:`svbrdf_cli.infer.swift.SwiftModel`
    gives its chain."""
    from svbrdf_cli.infer.physical import fit_flash

    out = []
    for p in photo.float().permute(0, 2, 3, 1).numpy():
        fit = fit_flash(p)
        out.append([float(fit.foot[0]), float(fit.foot[1]), float(fit.fit.height)])
    return torch.tensor(out, dtype=torch.float32)


def context_flash(photo, light, g, mode="jitter"):
    """(B, 3) the flash position the networks are given: ``jitter``, the true ``light`` moved a little
    (:func:`estimated_flash`: a capture that knew the field of view from EXIF); ``fit``, the position the
    runtime reads from the ``photo`` itself (:func:`fitted_flash`), whose height sits at a bound of its grid
    on most photos (RMS log error 0.29 on the generated known-light captures, against the jitter's 0.1):
    trained on it, the chain learns how far to trust the height it will be given."""
    if mode not in FLASH_CONTEXTS:
        raise ValueError(f"flash context {mode!r}: one of {', '.join(FLASH_CONTEXTS)}")
    return estimated_flash(light, g) if mode == "jitter" else fitted_flash(photo).to(light)


def make(bank, g, batch, size=128, stage="maps", index=None, specular_level="absolute", flash_context="jitter"):
    """One batch for ``stage`` (see the module docstring); every tensor (B, C, size, size) float32
    but ``intensity`` (B,). ``specular_level``: the maps stage's F0 target (:func:`stored_targets`);
    ``flash_context``: where the context's flash comes from (:func:`context_flash`).

    Returns:
        dict: ``photo`` (3, encoded), ``context`` (4), ``base`` (10), the stage's targets
        (encoded images, or for ``maps`` the stored maps under ``normal``, ``diffuse``,
        ``roughness``, ``specular``), ``intensity``, ``camera`` and ``light`` (B, 3).
    """
    maps = materials(bank, g, batch, size, index)
    capture = simulate.sample_capture(g, batch)
    capture = {k: v.float() for k, v in capture.items()}
    shot = as_the_runtime_exposes(photograph(maps, capture, g))
    cam, light, intensity = capture["camera"], capture["light"], shot["intensity"]
    seen = context_flash(shot["photo"], light, g, flash_context)
    out = {"photo": shot["photo"], "intensity": intensity, "camera": cam, "light": light,
           "context": flash.context(seen, seen, size), "base": flash.base(shot["photo"], seen, seen)}
    with torch.no_grad():
        if stage in ("masks", "joint"):
            clean = cv.image_to_encoded(shot["linear"])
            out["M_b"] = render_targets.bumpiness_mask(maps, light, intensity, image=clean, camera=cam)
            out["M_h"] = render_targets.highlight_mask(maps, light, intensity, image=clean, camera=cam)
        if stage in ("aux", "joint"):
            out["I_bf"] = render_targets.bumpiness_flattened(maps, light, intensity, camera=cam)
            out["I_hr"], out["I_hr2"] = highlight_removed_fast(maps, cam, intensity)
        if stage in ("maps", "joint"):
            level = flash.level_factor(intensity, light).reshape(-1, 1, 1, 1)
            out.update(stored_targets(maps, level, specular_level))
    return out


def stored_targets(maps, level, specular_level="absolute"):
    """The maps stage's targets: the maps in their stored encoding, the diffuse (and with
    ``specular_level`` "photo" the F0, :data:`svbrdf_cli.conventions.SPECULAR_LEVELS`: both then read the
    photo at the conventions' flash power, their ratio the photo's, a metal's F0 read from its
    highlight's brightness rather than guessed) times ``level`` (B, 1, 1, 1)."""
    if specular_level not in cv.SPECULAR_LEVELS:
        raise ValueError(f"specular_level {specular_level!r}: one of {', '.join(cv.SPECULAR_LEVELS)}")
    spec = (maps["specular"] * level).clamp(0, 1) if specular_level == "photo" else maps["specular"]
    return {"normal": cv.encode_normals(maps["normal"]),
            "diffuse": cv.albedo_to_stored((maps["diffuse"] * level).clamp(0, 1)),
            "roughness": maps["roughness"].clamp(0, 1),
            "specular": cv.albedo_to_stored(spec)}
