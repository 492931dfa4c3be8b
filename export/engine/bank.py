"""The material bank: materials made once, stored on disk, reused by every run.

A bank is a folder of shards (``shard_00000.npz`` …) and ``manifest.json``. Each shard holds
``SHARD`` materials at ``SIZE``² as

* ``diffuse``, ``specular``: (N, S, S, 3) uint8, linear albedo stored with the albedo gamma
  (:func:`svbrdf_cli.conventions.encode_maps`' encoding);
* ``roughness``: (N, S, S) uint8, linear;
* ``normal``: (N, S, S, 2) int16, the unit normal's x and y (+Y up) times 32767; z is rebuilt;

and the manifest lists every shard with its materials' sources (``procedural:<family>``,
``cc0:<set>``, ``mix:<a>+<b>``). Three kinds of material:

* **procedural**: :func:`export.data.procedural.random_materials` (every family, 8 % metals);
* **cc0**: random crops (zoom, rotation, flip) of every CC0 set under ``../shared/data/materials``
  (:func:`export.data.cc0.load_all`), several per set;
* **mix**: two bank materials blended through a smooth random mask.

``python -m export.engine bank --count 8000`` grows the bank to at least that many materials
(appending shards, so an interrupted build keeps what it made); a training run grows it to its
``--bank-count`` before it starts. Training maps every shard from disk (:class:`Bank`, through one file
per map under ``flat/``).
"""

from __future__ import annotations

import json
import math
import os
import time

import numpy as np
import torch

from export.data import augment, procedural
from export.data.noise import luminance
from export.files import read_json, write_json
from svbrdf_cli import conventions as cv

SIZE = 256
SHARD = 64
VERSION = 1
#: Mix of kinds in a grown bank (the rest procedural).
CC0_FRACTION = 0.25
MIX_FRACTION = 0.2
#: A CC0 shard holds this many crops of each of its sets.
CC0_CROPS = 8
#: Mixes blend two materials of the first this many shards (a fixed set: a bank grown in several
#: sittings is the bank grown at once).
MIX_SOURCE_SHARDS = 32
#: Shards of prints and dyed patterns (:func:`export.data.procedural.printed`: colour edges without
#: relief), appended after the first 8000 materials so that a bank grown before them keeps its shards.
PRINT_SHARDS = range(125, 135)
#: Shards of dark glossy dielectrics (black plastics, lacquer, dark leather, stained wood: the
#: procedural families darkened and made glossier, :func:`_dark`), after the prints. Auto-exposed,
#: a black glossy dielectric and a dark metal look alike; with metals 8 % of the procedural materials
#: and dark glossy dielectrics few, the chain called a black phone case kept out of training metal.
DARK_SHARDS = range(135, 143)
#: Families a dark shard draws from, and the ranges of its factors on the diffuse and the roughness.
DARK_FAMILIES = ("plastic_paint", "leather", "wood", "marble", "tiles", "scales", "fabric", "paper")
DARK_ALBEDO = (0.03, 0.3)
DARK_GLOSS = (0.3, 0.9)
#: Shards of dark grey glossy dielectrics (black and grey plastics, rubber, grey paint: :func:`_grey`), after
#: the first 12032 materials. In those 12032, 717 grey metals stood against 652 dark grey dielectrics
#: glossier than 0.5, so a dark grey photo with a broad highlight was a metal half the time, and the
#: chain run as trained (no input margin) called 18 of 267 real photos metal, dark grey plastics and a
#: woven mat among them (``docs/training.md``, "The input's margin"). With these, 2199 against 717.
GREY_SHARDS = range(188, 220)
#: How much of its colour a grey shard's diffuse keeps at most (a factor uniform in [0, this]).
GREY_CHROMA = 0.35
#: Shards of metals with relief (gilding, embossed foil, hammered and cast metal: :func:`_relief_metal`), after
#: the first 17920 materials. The procedural metals are flat plates, dark but for the flash's spot, and the
#: chain learnt that look as a metal: on ``paper_real`` its F0 before the runtime reads it as a dielectric
#: (``infer/swift.read_as_dielectric``) was 0.49-0.53 on two dark grey plastics and 0.038-0.044 on the gilded
#: carvings, the bronze relief, the gold foil of a card and a gift bag, and the card's foil scales.
RELIEF_METAL_SHARDS = range(280, 300)
#: Families whose relief (normals) and pattern a relief-metal shard takes.
RELIEF_FAMILIES = ("cobblestones", "scales", "leather", "bark", "tiles", "bricks", "wood", "paper", "plastic_paint",
                   "marble")
