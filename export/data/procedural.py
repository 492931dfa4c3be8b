"""Procedural SVBRDF materials in torch: random, batched, on any device.

Each *family* (see :data:`FAMILIES`) draws B random materials of one kind
(tiles, wood, brushed metal, ...) from a ``torch.Generator``; :func:`generate`
finishes a family's output (normals from height, clamping, checks) and
:func:`random_materials` mixes families in one batch. All maps are linear
and NCHW in the conventions of :mod:`svbrdf_cli.conventions`:

* ``height`` (B, 1, H, W) in [0, 1], scaled by ``depth`` surface units,
* ``normal`` (B, 3, H, W) unit, +Y up (from the height, plus fine detail),
* ``diffuse`` (B, 3, H, W) linear albedo, ``specular`` (B, 3, H, W) linear
  F0, ``roughness`` (B, 1, H, W) (alpha = r^2),
* ``depth`` (B,) the relief depth used for the normals.

The maps are correlated the way real materials are: joints and crevices
are lower, darker and rougher (dirt collects there), worn metal edges are
smoother and brighter, scratches change roughness and dent the surface.
Dielectrics get grey F0 of 0.02-0.08 (around
:data:`svbrdf_cli.conventions.DIELECTRIC_F0`); metals get a near-black
diffuse and a coloured F0 of 0.5-0.98.

A family function is ``fn(g, batch, size, device, dtype) -> dict`` with
``height``, ``diffuse``, ``roughness``, ``specular`` and optionally
``depth`` (B,) and ``normal_detail`` (B, 2, H, W): extra surface slopes
(d height / d x, d height / d y in surface units) added to those of the
height map, for detail too fine to be worth a height.
"""

from __future__ import annotations

import math
from typing import Callable

import torch

from export.data import noise as noise_fields
from export.data.cc0 import DEFAULT_DEPTH
from svbrdf_cli import conventions as cv

PI = math.pi

#: Linear F0 of common metals (sRGB-free, measured reflectance; rough values).
METAL_F0 = {
    "gold": (0.98, 0.78, 0.34),
    "copper": (0.95, 0.64, 0.54),
    "brass": (0.91, 0.78, 0.42),
    "bronze": (0.80, 0.58, 0.40),
    "iron": (0.56, 0.57, 0.58),
    "steel": (0.62, 0.63, 0.64),
    "aluminium": (0.91, 0.92, 0.92),
    "silver": (0.95, 0.93, 0.88),
    "chrome": (0.55, 0.56, 0.55),
    "nickel": (0.66, 0.61, 0.53),
    "titanium": (0.54, 0.50, 0.45),
    "zinc": (0.66, 0.67, 0.70),
}
_GREY_METALS = ("iron", "steel", "aluminium", "chrome", "zinc", "nickel", "titanium", "silver")


# --------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------


class _Ctx:
    """Generator, batch, grid and shortcuts shared by a family's code."""

    def __init__(self, g, batch, size, device, dtype):
        self.g, self.b, self.size, self.dev, self.dt = g, batch, size, device, dtype
        self.x, self.y = noise_fields.coords(size, device, dtype)

    def p(self, lo, hi, log=False):
        return noise_fields.param(self.g, self.b, lo, hi, self.dev, self.dt, log=log)

    def flag(self, prob):
        return noise_fields.chance(self.g, self.b, prob, self.dev, self.dt)

    def rot(self, max_angle=PI, snap=None, jitter=0.0, x=None, y=None):
        x = self.x if x is None else x
        y = self.y if y is None else y
        a = self.p(-max_angle, max_angle)
        if snap:
            a = torch.round(a / snap) * snap
        if jitter:
            a = a + self.p(-jitter, jitter)
        return noise_fields.rotate(x, y, a)

    def noise(self, x, y, channels=1):
        return noise_fields.value_noise(self.g, x, y, self.b, channels)

    def fbm(self, x, y, octaves=5, **kw):
        return noise_fields.fbm(self.g, x, y, self.b, octaves, **kw)

    def worley(self, x, y, **kw):
        return noise_fields.worley(self.g, x, y, self.b, **kw)

    def hsv(self, hue, sat, val):
        return noise_fields.random_hsv(self.g, self.b, self.dev, self.dt, hue, sat, val)

    def pick(self, palette, jitter=0.0):
        return noise_fields.palette_pick(self.g, self.b, palette, self.dev, self.dt, jitter)

    def spec(self, lo=0.03, hi=0.06):
        """Grey dielectric F0, (B, 3, 1, 1)."""
        return self.p(lo, hi).expand(self.b, 3, 1, 1)

    def metal(self, names=None, jitter=0.04):
        """A random metal F0 per sample, (B, 3, 1, 1) linear, within [0.5, 0.98]."""
        names = list(names or METAL_F0)
        pal = torch.tensor([METAL_F0[n] for n in names], device=self.dev, dtype=self.dt)
        idx = torch.floor(noise_fields.rand(self.g, (self.b,), self.dev, self.dt) * len(names)).long().clamp_max(len(names) - 1)
        c = pal[idx].reshape(self.b, 3, 1, 1)
        c = c * noise_fields.rand(self.g, (self.b, 1, 1, 1), self.dev, self.dt, 1.0 - jitter, 1.0 + jitter)
        return c.clamp(0.5, 0.98)

    def px(self, frac):
        """A length given as a fraction of the map width, in pixels (for blurs)."""
        return max(0.5, frac * self.size)


def _out(height, diffuse, roughness, specular, depth, detail=None):
    out = {"height": height, "diffuse": diffuse, "roughness": roughness, "specular": specular,
           "depth": depth.reshape(-1)}
    if detail is not None:
        out["normal_detail"] = detail
    return out


def _grime(c, height, diffuse, roughness, amount, sigma=0.02, colour=None, specular=None):
    """Dirt in crevices: where the height is below its neighbourhood, darker and rougher.

    ``amount`` (B, 1, 1, 1) in [0, 1]; ``sigma`` the neighbourhood size as a
    fraction of the map. Returns (diffuse, roughness) (and specular when given,
    pulled towards a dusty dielectric).
    """
    cav = noise_fields.cavity(height, c.px(sigma))
    cav = cav / (cav.amax(dim=(2, 3), keepdim=True) + 1e-6)
    blot = noise_fields.normalize01(c.fbm(c.x * c.p(2, 6), c.y * c.p(2, 6), 4))
    m = ((cav * 2.0).clamp(0, 1) * (0.4 + 0.8 * blot) + 0.25 * (blot - 0.6).clamp_min(0)).clamp(0, 1) * amount
    if colour is None:
        colour = c.hsv((0.05, 0.11), (0.25, 0.5), (0.12, 0.35))
    diffuse = noise_fields.lerp(diffuse, colour, m)
    roughness = noise_fields.lerp(roughness, torch.full_like(roughness, 0.95), m)
    if specular is not None:
        specular = noise_fields.lerp(specular, torch.full_like(specular, cv.DIELECTRIC_F0), m)
        return diffuse, roughness, specular
    return diffuse, roughness


def _scratches(c, layers=3, density=(4.0, 20.0), width=(0.7, 2.0), coverage=(0.2, 0.6), random_dir=True):
    """Scratch mask in [0, 1], (B, 1, H, W): thin wavy lines in a few directions.

    ``density``: lines per surface unit across each layer's direction;
    ``width``: line width range in pixels; ``coverage``: fraction of each line drawn.
    """
    total = 0.0
    main = c.p(-PI, PI)
    for k in range(layers):
        a = c.p(-PI, PI) if random_dir else main + c.p(-0.15, 0.15)
        x, y = noise_fields.rotate(c.x, c.y, a)
        dens = c.p(density[0], density[1], log=True)
        along = c.p(0.2, 0.8)
        n = c.noise(x * along, y * dens)
        # |noise| grows about 1.2 * dens per surface unit away from a zero crossing.
        w = c.p(width[0], width[1]) * 1.2 * dens * (2.0 / c.size)
        line = 1.0 - noise_fields.smoothstep(0.0, w, n.abs())
        seg = noise_fields.smoothstep(0.0, 0.15, c.noise(x * c.p(1.0, 4.0), y * dens) + c.p(coverage[0], coverage[1]) - 0.6)
        total = torch.maximum(torch.as_tensor(total, device=c.dev, dtype=c.dt), line * seg * c.p(0.4, 1.0))
    return total


# --------------------------------------------------------------------------
# Families
# --------------------------------------------------------------------------


