"""How well do maps reach high resolution? Guided against bicubic upsampling, measured.

    python -m export.studies.upsample_eval                 # CC0 seeds (../shared/data) + the glazed tiles, 1024 px
    python -m export.studies.upsample_eval --model EXPORT  # also through a network (a folder of exported models)

Ground-truth maps at ``--size`` are rendered into a flash photo with the
runtime's renderer. Two low-resolution sources are upsampled back to
``--size`` with each method of :func:`svbrdf_cli.infer.upsample.upsample_maps`:

* **ideal**: the ground truth area-downsampled to 256 (a perfect network),
  so only the upsampling is measured;
* **network** (with ``--model``): the chain's prediction from the photo
  downsampled to 256.

RMSE in the stored encoding against the full-resolution ground truth, per
map, averaged over materials; and seconds per upsampling.
"""

from __future__ import annotations

import time

import click
import numpy as np

from svbrdf_cli import imageops
from svbrdf_cli.infer import exposure
from svbrdf_cli.infer import upsample
from svbrdf_cli import conventions as cv
from svbrdf_cli.write.mapset import linear_to_stored
from svbrdf_cli.shading import render_maps

METHODS = ("bicubic", "guided")


def materials(size, shared=None):
    """(name, linear maps) at ``size``: the glazed tiles and, when present, the CC0 seeds."""
    from export.data.sample import glazed_tiles

    import os

    from export.data import cc0
    from export.files import shared_data

    yield "glazed_tiles", glazed_tiles(size, tiles=6)
    for loader, folder in cc0.seed_folders(shared_data(shared)):
        try:
            yield os.path.basename(folder), loader(folder, size)
        except Exception:  # noqa: BLE001 - an incomplete seed is skipped, as the data engine does
            continue


def _rmse(a, b):
    return float(np.sqrt(((a - b) ** 2).mean()))


@click.command()
@click.option("--size", default=1024, show_default=True)
@click.option("--model", default=None, help="Also measure through this model (tier or folder).")
@click.option("--shared", default=None, help="Shared data folder (default ../shared/data).")
@click.option("--limit", default=0, help="At most this many materials (0: all).")
def cli(size, model, shared, limit):
    """Measure guided against bicubic upsampling of maps from 256 px."""
    chain = None
    if model:
        from svbrdf_cli.infer.chain import Chain
        from svbrdf_cli.infer.registry import model_folder

        chain = Chain(model_folder(model))
    sources = ("ideal", "network") if chain else ("ideal",)
    err = {(s, m, k): [] for s in sources for m in METHODS + ("at 256",) for k in cv.MAP_NAMES}
    secs = {m: [] for m in METHODS}
    names = []
    for i, (name, maps) in enumerate(materials(size, shared)):
        if limit and i >= limit:
            break
        names.append(name)
        maps = {k: np.asarray(maps[k], np.float64) for k in cv.MAP_NAMES}
        lin = render_maps(maps, light=cv.FLASH_POSITION)
        gain = 2.0 ** exposure.auto_exposure_gain(imageops.resize(lin.astype(np.float32), exposure.NETWORK_SIZE))
        high = cv.image_to_encoded(lin * gain).astype(np.float32)
        low = imageops.resize(high, exposure.NETWORK_SIZE)
        gt = {k: v.astype(np.float32) for k, v in linear_to_stored(maps).items()}
        gt["roughness"] = gt["roughness"][..., :1]
        gt_low = {k: imageops.resize(v, exposure.NETWORK_SIZE) for k, v in gt.items()}
        lows = {"ideal": gt_low}
        if chain:
            out = chain(low)
            lows["network"] = {k: out[k] for k in cv.MAP_NAMES}
        for s, src in lows.items():
            for k in cv.MAP_NAMES:
                err[(s, "at 256", k)].append(_rmse(src[k], gt_low[k]))
            for m in METHODS:
                t0 = time.perf_counter()
                up = upsample.upsample_maps(src, low, high, m)
                secs[m].append(time.perf_counter() - t0)
                for k in cv.MAP_NAMES:
                    err[(s, m, k)].append(_rmse(up[k], gt[k]))
    click.echo(f"{len(names)} materials at {size} px: {', '.join(names)}")
    click.echo("| source | upsampling | " + " | ".join(cv.MAP_NAMES) + " | s per set |")
    click.echo("|---|---|" + "---|" * (len(cv.MAP_NAMES) + 1))
    for s in sources:
        for m in ("at 256",) + METHODS:
            cells = [f"{np.mean(err[(s, m, k)]):.4f}" for k in cv.MAP_NAMES]
            t = f"{np.median(secs[m]):.3f}" if m in secs else "-"
            label = "(RMSE at 256 vs downsampled GT)" if m == "at 256" else m
            click.echo(f"| {s} | {label} | " + " | ".join(cells) + f" | {t} |")


if __name__ == "__main__":
    cli()