#: Share of a relief-metal shard that is foil over a dielectric (the two blended through a random mask).
FOIL_SHARE = 0.5
#: A relief metal's roughness level (uniform), the factor on its relief's tilt (log-uniform) and how much its
#: F0 follows its family's pattern (tarnish in the crevices), either way.
RELIEF_METAL_ROUGHNESS = (0.2, 0.7)
RELIEF_METAL_TILT = (1.0, 2.0)
RELIEF_METAL_TARNISH = 0.3
#: Shards of surfaces with relief wider than their texture (:func:`_wavy`: corrugated and ribbed sheets, wavy
#: plastic, quilted and folded fabric), after the first 19200 materials. Every procedural family draws its
#: relief at the scale of its texture (a tile, a grain, a pore), and the chain read the corrugated metal sheet
#: of ``paper_real`` IMG_7303 flat, its ridges' highlights left in the diffuse and no bumpiness in ``M_b``,
#: where the paper's network draws the corrugation.
WAVY_SHARDS = range(300, 320)
#: Families a wavy shard draws its albedo, roughness, F0 and fine relief from, and the share of them metal.
WAVY_FAMILIES = ("brushed_metal", "metal_plate", "scratched_metal", "plastic_paint", "fabric", "leather", "paper",
                 "concrete", "wood")
WAVY_METAL_SHARE = 0.4
#: A wave's period, a share of the shard's width (log-uniform), and its steepest slope (uniform; 0.6 is 31
#: degrees); the profile's squareness (a sine at 1, corrugated flanks and flat crests above); the share of
#: materials with a second, weaker wave across the first (quilted, egg crate).
WAVY_PERIOD = (0.12, 0.5)
WAVY_SLOPE = (0.15, 0.6)
WAVY_SQUARENESS = (1.0, 3.0)
WAVY_CROSSED = 0.25
#: The factor (uniform) on a wavy material's own fine relief: a sheet's grain under its wave, not a stone's.
WAVY_OWN_RELIEF = (0.2, 0.6)
#: A relief metal is one of these with this probability (gilding, brass and copper foil), else any metal.
WARM_METALS = ("gold", "copper", "brass", "bronze")
WARM_SHARE = 0.5
#: Probability that a procedural material is a metal (real captures: about 12 % metals, with the CC0 sets).
METAL_FRACTION = 0.08


def default_root():
    """``$SVBRDF_BANK`` or ``~/.cache/svbrdf/bank``: the bank is rebuilt when absent, never committed."""
    return os.environ.get("SVBRDF_BANK") or os.path.join(os.path.expanduser("~"), ".cache", "svbrdf", "bank")


def encode(maps):
    """Linear float maps (B, C, S, S) -> dict of the shard's numpy arrays (see the module docstring)."""
    def u8(x):
        return (x.clamp(0, 1) * 255).round().to(torch.uint8).permute(0, 2, 3, 1).numpy()

    n = cv.normalize(maps["normal"], axis=1)
    return {
        "diffuse": u8(maps["diffuse"].clamp(0, 1) ** (1 / cv.ALBEDO_GAMMA)),
        "specular": u8(maps["specular"].clamp(0, 1) ** (1 / cv.ALBEDO_GAMMA)),
        "roughness": u8(maps["roughness"])[..., 0],
        "normal": (n[:, :2] * 32767).round().clamp(-32767, 32767).to(torch.int16).permute(0, 2, 3, 1).numpy(),
    }