def tiles(g, batch, size, device, dtype=torch.float32):
    """Ceramic / stone tiles in a grid (stacked or offset) with grout."""
    c = _Ctx(g, batch, size, device, dtype)
    x, y = c.rot(PI, snap=PI / 2, jitter=0.05)
    x, y = noise_fields.warp(g, x, y, batch, c.p(0.0, 0.004), 3.0)
    cols = torch.round(c.p(2, 10))
    aspect = torch.where(c.flag(0.35) > 0, torch.round(c.p(2, 4)), torch.ones_like(cols))
    rows = cols * torch.where(c.flag(0.5) > 0, 1.0 / aspect, aspect)
    rows = rows.clamp(1, 24)
    offset = torch.where(c.flag(0.3) > 0, c.p(0.0, 0.5), torch.zeros_like(cols))
    bk = noise_fields.bricks(g, x, y, batch, cols, rows, offset, channels=3)
    grout_w = c.p(0.006, 0.03)
    bevel = c.p(0.005, 0.04)
    edge = bk["edge"] + 0.003 * c.fbm(x * 30, y * 30, 3)
    inside = noise_fields.smoothstep(grout_w, grout_w + 0.002, edge)
    bev = noise_fields.smoothstep(grout_w, grout_w + bevel, edge).sqrt()
    wav = c.fbm(x * c.p(1, 4), y * c.p(1, 4), 3)
    tile_h = 0.55 + 0.35 * bev + 0.03 * wav + 0.06 * (bk["value"][:, :1] - 0.5) * c.p(0, 1)
    grout_h = 0.15 + 0.05 * c.fbm(x * 60, y * 60, 3)
    height = noise_fields.lerp(grout_h, tile_h, inside)
    # colours
    base = c.hsv((0.0, 1.0), (0.0, 0.7), (0.3, 0.95))
    alt = c.hsv((0.0, 1.0), (0.0, 0.7), (0.2, 0.95))
    two = (c.flag(0.3) * (bk["value"][:, 1:2] > 0.5).to(dtype))
    colour = noise_fields.lerp(base, alt, two)
    var = (bk["value"] - 0.5) * c.p(0.0, 0.4)
    mottle = c.fbm(x * c.p(3, 20), y * c.p(3, 20), 4, channels=1) * c.p(0.0, 0.15)
    tile_col = colour * torch.exp(var + mottle)
    grout_col = c.hsv((0.05, 0.12), (0.0, 0.25), (0.2, 0.8)) * torch.exp(0.15 * c.fbm(x * 50, y * 50, 2))
    diffuse = noise_fields.lerp(grout_col, tile_col, inside)
    glazed = c.flag(0.6)
    tile_r = torch.where(glazed > 0, c.p(0.05, 0.3), c.p(0.4, 0.8)) * torch.exp(0.15 * c.fbm(x * 8, y * 8, 3))
    roughness = noise_fields.lerp(c.p(0.75, 1.0).expand_as(height), tile_r.expand_as(height), inside)
    specular = noise_fields.lerp(c.spec(0.03, 0.05), torch.where(glazed > 0, c.spec(0.04, 0.07), c.spec(0.03, 0.05)), inside)
    diffuse, roughness, specular = _grime(c, height, diffuse, roughness, c.p(0, 0.8), 0.01, specular=specular)
    return _out(height, diffuse, roughness, specular, c.p(0.02, 0.08))


def bricks(g, batch, size, device, dtype=torch.float32):
    """Brick walls in running bond (or stack / flemish-like offsets) with mortar."""
    c = _Ctx(g, batch, size, device, dtype)
    x, y = c.rot(PI, snap=PI / 2, jitter=0.03)
    rows = c.p(4, 16)
    cols = rows / c.p(2.0, 3.5)
    offset = torch.where(c.flag(0.8) > 0, torch.full_like(rows, 0.5), c.p(0.2, 0.35))
    bk = noise_fields.bricks(g, x, y, batch, cols, rows, offset, channels=4)
    mort = c.p(0.008, 0.03)
    rough_edge = c.fbm(x * 25, y * 25, 4) * c.p(0.002, 0.008)
    edge = bk["edge"] + rough_edge
    inside = noise_fields.smoothstep(mort, mort + 0.004, edge)
    round_ = noise_fields.smoothstep(mort, mort + c.p(0.01, 0.03), edge)
    surf = c.fbm(x * 40, y * 40, 4)
    chips = noise_fields.smoothstep(0.4, 0.9, c.fbm(x * 12, y * 12, 4)) * c.p(0.0, 0.5)
    brick_h = 0.55 + 0.3 * round_ + 0.04 * surf + 0.08 * (bk["value"][:, 3:4] - 0.5) - 0.25 * chips
    mortar_h = 0.2 + 0.06 * c.fbm(x * 80, y * 80, 3)
    height = noise_fields.lerp(mortar_h, brick_h, inside)
    base = c.hsv((-0.02, 0.09), (0.3, 0.8), (0.25, 0.75))
    yellow = c.hsv((0.08, 0.13), (0.2, 0.5), (0.45, 0.85))
    base = torch.where(c.flag(0.25) > 0, yellow, base)
    var = torch.cat([(bk["value"][:, :1] - 0.5) * c.p(0.2, 0.9)] * 3, 1) + (bk["value"][:, :3] - 0.5) * 0.15
    speck = c.fbm(x * 60, y * 60, 3) * 0.12 + c.fbm(x * 6, y * 6, 3) * 0.1
    brick_col = base * torch.exp(var + speck)
    mortar_col = c.hsv((0.06, 0.13), (0.0, 0.2), (0.35, 0.8)) * torch.exp(0.15 * c.fbm(x * 90, y * 90, 2))
    diffuse = noise_fields.lerp(mortar_col, brick_col, inside)
    roughness = noise_fields.lerp(torch.full_like(height, 0.95), (c.p(0.7, 0.95) + 0.05 * surf), inside)
    diffuse, roughness = _grime(c, height, diffuse, roughness, c.p(0, 0.7), 0.015)
    return _out(height, diffuse, roughness, c.spec(0.03, 0.045), c.p(0.04, 0.12))


def cobblestones(g, batch, size, device, dtype=torch.float32):
    """Voronoi cobbles / flagstones with sand or dirt joints."""
    c = _Ctx(g, batch, size, device, dtype)
    scale = c.p(1.5, 7, log=True)
    x, y = c.rot(PI)
    xs, ys = x * scale, y * scale
    xs, ys = noise_fields.warp(g, xs, ys, batch, c.p(0.02, 0.12), 1.5)
    w = c.worley(xs, ys, jitter=c.p(0.6, 1.0), channels=4)
    edge = (w["f2"] - w["f1"]) * 0.5 + 0.03 * c.fbm(xs * 6, ys * 6, 3)
    gap = c.p(0.02, 0.12)
    flat = c.flag(0.3)  # flagstones: flat tops
    inside = noise_fields.smoothstep(gap, gap + 0.06, edge)
    dome_w = torch.where(flat > 0, c.p(0.05, 0.1), c.p(0.2, 0.5))
    dome = noise_fields.smoothstep(gap, gap + dome_w, edge).sqrt()
    surf = c.fbm(xs * 4, ys * 4, 4)
    stone_h = 0.35 + 0.5 * dome + 0.04 * surf + 0.1 * (w["value"][:, :1] - 0.5)
    joint_h = 0.05 + 0.08 * noise_fields.normalize01(c.fbm(x * 80, y * 80, 3))
    height = noise_fields.lerp(joint_h, stone_h, inside)
    base = c.hsv((0.03, 0.14), (0.0, 0.2), (0.25, 0.7))
    var = (w["value"][:, 1:4] - 0.5) * c.p(0.05, 0.3) + (w["value"][:, :1] - 0.5) * c.p(0.2, 0.8)
    stone_col = base * torch.exp(var + 0.15 * c.fbm(xs * 8, ys * 8, 4))
    joint_col = c.hsv((0.05, 0.15), (0.2, 0.5), (0.1, 0.45)) * torch.exp(0.3 * c.fbm(x * 100, y * 100, 2))
    diffuse = noise_fields.lerp(joint_col, stone_col, inside)
    wet = c.flag(0.15)
    stone_r = torch.where(wet > 0, c.p(0.15, 0.35), c.p(0.5, 0.85)) + 0.08 * surf - 0.15 * dome * c.p(0, 1)
    roughness = noise_fields.lerp(torch.full_like(height, 0.95), stone_r, inside)
    diffuse, roughness = _grime(c, height, diffuse, roughness, c.p(0.2, 0.9), 0.02)
    return _out(height, diffuse, roughness, c.spec(0.03, 0.05), c.p(0.05, 0.15))


