"""What the flash geometry tells for free, batched in torch: the networks' physics context.

For a flat surface seen by a camera at ``camera`` and lit by a flash at ``light`` (world units of
:mod:`svbrdf_cli.conventions`: the imaged square spans [-1, 1]², +Z towards the camera), per pixel:

* **context** (4 channels): the pixel's offset from the point under the flash, x and y, in flash
  heights; the cosine of the light's incidence; the inverse-square falloff relative to the point
  under the flash. Smooth fields that tell a network where the highlight is and how the light
  falls off.
* **base** (10 channels, the maps' stored encoding): the estimate an untrained chain returns: flat
  normal; diffuse = the linear photo divided by the irradiance of the conventions' flash
  (:data:`svbrdf_cli.conventions.FLASH_INTENSITY` at the camera's height, the level every capture
  reads albedo at), clipped to [0, 1]; roughness 0.5; F0 = 0.04 (a dielectric).

The runtime computes the same fields in numpy (:func:`context_numpy`, :func:`base_numpy`; tested
equal).
"""

from __future__ import annotations

import numpy as np
import torch

from svbrdf_cli import conventions as cv

CONTEXT_CHANNELS = 4
BASE_CHANNELS = 10
BASE_ROUGHNESS = 0.5


def _fields(xp, p, camera, light):
    """Shared arithmetic of the torch and numpy versions; ``p`` (…, 3, H, W) positions,
    ``camera``/``light`` (B, 3, 1, 1)."""
    to_light = light - p
    dist2 = (to_light * to_light).sum(-3, keepdims=True) if xp is np else (to_light * to_light).sum(-3, keepdim=True)
    h = light[:, 2:3]
    cos = to_light[:, 2:3] / xp.sqrt(dist2)
    falloff = h * h / dist2
    offset = (p[:, :2] - light[:, :2]) / h
    return offset, cos, falloff, dist2


def context(camera, light, size, like=None):
    """(B, 4, size, size) float32 context fields (see the module docstring).

    Args:
        camera, light: (B, 3) positions (any float dtype).
        size: output height and width.
    """
    dtype = torch.float32
    p = torch.from_numpy(cv.surface_positions(size, size)).to(dtype).permute(2, 0, 1)[None]
    light = light.to(dtype).reshape(-1, 3, 1, 1)
    offset, cos, falloff, _ = _fields(torch, p, camera, light)
    return torch.cat([offset, cos, falloff], 1)


def base(photo, camera, light):
    """(B, 10, H, W) base estimate in the stored encoding from (B, 3, H, W) encoded photos."""
    b, _, h, w = photo.shape
    p = torch.from_numpy(cv.surface_positions(h, w)).to(photo).permute(2, 0, 1)[None]
    light = light.to(photo).reshape(-1, 3, 1, 1)
    _, cos, _, dist2 = _fields(torch, p, camera, light)
    power = cv.FLASH_INTENSITY * (light[:, 2:3] / cv.CAMERA_HEIGHT) ** 2
    irradiance = power * cos.clamp_min(1e-3) / dist2
    diffuse = (cv.image_to_linear(photo) / irradiance).clamp(0.0, 1.0)
    ones = torch.ones_like(photo[:, :1])
    return torch.cat([ones * 0.5, ones * 0.5, ones, cv.albedo_to_stored(diffuse), ones * BASE_ROUGHNESS,
                      ones.expand(-1, 3, -1, -1) * cv.DIELECTRIC_F0 ** (1 / cv.ALBEDO_GAMMA)], 1)


def context_numpy(light, size):
    """:func:`context` for one photo in numpy: (size, size, 4) float32; ``light`` (3,)."""
    p = np.moveaxis(cv.surface_positions(size, size).astype(np.float64), -1, 0)[None]
    lt = np.asarray(light, np.float64).reshape(1, 3, 1, 1)
    offset, cos, falloff, _ = _fields(np, p, None, lt)
    return np.moveaxis(np.concatenate([offset, cos, falloff], 1)[0], 0, -1).astype(np.float32)


def base_numpy(photo, light):
    """:func:`base` for one (H, W, 3) encoded photo in numpy: (H, W, 10) float32."""
    h, w = photo.shape[:2]
    p = np.moveaxis(cv.surface_positions(h, w).astype(np.float64), -1, 0)[None]
    lt = np.asarray(light, np.float64).reshape(1, 3, 1, 1)
    _, cos, _, dist2 = _fields(np, p, None, lt)
    power = cv.FLASH_INTENSITY * (lt[:, 2:3] / cv.CAMERA_HEIGHT) ** 2
    irradiance = (power * np.maximum(cos, 1e-3) / dist2)[0, 0][..., None]
    diffuse = np.clip(cv.image_to_linear(photo.astype(np.float64)) / irradiance, 0.0, 1.0)
    out = np.empty((h, w, 10), np.float64)
    out[..., 0:2] = 0.5
    out[..., 2] = 1.0
    out[..., 3:6] = cv.albedo_to_stored(diffuse)
    out[..., 6] = BASE_ROUGHNESS
    out[..., 7:10] = cv.DIELECTRIC_F0 ** (1 / cv.ALBEDO_GAMMA)
    return out.astype(np.float32)


def level_factor(intensity, light):
    """(B,) how much brighter the photo's flash lit the surface than the conventions' flash at the
    same height: the diffuse targets are the material's albedo times this (what the base reads)."""
    h = light[:, 2].to(intensity)
    return intensity.reshape(-1) / (cv.FLASH_INTENSITY * (h / cv.CAMERA_HEIGHT) ** 2)
