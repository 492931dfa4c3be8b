"""Real detail or upsampled blur? The detail ratio of each map of ``svbrdf capture``'s output.

    python -m export.studies.detail_eval                      # 12 real photos at their crop's size (<= 1024) and the DNG at 2048
    python -m export.studies.detail_eval --model EXPORT --upsample bicubic

The **detail ratio** of a map is its high-frequency energy over the photo's, both at the output
size: the mean square of what a Gaussian blur of :data:`SIGMA` pixels takes away, on the
encoded luminance (diffuse, specular), the x and y of the normal, or the roughness, over the same of
the exposed, encoded crop's luminance. A map upsampled from 256 px has little (0.1 for the guided
upsampling of a network's diffuse); a diffuse computed at the output size keeps the photo's grain.
"""

from __future__ import annotations

import glob
import json
import os
import tempfile

import click
import numpy as np

from export.files import command_errors, shared_root
from svbrdf_cli import conventions as cv

#: Blur (output pixels) whose removed part counts as high frequency.
SIGMA = 1.5
#: Real photos measured (spread over the collections that are uncropped, full-size phone photos).
PHOTOS = 12


def high_frequency(x):
    """Mean square of ``x`` (H, W) less its Gaussian blur of :data:`SIGMA` pixels."""
    import cv2

    x = np.ascontiguousarray(x, np.float32)
    return float(((x - cv2.GaussianBlur(x, (0, 0), SIGMA, borderType=cv2.BORDER_REFLECT)) ** 2).mean())


def map_signal(name, stored):
    """The part of a stored map whose detail is measured (see the module docstring)."""
    lum = np.asarray(cv.LUMA, np.float32)
    if name in ("diffuse", "specular"):
        return stored[..., :3] @ lum
    if name == "normal":
        return stored[..., :2]
    return stored[..., 0]


def ratios(photo_path, size, chain, model="physical", upsample="guided", refine=0):
    """{map: detail ratio} of one capture at ``size`` (None: the crop's own size, at most 1024) by
    ``chain`` (:func:`svbrdf_cli.infer.registry.load_model` of ``model``)."""
    from svbrdf_cli.ingest import photo as ingest
    from svbrdf_cli.run import pipeline
    from svbrdf_cli import imageops
    from svbrdf_cli.imageio import read_image

    opts = pipeline.Options(size=size, upsample=upsample, refine=refine, preview=False, force=True)
    prepared = pipeline.prepare(photo_path, opts)
    with tempfile.TemporaryDirectory() as out:
        folder, record = pipeline.capture(prepared, chain, out, opts, model_name=model)
        side = record["size"]
        photo = ingest.encode_for_network(imageops.resize(prepared.crop.image, side) * np.float32(2.0 ** prepared.gain_ev))
        ref = high_frequency(photo @ np.asarray(cv.LUMA, np.float32))
        res = {"size": side}
        for name in cv.MAP_NAMES:
            img = read_image(os.path.join(folder, f"{name}.png"))
            sig = map_signal(name, img)
            res[name] = (np.mean([high_frequency(sig[..., i]) for i in range(sig.shape[-1])]) if sig.ndim == 3
                         else high_frequency(sig)) / max(ref, 1e-12)
    return res


def real_photos(count=PHOTOS):
    """``count`` full-size phone photos spread over ``henzler_train`` (uncropped JPEGs)."""
    files = sorted(glob.glob(str(shared_root() / "data" / "real" / "henzler_train" / "*" / "*.JPG")))
    step = max(1, len(files) // count)
    return files[::step][:count]


def run(model="physical", upsample="guided", refine=0, log=print):
    from svbrdf_cli.infer.registry import load_model

    chain = load_model(model, threads=1)  # one session for every photo
    rows = []
    photos = real_photos()
    for f in photos:
        r = ratios(f, None, chain, model, upsample, refine)
        rows.append({"photo": os.path.relpath(f, shared_root() / "data"), **r})
        log(f"{rows[-1]['photo']:45s} {r['size']:5d} " + " ".join(f"{k}={r[k]:.3f}" for k in cv.MAP_NAMES))
    dng = shared_root() / "data" / "raw" / "imageio_test_images" / "Blackmagic_PocketCinema4K_12bit.dng"
    if dng.is_file():
        r = ratios(str(dng), 2048, chain, model, upsample, refine)
        rows.append({"photo": os.path.relpath(dng, shared_root() / "data"), **r})
        log(f"{rows[-1]['photo']:45s} {r['size']:5d} " + " ".join(f"{k}={r[k]:.3f}" for k in cv.MAP_NAMES))
    med = {k: float(np.median([r[k] for r in rows[:len(photos)]])) for k in cv.MAP_NAMES}
    log("median over the real photos: " + " ".join(f"{k}={v:.3f}" for k, v in med.items()))
    return {"rows": rows, "median": med}


@click.command()
@click.option("--model", default="physical", show_default=True)
@click.option("--upsample", type=click.Choice(["guided", "bicubic"]), default="guided", show_default=True)
@click.option("--refine", default=0, show_default=True, help="Refinement steps (0: the model's maps).")
@click.option("--json", "json_out", type=click.Path(dir_okay=False), default=None)
def cli(model, upsample, refine, json_out):
    with command_errors():
        res = run(model, upsample, refine, log=click.echo)
    if json_out:
        with open(json_out, "w") as f:
            json.dump(res, f, indent=1)


if __name__ == "__main__":
    cli()