def decode_stored(arrays, dtype=torch.float32):
    """The shard arrays (numpy or torch, any leading batch) -> maps (B, C, S, S) with diffuse and
    specular still in the stored encoding (resample these, then :func:`linearize`: 4x fewer powers)."""
    def t(x):
        return torch.as_tensor(x)

    xy = t(arrays["normal"]).permute(0, 3, 1, 2).to(dtype) / 32767
    z = (1 - (xy * xy).sum(1, keepdim=True)).clamp_min(1e-6).sqrt()
    return {"normal": torch.cat([xy, z], 1),
            "diffuse": t(arrays["diffuse"]).permute(0, 3, 1, 2).to(dtype) / 255,
            "roughness": t(arrays["roughness"]).unsqueeze(1).to(dtype) / 255,
            "specular": t(arrays["specular"]).permute(0, 3, 1, 2).to(dtype) / 255}


def linearize(maps):
    """:func:`decode_stored`'s maps (resampled or not) -> linear maps, unit normals."""
    return {"normal": cv.normalize(maps["normal"], axis=1), "diffuse": maps["diffuse"] ** cv.ALBEDO_GAMMA,
            "roughness": maps["roughness"], "specular": maps["specular"] ** cv.ALBEDO_GAMMA}


def decode(arrays, dtype=torch.float32):
    """The shard arrays (numpy or torch, any leading batch) -> linear maps (B, C, S, S)."""
    return linearize(decode_stored(arrays, dtype))


def read_manifest(root):
    path = os.path.join(root, "manifest.json")
    if not os.path.isfile(path):
        return {"version": VERSION, "size": SIZE, "shards": []}
    with open(path) as f:
        m = json.load(f)
    if m.get("version") != VERSION or m.get("size") != SIZE:
        raise ValueError(f"{root}: a bank of another version or size; move it away or set SVBRDF_BANK")
    return m


def _write_manifest(root, manifest):
    tmp = os.path.join(root, "manifest.json.tmp")
    with open(tmp, "w") as f:
        json.dump(manifest, f, indent=1)
    os.replace(tmp, os.path.join(root, "manifest.json"))


def count(root):
    """Materials the bank at ``root`` holds (0 when absent)."""
    return sum(s["count"] for s in read_manifest(root)["shards"])


def _procedural(g, n):
    m = procedural.random_materials(g, n, SIZE, device="cpu", metal_fraction=METAL_FRACTION)
    return {k: m[k] for k in cv.MAP_NAMES}, [f"procedural:{f}" for f in m["family"]]


class _Cc0Source:
    """Random crops of the CC0 sets, one set in memory at a time."""

    def __init__(self, shared):
        from export.data import cc0

        self.folders = cc0.all_folders(shared)
        self.cc0 = cc0

    def __bool__(self):
        return bool(self.folders)

    def draw(self, g, n, per_set=CC0_CROPS):
        """``n`` crops, ``per_set`` from each of ``n / per_set`` random sets (None: no set loads)."""
        parts, names = [], []
        while len(names) < n:
            loader, folder = self.folders[int(torch.randint(0, len(self.folders), (1,), generator=g))]
            try:
                m = loader(folder, size=1024)
            except (FileNotFoundError, ValueError):
                continue
            k = min(per_set, n - len(names))
            maps = {key: torch.from_numpy(np.ascontiguousarray(np.moveaxis(m[key], -1, 0)))[None]
                    .expand(k, -1, -1, -1).contiguous() for key in cv.MAP_NAMES}
            parts.append(augment.random_geometry(maps, g, SIZE, scale=(0.25, 1.0)))
            names += [f"cc0:{os.path.basename(folder)}"] * k
        return {key: torch.cat([p[key] for p in parts]) for key in cv.MAP_NAMES}, names


