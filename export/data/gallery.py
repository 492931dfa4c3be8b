"""``docs/figures/materials.png``: generated materials as a grid of tiles.

One column per procedural family (plus CC0-seed crops and mixtures when the
seeds are present); rows: simulated photo, clean flash image, then the maps
in their stored encoding. When ``../shared/data/real`` is present a second
figure, ``<name>_vs_real.png``, puts real flash photos under the simulated
ones at the same scale for side-by-side judgement. That one holds
third-party photos, so it is written but never committed (``.gitignore``).
"""

from __future__ import annotations

import os

import numpy as np
import torch

from export.data import dataset
from export.data import procedural, simulate
from svbrdf_cli import conventions as cv

ROWS = ("photo", "I", "normal", "diffuse", "roughness", "specular")
TILE = 128
COLUMNS = 8
LABEL = 18


def _tiles(batch):
    """Batch -> {row: list of (TILE, TILE, 3) float arrays}."""
    stored = cv.encode_maps({k: batch[k] for k in cv.MAP_NAMES})
    out = {}
    for row in ROWS:
        x = stored[row] if row in stored else batch[row]
        x = x.expand(-1, 3, -1, -1) if x.shape[1] == 1 else x
        x = torch.nn.functional.interpolate(x.float(), size=(TILE, TILE), mode="area")
        out[row] = list(x.permute(0, 2, 3, 1).clamp(0, 1).numpy())
    return out


def _label(img, text, x, y, scale=0.45):
    import cv2

    u8 = (img * 255).astype(np.uint8)
    cv2.putText(u8, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), 1, cv2.LINE_AA)
    img[:] = u8.astype(np.float32) / 255


def _sheet(columns, rows, names, row_names):
    w = LABEL * 5 + len(columns) * TILE
    h = LABEL + len(rows) * TILE
    img = np.zeros((h, w, 3), np.float32)
    for j, col in enumerate(columns):
        x0 = LABEL * 5 + j * TILE
        for i, row in enumerate(rows):
            img[LABEL + i * TILE:LABEL + (i + 1) * TILE, x0:x0 + TILE] = col[row]
    for j, name in enumerate(names):
        _label(img, name[:15], LABEL * 5 + j * TILE + 3, LABEL - 5, 0.4)
    for i, name in enumerate(row_names):
        _label(img, name, 3, LABEL + i * TILE + TILE // 2)
    return img


def _bands(columns, rows, names, row_names, per_band=COLUMNS):
    """:func:`_sheet` wrapped into bands of ``per_band`` columns, stacked."""
    bands = []
    for i in range(0, len(columns), per_band):
        cols, labels = columns[i:i + per_band], names[i:i + per_band]
        pad = per_band - len(cols)
        blank = {r: np.zeros((TILE, TILE, 3), np.float32) for r in rows}
        bands.append(_sheet(cols + [blank] * pad, rows, labels + [""] * pad, row_names))
    return np.concatenate(bands, 0)


def generated_columns(seed=0, bank=None, size=256):
    """One sample per family, then seed crops and mixtures; list of (name, tiles)."""
    g = dataset.worker_generator(seed, 0)
    cols = []
    for name in procedural.FAMILIES:
        m = procedural.generate(name, g, 1, size)
        maps = {k: m[k] for k in cv.MAP_NAMES}
        cap = simulate.sample_capture(g, 1)
        shot = simulate.photograph(maps, cap, g)
        batch = {**maps, "photo": shot["photo"], "I": shot["I"]}
        cols.append((name, {k: v[0] for k, v in _tiles(batch).items()}))
    extra = []
    if bank is not None and len(bank):
        cfg = dataset.DataConfig(size=size, seed_fraction=1.0, mix_fraction=0.0, targets=())
        extra.append(("CC0 crop", dataset.make_batch(g, 2, cfg, bank)))
    cfg = dataset.DataConfig(size=size, seed_fraction=0.2 if bank else 0.0, mix_fraction=1.0, targets=())
    extra.append(("mixture", dataset.make_batch(g, 2, cfg, bank)))
    for label, b in extra:
        t = _tiles(b)
        for i in range(b["photo"].shape[0]):
            cols.append((label, {k: v[i] for k, v in t.items()}))
    return cols


def real_columns(count, real_dir):
    """Real flash photos (a spread over the sets), or [] without the shared data."""
    from export.data.realism import load_real_photos

    real = load_real_photos(real_dir, size=TILE) if os.path.isdir(real_dir) else {}
    pools = [v for v in real.values() if v]
    out = []
    i = 0
    while pools and len(out) < count:
        pool = pools[i % len(pools)]
        k = i // len(pools)
        if k < len(pool):
            out.append(pool[(k * 7) % len(pool)])
        i += 1
        if i > 10 * count:
            break
    return out


def make_gallery(output, seed=0, shared=None):
    """Write the gallery (and the side-by-side with real photos when possible); returns paths written.

    ``shared``: the shared data folder (holding ``materials/`` and ``real/``),
    default ``../shared/data``.
    """
    import cv2

    from export.files import shared_data

    root = shared_data(shared)
    bank = dataset.SeedBank.find(root)
    cols = generated_columns(seed, bank)
    names = [n for n, _ in cols]
    sheet = _bands([c for _, c in cols], ROWS, names, ["photo", "clean I", "normal", "diffuse", "rough", "spec"])
    os.makedirs(os.path.dirname(output) or ".", exist_ok=True)
    written = []

    def save(path, img):
        ok = cv2.imwrite(path, (img[..., ::-1] * 255).round().astype(np.uint8), [cv2.IMWRITE_PNG_COMPRESSION, 9])
        if not ok:
            raise OSError(f"could not write {path}")
        written.append(path)

    save(output, sheet)
    real = real_columns(2 * len(cols), os.path.join(root, "real"))
    if real:
        half = len(real) // 2
        rcols = [{"real 1": real[j], "real 2": real[half + j] if half + j < len(real) else np.zeros_like(real[j])}
                 for j in range(min(half, len(cols)))]
        rcols = [{"photo": c["photo"], **r} for (_, c), r in zip(cols, rcols)]
        side = _bands(rcols, ("photo", "real 1", "real 2"), names, ["simulated", "real", "real"])
        base, ext = os.path.splitext(output)
        save(base + "_vs_real" + ext, side)
    return written