def wood(g, batch, size, device, dtype=torch.float32):
    """Wood: growth rings, fibre streaks and pores; single boards or planks."""
    c = _Ctx(g, batch, size, device, dtype)
    x, y = c.rot(PI, snap=PI / 2, jitter=0.04)
    planks = c.flag(0.7)
    rows = torch.where(planks > 0, c.p(2, 9), torch.full_like(planks, 0.5))
    cols = torch.where(planks > 0, c.p(0.4, 2.0), torch.full_like(planks, 0.2))
    bk = noise_fields.bricks(g, x, y, batch, cols, rows, c.p(0.2, 0.8), channels=5)
    pv = bk["value"] * planks + 0.5 * (1 - planks)
    # Rings: distance from the log's axis, which runs along x, tilted a little
    # out of the board so the rings cut the surface in arches ("cathedrals").
    ring_f = c.p(6, 30, log=True)
    xw = x + (pv[:, 2:3] - 0.5) * 7
    yy = (y + (pv[:, :1] - 0.5) * 6.0) * ring_f
    tilt = c.p(0.0, 0.25) * torch.where(pv[:, 1:2] > 0.5, 1.0, -1.0)
    zz = (c.p(0.3, 3.0) + pv[:, 1:2] * 3.0 + tilt * xw) * ring_f
    wob = c.fbm(xw * c.p(0.5, 2), y * 3, 4) * c.p(0.1, 0.5) + c.fbm(xw * 8, y * 30, 3) * 0.05
    r = torch.sqrt(yy * yy + zz * zz) + wob
    t = torch.remainder(r, 1.0)
    late = t ** c.p(2.0, 6.0)
    late = late * (1 - noise_fields.smoothstep(0.92, 1.0, t))
    fib = c.fbm(xw * c.p(1, 4), y * c.p(120, 300), 3)
    pores = noise_fields.smoothstep(0.5, 1.4, c.fbm(xw * c.p(10, 30), y * c.p(150, 350), 2)) * c.p(0, 1)
    light = c.hsv((0.055, 0.11), (0.35, 0.7), (0.45, 0.9))
    dark_f = c.p(0.35, 0.75)
    warm = torch.tensor([1.0, 0.0, -1.0], device=device, dtype=dtype).reshape(1, 3, 1, 1)
    tint = torch.exp((pv[:, 3:4] - 0.5) * c.p(0.0, 0.6) + (pv[:, 4:5] - 0.5) * 0.1 * warm)
    diffuse = light * tint * torch.exp(torch.log(dark_f) * late + 0.12 * fib - 0.4 * pores)
    # Seams between planks.
    seam_w = c.p(0.002, 0.008)
    seam = 1.0 - noise_fields.smoothstep(seam_w, seam_w + 0.004, bk["edge"]) * planks - (1 - planks)
    height = 0.6 - 0.1 * late + 0.03 * fib - 0.12 * pores + 0.05 * (pv[:, 4:5] - 0.5)
    height = height - 0.45 * seam
    varnish = c.flag(0.55)
    base_r = torch.where(varnish > 0, c.p(0.12, 0.35), c.p(0.5, 0.8))
    roughness = base_r + 0.05 * fib + 0.1 * late * (1 - varnish) + 0.3 * pores
    roughness = noise_fields.lerp(roughness, torch.full_like(roughness, 0.9), seam)
    diffuse = noise_fields.lerp(diffuse, diffuse * 0.3, seam)
    spec = torch.where(varnish > 0, c.spec(0.04, 0.06), c.spec(0.025, 0.04))
    diffuse, roughness = _grime(c, height, diffuse, roughness, c.p(0.0, 0.4), 0.01)
    return _out(height, diffuse, roughness, spec, c.p(0.005, 0.03))


def brushed_metal(g, batch, size, device, dtype=torch.float32):
    """Brushed (anisotropic streak) metal in a random metal colour."""
    c = _Ctx(g, batch, size, device, dtype)
    x, y = c.rot(PI)
    circ = c.flag(0.2)
    # Circular brushing around a random centre (spun discs): streaks follow circles.
    cx, cy = c.p(-1.5, 1.5), c.p(-1.5, 1.5)
    rr = torch.sqrt((x - cx) ** 2 + (y - cy) ** 2)
    ang = torch.atan2(y - cy, x - cx) * rr
    sx = torch.where(circ > 0, ang, x)
    sy = torch.where(circ > 0, rr, y)
    across = c.p(100, 400, log=True)
    s1 = c.fbm(sx * c.p(0.3, 2.0), sy * across, 3)
    s2 = c.fbm(sx * c.p(3, 10), sy * across * 2, 2)
    streak = 0.7 * s1 + 0.3 * s2
    f0 = c.metal()
    specular = (f0 * torch.exp(0.07 * streak)).clamp(0.5, 0.98)
    smudge = c.fbm(x * c.p(1, 4), y * c.p(1, 4), 4)
    roughness = c.p(0.15, 0.45) + 0.08 * streak + 0.03 * smudge
    height = 0.5 + 0.06 * streak
    scr = _scratches(c, layers=2, density=(3, 10)) * c.flag(0.5)
    roughness = roughness + 0.15 * scr
    height = height - 0.2 * scr
    diffuse = f0 * 0.02
    return _out(height, diffuse, roughness, specular, c.p(0.002, 0.008))


def metal_plate(g, batch, size, device, dtype=torch.float32):
    """Metal panels with seams, rivets and worn (smoother, brighter) edges."""
    c = _Ctx(g, batch, size, device, dtype)
    x, y = c.rot(PI, snap=PI / 2, jitter=0.03)
    cols = torch.round(c.p(1, 4))
    rows = torch.round(c.p(1, 4))
    bk = noise_fields.bricks(g, x, y, batch, cols, rows, c.flag(0.3) * 0.5, channels=3)
    seam_w = c.p(0.003, 0.012)
    edge = bk["edge"]
    inside = noise_fields.smoothstep(seam_w, seam_w + 0.004, edge)
    bevel = noise_fields.smoothstep(seam_w, seam_w + c.p(0.01, 0.03), edge)
    # Rivets: a row along each plate border, every ``pitch`` surface units.
    inset = c.p(0.04, 0.08)
    pitch = c.p(0.07, 0.2)
    rad = c.p(0.012, 0.025)
    u = bk["u"] * bk["w"]
    v = bk["v"] * bk["h"]
    du = torch.minimum(u, bk["w"] - u)
    dv = torch.minimum(v, bk["h"] - v)
    # along-edge coordinate snapped to the rivet pitch
    def rivet_dist(across, along):
        a = along - torch.round(along / pitch) * pitch
        return torch.sqrt((across - inset) ** 2 + a * a)
    rd = torch.minimum(rivet_dist(du, v), rivet_dist(dv, u))
    rd = torch.where((du < inset * 0.5) & (dv < inset * 0.5), torch.full_like(rd, 1.0), rd)
    has_rivets = c.flag(0.7)
    rivet = (1 - (rd / rad).clamp(0, 1) ** 2).clamp_min(0).sqrt() * has_rivets
    dent = c.fbm(x * c.p(2, 8), y * c.p(2, 8), 4) * c.p(0.0, 0.06)
    height = 0.3 + 0.3 * bevel + dent + 0.35 * rivet
    height = noise_fields.lerp(torch.full_like(height, 0.05), height, inside)
    f0 = torch.where(c.flag(0.25) > 0, c.metal(), c.metal(_GREY_METALS))
    plate_var = (bk["value"] - 0.5) * 0.06
    smudge = c.fbm(x * c.p(1, 5), y * c.p(1, 5), 5)
    wear = (1 - noise_fields.smoothstep(seam_w, seam_w + c.p(0.02, 0.08), edge)) * inside + rivet
    wear = (wear * (0.6 + 0.4 * noise_fields.normalize01(c.fbm(x * 20, y * 20, 3)))).clamp(0, 1)
    base_r = c.p(0.25, 0.6)
    roughness = base_r + 0.08 * smudge - 0.25 * wear * c.p(0.3, 1.0)
    specular = f0 * torch.exp(plate_var + 0.05 * smudge) * (1 + 0.12 * wear)
    scr = _scratches(c, layers=3, density=(3, 12)) * c.p(0.0, 1.0)
    roughness = roughness + 0.2 * scr
    height = height - 0.05 * scr
    diffuse = torch.full_like(specular, 0.01) * (1 + 0.5 * smudge.clamp(-1, 1))
    # Grime in the seams raises roughness and dulls the specular (still metallic).
    cav = (1 - inside)
    roughness = noise_fields.lerp(roughness, torch.full_like(roughness, 0.9), cav * c.p(0.3, 1.0))
    specular = (specular * (1 - 0.25 * cav)).clamp(0.5, 0.98)
    return _out(height, diffuse, roughness, specular, c.p(0.01, 0.04))


