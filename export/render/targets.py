"""The paper's intermediate targets, made by re-rendering ground-truth maps.

Zhou et al., "Single-Image SVBRDF Estimation Using Auxiliary Renderings as
Intermediate Targets", section III-B and III-D:

* ``I_bf``  (Eq. 4): the flash image rendered with the uniform normal N_u.
* ``I_hr``  (Eqs. 5-6): mean of K renderings of (N_u, D, R, S) under the
  lights of :func:`svbrdf_cli.conventions.aux_light_positions`.
* ``I_hr2`` (Eqs. 7-8): the same with roughness R_1 = 1 everywhere.
* ``M_h``   (Eq. 10): input minus the image whose NDF values above
  delta_h = 0.9 are replaced by D-bar (the mean NDF over pixels below delta_h).
* ``M_b``   (Eq. 11): the image whose NDF values below delta_s = 0.15 are
  raised to delta_s, minus the input.

Every image is what the networks see: linear radiance clipped to [0, 1] and
gamma-encoded (:func:`svbrdf_cli.conventions.image_to_encoded`). The masks are
differences of such images, so they lie in [0, 1] and are exactly 0 wherever
the NDF was not changed. The K-light means average clipped *linear* renderings
(the photo one would get with all K lights at 1/K power each, each clipped as
a sensor would) and encode once.

All functions take a batch of linear maps (NCHW, see
:mod:`export.render.brdf`) and run on its device.
"""

from __future__ import annotations

import math

import torch

from export.render.brdf import (fresnel_schlick, ndf_ggx, render, render_maps, surface_positions,
                                visibility_smith_schlick)
from svbrdf_cli import conventions as cv

TARGET_NAMES = ("I", "I_bf", "I_hr", "I_hr2", "M_b", "M_h")


def flat_normal(like):
    """N_u as a (1, 3, 1, 1) unit-vector tensor on ``like``'s device."""
    return torch.tensor(cv.FLAT_NORMAL, device=like.device, dtype=like.dtype).reshape(1, 3, 1, 1)


def flash_image(maps, light=cv.FLASH_POSITION, intensity=cv.LIGHT_INTENSITY, normal=None, ndf=None, camera=None):
    """The encoded flash image I (Eq. 1), or a variant of it.

    Args:
        maps: dict of linear maps.
        light: flash position (3,) or (B, 3).
        intensity: flash intensity, float or (B,).
        normal: replaces ``maps['normal']`` when given.
        ndf: NDF transform (see :func:`export.render.brdf.brdf`).
        camera: camera position (3,) or (B, 3); ``None``: at the flash.

    Returns:
        (B, 3, H, W) encoded image in [0, 1].
    """
    n = maps["normal"] if normal is None else normal
    lin = render(n, maps["diffuse"], maps["roughness"], maps["specular"], light=light, camera=camera,
                 intensity=intensity, ndf=ndf)
    return cv.image_to_encoded(lin)


def auto_exposure(maps, light=cv.FLASH_POSITION, target=cv.AUTO_EXPOSURE_MEAN, iterations=24, camera=None):
    """Per-sample flash intensity giving the encoded image a mean of ``target``.

    What a camera's auto exposure does; the Des19 inputs are exposed this way
    (see :data:`svbrdf_cli.conventions.AUTO_EXPOSURE_MEAN`). Bisection on the
    log intensity, batched; no gradient.

    Args:
        target: mean encoded brightness, float or (B,).

    Returns:
        (B,) intensities.
    """
    with torch.no_grad():
        return exposure_of(render_maps(maps, light=light, camera=camera, intensity=1.0), target, iterations)


def exposure_of(unit, target=cv.AUTO_EXPOSURE_MEAN, iterations=24):
    """(B,) intensities giving the encoded image ``unit * intensity`` a mean of ``target`` (float or
    (B,)): bisection on the log intensity of a (B, C, H, W) unit-intensity linear render."""
    lo = torch.full((unit.shape[0],), -8.0, dtype=unit.dtype, device=unit.device)
    hi = torch.full_like(lo, 12.0)
    target_t = torch.as_tensor(target, dtype=unit.dtype, device=unit.device)
    for _ in range(iterations):
        mid = (lo + hi) / 2
        bright = cv.image_to_encoded(unit * mid.exp().reshape(-1, 1, 1, 1)).mean((1, 2, 3)) < target_t
        lo = torch.where(bright, mid, lo)
        hi = torch.where(bright, hi, mid)
    return ((lo + hi) / 2).exp()


