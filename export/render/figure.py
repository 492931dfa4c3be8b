r"""Figure of the intermediate targets, in the style of the paper's Figs. 4 and 6.

    python -m export.render.figure --materials ../shared/data/materials/ambientcg \
        --ids Tiles032 PavingStones098 -o docs/figures/intermediates.png

One row per material: the flash image I, I_bf, I_hr, I_hr^2, M_b and M_h
(masks scaled by ``--mask-gain`` so they read on screen), then the ground-truth
maps for reference.
"""

from __future__ import annotations

import argparse
import os

import numpy as np
import torch

from export.data.cc0 import load_ambientcg
from export.render.targets import auto_exposure, intermediate_targets
from svbrdf_cli import conventions as cv
from svbrdf_cli.imageio import write_image

COLUMNS = ("I", "I_bf", "I_hr", "I_hr2", "M_b", "M_h")
LABELS = {"I": "I (input)", "I_bf": "I_bf", "I_hr": "I_hr", "I_hr2": "I_hr^2", "M_b": "M_b", "M_h": "M_h",
          "normal": "N", "diffuse": "D", "roughness": "R", "specular": "S"}


def to_nchw(maps):
    """HWC numpy maps -> (1, C, H, W) float32 tensors."""
    return {k: torch.from_numpy(np.ascontiguousarray(maps[k])).permute(2, 0, 1)[None].float() for k in cv.MAP_NAMES}


def _label(tile, text):
    import cv2

    out = np.ascontiguousarray(tile if tile.dtype == np.uint8 else (tile.clip(0, 1) * 255 + 0.5).astype(np.uint8))
    cv2.rectangle(out, (0, 0), (out.shape[1], 22), (0, 0, 0), -1)
    cv2.putText(out, text, (5, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def captioned_tile(img, title, size):
    """An (H, W, 1 or 3) float image in [0, 1] -> a ``size``² uint8 tile with ``title`` on a dark band at its foot."""
    import cv2

    img = np.repeat(img, 3, -1) if img.shape[-1] == 1 else img
    t = cv2.resize(np.ascontiguousarray(img, np.float32), (size, size), interpolation=cv2.INTER_AREA)
    t = np.ascontiguousarray((np.clip(t, 0, 1) * 255 + 0.5).astype(np.uint8))
    t[-16:] = t[-16:] // 3
    cv2.putText(t, title, (4, size - 5), cv2.FONT_HERSHEY_SIMPLEX, 0.36 if size < 180 else 0.38, (255, 255, 255), 1,
                cv2.LINE_AA)
    return t


def figure(materials, ids, size=256, mask_gain=2.0, with_maps=True):
    """Build the figure as an (H, W, 3) uint8 array (display encoding)."""
    rows = []
    for mid in ids:
        maps = load_ambientcg(os.path.join(materials, mid), size=size)
        m = to_nchw(maps)
        t = intermediate_targets(m, intensity=auto_exposure(m))
        tiles = []
        for k in COLUMNS:
            img = t[k][0].permute(1, 2, 0).numpy()
            if k.startswith("M_"):
                img = (img * mask_gain).clip(0, 1)
            tiles.append(_label(img, LABELS[k] + (f" x{mask_gain:g}" if k.startswith("M_") else "")))
        if with_maps:
            enc = cv.encode_maps(to_nchw(maps))
            for k in cv.MAP_NAMES:
                img = enc[k][0].permute(1, 2, 0).numpy()
                img = np.repeat(img, 3, -1) if img.shape[-1] == 1 else img
                tiles.append(_label(img, LABELS[k]))
        row = np.concatenate(tiles, 1)
        rows.append(_label(np.concatenate([np.zeros((24, row.shape[1], 3), np.uint8), row], 0), mid))
    return np.concatenate(rows, 0)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--materials", default=os.path.join("..", "shared", "data", "materials", "ambientcg"))
    ap.add_argument("--ids", nargs="+", default=["Tiles032", "PavingStones098"])
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--mask-gain", type=float, default=4.0)
    ap.add_argument("-o", "--output", default=os.path.join("docs", "figures", "intermediates.png"))
    a = ap.parse_args(argv)
    img = figure(a.materials, a.ids, a.size, a.mask_gain)
    os.makedirs(os.path.dirname(os.path.abspath(a.output)), exist_ok=True)
    write_image(a.output, img / 255.0)
    print(f"wrote {a.output} ({img.shape[1]}x{img.shape[0]})")


if __name__ == "__main__":
    main()
