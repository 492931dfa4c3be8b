"""Vectorised noise and pattern primitives for procedural materials (torch).

Everything works on a batch at once and on any device. Images are NCHW; a
pattern is evaluated at coordinates ``x, y`` that broadcast to (B, 1, H, W)
(usually the surface grid of :func:`coords`, scaled, rotated and warped per
sample), and per-sample parameters are (B, 1, 1, 1) tensors, so one call
makes B different patterns.

Randomness: every function that needs random numbers takes a
``torch.Generator`` and draws on the generator's own device (then moves the
numbers to the working device), so a seed gives bit-identical results on a
given device. Nothing here uses the global RNG, numpy or :mod:`random`.

Building blocks:

* :func:`value_noise`: smooth lattice noise, a random periodic lattice sampled
  bicubically (``grid_sample``) at arbitrary coordinates; :func:`fbm`,
  :func:`turbulence`, :func:`ridged` sum octaves of it; :func:`warp` displaces
  coordinates by noise (domain warping).
* :func:`worley`: cellular (Voronoi) noise on a jittered grid, 3 x 3
  neighbourhood (O(9 H W)): F1, F2, the nearest feature's offset and
  per-cell random values.
* :func:`bricks` and :func:`hexagons`: tile layouts (running bond, stacked,
  hexagonal) with local coordinates, distance to the joint and per-cell
  random values.
* colour helpers: :func:`hsv_to_rgb`, :func:`srgb_to_linear` (the one in
  :mod:`svbrdf_cli.conventions`), :func:`palette_pick`.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from svbrdf_cli import conventions as cv

# --------------------------------------------------------------------------
# Random numbers
# --------------------------------------------------------------------------


def rand(g, shape, device, dtype=torch.float32, lo=0.0, hi=1.0):
    """Uniform numbers in [lo, hi) drawn from ``g`` (on ``g.device``), moved to ``device``."""
    r = torch.rand(shape, generator=g, device=g.device, dtype=torch.float32)
    r = r.to(device=device, dtype=dtype)
    return r * (hi - lo) + lo if (lo, hi) != (0.0, 1.0) else r


def randn(g, shape, device, dtype=torch.float32):
    """Standard normal numbers drawn from ``g``, moved to ``device``."""
    return torch.randn(shape, generator=g, device=g.device, dtype=torch.float32).to(device=device, dtype=dtype)


def param(g, batch, lo, hi, device, dtype=torch.float32, log=False):
    """A per-sample parameter, (B, 1, 1, 1), uniform (or log-uniform) in [lo, hi]."""
    r = rand(g, (batch, 1, 1, 1), device, dtype)
    if log:
        return torch.exp(math.log(lo) + r * (math.log(hi) - math.log(lo)))
    return lo + r * (hi - lo)


def chance(g, batch, p, device, dtype=torch.float32):
    """Per-sample 0/1 flag (B, 1, 1, 1) that is 1 with probability ``p``."""
    return (rand(g, (batch, 1, 1, 1), device, dtype) < p).to(dtype)


def param_int(g, batch, lo, hi, device, dtype=torch.float32):
    """Per-sample integer-valued float parameter in [lo, hi] (inclusive), (B, 1, 1, 1)."""
    return torch.floor(param(g, batch, lo, hi + 1 - 1e-4, device, dtype))


# --------------------------------------------------------------------------
# Coordinates and shaping
# --------------------------------------------------------------------------


def coords(size, device, dtype=torch.float32):
    """Surface coordinates of pixel centres, each (1, 1, size, size).

    x runs from -1 (column 0) to +1, y from +1 (row 0) to -1: the world
    axes of :func:`svbrdf_cli.conventions.surface_positions`.
    """
    s = cv.SURFACE_HALF_SIZE
    t = ((torch.arange(size, device=device, dtype=dtype) + 0.5) / size * 2.0 - 1.0) * s
    x = t.reshape(1, 1, 1, size).expand(1, 1, size, size)
    y = (-t).reshape(1, 1, size, 1).expand(1, 1, size, size)
    return x, y


def rotate(x, y, angle):
    """Coordinates rotated by ``angle`` radians (tensor broadcastable to x)."""
    c, s = torch.cos(angle), torch.sin(angle)
    return c * x - s * y, s * x + c * y


def random_rotation(g, batch, x, y, device, dtype=torch.float32, max_angle=math.pi, snap=None):
    """Rotate coordinates by a random per-sample angle in [-max_angle, max_angle].

    ``snap`` (radians) rounds the angle to multiples of it (e.g. pi/2 for
    layouts that should stay axis aligned but may turn by 90 degrees).
    """
    a = param(g, batch, -max_angle, max_angle, device, dtype)
    if snap:
        a = torch.round(a / snap) * snap
    return rotate(x, y, a)


def smoothstep(e0, e1, x):
    """Hermite step: 0 below e0, 1 above e1, smooth between."""
    t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def lerp(a, b, t):
    return a + (b - a) * t


def normalize01(x, eps=1e-8):
    """Per-sample (and per-channel) min-max rescale to [0, 1]."""
    lo = x.amin(dim=(-2, -1), keepdim=True)
    hi = x.amax(dim=(-2, -1), keepdim=True)
    return (x - lo) / (hi - lo + eps)


def standardize(x, eps=1e-8):
    """Per-sample zero mean, unit standard deviation."""
    m = x.mean(dim=(-2, -1), keepdim=True)
    s = x.std(dim=(-2, -1), keepdim=True)
    return (x - m) / (s + eps)


def blur(x, sigma):
    """Separable Gaussian blur with reflect padding; ``sigma`` in pixels (a float)."""
    if sigma <= 0:
        return x
    r = max(1, int(math.ceil(2.5 * sigma)))
    r = min(r, x.shape[-1] - 1, x.shape[-2] - 1)
    t = torch.arange(-r, r + 1, device=x.device, dtype=x.dtype)
    k = torch.exp(-0.5 * (t / sigma) ** 2)
    k = k / k.sum()
    b, c, h, w = x.shape
    y = x.reshape(b * c, 1, h, w)
    y = F.conv2d(F.pad(y, (r, r, 0, 0), mode="reflect"), k.reshape(1, 1, 1, -1))
    y = F.conv2d(F.pad(y, (0, 0, r, r), mode="reflect"), k.reshape(1, 1, -1, 1))
    return y.reshape(b, c, h, w)


def cavity(height, sigma):
    """How far each point lies below its blurred neighbourhood (>= 0): where dirt collects."""
    return (blur(height, sigma) - height).clamp_min(0.0)


# --------------------------------------------------------------------------
# Lattice (value) noise
# --------------------------------------------------------------------------


def _expand_coords(x, y, batch):
    shape = torch.broadcast_shapes(x.shape, y.shape)
    shape = (max(batch, shape[0]),) + tuple(shape[1:])
    return x.expand(shape), y.expand(shape)


def value_noise(g, x, y, batch, channels=1, period=128):
    """Smooth random noise in about [-1, 1] at lattice coordinates ``x, y``.

    A random lattice with period ``period`` (wrapped, so any coordinate is
    valid) is sampled with bicubic interpolation: one lattice cell per unit
    of x and y. Scale, rotate or warp the coordinates to shape the noise.

    Args:
        g: generator.
        x, y: coordinates broadcastable to (B, 1, H, W).
        batch: B.
        channels: independent noise channels.
        period: largest lattice period (the pattern repeats after that many
            units; a smaller one is used when the coordinates span less).

    Returns:
        (B, channels, H, W); standard deviation about 0.45.
    """
    device, dtype = x.device, x.dtype
    x, y = _expand_coords(x, y, batch)
    # A lattice no larger than the coordinates need (small maps stay cheap).
    extent = float(torch.maximum(x.amax() - x.amin(), y.amax() - y.amin()))
    period = int(min(period, max(8, 2 ** math.ceil(math.log2(extent + 4.0)))))
    lat = rand(g, (batch, channels, period, period), device, dtype, -1.0, 1.0)
    lat = F.pad(lat, (2, 2, 2, 2), mode="circular")
    # Random offset per sample so that equal coordinates do not repeat lattices.
    off = rand(g, (batch, 2, 1, 1), device, dtype, 0.0, float(period))
    u = torch.remainder(x[:, 0] + off[:, 0], period) + 2.0
    v = torch.remainder(y[:, 0] + off[:, 1], period) + 2.0
    n = period + 3.0  # align_corners=True: index i <-> -1 + 2 i / (period + 3)
    grid = torch.stack([u / n * 2.0 - 1.0, v / n * 2.0 - 1.0], dim=-1)
    return F.grid_sample(lat, grid, mode="bicubic", padding_mode="border", align_corners=True)


def fbm(g, x, y, batch, octaves=5, lacunarity=2.0, gain=0.5, channels=1, mode="plain", period=128):
    """Fractal sum of :func:`value_noise` octaves, normalised to about unit std.

    Args:
        x, y: base-octave lattice coordinates (B, 1, H, W)-broadcastable.
        octaves: number of octaves (int).
        lacunarity: frequency ratio between octaves.
        gain: amplitude ratio between octaves (float or (B, 1, 1, 1)).
        mode: "plain" (signed, ~N(0, 1)), "turbulence" (sum of |noise|,
            >= 0) or "ridged" (sum of (1 - |noise|)^2, >= 0).

    Returns:
        (B, channels, H, W).
    """
    total, norm, amp, freq = 0.0, 0.0, 1.0, 1.0
    for o in range(octaves):
        # Rotate each octave a little so lattice axes do not line up.
        a = 0.5 + 1.3 * o
        xo, yo = rotate(x * freq, y * freq, torch.tensor(a, device=x.device, dtype=x.dtype))
        n = value_noise(g, xo, yo, batch, channels, period)
        if mode == "turbulence":
            n = n.abs()
        elif mode == "ridged":
            n = (1.0 - n.abs()) ** 2
        total = total + amp * n
        norm = norm + amp * amp
        amp = amp * gain
        freq = freq * lacunarity
    if mode == "plain":
        return total / (0.45 * norm ** 0.5)
    return total / (norm ** 0.5)


def turbulence(g, x, y, batch, octaves=5, **kw):
    """FBm of |noise|: billowy, creased; >= 0."""
    return fbm(g, x, y, batch, octaves, mode="turbulence", **kw)


def ridged(g, x, y, batch, octaves=5, **kw):
    """Ridged multifractal-like sum: sharp crests where the noise crosses 0; >= 0."""
    return fbm(g, x, y, batch, octaves, mode="ridged", **kw)


def warp(g, x, y, batch, strength, freq, octaves=3):
    """Domain warping: coordinates displaced by a 2-channel fBm.

    ``strength`` is in the units of x, y; ``freq`` the warp noise's lattice
    cells per unit of x, y (floats or (B, 1, 1, 1)).
    """
    d = fbm(g, x * freq, y * freq, batch, octaves, channels=2)
    return x + strength * d[:, :1], y + strength * d[:, 1:]


def streaks(g, x, y, batch, along, across, octaves=3, channels=1):
    """Anisotropic noise stretched along x: ``along`` cells per unit in x, ``across`` in y."""
    return fbm(g, x * along, y * across, batch, octaves, channels=channels)


# --------------------------------------------------------------------------
# Per-cell random values
# --------------------------------------------------------------------------


def cell_table(g, batch, channels, period, device, dtype=torch.float32):
    """Random per-cell values, (B, channels, period * period) uniform in [0, 1)."""
    return rand(g, (batch, channels, period * period), device, dtype)


def cell_lookup(table, ix, iy, period):
    """Values of integer cells ``(ix, iy)`` (float tensors, (B, 1, H, W)) from :func:`cell_table`."""
    b, c, _ = table.shape
    ixl = torch.remainder(ix, period).long()
    iyl = torch.remainder(iy, period).long()
    idx = (iyl * period + ixl).expand(b, 1, *ix.shape[-2:])
    out = table.gather(2, idx.reshape(b, 1, -1).expand(b, c, -1))
    return out.reshape(b, c, *ix.shape[-2:])


# --------------------------------------------------------------------------
# Worley / Voronoi
# --------------------------------------------------------------------------


def worley(g, x, y, batch, jitter=0.9, channels=1, period=64, metric="euclid"):
    """Cellular noise on a jittered grid (one feature point per unit cell).

    Args:
        x, y: coordinates in cell units, (B, 1, H, W)-broadcastable.
        jitter: how far feature points move from cell centres (0..1; float
            or (B, 1, 1, 1)).
        channels: number of random values per cell returned in ``value``.
        metric: "euclid" or "manhattan" distances.

    Returns:
        dict with ``f1`` and ``f2`` (distances to the nearest and second
        nearest feature point), ``dx``/``dy`` (offset from the nearest
        feature point to the pixel), ``value`` (B, channels, H, W) random
        values of the nearest cell, ``id`` (B, 1, H, W) its integer index
        (as float), all (B, 1, H, W) unless noted.
    """
    device, dtype = x.device, x.dtype
    x, y = _expand_coords(x, y, batch)
    pts = rand(g, (batch, 2, period * period), device, dtype)
    vals = cell_table(g, batch, channels, period, device, dtype)
    ix, iy = torch.floor(x), torch.floor(y)
    big = torch.full_like(x, 1e9)
    f1, f2 = big, big.clone()
    best_ix, best_iy = ix.clone(), iy.clone()
    bdx, bdy = torch.zeros_like(x), torch.zeros_like(x)
    for oy in (-1.0, 0.0, 1.0):
        for ox in (-1.0, 0.0, 1.0):
            cx, cy = ix + ox, iy + oy
            p = cell_lookup(pts, cx, cy, period)
            px = cx + 0.5 + (p[:, :1] - 0.5) * jitter
            py = cy + 0.5 + (p[:, 1:] - 0.5) * jitter
            ddx, ddy = x - px, y - py
            d = ddx.abs() + ddy.abs() if metric == "manhattan" else torch.sqrt(ddx * ddx + ddy * ddy)
            closer = d < f1
            f2 = torch.where(closer, f1, torch.minimum(f2, d))
            f1 = torch.where(closer, d, f1)
            best_ix = torch.where(closer, cx, best_ix)
            best_iy = torch.where(closer, cy, best_iy)
            bdx = torch.where(closer, ddx, bdx)
            bdy = torch.where(closer, ddy, bdy)
    value = cell_lookup(vals, best_ix, best_iy, period)
    cid = torch.remainder(best_iy, period) * period + torch.remainder(best_ix, period)
    return {"f1": f1, "f2": f2, "dx": bdx, "dy": bdy, "value": value, "id": cid}


# --------------------------------------------------------------------------
# Tile layouts
# --------------------------------------------------------------------------


def bricks(g, x, y, batch, cols, rows, offset=0.5, channels=3, period=64):
    """Brick / tile layout over coordinates ``x, y`` (surface units, about [-1, 1]).

    Args:
        cols, rows: bricks per 2 surface units along x and y (floats or
            (B, 1, 1, 1)).
        offset: shift of every other row in brick widths (0 = stacked grid,
            0.5 = running bond); float or (B, 1, 1, 1).
        channels: random values per brick.

    Returns:
        dict with ``u``, ``v`` (local coordinates in [0, 1) inside the
        brick), ``edge`` (distance to the nearest joint in surface units),
        ``ix``, ``iy`` (integer brick indices as floats), ``value``
        (B, channels, H, W) random per brick, ``w``, ``h`` (brick size in
        surface units).
    """
    w = 2.0 / cols
    h = 2.0 / rows
    fy = (y + 1.0) / h
    iy = torch.floor(fy)
    row_shift = torch.remainder(iy, 2.0) * offset
    fx = (x + 1.0) / w + row_shift
    ix = torch.floor(fx)
    u, v = fx - ix, fy - iy
    edge = torch.minimum(torch.minimum(u, 1.0 - u) * w, torch.minimum(v, 1.0 - v) * h)
    table = cell_table(g, batch, channels, period, x.device, x.dtype)
    ixb, iyb = _expand_coords(ix, iy, batch)
    value = cell_lookup(table, ixb, iyb, period)
    return {"u": u, "v": v, "edge": edge, "ix": ix, "iy": iy, "value": value, "w": w, "h": h}


def hexagons(g, x, y, batch, scale, channels=3, period=64):
    """Hexagonal tiling (pointy-top) with ``scale`` cells per surface unit.

    Returns:
        dict with ``dx``, ``dy`` (offset from the cell centre in cell units,
        circumradius about 0.577), ``edge`` (distance to the cell border in
        cell units, 0.5 at the centre), ``value`` (B, channels, H, W) random
        per cell.
    """
    px, py = x * scale, y * scale
    s3 = math.sqrt(3.0)
    # Two rectangular lattices of hexagon centres; the nearer centre wins.
    ax, ay = 1.0, s3
    c1x = torch.floor(px / ax + 0.5) * ax
    c1y = torch.floor(py / ay + 0.5) * ay
    c2x = torch.floor((px - 0.5) / ax + 0.5) * ax + 0.5
    c2y = torch.floor((py - s3 / 2) / ay + 0.5) * ay + s3 / 2
    d1 = (px - c1x) ** 2 + (py - c1y) ** 2
    d2 = (px - c2x) ** 2 + (py - c2y) ** 2
    first = d1 <= d2
    cx = torch.where(first, c1x, c2x)
    cy = torch.where(first, c1y, c2y)
    dx, dy = px - cx, py - cy
    # Hex distance (pointy top: flat sides left/right): max of the 3 axis projections.
    ax_, ay_ = dx.abs(), dy.abs()
    hexd = torch.maximum(ax_, ax_ * 0.5 + ay_ * (s3 / 2))
    edge = 0.5 - hexd
    ix = torch.round(cx * 2.0)
    iy = torch.round(cy / (s3 / 2))
    table = cell_table(g, batch, channels, period, x.device, x.dtype)
    ixb, iyb = _expand_coords(ix, iy, batch)
    value = cell_lookup(table, ixb, iyb, period)
    return {"dx": dx, "dy": dy, "edge": edge, "value": value}


# --------------------------------------------------------------------------
# Colour
# --------------------------------------------------------------------------


def hsv_to_rgb(h, s, v):
    """HSV (each broadcastable, h in [0, 1) turns) -> RGB stacked on dim 1.

    Inputs are (B, 1, ...) tensors; output (B, 3, ...).
    """
    h = torch.remainder(h, 1.0) * 6.0
    k = torch.cat([torch.remainder(5.0 + h, 6.0), torch.remainder(3.0 + h, 6.0), torch.remainder(1.0 + h, 6.0)], 1)
    return v - v * s * torch.clamp(torch.minimum(k, 4.0 - k), 0.0, 1.0)


def srgb_to_linear(x):
    """sRGB-encoded colour -> linear (:func:`svbrdf_cli.conventions.srgb_to_linear`)."""
    return cv.srgb_to_linear(x)


def random_hsv(g, batch, device, dtype, hue, sat, val):
    """A random sRGB colour per sample, (B, 3, 1, 1), LINEAR.

    ``hue``, ``sat``, ``val`` are (lo, hi) ranges in sRGB HSV; hue in turns
    may exceed [0, 1] (it wraps), e.g. (-0.05, 0.1) for reds to oranges.
    """
    h = param(g, batch, hue[0], hue[1], device, dtype)
    s = param(g, batch, sat[0], sat[1], device, dtype)
    v = param(g, batch, val[0], val[1], device, dtype)
    return srgb_to_linear(hsv_to_rgb(h, s, v))


def palette_pick(g, batch, palette, device, dtype=torch.float32, jitter=0.0):
    """One colour per sample from a list of sRGB colours, LINEAR, (B, C, 1, 1).

    Entries may hold several colours concatenated (6 numbers for a pair that
    belongs together); C is the entry length.

    ``jitter`` multiplies each channel by a random factor in [1 - j, 1 + j]
    (in sRGB) so picks from a small palette still vary.
    """
    pal = torch.tensor(palette, device=device, dtype=dtype)
    idx = torch.floor(rand(g, (batch,), device, dtype) * len(palette)).long().clamp_max(len(palette) - 1)
    c = pal[idx].reshape(batch, -1, 1, 1)
    if jitter:
        c = c * rand(g, tuple(c.shape), device, dtype, 1.0 - jitter, 1.0 + jitter)
    return srgb_to_linear(c.clamp(0.0, 1.0))


def luminance(rgb):
    """Rec. 709 luminance of linear RGB on dim 1, keepdim."""
    r, g, b = cv.LUMA
    return r * rgb[:, :1] + g * rgb[:, 1:2] + b * rgb[:, 2:3]
