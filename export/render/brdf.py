"""Batched, differentiable Cook-Torrance rendering in torch (CPU and CUDA).

The torch twin of :mod:`svbrdf_cli.shading`; same model, same conventions
(:mod:`svbrdf_cli.conventions`), tensors in NCHW. References for D, G, F:
Walter et al. 2007 (GGX), Karis 2013 (Smith with Schlick-GGX, k = a/2, as in
Des18), Schlick 1994 (Fresnel). Every tensor argument broadcasts: a flat
normal can be (1, 3, 1, 1), a single light (3,), so averaging many lights over
a batch costs little more than the per-pixel arithmetic.

Maps, in linear units :

* ``normal``: (B, 3, H, W) unit vectors, +Y up.
* ``diffuse``: (B, 3, H, W) linear albedo in [0, 1].
* ``roughness``: (B, 1, H, W) in [0, 1] (alpha = r^2).
* ``specular``: (B, 3, H, W) linear albedo (F0) in [0, 1].

Decode stored maps with ``svbrdf_cli.conventions.decode_maps(stored, axis=1)``.
"""

from __future__ import annotations

import functools
import math

import torch

from svbrdf_cli import conventions as cv


def _dot(a, b):
    return (a * b).sum(1, keepdim=True)


def ndf_ggx(n_dot_h, alpha):
    """GGX normal distribution D (see :func:`svbrdf_cli.shading.ndf_ggx`)."""
    a2 = alpha * alpha
    nh = n_dot_h.clamp(0.0, 1.0)
    return a2 / (math.pi * (nh * nh * (a2 - 1.0) + 1.0).clamp_min(cv.EPS) ** 2)


def visibility_smith_schlick(n_dot_l, n_dot_v, alpha):
    """Smith G (Schlick-GGX, k = alpha/2) divided by (n.l)(n.v)."""
    k = alpha * 0.5
    nl = n_dot_l.clamp(0.0, 1.0)
    nv = n_dot_v.clamp(0.0, 1.0)
    return 1.0 / ((nl * (1.0 - k) + k).clamp_min(cv.EPS) * (nv * (1.0 - k) + k).clamp_min(cv.EPS))


def fresnel_schlick(v_dot_h, f0):
    """Schlick's Fresnel with reflectance ``f0`` at normal incidence."""
    return f0 + (1.0 - f0) * (1.0 - v_dot_h.clamp(0.0, 1.0)) ** 5


def brdf(n, l, v, diffuse, roughness, specular, ndf=None):
    """Cook-Torrance BRDF f(n, l, v) without the cosine; channel axis 1.

    Args:
        n, l, v: (B, 3, H, W) unit normal, light and view directions (broadcastable).
        diffuse, roughness, specular: linear maps (see module docstring).
        ndf: optional callable ``D -> D'`` on the (B, 1, H, W) NDF values.

    Returns:
        (B, 3, H, W) BRDF values.
    """
    h = cv.normalize(l + v, axis=1)
    alpha = cv.roughness_to_alpha(roughness)
    d = ndf_ggx(_dot(n, h), alpha)
    if ndf is not None:
        d = ndf(d)
    spec = d * fresnel_schlick(_dot(v, h), specular) * visibility_smith_schlick(_dot(n, l), _dot(n, v), alpha) * 0.25
    return diffuse * (1.0 - specular) / math.pi + spec


@functools.lru_cache(maxsize=16)
def _positions(height, width, device, dtype):
    p = torch.from_numpy(cv.surface_positions(height, width)).to(device=device, dtype=dtype)
    return p.permute(2, 0, 1).unsqueeze(0)  # (1, 3, H, W)


def surface_positions(height, width, like):
    """(1, 3, H, W) world positions of pixel centres, on ``like``'s device and dtype."""
    return _positions(height, width, like.device, like.dtype)


def _as_points(x, like):
    """A position (3,) or (B, 3) -> (B or 1, 3, 1, 1) tensor like ``like``."""
    t = torch.as_tensor(x, device=like.device, dtype=like.dtype)
    return t.reshape(-1, 3, 1, 1)


def _as_scalars(x, like):
    t = torch.as_tensor(x, device=like.device, dtype=like.dtype)
    return t.reshape(-1, 1, 1, 1)


def render(normal, diffuse, roughness, specular, light=cv.FLASH_POSITION, camera=None,
           intensity=cv.LIGHT_INTENSITY, ndf=None):
    """Linear radiance of a flat surface lit by a point light; differentiable.

    Args:
        normal, diffuse, roughness, specular: maps (see module docstring),
            broadcastable to a common (B, C, H, W); H and W come from the
            largest of them.
        light: light position, (3,) or (B, 3).
        camera: camera position, (3,) or (B, 3); ``None`` = at the light (flash).
        intensity: float or (B,) point-light intensity.
        ndf: optional transform of the NDF values (paper Eqs. 10-11).

    Returns:
        (B, 3, H, W) linear radiance, unclipped, >= 0.
    """
    ref = max((normal, diffuse, roughness, specular), key=lambda t: t.shape[-1] * t.shape[-2])
    p = surface_positions(ref.shape[-2], ref.shape[-1], ref)
    to_light = _as_points(light, ref) - p
    dist2 = _dot(to_light, to_light)
    l = to_light * dist2.rsqrt()
    v = l if camera is None else cv.normalize(_as_points(camera, ref) - p, axis=1)
    f = brdf(normal, l, v, diffuse, roughness, specular, ndf=ndf)
    above = (l[:, 2:3] > 0).to(ref.dtype)  # no light from below the surface plane
    return _as_scalars(intensity, ref) * math.pi * f * _dot(normal, l).clamp_min(0.0) * above / dist2


def render_maps(maps, **kwargs):
    """:func:`render` for a dict of linear maps (keys of ``MAP_NAMES``)."""
    return render(maps["normal"], maps["diffuse"], maps["roughness"], maps["specular"], **kwargs)