def tread_plate(g, batch, size, device, dtype=torch.float32):
    """Metal tread / checker plate: raised lozenges, dots or squares; worn tops."""
    c = _Ctx(g, batch, size, device, dtype)
    x, y = c.rot(PI / 4, snap=PI / 4, jitter=0.03)
    kind = c.p(0, 3)
    n = c.p(4, 16)
    u, v = x * n, y * n
    iu, iv = torch.floor(u), torch.floor(v)
    fu, fv = u - iu - 0.5, v - iv - 0.5
    # diamond plate: lozenge alternating orientation on a checkerboard
    alt = torch.remainder(iu + iv, 2.0)
    a = torch.where(alt > 0, fu + fv, fu - fv) * 0.7071
    b = torch.where(alt > 0, fu - fv, fu + fv) * 0.7071
    L, W = 0.42, 0.09
    loz = 1 - (torch.sqrt((a / L) ** 2 + (b / W) ** 2)).clamp(0, 1.5)
    loz = noise_fields.smoothstep(0.0, 0.35, loz)
    dot_r = c.p(0.2, 0.35)
    dots = noise_fields.smoothstep(0.0, 0.4, 1 - torch.sqrt(fu * fu + fv * fv) / dot_r)
    sq = 1 - torch.maximum(fu.abs(), fv.abs()) / c.p(0.25, 0.4)
    squares = noise_fields.smoothstep(0.0, 0.25, sq)
    bump = torch.where(kind < 1.5, loz, torch.where(kind < 2.4, dots, squares))
    base_dent = c.fbm(x * 3, y * 3, 4) * 0.03
    height = 0.2 + 0.7 * bump.sqrt() + base_dent
    f0 = c.metal(("steel", "aluminium", "iron", "zinc", "aluminium", "brass"))
    smudge = c.fbm(x * c.p(2, 6), y * c.p(2, 6), 5)
    wear = noise_fields.smoothstep(0.5, 1.0, bump) * c.p(0.3, 1.0)
    roughness = c.p(0.3, 0.6) + 0.1 * smudge - 0.25 * wear
    specular = f0 * (1 + 0.1 * wear) * torch.exp(0.05 * smudge)
    scr = _scratches(c, layers=2, density=(3, 10)) * c.p(0.0, 1.0)
    roughness = roughness + 0.15 * scr
    cav = (1 - bump) * noise_fields.smoothstep(0.3, 0.9, noise_fields.normalize01(c.fbm(x * 5, y * 5, 4))) * c.p(0.0, 0.7)
    roughness = noise_fields.lerp(roughness, torch.full_like(roughness, 0.85), cav)
    specular = (specular * (1 - 0.3 * cav)).clamp(0.5, 0.98)
    diffuse = torch.full_like(specular, 0.01)
    return _out(height, diffuse, roughness, specular, c.p(0.02, 0.05))


def scratched_metal(g, batch, size, device, dtype=torch.float32):
    """Polished, cast or oxidised metal with scratches, smudges and fingerprints."""
    c = _Ctx(g, batch, size, device, dtype)
    f0 = c.metal()
    x, y = c.x, c.y
    smudge = c.fbm(x * c.p(1, 5), y * c.p(1, 5), 5)
    blotch = noise_fields.smoothstep(0.6, 1.6, c.fbm(x * c.p(2, 8), y * c.p(2, 8), 5)) * c.flag(0.5) * c.p(0.2, 0.7)
    scr = _scratches(c, layers=5, density=(4, 25), random_dir=True)
    hammered = c.flag(0.25)
    hw = c.worley(x * c.p(6, 20), y * c.p(6, 20), jitter=0.9)
    hammer = (1 - hw["f1"] ** 2) * hammered
    grain = c.fbm(x * 120, y * 120, 2) * c.p(0.0, 1.0)
    height = 0.5 + 0.3 * hammer + 0.02 * grain - 0.15 * scr + 0.02 * smudge
    base_r = c.p(0.08, 0.45)
    brighter = c.flag(0.5)  # scratches either roughen a polished surface or burnish a dull one
    scr_r = torch.where(brighter > 0, -0.6 * base_r, 0.35 * torch.ones_like(base_r))
    roughness = base_r + 0.06 * smudge + 0.3 * blotch + scr_r * scr + 0.04 * grain
    specular = (f0 * torch.exp(0.06 * smudge - 0.3 * blotch) * (1 + 0.08 * scr)).clamp(0.5, 0.98)
    diffuse = f0 * 0.015
    return _out(height, diffuse, roughness, specular, c.p(0.003, 0.02))


def marble(g, batch, size, device, dtype=torch.float32):
    """Polished marble and onyx: warped veins on a mottled base, optional slab seams."""
    c = _Ctx(g, batch, size, device, dtype)
    x, y = c.rot(PI)
    f = c.p(0.5, 2.0)
    wx, wy = noise_fields.warp(g, x * f, y * f, batch, c.p(0.1, 0.4), 1.0, 4)
    # Main veins: long wavy bands, sin of a noise-perturbed ramp.
    phase = wx * c.p(0.3, 1.0) + c.p(0.3, 1.0) * c.fbm(wx * 0.7, wy * 0.7, 4)
    sv = torch.sin(phase * PI).abs()
    main = 1 - noise_fields.smoothstep(0.0, c.p(0.03, 0.12), sv)
    main = main * noise_fields.smoothstep(-0.3, 0.6, c.fbm(wx * 1.5, wy * 1.5, 3))  # veins fade in and out
    cloud = (1 - noise_fields.smoothstep(0.0, 0.8, sv)) * c.p(0.0, 0.4)
    # Thin veins: a crack network from ridged noise.
    rn = noise_fields.normalize01(c.fbm(wx * 1.5 + 5.0, wy * 1.5, 4, mode="ridged", gain=0.6))
    t0 = c.p(0.86, 0.93)
    thin = noise_fields.smoothstep(t0, t0 + 0.06, rn) * c.p(0.3, 0.9) * c.flag(0.8)
    vein = torch.maximum(torch.maximum(main * c.p(0.6, 1.0), thin), cloud)
    palettes = [
        (0.92, 0.91, 0.88, 0.35, 0.35, 0.37),  # Carrara
        (0.90, 0.86, 0.78, 0.60, 0.45, 0.25),  # cream with gold
        (0.10, 0.10, 0.11, 0.85, 0.85, 0.85),  # Nero Marquina
        (0.20, 0.35, 0.28, 0.85, 0.90, 0.85),  # verde
        (0.65, 0.45, 0.40, 0.90, 0.85, 0.80),  # rosso
        (0.55, 0.55, 0.57, 0.20, 0.20, 0.22),  # grey
        (0.85, 0.80, 0.70, 0.45, 0.35, 0.25),  # travertine-like
    ]
    pair = c.pick(palettes, jitter=0.08)
    base, vcol = pair[:, :3], pair[:, 3:]
    mott = c.fbm(x * c.p(2, 8), y * c.p(2, 8), 5)
    diffuse = noise_fields.lerp(base * torch.exp(0.1 * mott), vcol * torch.exp(0.1 * mott), vein)
    slabs = c.flag(0.4)
    bk = noise_fields.bricks(g, x, y, batch, torch.round(c.p(1, 4)), torch.round(c.p(1, 4)), 0.0, channels=1)
    seam = (1 - noise_fields.smoothstep(0.002, 0.005, bk["edge"])) * slabs
    height = 0.8 + 0.02 * mott - 0.05 * vein * c.p(0, 1) - 0.7 * seam
    polished = c.flag(0.8)
    roughness = torch.where(polished > 0, c.p(0.05, 0.2), c.p(0.4, 0.7)) + 0.03 * mott + 0.1 * vein * c.p(0, 1)
    scr = _scratches(c, layers=2, density=(3, 10)) * c.p(0.0, 0.8) * polished
    roughness = roughness + 0.2 * scr + 0.6 * seam
    diffuse = noise_fields.lerp(diffuse, diffuse * 0.4, seam)
    return _out(height, diffuse, roughness, c.spec(0.04, 0.06), c.p(0.003, 0.015))


def concrete(g, batch, size, device, dtype=torch.float32):
    """Concrete, plaster, sandstone and granite: fBm, pores, aggregate speckles, cracks."""
    c = _Ctx(g, batch, size, device, dtype)
    x, y = c.x, c.y
    kind = c.p(0, 3)  # <1 concrete, <2 plaster/sandstone, else granite
    base = c.hsv((0.05, 0.13), (0.0, 0.25), (0.35, 0.8))
    large = c.fbm(x * c.p(1, 4), y * c.p(1, 4), 6)
    mid = c.fbm(x * c.p(10, 30), y * c.p(10, 30), 4)
    fine = c.fbm(x * 150, y * 150, 2)
    # pores: small dark pits
    pw = c.worley(x * c.p(20, 60), y * c.p(20, 60), jitter=1.0, channels=1)
    pore_r = c.p(0.05, 0.25) * (pw["value"] < c.p(0.2, 0.7)).to(dtype)
    pores = 1 - noise_fields.smoothstep(pore_r * 0.5, pore_r, pw["f1"])
    # aggregate / granite grains: per-cell colours
    ag = c.worley(x * c.p(25, 80), y * c.p(25, 80), jitter=1.0, channels=3)
    grain_col = torch.where(ag["value"][:, :1] < 0.5, 0.3 + 0.2 * ag["value"][:, 1:2], 1.2 + ag["value"][:, 1:2])
    granite = (kind >= 2).to(dtype)
    speck = (ag["value"][:, 2:3] < c.p(0.05, 0.3)).to(dtype) * (1 - granite)
    cracks = noise_fields.smoothstep(0.88, 0.97, noise_fields.normalize01(c.fbm(x * c.p(1, 3), y * c.p(1, 3), 6, mode="ridged")))
    cracks = cracks * c.flag(0.4)
    diffuse = base * torch.exp(0.2 * large * c.p(0.3, 1.0) + 0.08 * mid + 0.05 * fine)
    diffuse = diffuse * (1 + granite * (grain_col - 1) * c.p(0.5, 1.0))
    diffuse = diffuse * (1 - 0.4 * speck * (ag["value"][:, 1:2] - 0.3))
    diffuse = diffuse * (1 - 0.6 * pores) * (1 - 0.6 * cracks)
    height = 0.6 + 0.05 * large + 0.06 * mid + 0.04 * fine - 0.45 * pores - 0.4 * cracks
    roughness = torch.where(granite > 0, torch.where(c.flag(0.6) > 0, c.p(0.1, 0.3), c.p(0.5, 0.8)),
                            c.p(0.65, 0.95)) + 0.05 * mid + 0.2 * pores
    diffuse, roughness = _grime(c, height, diffuse, roughness, c.p(0, 0.6), 0.01)
    return _out(height, diffuse, roughness, c.spec(0.03, 0.05), c.p(0.01, 0.05))