def log_uniform(g, n, low, high):
    """(n,) factors drawn log-uniformly in [low, high] from ``g``."""
    return torch.exp(math.log(low) + torch.rand(n, generator=g) * math.log(high / low))


def uniform(g, n, low, high):
    """(n,) factors drawn uniformly in [low, high] from ``g``."""
    return low + torch.rand(n, generator=g) * (high - low)


def _dark(g, n):
    """``n`` dark glossy dielectrics: procedural materials of :data:`DARK_FAMILIES` (F0 at most 0.08) with
    the diffuse times a factor log-uniform in :data:`DARK_ALBEDO` and the roughness times one uniform in
    :data:`DARK_GLOSS`."""
    m = procedural.random_materials(g, n, SIZE, device="cpu", families=DARK_FAMILIES)
    k = log_uniform(g, n, *DARK_ALBEDO)
    r = uniform(g, n, *DARK_GLOSS)
    maps = {k_: m[k_] for k_ in cv.MAP_NAMES}
    maps["diffuse"] = maps["diffuse"] * k.reshape(-1, 1, 1, 1)
    maps["roughness"] = (maps["roughness"] * r.reshape(-1, 1, 1, 1)).clamp(0.04, 1.0)
    maps["specular"] = maps["specular"].clamp(max=0.08)  # a painted metal's chips too: dielectric only
    return maps, [f"dark:{f}" for f in m["family"]]


def _grey(g, n):
    """``n`` dark grey glossy dielectrics: :func:`_dark`'s materials with their diffuse's colour mostly
    taken off (each keeps a share uniform in [0, :data:`GREY_CHROMA`] of its difference from its
    luminance) and a grey F0 (the luminance of theirs)."""
    maps, sources = _dark(g, n)
    d = maps["diffuse"]
    lum = luminance(d)
    keep = (torch.rand(n, generator=g) * GREY_CHROMA).reshape(-1, 1, 1, 1)
    maps["diffuse"] = (lum + keep * (d - lum)).clamp(0.0, 1.0)
    maps["specular"] = luminance(maps["specular"]).expand_as(d).clone()
    return maps, ["grey:" + x.split(":", 1)[1] for x in sources]


def _relief_metal(g, n):
    """``n`` metals with relief: procedural materials of :data:`RELIEF_FAMILIES` made metal (a metal's F0 of
    :data:`export.data.procedural.METAL_F0`, one of :data:`WARM_METALS` with :data:`WARM_SHARE`, times their pattern's brightness within
    :data:`RELIEF_METAL_TARNISH` either way, their diffuse times 0.02, their roughness's pattern at a level
    uniform in :data:`RELIEF_METAL_ROUGHNESS`, their tilt times a factor in :data:`RELIEF_METAL_TILT`); the
    first :data:`FOIL_SHARE` of them blended over a procedural dielectric through a random mask (foil)."""
    m = procedural.random_materials(g, n, SIZE, device="cpu", families=RELIEF_FAMILIES)
    names = list(procedural.METAL_F0)
    pal = torch.tensor([procedural.METAL_F0[k] for k in names], dtype=torch.float32)
    warm = torch.tensor([names.index(k) for k in WARM_METALS])
    pick = torch.where(torch.rand(n, generator=g) < WARM_SHARE, warm[torch.randint(0, len(warm), (n,), generator=g)],
                       torch.randint(0, len(pal), (n,), generator=g))
    colour = pal[pick].reshape(n, 3, 1, 1)
    lum = luminance(m["diffuse"])
    pattern = (lum / lum.mean((2, 3), keepdim=True).clamp_min(1e-4)).clamp(0.0, 2.0) - 1.0
    specular = (colour * (1.0 + RELIEF_METAL_TARNISH * pattern)).clamp(0.3, 0.98)
    r = m["roughness"]
    level = uniform(g, n, *RELIEF_METAL_ROUGHNESS)
    roughness = (level.reshape(-1, 1, 1, 1) * (r / r.mean((2, 3), keepdim=True).clamp_min(1e-4)).sqrt()).clamp(0.06, 1.0)
    k = log_uniform(g, n, *RELIEF_METAL_TILT).reshape(-1, 1, 1, 1)
    normal = cv.normalize(torch.cat([m["normal"][:, :2] * k, m["normal"][:, 2:]], 1), axis=1)
    maps = {"normal": normal, "diffuse": m["diffuse"] * 0.02, "roughness": roughness, "specular": specular}
    sources = [f"relief_metal:{f}" for f in m["family"]]
    foil = int(round(FOIL_SHARE * n))
    if foil:
        d = procedural.random_materials(g, foil, SIZE, device="cpu", metal_fraction=0.0)
        over = augment.blend({k_: d[k_] for k_ in cv.MAP_NAMES}, {k_: v[:foil] for k_, v in maps.items()},
                             _blend_masks(g, foil))
        maps = {k_: torch.cat([over[k_], maps[k_][foil:]]) for k_ in cv.MAP_NAMES}
        sources = [f"foil:{a.split(':', 1)[1]}+{b}" for a, b in zip(sources[:foil], d["family"])] + sources[foil:]
    return maps, sources


