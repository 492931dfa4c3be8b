"""The maps an engine wants, derived from ours: metallic from F0, height and ambient occlusion from
the normals, the normal map's conventions.

Inputs are the runtime's linear maps (:mod:`svbrdf_cli.write.mapset`): normals (H, W, 3) float unit
vectors, +Y up; diffuse and specular (H, W, 3) float linear albedo / F0 in [0, 1].
"""

from __future__ import annotations

import numpy as np

from svbrdf_cli import conventions as cv

#: Rec. 601 luma weights of the "perceived brightness" in the
#: KHR_materials_pbrSpecularGlossiness conversion sample.
_BRIGHTNESS_WEIGHTS = (0.299, 0.587, 0.114)

#: Smallest |n_z| used when turning normals into slopes (slope <= 20).
_MIN_NZ = 0.05


# --------------------------------------------------------------------------
# Conversions
# --------------------------------------------------------------------------

def _brightness(c):
    w = np.asarray(_BRIGHTNESS_WEIGHTS, dtype=np.float64)
    return np.sqrt((c * c * w).sum(-1, keepdims=True))


def specular_to_metallic(diffuse, specular):
    """Specular/diffuse albedos -> metallic-roughness base colour and metallic.

    KHR_materials_pbrSpecularGlossiness' ``solveMetallic``, written from its
    definition. The metallic workflow's two lobes are

        specular = lerp(F0, base, m)                    (F0 = DIELECTRIC_F0)
        c_diff   = base (1 - F0) (1 - m)

    and the specular workflow's diffuse lobe is ``diffuse (1 - max(specular))``
    (our renderer's ``d (1 - s)`` for grey specular). Working on the perceived
    brightness ``B(c) = sqrt(0.299 r^2 + 0.587 g^2 + 0.114 b^2)`` of each
    colour (D for diffuse, S for specular), equating the diffuse lobes gives
    ``base (1 - m) = D'`` with ``D' = D (1 - max(specular)) / (1 - F0)``;
    substituting ``base = D' / (1 - m)`` into the specular equation and
    multiplying by (1 - m):

        F0 m^2 + (D' + S - 2 F0) m + (F0 - S) = 0

    whose larger root is the metallic value (for S > F0 the roots have
    opposite signs, so it is the only one in [0, 1]). Below F0 the material is
    a dielectric, m = 0. The base colour blends the two estimates
    ``diffuse (1 - max(specular)) / (1 - F0) / (1 - m)`` (exact for
    dielectrics) and ``(specular - F0 (1 - m)) / m`` (exact for metals) with
    weight m^2, as the sample does.

    Dark materials are ambiguous: a dark dielectric and a dark grey metal
    reflect alike, and just above S = F0 the quadratic's larger root over a
    dark diffuse is large (diffuse 0.02 with F0 0.045 solves to m = 0.58).
    So a specular short of halfway to a metal's (brightness up to
    ``METAL_CALL_F0[0]`` of :data:`svbrdf_cli.conventions.METAL_CALL_F0`, any tint) is a dielectric,
    m = 0, and the root is faded in up to ``METAL_CALL_F0[1]`` (:func:`svbrdf_cli.conventions.metal_call`).
    Pure dielectrics (specular = F0) and metals brighter than that (diffuse = 0) round-trip exactly
    through ``diffuse = base (1 - m), specular = lerp(F0, base, m)``.

    Args:
        diffuse: (..., 3) linear diffuse albedo in [0, 1].
        specular: (..., 3) linear specular albedo (F0) in [0, 1].

    Returns:
        (base_colour (..., 3) linear RGB in [0, 1], metallic (..., 1) in
        [0, 1]), float32.
    """
    f0 = cv.DIELECTRIC_F0
    d = np.asarray(diffuse, dtype=np.float64)
    s = np.asarray(specular, dtype=np.float64)
    bd, bs = _brightness(d), _brightness(s)
    keep = 1.0 - s.max(-1, keepdims=True)  # the specular workflow's diffuse weight
    b = bd * keep / (1.0 - f0) + bs - 2.0 * f0
    c = f0 - bs
    disc = np.maximum(b * b - 4.0 * f0 * c, 0.0)
    m = ((np.sqrt(disc) - b) / (2.0 * f0)).clip(0.0, 1.0)
    m = m * cv.metal_call(bs)
    eps = 1e-6
    from_diffuse = d * (keep / (1.0 - f0) / np.maximum(1.0 - m, eps))
    from_specular = (s - f0 * (1.0 - m)) / np.maximum(m, eps)
    base = from_diffuse + (from_specular - from_diffuse) * (m * m)
    return base.clip(0.0, 1.0).astype(np.float32), m.astype(np.float32)


