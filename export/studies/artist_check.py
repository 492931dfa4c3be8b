"""What an artist gets from real photos: false metal, the flash hole, the albedo level and the height.

    python -m export.studies.artist_check                 # the 12 real benchmark photos and paper_real (~4 min)
    python -m export.studies.artist_check --keep /tmp/sets   # also keep the glTF sets to look at
    python -m export.studies.artist_check --model EXPORT     # another model than the default (a folder)

Every photo goes through ``svbrdf capture`` with its default options and ``--preset gltf`` (in process:
:func:`svbrdf_cli.run.pipeline.prepare` and :func:`svbrdf_cli.run.pipeline.capture`), and the written files are
measured:

* **metallic**: the mean of ``metallicRoughness.png``'s blue channel, and the share of pixels above 0.5;
* **the flash spot**: a disc at the centre of the highlight's blob in the photo as the capture exposed it,
  at the output size (:func:`svbrdf_cli.rectify.highlight.find`), as large as the blob (at least
  :data:`MIN_RADIUS` of the width), and a **ring** round it: the pixels from :data:`RING` ``[0]`` to
  ``[1]`` times its radius from its centre;
* **fine detail**: the RMS of the base colour's high-pass luminance (encoded sRGB less its Gaussian blur of
  sigma :data:`DETAIL_SIGMA` of the width) inside the spot over the ring's (the issue asks >= 0.5);
* **brightness**: the mean linear luminance of the base colour inside the spot over the ring's (asked:
  0.8-1.25);
* **albedo level**: the mean linear base colour (luminance);
* **height**: the height map's range in texture widths (``texture_set.json``), and how much of it is a
  trend with the distance to the flash spot (the ring means' range over the map's range: a bump or a
  crater at the flash).

:data:`METALLIC` names the photos with metal in them (gold or bronze foil, a metal sheet), decided by
looking at them; every other photo is a dielectric, whose mean metallic should be at most 0.02.
"""

from __future__ import annotations

import glob
import json
import os
import shutil
import tempfile

import click
import numpy as np

#: The ring round the flash spot, in multiples of the spot's radius from its centre.
RING = (1.5, 2.5)
#: The smallest spot radius, a fraction of the width (a spot smaller than a material's pattern would
#: measure the pattern: a white check of a gingham).
MIN_RADIUS = 0.08
#: Gaussian sigma of the high-pass that measures fine detail, a fraction of the width (4 px at 1024).
DETAIL_SIGMA = 1.0 / 256.0
#: Photos with metal in them (by looking): the card's gold and teal foil scales, a bronze relief, gilded
#: carvings, a corrugated metal sheet, gold foil on a card and on a gift bag.
METALLIC = ("card_blue_9lights/00.jpg", "IMG_6917-inputs", "IMG_7279-inputs", "IMG_7285-inputs",
            "IMG_7303-inputs", "real_cards-red_0", "real_giftbag1_4")


def photos(shared=None):
    """[(name, path)]: the 12 real benchmark photos, then every ``paper_real`` input."""
    import export.files as files

    real = os.path.join(files.shared_data(shared), "real")
    out = [(os.path.relpath(p, real), p) for p in files.real_photos(real)]
    for p in sorted(glob.glob(os.path.join(real, "paper_real", "*", "input.png"))):
        out.append((os.path.relpath(p, real), p))
    return out


def is_metallic(name):
    return any(m in name for m in METALLIC)


def spot_and_ring(image):
    """(spot, ring) boolean (H, W) masks of the encoded photo ``image`` (see the module docstring)."""
    from svbrdf_cli import conventions as cv
    from svbrdf_cli.rectify import highlight

    blob = highlight.find(image)
    h, w = blob.mask.shape
    radius = max(np.sqrt(blob.mask.sum() / np.pi), MIN_RADIUS * w)
    p = cv.surface_positions(h, w)
    px = w / 2.0  # pixels per surface unit (the surface is 2 units wide)
    dist = np.hypot(p[..., 0] - blob.centre[0], p[..., 1] - blob.centre[1]) * px
    return dist <= radius, (dist > RING[0] * radius) & (dist <= RING[1] * radius)