def wave_slopes(g, n, size=SIZE):
    """(n, 2, size, size) slopes (dh/dx, dh/dy) of one wave each across a square of ``size`` px: a direction
    uniform on the circle, a period of :data:`WAVY_PERIOD` of the width, a phase, a profile from a sine to
    corrugated flanks (``clamp(k sin, -1, 1)``, ``k`` in :data:`WAVY_SQUARENESS`), scaled so that its steepest
    slope is one of :data:`WAVY_SLOPE`."""
    theta = uniform(g, n, 0.0, 2.0 * math.pi).reshape(-1, 1, 1)
    period = (log_uniform(g, n, *WAVY_PERIOD) * size).reshape(-1, 1, 1)
    phase = uniform(g, n, 0.0, 2.0 * math.pi).reshape(-1, 1, 1)
    k = uniform(g, n, *WAVY_SQUARENESS).reshape(-1, 1, 1)
    steepest = uniform(g, n, *WAVY_SLOPE).reshape(-1, 1, 1)
    y, x = torch.meshgrid(torch.arange(size, dtype=torch.float32), torch.arange(size, dtype=torch.float32), indexing="ij")
    t = 2.0 * math.pi * (x * theta.cos() + y * theta.sin()) / period + phase
    slope = torch.where((k * t.sin()).abs() < 1.0, k * t.cos(), torch.zeros_like(t)) / k  # h = clamp(k sin t) / k
    slope = slope * steepest / slope.abs().amax((1, 2), keepdim=True).clamp_min(1e-6)
    return torch.stack([slope * theta.cos(), slope * theta.sin()], 1)


def _wavy(g, n):
    """``n`` materials of :data:`WAVY_FAMILIES` (:data:`WAVY_METAL_SHARE` metal) on a wave (:func:`wave_slopes`),
    :data:`WAVY_CROSSED` of them with a second across it at half the slope: the wave's tilt added to each
    material's own fine relief (times :data:`WAVY_OWN_RELIEF`); albedo, roughness and F0 as the family draws
    them."""
    m = procedural.random_materials(g, n, SIZE, device="cpu", families=WAVY_FAMILIES, metal_fraction=WAVY_METAL_SHARE)
    slopes = wave_slopes(g, n)
    crossed = (torch.rand(n, generator=g) < WAVY_CROSSED).float().reshape(-1, 1, 1, 1)
    slopes = slopes + 0.5 * crossed * wave_slopes(g, n)
    own = uniform(g, n, *WAVY_OWN_RELIEF).reshape(-1, 1, 1, 1)
    tilt = own * m["normal"][:, :2] / m["normal"][:, 2:].clamp_min(1e-3) + slopes  # (a wave's sign is its phase's)
    normal = cv.normalize(torch.cat([tilt, torch.ones_like(tilt[:, :1])], 1), axis=1)
    maps = {k_: m[k_] for k_ in cv.MAP_NAMES}
    maps["normal"] = normal
    return maps, [f"wavy:{f}" for f in m["family"]]