def normals_to_height(normals, tileable=False):
    """Height field whose normals best match a normal map (Frankot-Chellappa).

    The slopes are ``dh/dx = -n_x / n_z`` and ``dh/dy = -n_y / n_z`` in
    surface units; the surface spans ``2 * SURFACE_HALF_SIZE`` units across
    the image width (square pixels) and row 0 is +Y, so
    ``dh/drow = -dh/dy * pixel``. The least-squares integrable surface is
    found in the Fourier domain (Frankot & Chellappa 1988):
    ``H = -j (wx Gx + wy Gy) / (wx^2 + wy^2)``, mean height 0.

    The FFT treats the map as periodic. A map that does not tile would wrap
    its left/right and top/bottom slope mismatch into a tilt; unless
    ``tileable``, the slope field is mirrored to twice the size first (slopes
    change sign in the mirrored copies), which is periodic by construction.

    Args:
        normals: (H, W, 3) unit normals, +Y up (OpenGL).
        tileable: the map tiles; integrate it as periodic without mirroring.

    Returns:
        (H, W) float32 heights in surface units (mean 0 over the integrated
        domain).
    """
    n = np.asarray(normals, dtype=np.float64)
    h, w = n.shape[:2]
    pixel = 2.0 * cv.SURFACE_HALF_SIZE / w
    nz = np.maximum(n[..., 2], _MIN_NZ)
    # float32 halves the FFT memory on numpy >= 2 (a 4096^2 map is mirrored to 8192^2).
    g_col = (-n[..., 0] / nz * pixel).astype(np.float32)   # dh per column step (+x)
    g_row = (n[..., 1] / nz * pixel).astype(np.float32)    # dh per row step (-y)
    if not tileable:
        g_col = np.concatenate([g_col, -g_col[:, ::-1]], 1)
        g_col = np.concatenate([g_col, g_col[::-1]], 0)
        g_row = np.concatenate([g_row, g_row[:, ::-1]], 1)
        g_row = np.concatenate([g_row, -g_row[::-1]], 0)
    rows, cols = g_col.shape
    wx = (2.0 * np.pi * np.fft.rfftfreq(cols)[None, :]).astype(np.float32)
    wy = (2.0 * np.pi * np.fft.fftfreq(rows)[:, None]).astype(np.float32)
    gx, gy = np.fft.rfft2(g_col), np.fft.rfft2(g_row)
    denom = wx * wx + wy * wy
    denom[0, 0] = 1.0
    spectrum = -1j * (wx * gx + wy * gy) / denom
    spectrum[0, 0] = 0.0
    height = np.fft.irfft2(spectrum, s=(rows, cols))
    return height[:h, :w].astype(np.float32)


#: Ambient occlusion: horizon search in this many directions, out to these distances (pixels of a
#: 1024 px map: the same share of any map's width), on the map at most AO_MAX_SIDE px (then resized).
AO_DIRECTIONS = 8
AO_STEPS = (1, 2, 4, 8, 16, 32)
AO_MAX_SIDE = 512
AO_NOTE = ("horizon-based, from the integrated height: 1 - mean over 8 directions of the sine of the highest "
           "horizon within 32/1024 of the width")


