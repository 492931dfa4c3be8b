"""What the flash geometry tells for free, batched in torch: the networks' physics context and
the base estimate (:mod:`svbrdf_cli.infer.flash_fields` defines them and computes them in numpy for
the runtime; :func:`context` and :func:`base` are the same arithmetic on batches, tested equal).
"""

from __future__ import annotations

import torch

from svbrdf_cli import conventions as cv
from svbrdf_cli.infer.flash_fields import BASE_CHANNELS, BASE_ROUGHNESS, CONTEXT_CHANNELS, fields, flash_power

__all__ = ["BASE_CHANNELS", "BASE_ROUGHNESS", "CONTEXT_CHANNELS", "base", "context", "level_factor"]


def context(camera, light, size, like=None):
    """(B, 4, size, size) float32 context fields (see the module docstring).

    Args:
        camera, light: (B, 3) positions (any float dtype).
        size: output height and width.
    """
    dtype = torch.float32
    p = torch.from_numpy(cv.surface_positions(size, size)).to(dtype).permute(2, 0, 1)[None]
    light = light.to(dtype).reshape(-1, 3, 1, 1)
    offset, cos, falloff, _ = fields(torch, p, light)
    return torch.cat([offset, cos, falloff], 1)


def base(photo, camera, light):
    """(B, 10, H, W) base estimate in the stored encoding from (B, 3, H, W) encoded photos."""
    b, _, h, w = photo.shape
    p = torch.from_numpy(cv.surface_positions(h, w)).to(photo).permute(2, 0, 1)[None]
    light = light.to(photo).reshape(-1, 3, 1, 1)
    _, cos, _, dist2 = fields(torch, p, light)
    power = flash_power(light[:, 2:3])
    irradiance = power * cos.clamp_min(1e-3) / dist2
    diffuse = (cv.image_to_linear(photo) / irradiance).clamp(0.0, 1.0)
    ones = torch.ones_like(photo[:, :1])
    return torch.cat([ones * 0.5, ones * 0.5, ones, cv.albedo_to_stored(diffuse), ones * BASE_ROUGHNESS,
                      ones.expand(-1, 3, -1, -1) * cv.DIELECTRIC_F0 ** (1 / cv.ALBEDO_GAMMA)], 1)


def level_factor(intensity, light):
    """(B,) how much brighter the photo's flash lit the surface than the conventions' flash at the
    same height: the diffuse targets are the material's albedo times this (what the base reads)."""
    h = light[:, 2].to(intensity)
    return intensity.reshape(-1) / flash_power(h)