def _blend_masks(g, n):
    from export.data.dataset import blend_mask

    return blend_mask(g, n, SIZE, "cpu", torch.float32)


def grow(root=None, target=8000, seed=0, shared=None, progress=print):
    """Append shards until the bank holds at least ``target`` materials; returns the count.

    Every shard draws from a generator seeded with (``seed``, shard index), so a bank grown in
    several sittings is the bank grown at once.
    """
    root = root or default_root()
    os.makedirs(root, exist_ok=True)
    manifest = read_manifest(root)
    have = sum(s["count"] for s in manifest["shards"])
    cc0_source = None
    mix_bank = None
    t0 = time.time()
    while have < target:
        index = len(manifest["shards"])
        g = torch.Generator().manual_seed(seed * 1_000_003 + index)
        u = float(torch.rand(1, generator=g))
        kind = "procedural"
        if index in PRINT_SHARDS:
            kind = "print"
        elif index in DARK_SHARDS:
            kind = "dark"
        elif index in GREY_SHARDS:
            kind = "grey"
        elif index in RELIEF_METAL_SHARDS:
            kind = "relief_metal"
        elif index in WAVY_SHARDS:
            kind = "wavy"
        elif u < CC0_FRACTION:
            if cc0_source is None:
                cc0_source = _Cc0Source(shared)
            kind = "cc0" if cc0_source else "procedural"
        elif u < CC0_FRACTION + MIX_FRACTION and index >= MIX_SOURCE_SHARDS:
            kind = "mix"
        drawn = None
        if kind == "dark":
            drawn = _dark(g, SHARD)
        elif kind == "grey":
            drawn = _grey(g, SHARD)
        elif kind == "relief_metal":
            drawn = _relief_metal(g, SHARD)
        elif kind == "wavy":
            drawn = _wavy(g, SHARD)
        elif kind == "print":
            m = procedural.random_materials(g, SHARD, SIZE, device="cpu", families=["printed"])
            drawn = {k: m[k] for k in cv.MAP_NAMES}, [f"print:{f}" for f in m["family"]]
        elif kind == "cc0":
            drawn = cc0_source.draw(g, SHARD)
        elif kind == "mix":
            mix_bank = mix_bank or Bank(root, limit_shards=MIX_SOURCE_SHARDS)
            a, b = mix_bank.draw_whole(g, SHARD), mix_bank.draw_whole(g, SHARD)
            maps = augment.blend(a[0], b[0], _blend_masks(g, SHARD))
            maps["normal"] = cv.normalize(maps["normal"], axis=1)
            drawn = ({k: maps[k] for k in cv.MAP_NAMES}, [f"mix:{x}+{y}" for x, y in zip(a[1], b[1])])
        if drawn is None:
            kind = "procedural"
            drawn = _procedural(g, SHARD)
        maps, sources = drawn
        name = f"shard_{index:05d}.npz"
        tmp = os.path.join(root, name + ".tmp.npz")
        np.savez(tmp, **encode(maps))
        os.replace(tmp, os.path.join(root, name))
        manifest["shards"].append({"file": name, "count": SHARD, "kind": kind, "sources": sources})
        _write_manifest(root, manifest)
        have += SHARD
        if progress:
            progress(f"bank: {have} materials ({kind} shard {index}, {time.time() - t0:.0f} s)")
    return have


#: The maps a shard holds, in the order :func:`flat_arrays` writes them.
MAPS = ("diffuse", "specular", "roughness", "normal")
#: The folder under the bank where :func:`flat_arrays` keeps every shard's maps end to end.
FLAT = "flat"


