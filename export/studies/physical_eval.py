"""Calibration and checks of the physical estimate (:mod:`svbrdf_cli.infer.physical`), never on validation ground truth
except for the one documented convention fit.

    python -m export.studies.physical_eval --fit-flash      # the Des19 inputs' flash power (conventions.FLASH_INTENSITY)

``--fit-flash`` fits, per Des19 sample, the point-light intensity at the conventions' flash position
that reproduces the input from its maps read as linear albedo, on the pixels where the diffuse term
dominates (the highlight's shape depends on the unknown exact light position; the diffuse falloff
barely does). It is a fit of the data's convention (one scalar: the flash power the paper's inputs
were rendered with), the same kind of fit as the renderer's geometry, not a fit of any method to
the ground truth.

:func:`generated_photos` draws photos from the training simulator (:mod:`export.data.dataset`, a
fixed seed) for the studies that score the estimate on them.
"""

from __future__ import annotations

import os

import click
import numpy as np

from svbrdf_cli import conventions as cv


def fit_flash(des19, log=print):
    """{sample: intensity} of the Des19 inputs (see the module doc) and their median."""
    from svbrdf_cli.imageio import read_image
    from svbrdf_cli.write.mapset import read_map_set
    from svbrdf_cli.shading import render

    out = {}
    for name in sorted(os.listdir(des19)):
        d = os.path.join(des19, name)
        if not os.path.isfile(os.path.join(d, "input.png")):
            continue
        photo = read_image(os.path.join(d, "input.png"))[..., :3].astype(np.float64)
        m = read_map_set(d, linear_albedo=True)
        n, D, R, S = (m[k].astype(np.float64) for k in cv.MAP_NAMES)
        dif = render(n, D, R, S * 0, intensity=1.0) * (1 - S)
        spec = render(n, D, R, S, intensity=1.0) - dif
        ok = np.broadcast_to((photo < 0.98).all(-1, keepdims=True) & (spec < 0.1 * dif), dif.shape)
        if ok.sum() < 1000:
            log(f"{name:30s} too few diffuse-dominated pixels")
            continue
        t = cv.image_to_linear(photo)
        out[name] = float((dif[ok] * t[ok]).sum() / (dif[ok] ** 2).sum())
        log(f"{name:30s} intensity {out[name]:7.2f} ({ok[..., 0].mean():.0%} of pixels)")
    k = np.array(list(out.values()))
    log(f"median {np.median(k):.2f}  p10 {np.percentile(k, 10):.2f}  p90 {np.percentile(k, 90):.2f}  "
        f"over {len(k)} samples (conventions.FLASH_INTENSITY = {cv.FLASH_INTENSITY})")
    return out, float(np.median(k))


def generated_photos(count=64, size=256, seed=2468):
    """(photos (N, H, W, 3) encoded, linear maps dict of (N, H, W, C)) from the training simulator."""
    import torch

    from export.data import dataset
    g = dataset.worker_generator(seed, 0, "cpu")
    cfg = dataset.DataConfig(size=size, targets=())
    photos, maps = [], {k: [] for k in cv.MAP_NAMES}
    with torch.no_grad():
        for start in range(0, count, 16):
            b = dataset.make_batch(g, min(16, count - start), cfg, seeds=dataset.SeedBank.find())
            photos.append(b["photo"].permute(0, 2, 3, 1).numpy())
            for k in cv.MAP_NAMES:
                maps[k].append(b[k].permute(0, 2, 3, 1).numpy())
    return np.concatenate(photos), {k: np.concatenate(v) for k, v in maps.items()}


@click.command()
@click.option("--fit-flash", "flash", is_flag=True, help="Fit the Des19 inputs' flash power (a convention).")
def cli(flash):
    """Calibrate and check the physical estimate."""
    from export.files import shared_root

    if flash:
        fit_flash(str(shared_root() / "data" / "validation" / "des19"), log=click.echo)


if __name__ == "__main__":
    cli()
