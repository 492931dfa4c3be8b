"""Calibration and checks of the physical estimate (:mod:`svbrdf_cli.infer.physical`), never on validation ground truth
except for the one documented convention fit.

    python -m export.studies.physical_eval --fit-flash      # the Des19 inputs' flash power (conventions.FLASH_INTENSITY)
    python -m export.studies.physical_eval --normals        # NORMAL_STRENGTH on generated photos
    python -m export.studies.physical_eval --highlight-figure F.png --photo A.jpg ...   # v5's colour separation

``--fit-flash`` fits, per Des19 sample, the point-light intensity at the conventions' flash position
that reproduces the input from its maps read as linear albedo, on the pixels where the diffuse term
dominates (the highlight's shape depends on the unknown exact light position; the diffuse falloff
barely does). It is a fit of the data's convention (one scalar: the flash power the paper's inputs
were rendered with), the same kind of fit as the renderer's geometry, not a fit of any method to
the ground truth.

``--normals`` draws photos from the training simulator (:mod:`export.data.dataset`, a fixed seed)
and reports the normal RMSE of the physical estimate for a range of strengths; the shipped
:data:`svbrdf_cli.infer.physical.NORMAL_STRENGTH` is the best of them (a conservative single number).
"""

from __future__ import annotations

import os

import click
import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli.infer import physical


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


def normal_sweep(strengths, count=64, log=print):
    """{strength: normal RMSE (stored encoding)} of the physical estimate on generated photos."""
    photos, maps = generated_photos(count)
    gt = cv.encode_normals(maps["normal"])
    res = {}
    for s in strengths:
        errs = [float(np.sqrt(((physical.estimate(p, normal_strength=s)[0]["normal"] - gt[i]) ** 2).mean()))
                for i, p in enumerate(photos)]
        res[s] = float(np.mean(errs))
        log(f"strength {s:.4f}: normal RMSE {res[s]:.4f}")
    best = min(res.values())
    pick = max(s for s, e in res.items() if e <= 1.01 * best)
    log(f"the strongest within 1% of the best: {pick} (physical.NORMAL_STRENGTH = {physical.NORMAL_STRENGTH})")
    return res, pick


def highlight_figure(photos, path, size=512, tile=256):
    """For each photo (cropped and exposed as ``svbrdf capture`` does it, at ``size``): the photo, the
    estimate's diffuse with the highlight taken off as the lobe's share alone, and with the colour
    separation (:func:`svbrdf_cli.infer.physical.separate_by_colour`, the shipped default)."""
    from export.render.figure import captioned_tile
    from svbrdf_cli.ingest import photo as ingest
    from svbrdf_cli.imageio import write_image
    from svbrdf_cli.run.pipeline import Options, prepare
    from svbrdf_cli.imageops import resize

    rows = []
    for photo in photos:
        p = prepare(photo, Options())
        image = ingest.encode_for_network(resize(p.crop.image, size) * np.float32(2.0 ** p.gain_ev))
        cells = [(os.path.basename(photo), image)]
        for flag, title in ((False, "diffuse, lobe share only"), (True, "diffuse, by colour (v5)")):
            old, physical.COLOUR_SEPARATION = physical.COLOUR_SEPARATION, flag
            try:
                cells.append((title, physical.estimate(image)[0]["diffuse"]))
            finally:
                physical.COLOUR_SEPARATION = old
        rows.append(np.concatenate([captioned_tile(img, t, tile) for t, img in cells], 1))
    write_image(path, np.concatenate(rows, 0).astype(np.float32) / 255)


@click.command()
@click.option("--fit-flash", "flash", is_flag=True, help="Fit the Des19 inputs' flash power (a convention).")
@click.option("--normals", is_flag=True, help="Normal RMSE against strength on generated photos.")
@click.option("--count", default=64, show_default=True)
@click.option("--highlight-figure", "figure", type=click.Path(dir_okay=False), default=None,
              help="Draw the diffuse with and without the colour separation for the --photo files into this PNG.")
@click.option("--photo", "photos", multiple=True, type=click.Path(exists=True, dir_okay=False))
def cli(flash, normals, count, figure, photos):
    """Calibrate and check the physical estimate."""
    from export.files import command_errors, shared_root

    if flash:
        fit_flash(str(shared_root() / "data" / "validation" / "des19"), log=click.echo)
    if normals:
        normal_sweep([0.0, 0.05, 0.1, 0.2, 0.3, 0.5, 0.8], count=count, log=click.echo)
    if figure:
        with command_errors():
            highlight_figure(photos, figure)


if __name__ == "__main__":
    cli()