def flat_arrays(root, shards):
    """The maps of ``shards`` (the manifest's first shards, in order) as arrays mapped from disk,
    name -> (N, S, S[, C]), from one uncompressed ``.npy`` per map under ``root/flat/`` that holds every
    shard of the manifest end to end (written on first use, and again when the bank has grown).

    Mapped, not read into memory: the bank (19200 materials: 13 GB) is the page cache's, which the
    kernel takes back when another process needs the memory, where as a process's own memory the run
    held 14.5 GB and the kernel killed it when an evaluation beside it took 9 GB more."""
    folder = os.path.join(root, FLAT)
    want = [s["file"] for s in shards]
    have = read_json(os.path.join(folder, "flat.json"))
    if have.get("shards", [])[:len(want)] != want:
        have = _write_flat(root, folder)
    total = sum(have["counts"][:len(want)])
    # copy-on-write mapping: writable for torch, and nothing is ever written to it
    return {k: np.load(os.path.join(folder, f"{k}.npy"), mmap_mode="c")[:total] for k in MAPS}


def _write_flat(root, folder):
    """Every shard of the manifest under ``root`` end to end into ``folder`` (:func:`flat_arrays`), each
    shard read once; returns what ``flat.json`` records (the shards and their counts), written last."""
    shards = read_manifest(root)["shards"]
    os.makedirs(folder, exist_ok=True)
    info = os.path.join(folder, "flat.json")
    if os.path.exists(info):
        os.remove(info)  # (a write cut short leaves no record that its files are whole)
    counts = [len(s["sources"]) for s in shards]
    tmp = {k: os.path.join(folder, f"{k}.{os.getpid()}.tmp.npy") for k in MAPS}
    out, at = {}, 0
    try:
        for s, n in zip(shards, counts):
            with np.load(os.path.join(root, s["file"])) as z:
                for k in MAPS:
                    part = z[k]
                    if k not in out:
                        out[k] = np.lib.format.open_memmap(tmp[k], mode="w+", dtype=part.dtype,
                                                           shape=(sum(counts),) + part.shape[1:])
                    out[k][at:at + n] = part
            at += n
        for k in MAPS:
            out.pop(k).flush()
            os.replace(tmp[k], os.path.join(folder, f"{k}.npy"))
    finally:
        out.clear()
        for path in tmp.values():
            if os.path.exists(path):
                os.remove(path)
    record = {"shards": [s["file"] for s in shards], "counts": counts}
    write_json(info, record)
    return record


class Bank:
    """Every shard of a bank as uint8/int16 tensors (about 11 bytes a pixel), mapped from disk
    (:func:`flat_arrays`)."""

    def __init__(self, root=None, limit_shards=None):
        root = root or default_root()
        manifest = read_manifest(root)
        shards = manifest["shards"][:limit_shards] if limit_shards is not None else manifest["shards"]
        if not shards:
            raise FileNotFoundError(f"{root}: the material bank is empty; grow it with "
                                    "`python -m export.engine bank --count 8000`")
        self.arrays = {k: torch.from_numpy(v) for k, v in flat_arrays(root, shards).items()}
        self.sources = [src for s in shards for src in s["sources"]]
        #: (N,) bool: the materials scanned from real ones (the CC0 sets), not made procedurally.
        self.scanned = torch.tensor([s.startswith("cc0:") for s in self.sources], dtype=torch.bool)
        self.root = root

    def __len__(self):
        return len(self.sources)

    def maps(self, index, dtype=torch.float32):
        """Linear maps (B, C, S, S) of the materials at ``index`` (a (B,) tensor)."""
        return decode({k: v[index] for k, v in self.arrays.items()}, dtype)

    def stored(self, index, dtype=torch.float32):
        """:func:`decode_stored` maps of the materials at ``index``."""
        return decode_stored({k: v[index] for k, v in self.arrays.items()}, dtype)

    def draw_whole(self, g, n):
        idx = torch.randint(0, len(self), (n,), generator=g)
        return self.maps(idx), [self.sources[i] for i in idx.tolist()]