def leather(g, batch, size, device, dtype=torch.float32):
    """Leather: pebbled Voronoi grain, creases and wrinkles; dyed colours."""
    c = _Ctx(g, batch, size, device, dtype)
    x, y = c.rot(PI)
    sc = c.p(8, 30, log=True)
    xs, ys = noise_fields.warp(g, x * sc, y * sc, batch, c.p(0.1, 0.3), 0.7)
    w = c.worley(xs, ys, jitter=1.0, channels=1)
    crease = 1 - noise_fields.smoothstep(0.0, c.p(0.05, 0.2), w["f2"] - w["f1"])
    pebble = (1 - w["f1"] ** 2 * 0.8).clamp(0, 1)
    wr = c.fbm(x * c.p(2, 6), y * c.p(2, 6), 5, mode="ridged")
    wrinkles = noise_fields.smoothstep(0.6, 0.95, noise_fields.normalize01(wr)) * c.p(0.0, 1.0)
    height = 0.5 + 0.3 * pebble - 0.3 * crease - 0.4 * wrinkles + 0.05 * (w["value"] - 0.5)
    colour = c.hsv((0.0, 0.12), (0.3, 0.8), (0.08, 0.7))
    dyed = c.hsv((0.0, 1.0), (0.4, 0.9), (0.1, 0.6))
    colour = torch.where(c.flag(0.25) > 0, dyed, colour)
    colour = torch.where(c.flag(0.15) > 0, c.hsv((0, 1), (0, 0.1), (0.05, 0.15)), colour)
    mott = c.fbm(x * c.p(2, 10), y * c.p(2, 10), 5)
    diffuse = colour * torch.exp(0.15 * mott - c.p(0.2, 0.8) * crease - 0.5 * wrinkles + 0.1 * (w["value"] - 0.5))
    roughness = c.p(0.3, 0.7) + 0.02 * mott + 0.2 * crease + 0.15 * wrinkles - 0.1 * pebble * c.p(0, 1)
    # worn, polished highlights on the tops
    wear = noise_fields.smoothstep(0.5, 1.2, c.fbm(x * 3, y * 3, 4)) * c.p(0.0, 1.0)
    diffuse = diffuse * (1 + 0.4 * wear * pebble)
    roughness = roughness - 0.15 * wear * pebble
    return _out(height, diffuse, roughness, c.spec(0.035, 0.05), c.p(0.01, 0.035))


def fabric(g, batch, size, device, dtype=torch.float32):
    """Woven fabric: plain, twill or basket weave of round threads with fibres."""
    c = _Ctx(g, batch, size, device, dtype)
    x, y = c.rot(PI / 2, snap=PI / 2, jitter=0.05)
    x, y = noise_fields.warp(g, x, y, batch, c.p(0.0, 0.01), 2.0)
    n = c.p(8, 40, log=True)
    u, v = x * n, y * n
    iu, iv = torch.floor(u), torch.floor(v)
    fu, fv = u - iu, v - iv
    kind = c.p(0, 3)
    k = torch.where(kind < 1, torch.full_like(kind, 2.0), torch.where(kind < 2, c.p(3, 4.99).floor(), torch.full_like(kind, 4.0)))
    # Over/under: plain (k=2), twill (diagonal), basket (2x2 blocks).
    twill = torch.remainder(iu + iv, k) < k / 2
    basket = torch.remainder(torch.floor(iu / 2) + torch.floor(iv / 2), 2.0) < 1
    warp_top = torch.where(kind < 1, torch.remainder(iu + iv, 2.0) < 1, torch.where(kind < 2, twill, basket))
    gap = c.p(0.05, 0.25)
    prof_w = (1 - ((2 * fu - 1) / (1 - gap)) ** 2).clamp_min(0).sqrt()  # thread along y (warp)
    prof_f = (1 - ((2 * fv - 1) / (1 - gap)) ** 2).clamp_min(0).sqrt()  # thread along x (weft)
    bend_w = 0.75 + 0.25 * torch.sin(PI * fv)
    bend_f = 0.75 + 0.25 * torch.sin(PI * fu)
    fib_w = c.fbm(x * n * 0.5, y * n * 8, 2)  # fibres along each thread
    fib_f = c.fbm(x * n * 8, y * n * 0.5, 2)
    h_w = prof_w * bend_w + 0.06 * fib_w
    h_f = prof_f * bend_f + 0.06 * fib_f
    height = torch.where(warp_top, torch.maximum(h_w, h_f * 0.5), torch.maximum(h_f, h_w * 0.5))
    fuzz = c.fbm(x * 150, y * 150, 2)
    height = height * 0.8 + 0.03 * fuzz
    col_w = c.hsv((0, 1), (0.0, 0.85), (0.1, 0.85))
    col_f = torch.where(c.flag(0.5) > 0, col_w * c.p(0.6, 1.2), c.hsv((0, 1), (0.0, 0.6), (0.2, 0.9)))
    # Per-thread tone variation (slub yarn).
    tone_w = c.fbm(iu * 7.3 + 0.5, v * 0.3, 2) * 0.08
    tone_f = c.fbm(u * 0.3, iv * 7.3 + 0.5, 2) * 0.08
    diffuse = torch.where(warp_top, col_w * torch.exp(0.1 * fib_w + tone_w), col_f * torch.exp(0.1 * fib_f + tone_f))
    occl = torch.where(warp_top, prof_w, prof_f)
    diffuse = diffuse * (0.55 + 0.45 * occl)
    sheen = c.flag(0.2)  # satin / synthetic threads
    roughness = torch.where(sheen > 0, c.p(0.3, 0.5), c.p(0.7, 1.0)) + 0.1 * (1 - occl) + 0.03 * fuzz
    diffuse, roughness = _grime(c, height, diffuse, roughness, c.p(0, 0.3), 0.02)
    return _out(height, diffuse, roughness, c.spec(0.02, 0.04), c.p(0.004, 0.015))


def plastic_paint(g, batch, size, device, dtype=torch.float32):
    """Painted surfaces and plastics (any hue): texture, scratches, chips, dirt."""
    c = _Ctx(g, batch, size, device, dtype)
    x, y = c.x, c.y
    colour = c.hsv((0, 1), (0.0, 0.95), (0.1, 0.95))
    tex_kind = c.p(0, 3)
    peel = c.fbm(x * c.p(20, 60), y * c.p(20, 60), 3)  # orange peel
    grain_w = c.worley(x * c.p(30, 80), y * c.p(30, 80), jitter=1.0)
    grain = 1 - grain_w["f1"]
    smooth = c.fbm(x * 3, y * 3, 3)
    tex = torch.where(tex_kind < 1, 0.2 * smooth, torch.where(tex_kind < 2, 0.5 * peel, grain))
    height = 0.6 + 0.2 * tex
    scr = _scratches(c, layers=4, density=(3, 15)) * c.p(0.2, 1.0)
    height = height - 0.15 * scr
    base_r = c.p(0.08, 0.6)
    roughness = base_r + 0.05 * tex + c.p(0.1, 0.35) * scr
    diffuse = colour * torch.exp(0.05 * smooth) * (1 + c.p(0.0, 0.5) * scr)
    specular = c.spec(0.035, 0.055).expand_as(diffuse)
    # Chipped paint over metal (or primer / wood under it).
    chipped = c.flag(0.35)
    ch = noise_fields.normalize01(c.fbm(x * c.p(2, 8), y * c.p(2, 8), 6))
    thr = c.p(0.65, 0.85)
    chip = noise_fields.smoothstep(thr, thr + 0.02, ch) * chipped
    under_metal = c.flag(0.5)
    under_d = torch.where(under_metal > 0, torch.full_like(colour, 0.01), c.hsv((0.05, 0.1), (0.2, 0.5), (0.2, 0.6)))
    under_s = torch.where(under_metal > 0, c.metal(_GREY_METALS), c.spec(0.03, 0.04))
    under_r = torch.where(under_metal > 0, c.p(0.3, 0.6), c.p(0.7, 0.9))
    diffuse = noise_fields.lerp(diffuse, under_d, chip)
    specular = noise_fields.lerp(specular, under_s.expand_as(specular), chip)
    roughness = noise_fields.lerp(roughness, under_r + 0.1 * peel, chip)
    height = height - 0.4 * chip
    diffuse, roughness, specular = _grime(c, height, diffuse, roughness, c.p(0.0, 0.8), 0.015, specular=specular)
    # Dust film over everything.
    dust = c.p(0.0, 0.3) * noise_fields.normalize01(c.fbm(x * 4, y * 4, 4))
    diffuse = noise_fields.lerp(diffuse, torch.full_like(diffuse, 0.35), dust * 0.5)
    roughness = noise_fields.lerp(roughness, torch.full_like(roughness, 0.9), dust)
    return _out(height, diffuse, roughness, specular, c.p(0.003, 0.015))


