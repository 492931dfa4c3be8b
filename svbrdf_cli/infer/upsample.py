"""Maps at the network's resolution brought to the output size, guided by the photo's own detail.

A network's larger outputs are made by *guided upsampling* (:func:`guided_upsample`): the normal and
diffuse maps are regressed locally on the photo's brightness at network resolution, and the
full-resolution photo's fine detail (grain, scratches, pores) is added to their bicubic upsampling in
that proportion. ``docs/capture.md`` has the measured cost and quality against plain bicubic
upsampling."""

from __future__ import annotations

import numpy as np

from svbrdf_cli.imageops import box, luminance, resize, resize_to

#: Guided upsampling: window radius (network pixels) and regularisation.
GUIDE_RADIUS = 1
GUIDE_EPS = 1e-3


def guided_upsample(low, guide_low, guide_high, radius=GUIDE_RADIUS, eps=GUIDE_EPS, detail=None):
    """Bicubic upsampling plus the photo's own fine detail, scaled by a local regression.

    In each (2r+1)^2 window at network resolution the map is regressed on
    the guide (slope ``a = cov(guide, map) / (var(guide) + eps)``, as in He
    et al.'s guided filter); the upsampled map then gains ``a`` times the
    guide's detail that the low resolution could not hold
    (``guide_high - upsample(guide_low)``). Where the map does not follow
    the photo's brightness, ``a`` is ~0 and this is plain bicubic.

    Args:
        low: (h, w, C) map at network resolution.
        guide_low: (h, w) guide (the photo's encoded brightness) at that resolution.
        guide_high: (H, W) the same guide at the output resolution (square).
        radius: the regression window's radius, in network pixels.
        eps: the regularisation of the slope (in the guide's squared units).
        detail: ``guide_high`` less the guide's bicubic upsampling, if the caller has it already.

    Returns:
        (H, W, C) float32.
    """
    low = np.ascontiguousarray(low, np.float32)
    g = np.ascontiguousarray(guide_low, np.float32)[..., None]
    mean_g = box(g, radius)
    var_g = box(g * g, radius) - mean_g ** 2
    cov = box(np.ascontiguousarray(g * low), radius) - mean_g * box(low, radius)
    a = box(np.ascontiguousarray(cov / (var_g + eps)), radius)
    side = guide_high.shape[0]
    if detail is None:
        detail = guide_detail(guide_low, guide_high)
    out = resize(low, side).reshape(side, side, -1)
    a = resize_to(a, guide_high.shape)
    a *= detail[..., None]
    out += a
    return out


def guide_detail(guide_low, guide_high):
    """What the output-size guide holds beyond the bicubic upsampling of the network-size one."""
    g = np.ascontiguousarray(guide_low, np.float32)[..., None]
    return guide_high - resize(g, guide_high.shape[0])[..., 0]


#: Maps that take the photo's detail in guided upsampling; the others are
#: bicubic (measured: ``python -m export.studies.upsample_eval``, docs/capture.md).
GUIDED_MAPS = ("normal", "diffuse")
#: How maps reach the output size: guided by the photo (:data:`GUIDED_MAPS`), or plain bicubic.
UPSAMPLE_METHODS = ("guided", "bicubic")


def upsample_maps(stored, photo_low, photo_high, method="guided"):
    """Stored-encoding maps at network resolution -> the output resolution.

    ``photo_low`` / ``photo_high``: the encoded network input and the encoded
    crop at the output size. ``method``: "guided" (:func:`guided_upsample`
    for :data:`GUIDED_MAPS`, bicubic for the rest) or "bicubic".
    """
    side = photo_high.shape[0]
    if stored["normal"].shape[0] == side:
        return dict(stored)
    if method not in UPSAMPLE_METHODS:
        raise ValueError(f"unknown upsampling method {method!r}")
    gl, gh = luminance(photo_low), luminance(photo_high)
    detail = guide_detail(gl, gh) if method == "guided" else None  # once for every guided map
    out = {}
    for k, v in stored.items():
        if method == "guided" and k in GUIDED_MAPS:
            out[k] = guided_upsample(v, gl, gh, detail=detail)
        else:
            out[k] = resize(v, side).reshape(side, side, -1)
    n = out["normal"]
    n *= np.float32(2.0)
    n -= np.float32(1.0)
    np.maximum(n[..., 2], np.float32(1e-3), out=n[..., 2])  # stay in the upper hemisphere
    # cv.normalize then cv.encode_normals, in place (the same sums, without numpy's slow reduction
    # over a 3-long axis)
    norm = n[..., 0] * n[..., 0]
    norm += n[..., 1] * n[..., 1]
    norm += n[..., 2] * n[..., 2]
    norm += np.float32(1e-20)
    np.sqrt(norm, out=norm)
    n /= norm[..., None]
    n *= np.float32(0.5)
    n += np.float32(0.5)
    for k, v in out.items():
        np.clip(v, 0.0, 1.0, out=v)
        out[k] = v if v.dtype == np.float32 else v.astype(np.float32)
    return out