def ambient_occlusion(height, pixel, tileable=False):
    """(H, W) ambient occlusion in [0, 1] of a height field (surface units, ``pixel`` wide pixels).

    For each of :data:`AO_DIRECTIONS` directions, the highest horizon within :data:`AO_STEPS` pixels
    (elevation angle of the neighbour's height over its distance) above the local tangent plane; the
    unoccluded fraction is 1 minus the mean difference of their sines (1 on any plane, tilted or
    not; lower in grooves and pores). Borders repeat
    the edge (or wrap, for a ``tileable`` map).
    """
    import cv2

    h, w = height.shape
    scale = min(1.0, AO_MAX_SIDE / max(h, w))
    hf = np.asarray(height, np.float32)
    if scale < 1.0:
        hf = cv2.resize(hf, (max(1, round(w * scale)), max(1, round(h * scale))), interpolation=cv2.INTER_AREA)
    px = pixel / scale
    hh, ww = hf.shape
    steps = sorted({max(1, round(d * max(hh, ww) / 1024)) for d in AO_STEPS})  # the same share of any map
    r = max(steps)
    # beyond the border: the wrapped map when it tiles, else nothing (NaN neighbours are ignored)
    padded = np.pad(hf, r, mode="wrap") if tileable else np.pad(hf, r, constant_values=np.nan)
    gy, gx = np.gradient(hf, px)  # the local slope: horizons are measured above the tangent plane
    occl = np.zeros_like(hf)
    for k in range(AO_DIRECTIONS):
        a = 2 * np.pi * k / AO_DIRECTIONS
        tangent = gx * np.cos(a) + gy * np.sin(a)  # tan of the tangent plane's elevation that way
        best = tangent.copy()
        for d in steps:
            dy, dx = int(round(d * np.sin(a))), int(round(d * np.cos(a)))
            nb = padded[r + dy:r + dy + hh, r + dx:r + dx + ww]
            best = np.fmax(best, (nb - hf) / (np.hypot(dx, dy) * px))  # tan of the horizon's elevation
        sin = lambda t: t / np.sqrt(1.0 + t * t)  # noqa: E731
        occl += sin(best) - sin(tangent)
    ao = 1.0 - occl / AO_DIRECTIONS
    if scale < 1.0:
        ao = cv2.resize(ao, (w, h), interpolation=cv2.INTER_LINEAR)
    return np.clip(ao, 0.0, 1.0).astype(np.float32)


#: The height map's fixed scale: its [0, 1] range spans this many texture widths, 0.5 being the mean
#: surface (height in widths = (value - 0.5) * HEIGHT_SPAN). Fixed, not stretched to each map's own
#: range: a nearly flat material stays a nearly flat grey, and every set reads the same way.
HEIGHT_SPAN = 0.1
#: The height map's value for the mean surface (Blender's Displacement node's default midlevel).
HEIGHT_MIDLEVEL = 0.5


def height_to_map(height, width_units):
    """Heights -> the height map's values at the fixed scale (:data:`HEIGHT_SPAN`, :data:`HEIGHT_MIDLEVEL`).

    Args:
        height: (H, W) heights in surface units (:func:`normals_to_height`).
        width_units: the map's width in the same units.

    Returns:
        (H, W) float32 in [0, 1]: ``HEIGHT_MIDLEVEL + (height - mean) / width_units / HEIGHT_SPAN``, clipped.
        A flat field gives HEIGHT_MIDLEVEL everywhere.
    """
    h = np.asarray(height, np.float64)
    widths = (h - h.mean()) / float(width_units)
    return np.clip(HEIGHT_MIDLEVEL + widths / HEIGHT_SPAN, 0.0, 1.0).astype(np.float32)


def normals_to_opengl(normals):
    """Unit normals -> OpenGL (+Y up) normal-map pixels in [0, 1]."""
    return cv.encode_normals(np.asarray(normals, dtype=np.float32))


def normals_to_directx(normals):
    """Unit normals -> DirectX (Y down, green flipped) normal-map pixels in [0, 1]."""
    flip = np.array([1.0, -1.0, 1.0], dtype=np.float32)
    return cv.encode_normals(np.asarray(normals, dtype=np.float32) * flip)
