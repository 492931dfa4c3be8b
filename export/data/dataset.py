"""Training samples: materials -> simulated flash photo + every ground truth.

One sample holds the network input ``photo`` (the simulated capture, see
:mod:`export.data.simulate`), the clean flash image ``I``, the paper's
intermediate targets (``I_bf``, ``I_hr``, ``I_hr2``, ``M_b``, ``M_h``, all
rendered from the clean maps with the capture's geometry and exposure) and
the linear maps ``normal``, ``diffuse``, ``roughness``, ``specular``.

Materials come from the procedural generator (:mod:`export.data.procedural`)
and, where ``../shared/data/materials`` is present, from the CC0 seed maps
(:mod:`export.data.cc0`), randomly cropped, zoomed, rotated and flipped; a
fraction are mixtures of two materials, and all get a colour jitter
(:mod:`export.data.augment`).

Two ways to deliver them:

* :func:`make_batch` with a :func:`worker_generator`: batches on the fly, on
  the CPU or directly on a GPU (what training uses);
* :func:`write_shards` / :class:`Shards`: fixed, reproducible sets on disk
  (8-bit, stored encoding) for validation.
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
import os

import numpy as np
import torch
import torch.nn.functional as F

from export.data import augment, procedural, simulate
from export.files import atomic_write, read_json, shared_data, write_json
from export.render import targets as render_targets
from svbrdf_cli import conventions as cv

#: Ground-truth images besides ``I`` (which the simulator makes).
AUX_NAMES = ("I_bf", "I_hr", "I_hr2", "M_b", "M_h")
#: Everything a sample holds, in shard order (maps in their stored encoding there).
SAMPLE_NAMES = ("photo", "I") + AUX_NAMES + cv.MAP_NAMES


@dataclasses.dataclass(frozen=True)
class DataConfig:
    """What :func:`make_batch` makes."""

    size: int = 256
    #: Fraction of materials taken from the CC0 seeds when they are available.
    seed_fraction: float = 0.2
    #: Fraction of materials that are a mix of two.
    mix_fraction: float = 0.25
    #: Zoom range for seed crops (window width / seed width).
    seed_scale: tuple = (0.3, 1.0)
    #: Procedural families to draw from (``None``: all).
    families: tuple | None = None
    #: Probability that a procedural material is a metal. Real captures are mostly dielectric:
    #: 9 of the 77 labelled real flash-photo materials (../shared/data/real/henzler_train) are
    #: metal (12 %); the CC0 seeds add about 5 points (6 of their 25 are metals), so 0.08 here
    #: gives about 12 % metals in all. ``None``: families uniformly (4 of 18 are metals).
    metal_fraction: float | None = 0.08
    capture: simulate.CaptureRanges = simulate.DEFAULT_RANGES
    #: Which of :data:`AUX_NAMES` to render (I_hr and I_hr2 cost the most).
    targets: tuple = AUX_NAMES


class SeedBank:
    """CC0 seed materials held in memory as (N, C, S, S) tensors."""

    def __init__(self, root, size=512, device="cpu"):
        from export.data.cc0 import load_seeds

        self.names, maps = load_seeds(root, size=size)
        self.maps = {k: torch.from_numpy(v).to(device) for k, v in maps.items()}

    @classmethod
    def find(cls, root=None, size=512, device="cpu"):
        """The seed bank of the shared data folder (default ``../shared/data``),
        or ``None`` when it has no ``materials/`` (a user's fresh clone)."""
        root = shared_data(root)
        if not os.path.isdir(os.path.join(root, "materials")):
            return None
        return cls(root, size=size, device=device)

    def __len__(self):
        return len(self.names)

    def sample(self, g, batch, size, scale=(0.3, 1.0)):
        """Random crops (zoom, any rotation, flip) of random seeds; (B, C, size, size) each."""
        idx = torch.randint(0, len(self.names), (batch,), generator=g, device=g.device).cpu()
        picked = {k: v[idx.to(v.device)] for k, v in self.maps.items()}
        out = augment.random_geometry(picked, g, size, scale=scale)
        out["source"] = [f"cc0:{self.names[i]}" for i in idx.tolist()]
        return out


def blend_mask(g, batch, size, device, dtype):
    """Smooth random (B, 1, H, W) masks in [0, 1]: thresholded low-frequency noise."""
    cells = int(torch.randint(2, 7, (1,), generator=g, device=g.device))
    noise = torch.rand(batch, 1, cells + 3, cells + 3, generator=g, device=g.device).to(device=device, dtype=dtype)
    field = F.interpolate(noise, size=(size + 2 * size // cells,) * 2, mode="bicubic", align_corners=False)
    off = size // cells
    field = field[..., off:off + size, off:off + size]
    threshold = torch.rand(batch, 1, 1, 1, generator=g, device=g.device).to(field) * 0.6 + 0.2
    sharp = torch.rand(batch, 1, 1, 1, generator=g, device=g.device).to(field) * 40 + 5
    return torch.sigmoid((field - threshold) * sharp)


def _choose(mask, a, b):
    """Per-sample choice between two map dicts (``mask`` (B,) True: ``b``)."""
    m = mask.reshape(-1, 1, 1, 1)
    return {k: torch.where(m, b[k], a[k]) for k in cv.MAP_NAMES}


def materials(g, batch, config=DataConfig(), seeds=None, device=None, dtype=torch.float32):
    """A batch of linear map sets (dict of (B, C, H, W)) plus ``source`` names."""
    device = torch.device(device) if device is not None else g.device
    size = config.size

    def draw(n):
        m = procedural.random_materials(g, n, size, device=device, families=config.families, dtype=dtype,
                                        metal_fraction=config.metal_fraction)
        source = [f"procedural:{f}" for f in m["family"]]
        m = {k: m[k] for k in cv.MAP_NAMES}
        if seeds is not None and len(seeds) and config.seed_fraction > 0:
            use = torch.rand(n, generator=g, device=g.device) < config.seed_fraction
            if bool(use.any()):
                s = seeds.sample(g, n, size, config.seed_scale)
                m = _choose(use.to(device), m, {k: s[k].to(device=device, dtype=dtype) for k in cv.MAP_NAMES})
                source = [b if u else a for a, b, u in zip(source, s["source"], use.tolist())]
        return m, source

    maps, source = draw(batch)
    mix = torch.rand(batch, generator=g, device=g.device) < config.mix_fraction
    if bool(mix.any()):
        other, other_source = draw(batch)
        mixed = augment.blend(maps, other, blend_mask(g, batch, size, device, dtype))
        maps = _choose(mix.to(device), maps, mixed)
        source = [f"{a}+{b}" if m else a for a, b, m in zip(source, other_source, mix.tolist())]
    k = torch.randint(0, 4, (1,), generator=g, device=g.device).item()
    maps = augment.rot90(maps, k)
    maps = augment.jitter_colour(maps, g)
    maps["roughness"] = maps["roughness"].clamp(0.0, 1.0)
    maps["source"] = source
    return maps


def make_batch(g, batch, config=DataConfig(), seeds=None, device=None, dtype=torch.float32):
    """One batch of training samples.

    Args:
        g: ``torch.Generator``; every random choice comes from it, so a seed
            fixes the batch (on a given device).
        batch: number of samples.
        config: :class:`DataConfig`.
        seeds: optional :class:`SeedBank`.
        device: where to compute (default: the generator's device).

    Returns:
        dict: ``photo``, ``I`` and :data:`AUX_NAMES` (B, 3, H, W) encoded
        images in [0, 1]; linear maps (keys of ``MAP_NAMES``); ``capture``
        (the simulator's parameters); ``intensity`` (B,) the flash intensity the photo was
        taken with (auto exposure's, or the fixed power); ``source`` (B names).
    """
    maps = materials(g, batch, config, seeds, device, dtype)
    capture = simulate.sample_capture(g, batch, config.capture)
    shot = simulate.photograph(maps, capture, g)
    with torch.no_grad():
        aux = render_targets.intermediate_targets(maps, light=capture["light"].to(dtype), intensity=shot["intensity"],
                                     names=config.targets, camera=capture["camera"].to(dtype))
    out = {"photo": shot["photo"], "I": shot["I"], "intensity": shot["intensity"], **aux}
    out.update({k: maps[k] for k in cv.MAP_NAMES})
    out["capture"] = capture
    out["source"] = maps["source"]
    return out


def worker_generator(seed, stream, device="cpu"):
    """A generator for stream ``stream`` (worker, rank, epoch...) of ``seed``."""
    g = torch.Generator(device=device)
    g.manual_seed((int(seed) * 1_000_003 + int(stream)) % (2 ** 63))
    return g


# --------------------------------------------------------------------------
# Shards
# --------------------------------------------------------------------------

def _to_uint8(x):
    return (x.detach().clamp(0, 1) * 255).round().to(torch.uint8).cpu().numpy()


def encode_sample_arrays(batch):
    """A batch -> dict of uint8 NCHW arrays: images as they are, maps in their stored encoding."""
    stored = cv.encode_maps({k: batch[k] for k in cv.MAP_NAMES})
    return {k: _to_uint8(stored[k] if k in stored else batch[k]) for k in SAMPLE_NAMES if k in batch}


def decode_sample_arrays(arrays):
    """Inverse of :func:`encode_sample_arrays` -> float32 tensors, maps linear."""
    t = {k: torch.from_numpy(v).float() / 255 for k, v in arrays.items()}
    if all(k in t for k in cv.MAP_NAMES):
        t.update(cv.decode_maps({k: t[k] for k in cv.MAP_NAMES}, axis=1))
    return t


def write_shards(out_dir, count, seed=0, shard_size=64, config=DataConfig(), seeds_root=None, progress=True):
    """Write ``count`` samples as ``shard-NNNNN.npz`` plus ``manifest.json``.

    Each shard is generated from its own stream of ``seed`` (so any shard can
    be regenerated alone) and written atomically; shards already present with
    the same manifest are kept, so an interrupted run resumes.
    """
    from tqdm import tqdm

    os.makedirs(out_dir, exist_ok=True)
    bank = SeedBank.find(seeds_root) if seeds_root else None
    manifest = {"count": count, "seed": seed, "shard_size": shard_size, "config": config_dict(config),
                "conventions": cv.CONVENTIONS_VERSION, "seeds": bank.names if bank else [],
                "arrays": {k: "uint8 NCHW; maps in stored encoding" for k in SAMPLE_NAMES}}
    mpath = os.path.join(out_dir, "manifest.json")
    old = read_json(mpath)
    if old and old != manifest:
        raise FileExistsError(f"{out_dir}: holds shards made with other settings; use an empty folder")
    write_json(mpath, manifest)
    n_shards = math.ceil(count / shard_size)
    bar = tqdm(total=count, unit="sample", disable=not progress, desc="shards")
    for i in range(n_shards):
        n = min(shard_size, count - i * shard_size)
        path = os.path.join(out_dir, f"shard-{i:05d}.npz")
        if not os.path.exists(path):
            g = worker_generator(seed, 1_000 + i)
            arrays = encode_sample_arrays(make_batch(g, n, config, bank))
            buf = io.BytesIO()
            np.savez_compressed(buf, **arrays)
            atomic_write(path, buf.getvalue())
        bar.update(n)
    bar.close()
    return n_shards


def config_dict(config):
    """A :class:`DataConfig` as plain JSON values (tuples as lists), for manifests and provenance."""
    d = dataclasses.asdict(config)
    return json.loads(json.dumps(d, default=list))


class Shards(torch.utils.data.Dataset):
    """Samples read back from :func:`write_shards` (float32, maps linear)."""

    def __init__(self, folder):
        self.files = sorted(os.path.join(folder, f) for f in os.listdir(folder)
                            if f.startswith("shard-") and f.endswith(".npz"))
        if not self.files:
            raise FileNotFoundError(f"{folder}: no shard-*.npz files")
        # Shard sizes from the manifest: reading them from the files would decompress every shard.
        m = read_json(os.path.join(folder, "manifest.json"))
        self._sizes = [min(m["shard_size"], m["count"] - int(os.path.basename(f)[6:11]) * m["shard_size"])
                       for f in self.files]
        self._cache = (None, None)

    def __len__(self):
        return sum(self._sizes)

    def __getitem__(self, i):
        for f, n in zip(self.files, self._sizes):
            if i < n:
                if self._cache[0] != f:
                    with np.load(f) as z:
                        self._cache = (f, decode_sample_arrays({k: z[k] for k in z.files}))
                return {k: v[i] for k, v in self._cache[1].items()}
            i -= n
        raise IndexError(i)
