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
    if isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.shape[-1] == 3 and b.shape[-1] == 3:
        # the three products added directly: the same sum (same order), 5-14x faster than numpy's
        # reduction over a 3-long axis
        return a[..., 0:1] * b[..., 0:1] + a[..., 1:2] * b[..., 1:2] + a[..., 2:3] * b[..., 2:3]
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
        n: (..., 3) unit normal.
        l: (..., 3) unit direction to the light.
        v: (..., 3) unit direction to the viewer.
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


# --------------------------------------------------------------------------
# The same rendering with its gradient (for svbrdf_cli.infer.refine)
# --------------------------------------------------------------------------

class Lighting:
    """Per-pixel light and view directions for one capture geometry, computed once.

    Args:
        height, width: the image's pixels (the surface spans [-1, 1]^2 at any size).
        light: light position (3,).
        camera: camera position (3,); ``None``: at the light (a flash at the lens).
        intensity: point-light intensity.
    """

    def __init__(self, height, width, light, camera=None, intensity=cv.LIGHT_INTENSITY):
        p = cv.surface_positions(height, width)
        to_light = np.asarray(light, np.float64) - p
        dist2 = _dot(to_light, to_light)
        self.l = (to_light / np.sqrt(dist2)).astype(np.float32)
        self.v = self.l if camera is None else cv.normalize(np.asarray(camera, np.float64) - p).astype(np.float32)
        self.h = cv.normalize(self.l + self.v).astype(np.float32)
        self.fresnel_weight = ((1.0 - np.clip(_dot(self.v, self.h), 0.0, 1.0)) ** 5).astype(np.float32)
        above = self.l[..., 2:] > 0
        self.scale = (intensity * np.pi * above / dist2).astype(np.float32)  # I pi / d^2, 0 below the plane


def tilt_to_normal(tilt):
    """(..., 2) tilt (the normal's x/z and y/z) -> (..., 3) unit normals; any tilt is a valid normal."""
    m = np.concatenate([tilt, np.ones_like(tilt[..., :1])], -1)
    return m / np.sqrt((m * m).sum(-1, keepdims=True))


def normal_to_tilt(normal, limit=10.0):
    """Inverse of :func:`tilt_to_normal` (normals at grazing angles are held at ``limit``)."""
    z = np.maximum(normal[..., 2:], 1e-3)
    return np.clip(normal[..., :2] / z, -limit, limit).astype(np.float32)


def render_with_gradient(tilt, diffuse, roughness, specular, lighting):
    """:func:`render` of a tilt-parameterised map set, and the map of its vector-Jacobian product.

    The model and clamps are :func:`render`'s; the gradient is analytic (checked against finite
    differences and against torch's autograd of ``export/render/brdf.py`` in the tests). Where a
    clamp is active (a cosine at 0 or 1, a denominator at its floor) the gradient is the clamped
    function's, 0 through the clamped quantity.

    Args:
        tilt: (H, W, 2) normal tilt (see :func:`tilt_to_normal`).
        diffuse: (H, W, 3) linear diffuse albedo.
        roughness: (H, W, 1) roughness, in [MIN_ROUGHNESS, 1] (not clipped here).
        specular: (H, W, 3) linear F0.
        lighting: a :class:`Lighting` of the same size.

    Returns:
        (radiance (H, W, 3), backward), ``backward(grad_radiance)`` -> dict of gradients with keys
        ``tilt``, ``diffuse``, ``roughness``, ``specular``, shaped as the arguments.
    """
    L = lighting
    m = np.concatenate([tilt, np.ones_like(tilt[..., :1])], -1)
    inv = 1.0 / np.sqrt(tilt[..., 0:1] * tilt[..., 0:1] + tilt[..., 1:2] * tilt[..., 1:2] + 1.0)
    n = m * inv
    nl, nv, nh = _dot(n, L.l), _dot(n, L.v), _dot(n, L.h)
    nlc, nvc, nhc = np.clip(nl, 0.0, 1.0), np.clip(nv, 0.0, 1.0), np.clip(nh, 0.0, 1.0)
    alpha = roughness * roughness
    a2 = alpha * alpha
    q = nhc * nhc * (a2 - 1.0) + 1.0
    q_free = q > cv.EPS
    qc = np.maximum(q, cv.EPS)
    ndf = a2 / (np.pi * qc * qc)
    k = alpha * 0.5
    a_raw, b_raw = nlc * (1.0 - k) + k, nvc * (1.0 - k) + k
    a_c, b_c = np.maximum(a_raw, cv.EPS), np.maximum(b_raw, cv.EPS)
    vis = 1.0 / (a_c * b_c)
    fw = L.fresnel_weight
    kept = (1.0 - specular) * (1.0 / np.pi)  # the diffuse's share: d (1 - s) / pi
    fres = specular + (1.0 - specular) * fw
    lobe = ndf * vis * 0.25
    f = diffuse * kept + lobe * fres
    lit = L.scale * nlc
    radiance = f * lit

    def backward(grad):
        g_f = grad * lit
        g = {"diffuse": g_f * kept,
             "specular": g_f * (lobe * (1.0 - fw) - diffuse * (1.0 / np.pi))}
        g_lobe = _dot(g_f, fres)
        g_ndf, g_vis = g_lobe * vis * 0.25, g_lobe * ndf * 0.25
        # D = a2 / (pi q^2), q = nh^2 (a2 - 1) + 1
        d_ndf_a2 = 1.0 / (np.pi * qc * qc) - q_free * 2.0 * a2 * nhc * nhc / (np.pi * qc ** 3)
        d_ndf_nh = q_free * ((nh > 0) & (nh < 1)) * (-4.0 * a2 * nhc * (a2 - 1.0) / (np.pi * qc ** 3))
        # vis = 1 / (A B), A = nl (1 - k) + k, B = nv (1 - k) + k
        da, db = (a_raw > cv.EPS) / a_c, (b_raw > cv.EPS) / b_c
        d_vis_k = -vis * (da * (1.0 - nlc) + db * (1.0 - nvc))
        in_l, in_v = (nl > 0) & (nl < 1), (nv > 0) & (nv < 1)
        d_vis_nl = -vis * da * (1.0 - k) * in_l
        d_vis_nv = -vis * db * (1.0 - k) * in_v
        g_alpha = g_ndf * d_ndf_a2 * 2.0 * alpha + g_vis * d_vis_k * 0.5
        g["roughness"] = g_alpha * 2.0 * roughness
        g_nl = _dot(grad, f) * L.scale * in_l + g_vis * d_vis_nl
        g_n = g_ndf * d_ndf_nh * L.h + g_nl * L.l + g_vis * d_vis_nv * L.v
        g_m = (g_n - _dot(g_n, n) * n) * inv
        g["tilt"] = g_m[..., :2]
        return g

    return radiance, backward
