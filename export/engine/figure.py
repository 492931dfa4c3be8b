"""``docs/figures/bank.png``: 64 random materials of the bank, each as its training batch shows it:
the simulated photo, then normal, diffuse (at the photo's flash level), roughness and specular in
their stored encoding, with the material's source under it.

    python -m export.engine figure --out docs/figures/bank.png
"""

from __future__ import annotations

import numpy as np
import torch

from export.engine import batches
from svbrdf_cli import conventions as cv

TILE = 64
COLUMNS = 4
STRIP = ("photo",) + cv.MAP_NAMES
LABEL = 12


def _u8(x):
    x = x.expand(-1, 3, -1, -1) if x.shape[1] == 1 else x
    return (x.clamp(0, 1).permute(0, 2, 3, 1).numpy() * 255).round().astype(np.uint8)


def bank_figure(bank, seed=0, count=64, size=128):
    """(H, W, 3) uint8 sheet of ``count`` random bank materials (see the module docstring)."""
    import cv2

    g = torch.Generator().manual_seed(seed)
    idx = torch.randint(0, len(bank), (count,), generator=g)
    names = [bank.sources[i] for i in idx.tolist()]
    b = batches.make(bank, g, count, size, "maps", index=idx)
    tiles = {k: _u8(torch.nn.functional.interpolate(b[k], size=(TILE, TILE), mode="area")) for k in STRIP}
    rows = (count + COLUMNS - 1) // COLUMNS
    cell_w, cell_h = TILE * len(STRIP) + 6, TILE + LABEL + 4
    sheet = np.full((rows * cell_h, COLUMNS * cell_w, 3), 24, np.uint8)
    for i in range(count):
        y, x = (i // COLUMNS) * cell_h, (i % COLUMNS) * cell_w
        for j, k in enumerate(STRIP):
            sheet[y:y + TILE, x + j * TILE:x + (j + 1) * TILE] = tiles[k][i]
        cv2.putText(sheet, names[i][:44], (x + 2, y + TILE + LABEL - 2), cv2.FONT_HERSHEY_SIMPLEX, 0.33,
                    (230, 230, 230), 1, cv2.LINE_AA)
    return sheet