def detail(encoded_lum, sigma):
    """High-pass of an encoded luminance image (itself less its Gaussian blur)."""
    from svbrdf_cli.imageops import blur

    return encoded_lum - blur(encoded_lum, sigma)


def flash_hole(base_srgb, spot, ring):
    """(fine-detail ratio, brightness ratio) of an sRGB base colour inside ``spot`` against ``ring``."""
    from svbrdf_cli import conventions as cv
    from svbrdf_cli.imageops import luminance

    lin = cv.srgb_to_linear(base_srgb)
    lum = luminance(lin)
    hp = detail(luminance(base_srgb), DETAIL_SIGMA * base_srgb.shape[1])
    rms = lambda m: float(np.sqrt(np.mean(hp[m] ** 2)))  # noqa: E731
    return rms(spot) / max(rms(ring), 1e-9), float(lum[spot].mean()) / max(float(lum[ring].mean()), 1e-9)


def height_trend(height, spot):
    """The height's trend with the distance to ``spot`` (range of 16 ring means) over its range."""
    import cv2

    dist = cv2.distanceTransform((~spot).astype(np.uint8), cv2.DIST_L2, 5)
    bins = np.minimum((dist / (dist.max() + 1e-9) * 16).astype(int), 15)
    means = [float(height[bins == b].mean()) for b in range(16) if (bins == b).sum() > 50]
    span = float(height.max() - height.min())
    return (max(means) - min(means)) / span if span > 1e-9 else 0.0


def measure(folder, image):
    """The measures of one written glTF set ``folder`` of the encoded photo ``image`` (output size)."""
    from svbrdf_cli import conventions as cv
    from svbrdf_cli.imageio import read_image
    from svbrdf_cli.imageops import luminance

    base = read_image(os.path.join(folder, "baseColor.png"))[..., :3]
    mr = read_image(os.path.join(folder, "metallicRoughness.png"))
    height = read_image(os.path.join(folder, "height.png"))[..., 0]
    with open(os.path.join(folder, "texture_set.json")) as f:
        meta = json.load(f)["height"]
    spot, ring = spot_and_ring(image)
    fine, bright = flash_hole(base, spot, ring)
    scale = meta.get("depth_to_width", meta.get("scale_to_width", 0.0))
    widths = height * scale
    return {"metallic": float(mr[..., 2].mean()), "metal_px": float((mr[..., 2] > 0.5).mean()),
            "fine": fine, "bright": bright,
            "albedo": float(luminance(cv.srgb_to_linear(base)).mean()),
            "relief": float(widths.max() - widths.min()), "height_trend": height_trend(height, spot)}


def paper_spot(path, image):
    """{"paper_fine", "paper_bright"}: :func:`flash_hole` of the paper's own diffuse (``paper_diffuse.png``
    beside a ``paper_real`` photo, the paper's network's output) in the same spot and ring as ours, at the
    output size; {} for a photo without one. The spot and the ring hold different parts of many photos
    (yellow grout in the ring, a pale band in the spot): a map without any flash hole measures what the
    photo's content gives."""
    from svbrdf_cli.imageio import read_image
    from svbrdf_cli.imageops import resize

    theirs = os.path.join(os.path.dirname(path), "paper_diffuse.png")
    if not os.path.isfile(theirs):
        return {}
    side = image.shape[0]
    diffuse = resize(read_image(theirs)[..., :3], side).reshape(side, side, 3)
    spot, ring = spot_and_ring(image)
    fine, bright = flash_hole(np.clip(diffuse, 0.0, 1.0), spot, ring)
    return {"paper_fine": fine, "paper_bright": bright}