def bumpiness_flattened(maps, light=cv.FLASH_POSITION, intensity=cv.LIGHT_INTENSITY, camera=None):
    """I_bf (Eq. 4): the flash image with the uniform normal N_u."""
    return flash_image(maps, light, intensity, normal=flat_normal(maps["diffuse"]), camera=camera)


def highlight_removed(maps, camera=cv.FLASH_POSITION, intensity=cv.LIGHT_INTENSITY, high_roughness=False,
                      count=cv.AUX_LIGHT_COUNT, chunk=5):
    """I_hr (Eqs. 5-6) or, with ``high_roughness``, I_hr^2 (Eqs. 7-8).

    Args:
        maps: dict of linear maps (the normal map is ignored: N_u is used).
        camera: camera position (3,) or (B, 3), shared by all K renderings;
            the light disc is centred on it, at its height, and the
            per-light intensities follow its height.
        intensity: flash intensity the per-light intensities are scaled from.
        high_roughness: render with R_1 = 1 everywhere (I_hr^2).
        count: K, the number of lights.
        chunk: lights rendered at once (memory vs. speed).

    Returns:
        (B, 3, H, W) encoded image in [0, 1].
    """
    return _highlight_removed(maps, camera, intensity, (high_roughness,), count, chunk)[0]


def highlight_removed_pair(maps, camera=cv.FLASH_POSITION, intensity=cv.LIGHT_INTENSITY,
                           count=cv.AUX_LIGHT_COUNT, chunk=5):
    """(I_hr, I_hr^2) together: the light geometry is computed once for both."""
    return _highlight_removed(maps, camera, intensity, (False, True), count, chunk)


def _highlight_removed(maps, camera, intensity, high_roughness, count, chunk):
    d = maps["diffuse"]
    # R_1 as a single (1, 1, 1, 1) value: D and G are then computed once per light, not per sample.
    one = torch.full_like(maps["roughness"][:1, :1, :1, :1], cv.AUX_HIGH_ROUGHNESS)
    alphas = [cv.roughness_to_alpha(one if high else maps["roughness"]).unsqueeze(1) for high in high_roughness]
    cam = torch.as_tensor(camera, device=d.device, dtype=d.dtype).reshape(-1, 1, 3)
    disc = torch.as_tensor(cv.aux_light_positions(count, height=0.0), device=d.device, dtype=d.dtype)
    lights = cam + disc  # (1 or B, K, 3): a disc at the camera's height, centred on it
    # Per-light weights so the mean stays about as bright as the flash image; see conventions.
    power = cv.aux_light_intensities(lights - cam * cam.new_tensor([1.0, 1.0, 0.0]), 1.0, height=cam[..., 2])
    intensity = torch.as_tensor(intensity, device=d.device, dtype=d.dtype).reshape(-1, 1) * power  # (B or 1, K)
    dd = (d * (1.0 - maps["specular"])).unsqueeze(1)                # (B, 1, 3, H, W)
    spec = maps["specular"].unsqueeze(1)
    totals = [0] * len(alphas)
    for k0 in range(0, count, chunk):
        k1 = min(count, k0 + chunk)
        geo = _flat_normal_geometry(d, lights[:, k0:k1], cam[:, 0], intensity[:, k0:k1])
        for i, alpha in enumerate(alphas):
            totals[i] = totals[i] + _flat_normal_shading(geo, dd, alpha, spec).clamp(0.0, 1.0).sum(1)
    return [cv.image_to_encoded(t / count) for t in totals]


def _flat_normal_geometry(like, lights, camera, intensity):
    """Light/view terms of a surface with the uniform normal N_u = (0, 0, 1).

    Every geometric term is then a scalar field that depends on the light
    and camera only: computed once per light (and per sample only when the
    camera is) and shared by every map and roughness shaded with it.

    Args:
        like: a (B, C, H, W) map giving size, device and dtype.
        lights: (Bc, K, 3) positions (Bc = 1 or B).
        camera: (Bc, 3) positions.
        intensity: (Bi, K) intensities (Bi = 1 or B).

    Returns:
        dict of (Bc or Bi, K, 1, H, W) fields: ``irradiance``, ``nl``, ``nv``, ``nh``, ``vh``.
    """
    h, w = like.shape[-2:]
    p = surface_positions(h, w, like).unsqueeze(1)                  # (1, 1, 3, H, W)
    to_light = lights[..., None, None] - p                          # (Bc, K, 3, H, W)
    dist2 = (to_light * to_light).sum(2, keepdim=True)
    l = to_light * dist2.rsqrt()
    v = cv.normalize(camera[:, None, :, None, None] - p, axis=2)   # (Bc, 1, 3, H, W)
    half = cv.normalize(l + v, axis=2)
    nl = l[:, :, 2:3]
    return {"irradiance": intensity[..., None, None, None] * nl.clamp_min(0.0) * (nl > 0) / dist2,
            "nl": nl, "nv": v[:, :, 2:3], "nh": half[:, :, 2:3], "vh": (v * half).sum(2, keepdim=True)}


