"""What the flash geometry tells for free: the trained chain's physics context and base estimate.

For a flat surface lit by a flash at ``light`` (world units of :mod:`svbrdf_cli.conventions`: the
imaged square spans [-1, 1]², +Z towards the camera), per pixel:

* **context** (4 channels): the pixel's offset from the point under the flash, x and y, in flash
  heights; the cosine of the light's incidence; the inverse-square falloff relative to the point
  under the flash. Smooth fields that tell a network where the highlight is and how the light
  falls off.
* **base** (10 channels, the maps' stored encoding): the estimate an untrained chain returns: flat
  normal; diffuse = the linear photo divided by the irradiance of the conventions' flash
  (:data:`svbrdf_cli.conventions.FLASH_INTENSITY` at the flash's height, the level every capture
  reads albedo at), clipped to [0, 1]; roughness 0.5; F0 = 0.04 (a dielectric).

:func:`fields` is written once for numpy and torch (``xp``); the training computes the same fields
batched in torch (``export/engine/flash.py``, tested equal).
"""

from __future__ import annotations

import numpy as np

from svbrdf_cli import conventions as cv

CONTEXT_CHANNELS = 4
BASE_CHANNELS = 10
BASE_ROUGHNESS = 0.5


def fields(xp, p, light):
    """(offset (B, 2, H, W), cos, falloff, squared distance (B, 1, H, W)) of positions ``p``
    (…, 3, H, W) under a flash at ``light`` (B, 3, 1, 1); ``xp`` is numpy or torch."""
    to_light = light - p
    dist2 = (to_light * to_light).sum(-3, keepdims=True) if xp is np else (to_light * to_light).sum(-3, keepdim=True)
    h = light[:, 2:3]
    cos = to_light[:, 2:3] / xp.sqrt(dist2)
    falloff = h * h / dist2
    offset = (p[:, :2] - light[:, :2]) / h
    return offset, cos, falloff, dist2


def flash_power(height):
    """The conventions' flash intensity for a flash at ``height`` (it lights the point under it as
    :data:`svbrdf_cli.conventions.FLASH_INTENSITY` does from the camera's height)."""
    return cv.FLASH_INTENSITY * (height / cv.CAMERA_HEIGHT) ** 2


def _positions(h, w):
    return np.moveaxis(cv.surface_positions(h, w).astype(np.float64), -1, 0)[None]


def context(light, size, width=None):
    """(size, width or size, 4) float32 context fields of a flash at ``light`` (3,)."""
    lt = np.asarray(light, np.float64).reshape(1, 3, 1, 1)
    offset, cos, falloff, _ = fields(np, _positions(size, width or size), lt)
    return np.moveaxis(np.concatenate([offset, cos, falloff], 1)[0], 0, -1).astype(np.float32)


def base(photo, light):
    """(H, W, 10) float32 base estimate of one (H, W, 3) encoded photo under a flash at ``light``."""
    h, w = photo.shape[:2]
    lt = np.asarray(light, np.float64).reshape(1, 3, 1, 1)
    _, cos, _, dist2 = fields(np, _positions(h, w), lt)
    irradiance = (flash_power(lt[:, 2:3]) * np.maximum(cos, 1e-3) / dist2)[0, 0][..., None]
    diffuse = np.clip(cv.image_to_linear(photo.astype(np.float64)) / irradiance, 0.0, 1.0)
    out = np.empty((h, w, BASE_CHANNELS), np.float64)
    out[..., 0:2] = 0.5
    out[..., 2] = 1.0
    out[..., 3:6] = cv.albedo_to_stored(diffuse)
    out[..., 6] = BASE_ROUGHNESS
    out[..., 7:10] = cv.DIELECTRIC_F0 ** (1 / cv.ALBEDO_GAMMA)
    return out.astype(np.float32)
