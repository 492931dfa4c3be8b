"""Cook-Torrance shading in numpy: the runtime's reference renderer.

Used for previews, relighting and checks; ``export/render/brdf.py`` is the
batched, differentiable torch twin, and both are tested against the golden
table ``tests/data/brdf_golden.npz`` and against each other.

The model (paper Eq. 9, Des18's variant):

    f(n, l, v) = d (1 - s) / pi + D(n.h; a) F(v.h; s) G(n.l, n.v; a) / (4 (n.l)(n.v))

* D: GGX / Trowbridge-Reitz normal distribution (Walter et al. 2007),
  ``a^2 / (pi ((n.h)^2 (a^2 - 1) + 1)^2)`` with a = r^2.
* G: separable Smith shadowing with Schlick's GGX approximation
  (Karis 2013, "Real Shading in Unreal Engine 4"), k = a / 2 as in Des18.
  It is returned already divided by (n.l)(n.v), the "visibility" form, which
  stays finite at grazing angles.
* F: Schlick's Fresnel (Schlick 1994), ``s + (1 - s)(1 - v.h)^5``.

A point light at ``light`` with intensity ``I`` gives radiance
``I * pi * f * max(n.l, 0) / |light - p|^2`` at a surface point p (the pi
makes a white Lambertian surface reflect I / d^2, as in Des18), and nothing
when the light is below the surface plane. Geometry,
encodings and constants come from :mod:`svbrdf_cli.conventions`.
"""

from __future__ import annotations

import numpy as np

from svbrdf_cli import conventions as cv


def _dot(a, b):
    return (a * b).sum(-1, keepdims=True)


def ndf_ggx(n_dot_h, alpha):
    """GGX normal distribution D.

    Args:
        n_dot_h: cosine between normal and half vector, any shape.
        alpha: GGX alpha (roughness squared), broadcastable.

    Returns:
        D values, same shape, >= 0.
    """
    a2 = alpha * alpha
    nh = np.clip(n_dot_h, 0.0, 1.0)
    return a2 / (np.pi * np.maximum(nh * nh * (a2 - 1.0) + 1.0, cv.EPS) ** 2)


def visibility_smith_schlick(n_dot_l, n_dot_v, alpha):
    """Smith G (Schlick-GGX, k = alpha/2) divided by (n.l)(n.v)."""
    k = alpha * 0.5
    nl = np.clip(n_dot_l, 0.0, 1.0)
    nv = np.clip(n_dot_v, 0.0, 1.0)
    return 1.0 / (np.maximum(nl * (1.0 - k) + k, cv.EPS) * np.maximum(nv * (1.0 - k) + k, cv.EPS))


def fresnel_schlick(v_dot_h, f0):
    """Schlick's Fresnel with reflectance ``f0`` at normal incidence."""
    return f0 + (1.0 - f0) * (1.0 - np.clip(v_dot_h, 0.0, 1.0)) ** 5


def brdf(n, l, v, diffuse, roughness, specular, ndf=None):
    """Cook-Torrance BRDF value f(n, l, v), without the cosine.

    Args:
        n, l, v: (..., 3) unit normal, light and view directions.
        diffuse: (..., 3) linear diffuse albedo in [0, 1].
        roughness: (..., 1) roughness in [0, 1].
        specular: (..., 3) linear specular albedo (F0) in [0, 1].
        ndf: optional callable ``D -> D'`` applied to the NDF values (used by
            the paper's mask targets, Eqs. 10-11).

    Returns:
        (..., 3) BRDF values (1/sr), >= 0.
    """
    h = cv.normalize(l + v)
    alpha = cv.roughness_to_alpha(np.asarray(roughness))
    d = ndf_ggx(_dot(n, h), alpha)
    if ndf is not None:
        d = ndf(d)
    spec = d * fresnel_schlick(_dot(v, h), specular) * visibility_smith_schlick(_dot(n, l), _dot(n, v), alpha) * 0.25
    return diffuse * (1.0 - specular) / np.pi + spec


def render(normal, diffuse, roughness, specular, light=cv.FLASH_POSITION, camera=None,
           intensity=cv.LIGHT_INTENSITY, ndf=None):
    """Linear radiance of a flat surface lit by a point light.

    Args:
        normal: (H, W, 3) unit normals (decode stored maps with
            :func:`svbrdf_cli.conventions.decode_normals`).
        diffuse: (H, W, 3) linear diffuse albedo in [0, 1].
        roughness: (H, W, 1) roughness in [0, 1].
        specular: (H, W, 3) linear specular albedo in [0, 1].
        light: light position (3,), world units (surface spans [-1, 1]^2).
        camera: camera position (3,); ``None`` puts it at the light (flash).
        intensity: point-light intensity.
        ndf: optional transform of the NDF values (see :func:`brdf`).

    Returns:
        (H, W, 3) linear radiance, unclipped, >= 0.
    """
    h, w = normal.shape[:2]
    p = cv.surface_positions(h, w).astype(normal.dtype, copy=False)
    to_light = np.asarray(light, dtype=normal.dtype) - p
    dist2 = _dot(to_light, to_light)
    l = to_light / np.sqrt(dist2)
    v = l if camera is None else cv.normalize(np.asarray(camera, dtype=normal.dtype) - p)
    f = brdf(normal, l, v, diffuse, roughness, specular, ndf=ndf)
    # A light below the surface plane reaches no pixel, whatever its mapped normal.
    above = l[..., 2:] > 0
    return intensity * np.pi * f * np.clip(_dot(normal, l), 0.0, None) * above / dist2


def render_maps(maps, **kwargs):
    """:func:`render` for a dict of decoded maps (keys of ``MAP_NAMES``)."""
    return render(maps["normal"], maps["diffuse"], maps["roughness"], maps["specular"], **kwargs)