def run(names=None, keep=None, log=print, model_name=None, refine=None):
    """Capture every photo (glTF preset, default options; ``model_name``: what ``--model`` takes, the
    default when None; ``refine``: ``--refine``'s steps, None for its default) and measure it; returns
    [(name, row)]."""
    from svbrdf_cli.imageops import resize
    from svbrdf_cli.infer.registry import DEFAULT_MODEL, load_model
    from svbrdf_cli.ingest import photo as ingest
    from svbrdf_cli.run import pipeline

    opts = pipeline.Options(preset="gltf", **({} if refine is None else {"refine": refine}))
    model_name = model_name or DEFAULT_MODEL
    model = load_model(model_name)
    out_root = keep or tempfile.mkdtemp(prefix="svbrdf-artist-")
    rows = []
    try:
        for name, path in photos():
            if names and not any(n in name for n in names):
                continue
            prepared = pipeline.prepare(path, opts)
            out = os.path.join(out_root, os.path.dirname(name).replace(os.sep, "_") or "photo")
            os.makedirs(out, exist_ok=True)
            folder, record = pipeline.capture(prepared, model, out, opts, model_name)
            side = record["size"]
            image = ingest.encode_for_network(resize(prepared.crop.image, side), np.float32(2.0 ** prepared.gain_ev),
                                              fast=True)
            row = measure(folder, image)
            row.update(paper_spot(path, image))
            rows.append((name, row))
            log(f"{name:48s} " + " ".join(f"{k} {v:.3f}" for k, v in row.items()))
    finally:
        if keep is None:
            shutil.rmtree(out_root, ignore_errors=True)
    return rows


def table(rows):
    """Markdown table of :func:`run`'s rows, with the pass counts."""
    lines = ["| photo | kind | mean metallic | pixels > 0.5 | fine detail in spot / ring | brightness in spot / ring "
             "| the paper's diffuse: fine detail, brightness | mean linear albedo | relief (widths) | height trend at flash |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for name, r in rows:
        kind = "metal" if is_metallic(name) else "dielectric"
        paper = f"{r['paper_fine']:.2f}, {r['paper_bright']:.2f}" if "paper_fine" in r else "–"
        lines.append(f"| {name} | {kind} | {r['metallic']:.3f} | {r['metal_px']:.3f} | {r['fine']:.2f} | "
                     f"{r['bright']:.2f} | {paper} | {r['albedo']:.3f} | {r['relief']:.4f} | {r['height_trend']:.2f} |")
    diel = [r for n, r in rows if not is_metallic(n)]
    ok_metal = sum(r["metallic"] <= 0.02 for r in diel)
    ok_fine = sum(r["fine"] >= 0.5 for _, r in rows)
    ok_bright = sum(0.8 <= r["bright"] <= 1.25 for _, r in rows)
    lines.append("")
    lines.append(f"Dielectrics with mean metallic <= 0.02: {ok_metal} of {len(diel)}; fine detail >= 0.5: "
                 f"{ok_fine} of {len(rows)}; brightness within 0.8-1.25: {ok_bright} of {len(rows)}.")
    paper = [(n, r) for n, r in rows if "paper_fine" in r]
    if paper:
        ours = sum(r["fine"] >= 0.5 and 0.8 <= r["bright"] <= 1.25 for _, r in paper)
        theirs = sum(r["paper_fine"] >= 0.5 and 0.8 <= r["paper_bright"] <= 1.25 for _, r in paper)
        lines.append(f"Of the {len(paper)} photos with the paper's own diffuse, both spot measures within bounds: "
                     f"ours {ours}, the paper's {theirs}.")
    return "\n".join(lines)


@click.command()
@click.option("--photo", "names", multiple=True, help="Only photos whose name holds this (repeatable).")
@click.option("--keep", type=click.Path(file_okay=False), default=None, help="Keep the glTF sets in this folder.")
@click.option("--model", "model_name", default=None, help="What `svbrdf capture --model` takes (default: its default).")
@click.option("--refine", type=int, default=None, help="What `svbrdf capture --refine` takes (default: its default).")
def cli(names, keep, model_name, refine):
    """Capture the real photos with the glTF preset and measure what an artist would reject."""
    rows = run(names, keep, log=click.echo, model_name=model_name, refine=refine)
    click.echo(table(rows))


if __name__ == "__main__":
    cli()
