"""Test-time augmentation: the chain run on rotated and mirrored copies of a photo.

A flat surface under a centred flash looks the same, physically, after a
quarter turn or a mirror: the maps of the transformed photo, transformed
back, should be the maps of the photo. Where the passes disagree the network
is guessing, which is what :func:`confidence` turns into per-pixel maps,
one per texture (``svbrdf capture --confidence``); the stability suite
(``export/studies/stability.py``, run by ``python -m export.studies.benchmark``) uses the same transforms.

Geometry follows :mod:`svbrdf_cli.conventions`: +X right, +Y up (towards row
0). Turning the image a quarter turn counter-clockwise (as displayed) turns
the normal vectors' (x, y) by +90 degrees; mirroring left-right negates x.
Images are (H, W, C) arrays; maps are in their stored encoding.
"""

from __future__ import annotations

import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli.imageops import resize_to

#: The 8 symmetries of the square as (quarter turns counter-clockwise, mirrored first).
DIHEDRAL = tuple((k, m) for m in (False, True) for k in range(4))
#: Passes used for the confidence map: identity, the three turns, and a mirror.
CONFIDENCE_PASSES = DIHEDRAL[:5]
#: Disagreement (RMS over passes and a map's channels, stored encoding) at which confidence is 0.5.
#: One absolute scale for every map (on Des19 the albedo and roughness maps' median spread is
#: 0.015-0.02, the mostly flat normal maps' 0.001), so a scene the network is sure of reads high.
CONFIDENCE_HALF = 0.02


def transform_image(x, k, mirror):
    """Apply (``k`` quarter turns counter-clockwise, after a left-right ``mirror``) to an image."""
    x = x[:, ::-1] if mirror else x
    return np.ascontiguousarray(np.rot90(x, k, axes=(0, 1)))


def untransform_image(x, k, mirror):
    """Inverse of :func:`transform_image`."""
    x = np.rot90(x, -k, axes=(0, 1))
    return np.ascontiguousarray(x[:, ::-1] if mirror else x)


def _turn_vectors(n, k, mirror, inverse=False):
    """Transform (x, y) of (..., 3) unit normals like the pixels they sit on."""
    n = np.array(n, dtype=np.float32, copy=True)
    a = (-k if inverse else k) * np.pi / 2
    c, s = np.float32(round(np.cos(a))), np.float32(round(np.sin(a)))
    if mirror and not inverse:
        n[..., 0] *= -1
    x, y = n[..., 0].copy(), n[..., 1].copy()
    n[..., 0], n[..., 1] = c * x - s * y, s * x + c * y
    if mirror and inverse:
        n[..., 0] *= -1
    return n


def transform_point(p, k, mirror):
    """A point (x, y, z) in surface units (the crop spans [-1, 1]^2) where it lands when its photo is
    transformed by :func:`transform_image` (the square turns and mirrors about its centre)."""
    return _turn_vectors(np.asarray(p, np.float32), k, mirror).astype(np.float64)


def transform_maps(stored, k, mirror):
    """Transform a stored map set (pixels and normal vectors) as its photo was transformed."""
    out = {name: transform_image(v, k, mirror) for name, v in stored.items()}
    out["normal"] = cv.encode_normals(_turn_vectors(cv.decode_normals(out["normal"]), k, mirror))
    return out


def untransform_maps(stored, k, mirror):
    """Inverse of :func:`transform_maps`."""
    out = {name: untransform_image(v, k, mirror) for name, v in stored.items()}
    out["normal"] = cv.encode_normals(_turn_vectors(cv.decode_normals(out["normal"]), k, mirror, inverse=True))
    return out


def passes(chain, image, transforms=CONFIDENCE_PASSES):
    """Stored maps of ``image`` for each transform, brought back to the photo's frame."""
    out = []
    for k, mirror in transforms:
        res = chain(transform_image(image, k, mirror))
        out.append(untransform_maps({n: res[n] for n in cv.MAP_NAMES}, k, mirror))
    return out


def disagreement(results):
    """{map: (H, W) RMS deviation of the passes from their mean} (over the map's channels, stored encoding)."""
    out = {}
    for name in cv.MAP_NAMES:
        stack = np.stack([r[name] for r in results])
        out[name] = np.sqrt(((stack - stack.mean(0)) ** 2).mean(axis=(0, 3))).astype(np.float32)
    return out


def confidence(results, half=CONFIDENCE_HALF):
    """{map: (H, W) confidence in (0, 1]}: 1 where the passes agree, 0.5 at a disagreement of ``half``."""
    return {name: (1.0 / (1.0 + (d / half) ** 2)).astype(np.float32) for name, d in disagreement(results).items()}


def confidence_maps(chain, net_in, stored, side):
    """{map: (side, side) confidence} from :data:`CONFIDENCE_PASSES` (``stored``: the plain pass)."""
    conf = confidence([stored] + passes(chain, net_in, CONFIDENCE_PASSES[1:]))
    return {k: v if v.shape[0] == side else np.clip(resize_to(v[..., None], (side, side))[..., 0], 0, 1)
            for k, v in conf.items()}