def foam(g, batch, size, device, dtype=torch.float32):
    """Foam and sponge: open round pores at two scales, thin walls."""
    c = _Ctx(g, batch, size, device, dtype)
    x, y = c.x, c.y
    sc = c.p(10, 35, log=True)
    xs, ys = noise_fields.warp(g, x * sc, y * sc, batch, c.p(0.05, 0.2), 0.5)
    w1 = c.worley(xs, ys, jitter=1.0, channels=1)
    r1 = c.p(0.3, 0.55) * (0.7 + 0.6 * w1["value"])
    bowl = (1 - (w1["f1"] / r1).clamp(0, 1) ** 2)  # 1 at the pore centre, 0 at its rim
    pore1 = noise_fields.smoothstep(0.0, 0.15, bowl)
    w2 = c.worley(xs * 2.3 + 10, ys * 2.3, jitter=1.0, channels=1)
    r2 = 0.3 * (w2["value"] < 0.5).to(dtype)
    pore2 = (1 - (w2["f1"] / (r2 + 1e-3)).clamp(0, 1) ** 2) * (1 - pore1)
    walls = noise_fields.smoothstep(0.0, 0.1, w1["f2"] - w1["f1"])
    height = 0.9 - 0.8 * bowl.sqrt() * pore1 - 0.35 * pore2 - 0.1 * (1 - walls) * (1 - pore1)
    height = height + 0.03 * c.fbm(x * 120, y * 120, 2)
    colour = c.hsv((0.0, 1.0), (0.0, 0.6), (0.35, 0.9))
    colour = torch.where(c.flag(0.4) > 0, c.hsv((0.1, 0.17), (0.2, 0.6), (0.55, 0.9)), colour)
    occl = torch.exp(-1.5 * bowl * pore1 - 0.6 * pore2)
    diffuse = colour * occl * torch.exp(0.05 * c.fbm(x * 5, y * 5, 3))
    roughness = c.p(0.8, 1.0) + 0.05 * pore1
    return _out(height, diffuse, roughness, c.spec(0.02, 0.04), c.p(0.03, 0.08))


def scales(g, batch, size, device, dtype=torch.float32):
    """Scales and hexagons: reptile scales, overlapping fish scales, hex tiles."""
    c = _Ctx(g, batch, size, device, dtype)
    x, y = c.rot(PI)
    kind = c.p(0, 3)
    sc = c.p(2.0, 10.0, log=True)
    # -- hexagonal cells (reptile scales or hex tiles)
    hx = noise_fields.hexagons(g, x, y, batch, sc, channels=3)
    gap = c.p(0.02, 0.08)
    hinside = noise_fields.smoothstep(gap, gap + 0.03, hx["edge"])
    dome = noise_fields.smoothstep(gap, 0.5, hx["edge"]).sqrt()
    hex_h = noise_fields.lerp(torch.full_like(dome, 0.1), 0.4 + 0.5 * dome, hinside)
    # -- overlapping fish scales: rows of discs, each row over the one above it
    u, v = x * sc, y * sc * 2.0  # rows 0.5 units apart
    r0 = torch.floor(v)
    best_h = torch.zeros_like(u)
    best_val = torch.zeros_like(u)
    best_in = torch.zeros_like(u)
    R = 0.62
    for dr in (1.0, 0.0, -1.0):  # lower rows (smaller v) drawn later, on top
        r = r0 + dr
        shift = torch.remainder(r, 2.0) * 0.5
        cx = torch.floor(u - shift + 0.5) + shift
        ddx = u - cx
        ddy = (v - r) * 0.5
        d = torch.sqrt(ddx * ddx + ddy * ddy) / R
        cover = (d < 1.0) & (ddy >= -0.05)
        prof = (1.0 - d).clamp(0, 1)
        rv = torch.remainder(cx * 12.9898 + r * 78.233, 1.0)
        best_h = torch.where(cover, 0.2 + 0.8 * (prof ** 0.5) * (0.7 + 0.3 * (ddy / 0.5).clamp(0, 1)), best_h)
        best_val = torch.where(cover, rv, best_val)
        best_in = torch.where(cover, prof, best_in)
    fish = kind >= 2
    height = torch.where(fish, best_h, hex_h)
    val = torch.where(fish, best_val, hx["value"][:, :1])
    base = c.hsv((0.0, 1.0), (0.1, 0.7), (0.1, 0.7))
    alt = c.hsv((0.0, 1.0), (0.1, 0.7), (0.1, 0.7))
    colour = noise_fields.lerp(base, alt, (val * c.p(0.0, 1.0)))
    rim = torch.where(fish, 1 - noise_fields.smoothstep(0.0, 0.25, best_in),
                      1 - noise_fields.smoothstep(gap, gap + 0.15, hx["edge"]))
    diffuse = colour * torch.exp(-c.p(0.0, 1.0) * rim + 0.1 * c.fbm(x * sc * 2, y * sc * 2, 3))
    hex_tile = kind < 1  # hex tiles with grout
    grout = c.hsv((0.05, 0.12), (0.0, 0.2), (0.3, 0.8))
    diffuse = torch.where(hex_tile & (hinside < 0.5), grout.expand_as(diffuse), diffuse)
    glossy = c.flag(0.5)
    roughness = torch.where(glossy > 0, c.p(0.15, 0.4), c.p(0.45, 0.8)) + 0.2 * rim
    roughness = torch.where(hex_tile & (hinside < 0.5), torch.full_like(roughness, 0.95), roughness)
    diffuse, roughness = _grime(c, height, diffuse, roughness, c.p(0.0, 0.5), 0.01)
    return _out(height, diffuse, roughness, c.spec(0.035, 0.06), c.p(0.01, 0.05))


def paper(g, batch, size, device, dtype=torch.float32):
    """Paper and card: fibres, low relief, printed text-like blocks or patterns."""
    c = _Ctx(g, batch, size, device, dtype)
    x, y = c.rot(0.05)
    white = c.hsv((0.08, 0.15), (0.0, 0.12), (0.75, 0.95))
    kraft = c.hsv((0.07, 0.1), (0.35, 0.55), (0.45, 0.7))
    pastel = c.hsv((0.0, 1.0), (0.1, 0.45), (0.6, 0.95))
    kind = c.p(0, 1)
    base = torch.where(kind < 0.55, white, torch.where(kind < 0.8, kraft, pastel))
    fib = c.fbm(x * 40, y * 40, 4) + 0.5 * c.fbm(x * 8, y * 200, 2)
    cloud = c.fbm(x * 6, y * 6, 4)
    height = 0.5 + 0.15 * fib + 0.1 * cloud
    diffuse = base * torch.exp(0.04 * fib + 0.04 * cloud)
    # Text-like lines: rows of words with letter strokes.
    line_h = c.p(0.035, 0.1)
    rows = 2.0 / line_h
    word_cols = rows * c.p(0.3, 0.8)
    bk = noise_fields.bricks(g, x, y, batch, word_cols, rows, c.p(0.2, 0.7), channels=2)
    in_line = (bk["v"] > 0.3) & (bk["v"] < 0.8)
    word = (bk["value"][:, :1] > 0.2) & (bk["u"] > 0.08) & (bk["u"] < 0.92)
    letters = c.noise(x * rows * c.p(1.5, 3.0), y * 0.5) + 0.3 * c.noise(x * rows * 2, y * rows * 2)
    stroke = (letters.abs() < 0.35)
    margin = (x.abs() < c.p(0.6, 0.95)) & (y.abs() < c.p(0.6, 0.95))
    para = c.noise(x * 0.1, y * rows * 0.15) > -0.3
    text = (in_line & word & stroke & margin & para).to(dtype) * c.flag(0.5)
    # Printed pattern: stripes, dots or checks in a second colour.
    pu, pv = noise_fields.rotate(x, y, c.p(-PI, PI))
    pf = c.p(3, 15)
    stripes = (torch.sin(pu * pf * PI) > c.p(-0.5, 0.5)).to(dtype)
    du, dv = torch.remainder(pu * pf, 1.0) - 0.5, torch.remainder(pv * pf, 1.0) - 0.5
    dots = (du * du + dv * dv < c.p(0.03, 0.15)).to(dtype)
    pk = c.p(0, 2)
    pattern = torch.where(pk < 1, stripes, dots) * (1 - c.flag(0.5)) * (1 - text.amax(dim=(2, 3), keepdim=True).clamp(0, 1))
    ink = c.hsv((0.0, 1.0), (0.0, 0.9), (0.02, 0.5))
    ink2 = c.hsv((0.0, 1.0), (0.3, 0.9), (0.2, 0.8))
    ink_amt = text + pattern * c.p(0.5, 1.0)
    ink_col = torch.where(text > 0, ink, ink2)
    ink_amt = ink_amt * (0.85 + 0.15 * noise_fields.normalize01(c.fbm(x * 80, y * 80, 2)))
    diffuse = noise_fields.lerp(diffuse, ink_col * torch.exp(0.05 * fib), ink_amt)
    coated = c.flag(0.3)
    roughness = torch.where(coated > 0, c.p(0.3, 0.5), c.p(0.7, 0.95)) + 0.04 * fib - 0.15 * ink_amt * c.p(0, 1)
    height = height + 0.1 * ink_amt * c.p(0, 1)
    creased = c.flag(0.3)
    cx, cy = noise_fields.rotate(x, y, c.p(-PI, PI))
    fold = torch.exp(-((cy - c.p(-0.6, 0.6)) / 0.02) ** 2) * creased
    height = height - 0.3 * fold
    return _out(height, diffuse, roughness, c.spec(0.03, 0.045), c.p(0.005, 0.015))