def _flat_normal_shading(geo, diffuse_term, alpha, specular):
    """Linear radiance (B, K, 3, H, W), unclipped, from :func:`_flat_normal_geometry`'s
    fields; same model as :func:`export.render.brdf.render` (tested equal to it).

    Args:
        diffuse_term: (B, 1, 3, H, W) ``diffuse * (1 - specular)``.
        alpha: (B or 1, 1, 1, H or 1, W or 1) GGX alpha.
        specular: (B, 1, 3, H, W) F0.
    """
    dg = ndf_ggx(geo["nh"], alpha) * visibility_smith_schlick(geo["nl"], geo["nv"], alpha) * (0.25 * math.pi)
    return geo["irradiance"] * (diffuse_term + dg * fresnel_schlick(geo["vh"], specular))


def _highlight_suppressor(d):
    """D_h (Eq. 10): NDF values above delta_h replaced by D-bar, per sample."""
    below = d <= cv.HIGHLIGHT_NDF_THRESHOLD
    dbar = (d * below).sum((1, 2, 3), keepdim=True) / below.sum((1, 2, 3), keepdim=True).clamp_min(1)
    return torch.where(below, d, dbar)


def _lowlight_suppressor(d):
    """D_l (Eq. 11): NDF values below delta_s raised to delta_s."""
    return d.clamp_min(cv.LOWLIGHT_NDF_THRESHOLD)


def highlight_mask(maps, light=cv.FLASH_POSITION, intensity=cv.LIGHT_INTENSITY, image=None, camera=None):
    """M_h (Eq. 10): input minus the highlight-suppressed image; (B, 3, H, W) in [0, 1]."""
    image = flash_image(maps, light, intensity, camera=camera) if image is None else image
    return (image - flash_image(maps, light, intensity, ndf=_highlight_suppressor, camera=camera)).clamp_min(0.0)


def bumpiness_mask(maps, light=cv.FLASH_POSITION, intensity=cv.LIGHT_INTENSITY, image=None, camera=None):
    """M_b (Eq. 11): the lowlight-suppressed image minus the input; (B, 3, H, W) in [0, 1]."""
    image = flash_image(maps, light, intensity, camera=camera) if image is None else image
    return (flash_image(maps, light, intensity, ndf=_lowlight_suppressor, camera=camera) - image).clamp_min(0.0)


def intermediate_targets(maps, light=cv.FLASH_POSITION, intensity=cv.LIGHT_INTENSITY, names=TARGET_NAMES,
                         camera=None):
    """All targets for a batch: dict of (B, 3, H, W) encoded images/masks.

    Args:
        maps: dict of linear maps (B, C, H, W).
        light: flash position, (3,) or (B, 3).
        intensity: flash intensity, float or (B,).
        names: which of :data:`TARGET_NAMES` to compute.
        camera: camera position, (3,) or (B, 3); ``None``: at the flash.
            I_hr and I_hr^2 centre their light disc on it.
    """
    out = {}
    cam = light if camera is None else camera
    image = flash_image(maps, light, intensity, camera=camera)
    if "I" in names:
        out["I"] = image
    if "I_bf" in names:
        out["I_bf"] = bumpiness_flattened(maps, light, intensity, camera=camera)
    if "I_hr" in names and "I_hr2" in names:
        out["I_hr"], out["I_hr2"] = highlight_removed_pair(maps, cam, intensity)
    elif "I_hr" in names:
        out["I_hr"] = highlight_removed(maps, cam, intensity)
    elif "I_hr2" in names:
        out["I_hr2"] = highlight_removed(maps, cam, intensity, high_roughness=True)
    if "M_b" in names:
        out["M_b"] = bumpiness_mask(maps, light, intensity, image=image, camera=camera)
    if "M_h" in names:
        out["M_h"] = highlight_mask(maps, light, intensity, image=image, camera=camera)
    return out
