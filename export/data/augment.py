"""Geometric and colour augmentation of linear map sets, and material mixing.

Maps are dicts of NCHW tensors (``normal`` unit vectors +Y up, ``diffuse``,
``roughness``, ``specular`` linear; an optional ``height``). Moving pixels
moves the surface, so every geometric operation also transforms the normal
*vectors*: rotating the image by an angle rotates (n_x, n_y) by the same angle
in world space (+X right, +Y up, i.e. towards row 0), flipping left-right
negates n_x, flipping top-bottom negates n_y. Resampling averages normals,
which shortens them: they are renormalised after every operation.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from svbrdf_cli import conventions as cv

#: Upper bound on a diffuse albedo after brightness jitter (fresh snow ~0.9).
MAX_ALBEDO = 0.9


def _map_items(maps):
    return [(k, v) for k, v in maps.items() if torch.is_tensor(v) and v.dim() == 4]


def _renormalized(maps):
    maps["normal"] = cv.normalize(maps["normal"], axis=1)
    return maps


def rotate_vectors(normal, angle):
    """Rotate the (x, y) components of (B, 3, H, W) normals by ``angle`` radians (float or (B,)), counter-clockwise."""
    a = torch.as_tensor(angle, dtype=normal.dtype, device=normal.device).reshape(-1, 1, 1)
    c, s = a.cos(), a.sin()
    x, y = normal[:, 0], normal[:, 1]
    return torch.stack([c * x - s * y, s * x + c * y, normal[:, 2]], 1)


def rot90(maps, k=1):
    """Rotate every map ``k`` quarter turns counter-clockwise (as displayed), normals included."""
    out = {key: torch.rot90(v, k, dims=(2, 3)) for key, v in _map_items(maps)}
    out["normal"] = rotate_vectors(out["normal"], k * math.pi / 2)
    return _renormalized({**maps, **out})


def flip(maps, horizontal=True):
    """Mirror left-right (``horizontal``) or top-bottom; the matching normal component changes sign."""
    dim, comp = (3, 0) if horizontal else (2, 1)
    out = {key: v.flip(dim) for key, v in _map_items(maps)}
    sign = torch.ones(3, dtype=out["normal"].dtype, device=out["normal"].device)
    sign[comp] = -1
    out["normal"] = out["normal"] * sign.reshape(1, 3, 1, 1)
    return {**maps, **out}


def affine_crop(maps, angle, scale, centre, size):
    """Resample a rotated, scaled square window of every map.

    Args:
        maps: map dict (B, C, H, W).
        angle: (B,) radians; the material turns counter-clockwise by it.
        scale: (B,) window width as a fraction of the map width (< 1 zooms in).
        centre: (B, 2) window centre in normalised coordinates [-1, 1] (x right, y down).
        size: output size in pixels.

    Windows reaching past the map are reflected back into it.
    """
    ref = maps["normal"]
    b = ref.shape[0]
    a = torch.as_tensor(angle, dtype=ref.dtype, device=ref.device).reshape(b)
    s = torch.as_tensor(scale, dtype=ref.dtype, device=ref.device).reshape(b)
    c, sn = a.cos() * s, a.sin() * s
    # Output (u, v) in grid coordinates (v down) samples input R(-angle) (u, v) * s + centre;
    # with v pointing down a counter-clockwise turn on screen is a clockwise one in (u, v).
    theta = torch.stack([torch.stack([c, -sn, centre[:, 0].to(ref)], 1),
                         torch.stack([sn, c, centre[:, 1].to(ref)], 1)], 1)
    grid = F.affine_grid(theta, (b, 1, size, size), align_corners=False)
    out = {key: F.grid_sample(v, grid, mode="bilinear", padding_mode="reflection", align_corners=False)
           for key, v in _map_items(maps)}
    out["normal"] = rotate_vectors(out["normal"], a)
    return _renormalized({**maps, **out})


def random_geometry(maps, g, size, scale=(0.5, 1.0), free_rotation=0.5):
    """Random crop/zoom, rotation (any angle with probability ``free_rotation``,
    else quarter turns) and flip; one draw per sample."""
    ref = maps["normal"]
    b = ref.shape[0]
    dev = g.device
    s = scale[0] + torch.rand(b, generator=g, device=dev) * (scale[1] - scale[0])
    quarter = torch.randint(0, 4, (b,), generator=g, device=dev).float() * (math.pi / 2)
    free = torch.rand(b, generator=g, device=dev) * 2 * math.pi
    use_free = torch.rand(b, generator=g, device=dev) < free_rotation
    angle = torch.where(use_free, free, quarter)
    # A rotated window of width s fits inside the map if its half-diagonal does.
    reach = (1 - s * (angle.sin().abs() + angle.cos().abs())).clamp_min(0)
    centre = (torch.rand(b, 2, generator=g, device=dev) * 2 - 1) * reach[:, None]
    out = affine_crop(maps, angle.to(ref.device), s.to(ref.device), centre.to(ref.device), size)
    mirror = (torch.rand(b, generator=g, device=dev) < 0.5).to(ref.device)
    flipped = flip(out, horizontal=True)
    return {k: (torch.where(mirror.reshape(-1, 1, 1, 1), flipped[k], v) if torch.is_tensor(v) and v.dim() == 4 else v)
            for k, v in out.items()}


def rgb_to_hsv(rgb):
    """(B, 3, H, W) in [0, 1] -> hue in [0, 1), saturation, value."""
    mx, arg = rgb.max(1, keepdim=True)
    mn = rgb.min(1, keepdim=True)[0]
    delta = mx - mn
    r, g_, b = rgb[:, :1], rgb[:, 1:2], rgb[:, 2:3]
    safe = delta.clamp_min(1e-12)
    h = torch.where(arg == 0, ((g_ - b) / safe) % 6, torch.where(arg == 1, (b - r) / safe + 2, (r - g_) / safe + 4))
    h = torch.where(delta > 0, h / 6, torch.zeros_like(h))
    s = torch.where(mx > 0, delta / mx.clamp_min(1e-12), torch.zeros_like(mx))
    return h % 1.0, s, mx


def hsv_to_rgb(h, s, v):
    """Inverse of :func:`rgb_to_hsv`."""
    k = torch.tensor([5.0, 3.0, 1.0], dtype=h.dtype, device=h.device).reshape(1, 3, 1, 1)
    t = (k + h * 6) % 6
    return v - v * s * torch.clamp(torch.minimum(t, 4 - t), 0, 1)


def jitter_colour(maps, g, hue=0.05, saturation=(0.8, 1.5), brightness=0.3):
    """Hue shift (fraction of a turn), saturation (factor range) and brightness scaling of the
    diffuse albedo, and of the specular albedo where it is coloured (metals),
    kept within physical bounds: diffuse <= :data:`MAX_ALBEDO`, specular in
    [0, 1], dielectric (grey) specular untouched."""
    d = maps["diffuse"]
    b = d.shape[0]
    dev = g.device

    def draw(lo, hi):
        return (lo + torch.rand(b, generator=g, device=dev) * (hi - lo)).to(d).reshape(-1, 1, 1, 1)

    dh = draw(-hue, hue)
    ds = draw(*saturation)
    dv = draw(1 - brightness, 1 + brightness)

    def jitter(x, v_max):
        h, s, v = rgb_to_hsv(x)
        return hsv_to_rgb((h + dh) % 1.0, (s * ds).clamp(0, 1), (v * dv).clamp(0, v_max))

    out = dict(maps)
    out["diffuse"] = jitter(d, MAX_ALBEDO)
    spec = maps["specular"]
    metal = (spec.amax(1, keepdim=True) - spec.amin(1, keepdim=True)) > 0.02
    out["specular"] = torch.where(metal, jitter(spec, 1.0), spec)
    return out


def blend(a, b, mask):
    """Mix two map sets with a (B, 1, H, W) mask in [0, 1] (1: all ``b``).

    Normals are blended as vectors and renormalised; every other map linearly.
    """
    out = {}
    for key, va in _map_items(a):
        if key in b:
            out[key] = torch.lerp(va, b[key], mask)
    out["normal"] = cv.normalize(out["normal"], axis=1)
    return out