def bark(g, batch, size, device, dtype=torch.float32):
    """Tree bark: vertical furrows and plates, cracks, lichen patches."""
    c = _Ctx(g, batch, size, device, dtype)
    x, y = c.rot(0.15)
    sx = c.p(3, 12)
    xs, ys = noise_fields.warp(g, x * sx, y * sx * c.p(0.15, 0.4), batch, c.p(0.2, 0.7), 1.0, 4)
    rid = c.fbm(xs, ys, 5, mode="ridged")
    plates = c.worley(xs * 0.8, ys * 0.8, jitter=1.0, channels=1)
    plate_edge = noise_fields.smoothstep(0.0, 0.25, plates["f2"] - plates["f1"])
    mix = c.p(0.1, 0.5)
    height = noise_fields.normalize01((1 - mix) * noise_fields.normalize01(rid)
                                      + mix * plate_edge * (0.7 + 0.3 * plates["value"]))
    height = height ** c.p(0.5, 1.2)
    fine = c.fbm(x * 60, y * 20, 3)
    height = (height + 0.05 * fine).clamp(0, 1)
    base = c.hsv((0.04, 0.12), (0.1, 0.45), (0.15, 0.5))
    diffuse = base * torch.exp(0.6 * (height - 0.5) + 0.1 * fine + 0.1 * c.fbm(x * 4, y * 4, 3))
    lichen = noise_fields.smoothstep(0.65, 0.85, noise_fields.normalize01(c.fbm(x * c.p(2, 6), y * c.p(2, 6), 5))) * c.flag(0.35)
    lichen = lichen * noise_fields.smoothstep(0.3, 0.6, height)
    lcol = c.hsv((0.12, 0.3), (0.1, 0.35), (0.35, 0.7))
    diffuse = noise_fields.lerp(diffuse, lcol * torch.exp(0.15 * fine), lichen)
    roughness = c.p(0.75, 1.0) + 0.05 * fine
    diffuse, roughness = _grime(c, height, diffuse, roughness, c.p(0.3, 1.0), 0.01,
                                colour=c.hsv((0.05, 0.1), (0.2, 0.4), (0.03, 0.1)))
    return _out(height, diffuse, roughness, c.spec(0.02, 0.04), c.p(0.06, 0.2))


def ground(g, batch, size, device, dtype=torch.float32):
    """Asphalt, gravel, pebbles and soil: aggregate in a binder."""
    c = _Ctx(g, batch, size, device, dtype)
    x, y = c.x, c.y
    kind = c.p(0, 3)  # <1 asphalt, <2 gravel / pebbles, else soil with stones
    sc = torch.where(kind < 1, c.p(25, 60), torch.where(kind < 2, c.p(5, 20), c.p(8, 25)))
    xs, ys = noise_fields.warp(g, x * sc, y * sc, batch, c.p(0.1, 0.3), 0.8)
    w = c.worley(xs, ys, jitter=1.0, channels=4)
    size_r = 0.3 + 0.4 * w["value"][:, 3:4]
    share = torch.where(kind < 1, c.p(0.5, 0.9), torch.where(kind < 2, c.p(0.9, 1.0), c.p(0.2, 0.5)))
    present = (w["value"][:, 2:3] < share).to(dtype)
    stone = (1 - (w["f1"] / size_r).clamp(0, 1) ** 2).clamp_min(0).sqrt() * present
    binder_n = c.fbm(x * c.p(20, 60), y * c.p(20, 60), 4)
    height = 0.25 + 0.05 * binder_n + 0.65 * stone
    asphalt = (kind < 1).to(dtype)
    binder = torch.where(kind < 1, c.hsv((0, 1), (0, 0.05), (0.04, 0.12)), c.hsv((0.05, 0.11), (0.3, 0.6), (0.12, 0.4)))
    stone_base = torch.where(kind < 1, c.hsv((0, 1), (0, 0.1), (0.3, 0.6)), c.hsv((0.0, 0.14), (0.05, 0.35), (0.3, 0.8)))
    sv = w["value"][:, :3]
    stone_col = stone_base * torch.exp((sv[:, :1] - 0.5) * 1.2 + (sv - 0.5) * 0.25 + 0.1 * c.fbm(xs * 3, ys * 3, 2))
    cover = noise_fields.smoothstep(0.0, 0.25, stone)
    diffuse = noise_fields.lerp(binder * torch.exp(0.15 * binder_n), stone_col, cover)
    roughness = noise_fields.lerp(c.p(0.7, 1.0) + 0.05 * binder_n, c.p(0.45, 0.85) + 0.0 * binder_n, cover)
    roughness = roughness - 0.3 * asphalt * (1 - cover) * c.flag(0.3)  # fresh, glossier binder
    diffuse, roughness = _grime(c, height, diffuse, roughness, c.p(0.2, 0.9), 0.015)
    return _out(height, diffuse, roughness, c.spec(0.03, 0.05), c.p(0.03, 0.1))


def printed(g, batch, size, device, dtype=torch.float32):
    """Prints and dyed patterns on a flat or finely textured ground: gingham, stripes, plaid, dots,
    blotches. The pattern is colour (and a little gloss) only, never relief: what teaches the chain
    that a colour edge is not a ridge (it turned a gingham's checks into ridges)."""
    c = _Ctx(g, batch, size, device, dtype)
    # the ground: a fine weave, a paper's fibres, a smooth plastic or board
    ground = c.p(0, 3)
    x, y = c.rot(PI / 2, snap=PI / 2, jitter=0.03)
    n = c.p(30, 90, log=True)
    weave = torch.sin(PI * x * n).abs() * torch.sin(PI * y * n).abs()
    fibres = c.fbm(x * 60, y * 60, 3)
    height = torch.where(ground < 1, 0.5 + 0.4 * weave + 0.05 * fibres,
                         torch.where(ground < 2, 0.5 + 0.15 * fibres, 0.5 + 0.03 * c.fbm(x * 4, y * 4, 3)))
    depth = torch.where(ground < 1, c.p(0.002, 0.008), torch.where(ground < 2, c.p(0.002, 0.006), c.p(0.0005, 0.003)))
    # the pattern: levels 0, 0.5 and 1 of up to three colours
    kind = c.p(0, 5)
    px, py = c.rot(PI / 2, snap=PI / 4, jitter=0.05)
    f = c.p(2.0, 12.0, log=True)
    duty = c.p(0.3, 0.7)
    bands_x = (torch.remainder(px * f, 2.0) < 2.0 * duty).to(dtype)
    bands_y = (torch.remainder(py * f, 2.0) < 2.0 * duty).to(dtype)
    gingham = 0.5 * (bands_x + bands_y)
    plaid = noise_fields.normalize01(torch.sin(px * f * PI) + 0.6 * torch.sin(px * f * 2.7 * PI + 1.0)
                                     + torch.sin(py * f * PI) + 0.6 * torch.sin(py * f * 2.3 * PI + 2.0))
    plaid = torch.round(plaid * 2.0) / 2.0
    du, dv = torch.remainder(px * f, 1.0) - 0.5, torch.remainder(py * f, 1.0) - 0.5
    dots = (du * du + dv * dv < c.p(0.02, 0.12)).to(dtype)
    blotch = (c.fbm(x * f * 0.7, y * f * 0.7, 4) > c.p(-0.2, 0.3)).to(dtype)
    pattern = torch.where(kind < 1, gingham, torch.where(kind < 2, bands_x, torch.where(
        kind < 3, plaid, torch.where(kind < 4, dots, blotch))))
    dark, light = c.hsv((0, 1), (0.0, 0.9), (0.03, 0.35)), c.hsv((0, 1), (0.0, 0.9), (0.45, 0.9))
    swap = c.flag(0.5) > 0
    a, b = torch.where(swap, light, dark), torch.where(swap, dark, light)  # the contrast of a print that shows
    mid = torch.where(c.flag(0.5) > 0, 0.5 * (a + b) * c.p(0.7, 1.1), c.hsv((0, 1), (0.0, 0.9), (0.05, 0.9)))
    colour = torch.where(pattern < 0.25, a, torch.where(pattern < 0.75, mid, b))
    shade = torch.where(ground < 1, 0.75 + 0.25 * weave, torch.ones_like(weave))  # a weave's thread shading
    diffuse = colour * shade * torch.exp(0.05 * fibres)
    base_r = torch.where(ground < 1, c.p(0.6, 1.0), torch.where(ground < 2, c.p(0.5, 0.95), c.p(0.15, 0.7)))
    roughness = base_r + c.p(-0.1, 0.1) * pattern + 0.03 * fibres  # an ink a little glossier or duller
    diffuse, roughness = _grime(c, height, diffuse, roughness, c.p(0.0, 0.2), 0.02)
    return _out(height, diffuse, roughness, c.spec(0.03, 0.05), depth)


#: name -> family function ``fn(g, batch, size, device, dtype) -> dict``.
FAMILIES: dict[str, Callable] = {
    "tiles": tiles,
    "bricks": bricks,
    "cobblestones": cobblestones,
    "wood": wood,
    "brushed_metal": brushed_metal,
    "metal_plate": metal_plate,
    "tread_plate": tread_plate,
    "scratched_metal": scratched_metal,
    "marble": marble,
    "concrete": concrete,
    "leather": leather,
    "fabric": fabric,
    "plastic_paint": plastic_paint,
    "foam": foam,
    "scales": scales,
    "paper": paper,
    "bark": bark,
    "ground": ground,
}

#: Families drawn only when named (``families=``): the bank's print shards (``export/engine/bank.py``).
#: Kept out of :data:`FAMILIES` so that a default draw is the same as before they existed.
EXTRA_FAMILIES: dict[str, Callable] = {"printed": printed}

#: Families whose materials are metals (diffuse ~ 0, coloured F0 >= 0.5).
METAL_FAMILIES = ("brushed_metal", "metal_plate", "tread_plate", "scratched_metal")


# --------------------------------------------------------------------------
# Finishing
# --------------------------------------------------------------------------


def _gradients(height):
    """d/dcol and d/drow of (B, 1, H, W) by central differences, one-sided at the borders."""
    gx = torch.cat([height[..., :, 1:2] - height[..., :, :1],
                    (height[..., :, 2:] - height[..., :, :-2]) * 0.5,
                    height[..., :, -1:] - height[..., :, -2:-1]], dim=-1)
    gy = torch.cat([height[..., 1:2, :] - height[..., :1, :],
                    (height[..., 2:, :] - height[..., :-2, :]) * 0.5,
                    height[..., -1:, :] - height[..., -2:-1, :]], dim=-2)
    return gx, gy


def height_to_normal(height, depth=DEFAULT_DEPTH, detail=None):
    """Unit normals (+Y up, z > 0) of a height map over the 2-unit surface.

    Central differences inside, one-sided differences on the border rows and
    columns (the maps need not tile; a linear ramp gives its exact slope
    everywhere). Same convention as :func:`export.data.cc0.normals_from_height`.

    Args:
        height: (B, 1, H, W) in [0, 1].
        depth: surface units of a full [0, 1] swing; float or (B,).
        detail: optional (B, 2, H, W) extra slopes (dh/dx, dh/dy in surface
            units) added before normalising.

    Returns:
        (B, 3, H, W) unit normals.
    """
    b, _, h, w = height.shape
    depth = torch.as_tensor(depth, device=height.device, dtype=height.dtype).reshape(-1, 1, 1, 1)
    span = 2.0 * cv.SURFACE_HALF_SIZE
    gcol, grow = _gradients(height)
    dx = gcol * depth / (span / w)
    dy = -grow * depth / (span / h)  # row index grows downward, world +Y is up
    if detail is not None:
        dx = dx + detail[:, :1]
        dy = dy + detail[:, 1:2]
    n = torch.cat([-dx, -dy, torch.ones_like(dx)], dim=1)
    return cv.normalize(n, axis=1)


def generate(family, generator, batch, size, device=None, dtype=torch.float32):
    """B random materials of one family, finished.

    Args:
        family: a key of :data:`FAMILIES`.
        generator: the only source of randomness (same seed, same device ->
            bit-identical maps).
        batch, size: B and H = W.
        device: where the maps are made; defaults to ``generator.device``.
        dtype: floating dtype of the maps.

    Returns:
        dict of (B, C, size, size) tensors: ``height``, ``normal``,
        ``diffuse``, ``roughness``, ``specular`` (linear, see the module
        docstring) and ``depth`` (B,).
    """
    known = {**FAMILIES, **EXTRA_FAMILIES}
    if family not in known:
        raise KeyError(f"unknown material family {family!r}; known: {sorted(known)}")
    device = generator.device if device is None else torch.device(device)
    raw = known[family](generator, batch, size, device, dtype)
    shape = (batch, 1, size, size)
    height = raw["height"].expand(shape).clamp(0.0, 1.0)
    depth = raw.get("depth", DEFAULT_DEPTH)
    depth = torch.as_tensor(depth, device=device, dtype=dtype).reshape(-1).expand(batch).contiguous()
    normal = height_to_normal(height, depth, raw.get("normal_detail"))
    # Nothing is perfectly white: albedo above 0.75 is compressed smoothly below 0.9.
    diffuse = raw["diffuse"].expand(batch, 3, size, size).clamp_min(0.0)
    diffuse = torch.where(diffuse > 0.75, 0.75 + 0.15 * torch.tanh((diffuse - 0.75) / 0.15), diffuse)
    roughness = raw["roughness"].expand(shape).clamp(0.04, 1.0)
    specular = raw["specular"].expand(batch, 3, size, size).clamp(0.0, 1.0)
    out = {"height": height.contiguous(), "normal": normal.contiguous(), "diffuse": diffuse.contiguous(),
           "roughness": roughness.contiguous(), "specular": specular.contiguous(), "depth": depth}
    for k, v in out.items():
        if not bool(torch.isfinite(v).all()):
            raise FloatingPointError(f"procedural family {family!r} produced non-finite {k}")
    return out


def random_materials(generator, batch, size, device=None, families=None, dtype=torch.float32, metal_fraction=None):
    """A batch of materials, each from a family drawn uniformly (or, with ``metal_fraction``, a metal
    family with that probability and otherwise a dielectric one, each uniformly).

    Args:
        generator: the only source of randomness.
        batch, size: B and H = W.
        device: defaults to ``generator.device``.
        families: names to draw from (default: all of :data:`FAMILIES`).
        dtype: floating dtype.

    Returns:
        the dict of :func:`generate` for the whole batch plus ``"family"``:
        the list of B family names.
    """
    names = list(FAMILIES) if families is None else list(families)
    if not names:
        raise ValueError("families is empty")
    for n in names:
        if n not in FAMILIES and n not in EXTRA_FAMILIES:
            raise KeyError(f"unknown material family {n!r}")
    device = generator.device if device is None else torch.device(device)
    if metal_fraction is None:
        pick = torch.randint(0, len(names), (batch,), generator=generator, device=generator.device).cpu().tolist()
    else:
        metal = torch.tensor([n in METAL_FAMILIES for n in names], dtype=torch.float64)
        if metal.sum() == 0 or metal.sum() == len(names):
            w = torch.ones(len(names), dtype=torch.float64)
        else:
            w = torch.where(metal > 0, metal_fraction / metal.sum(), (1 - metal_fraction) / (len(names) - metal.sum()))
        pick = torch.multinomial(w.to(generator.device).expand(batch, -1), 1, generator=generator)[:, 0].cpu().tolist()
    out = None
    for k, name in enumerate(names):
        idx = [i for i, p in enumerate(pick) if p == k]
        if not idx:
            continue
        part = generate(name, generator, len(idx), size, device=device, dtype=dtype)
        if out is None:
            out = {key: torch.empty((batch,) + tuple(v.shape[1:]), device=device, dtype=v.dtype)
                   for key, v in part.items()}
        index = torch.tensor(idx, device=device)
        for key, v in part.items():
            out[key][index] = v
    out["family"] = [names[p] for p in pick]
    return out
