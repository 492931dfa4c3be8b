"""Does ``--refine`` relight better? Every method with and without test-time refinement, on lights it never saw.

    python -m export.studies.refine_eval                       # physical + every shipped tier, 150 iterations
    python -m export.studies.refine_eval --methods physical --iterations 150 --limit 5

For each method (:mod:`export.studies.methods`) and each setting (no refinement, ``--refine N``):

* **card_blue_9lights**: maps from photo 00 (the most frontal), the capture's geometry estimated
  from that photo alone (:func:`svbrdf_cli.infer.geometry.estimate`, no EXIF in these files), rendered
  under the 8 other photos' known lights with one intensity fitted on photo 00
  (:meth:`export.studies.benchmark.NineLights.relight_rmse`);
* **Des19**: per-map RMSE by the reference scorer (``score_maps.py``, linear albedo), and the
  re-rendering RMSE against the ground truth under :data:`HELD_OUT_LIGHTS` (9 lights, none at
  the input's flash);
* **generated photos** (``--generated N``, off by default): a third set, neither the card nor Des19: N
  photos from the data engine, re-rendered under :data:`HELD_OUT_LIGHTS` (:func:`generated_relight`);
* **time**: median of ``--repeat`` runs of the refinement alone at 256^2, and of the whole
  ``svbrdf capture`` job (``--size 1024``) on the bundled sample.

Prints a table and writes it as JSON with ``--json``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
import sys
import tempfile
import time

import click
import numpy as np
import torch

from export.studies import methods as method_zoo
from export.render.relight import NineLights
from export.studies.evaluate import chw
from export.studies.evaluate import load_des19, relight_rmse, render, score
from export.files import command_errors, shared_root
from svbrdf_cli import conventions as cv
from svbrdf_cli.infer import geometry
from svbrdf_cli.infer import refine
from svbrdf_cli.write.mapset import write_map_set

#: Relighting lights for Des19: 9 on a ring around the flash (radius 1.2 at the camera's height, the
#: first at 20 degrees), none where the input's flash was.
HELD_OUT_LIGHTS = [(1.2 * math.cos(a), 1.2 * math.sin(a), cv.CAMERA_HEIGHT)
                   for a in np.radians(20.0 + 40.0 * np.arange(9))]


def held_out_relight(pred_linear, gt_linear):
    """Mean RMSE of encoded renders under :data:`HELD_OUT_LIGHTS` (maps as (C, H, W) linear tensors)."""
    return relight_rmse(pred_linear, gt_linear, HELD_OUT_LIGHTS)


#: Seed of the generated photos of ``--generated`` (a set that is neither the card nor Des19).
GENERATED_SEED = 12345


def generated_relight(method, samples):
    """Mean held-out relighting RMSE of ``method`` on generated ``samples`` ((network input, linear GT
    maps of (C, H, W))): the predicted maps re-rendered under :data:`HELD_OUT_LIGHTS` against the ground
    truth's, after one intensity fitted so that the two match under the input's flash (the estimate's
    albedo level is a convention, the data engine's exposure is not)."""
    from svbrdf_cli.write.mapset import stored_to_linear

    flash = (0.0, 0.0, cv.CAMERA_HEIGHT)
    errs = []
    for image, gt in samples:
        pred = chw(stored_to_linear({k: v for k, v in method(image).items() if k in cv.MAP_NAMES}))
        a, b = (render(*(m[k][None] for k in cv.MAP_NAMES), light=flash) for m in (pred, gt))
        k = float((a * b).sum() / (a * a).sum().clamp_min(1e-12))
        pred["diffuse"], pred["specular"] = pred["diffuse"] * k, (pred["specular"] * k).clamp(0, 1)
        errs.append(held_out_relight(pred, gt))
    return float(np.mean(errs))


def refined(method, iterations, timings=None, priors=None):
    """``method`` followed by :func:`svbrdf_cli.infer.refine.refine` under the photo's estimated geometry
    (:class:`export.studies.methods.Refined`, ``priors`` its :class:`svbrdf_cli.infer.refine.Priors`); ``method`` itself
    when ``iterations`` is 0."""
    return method_zoo.Refined(method, iterations, timings, priors) if iterations else method


def parse_priors(pairs):
    """``("specular=10", ...)`` -> a :class:`svbrdf_cli.infer.refine.Priors` with those weights changed (None if none)."""
    if not pairs:
        return None
    names = {f.name for f in dataclasses.fields(refine.Priors)}
    kw = {}
    for pair in pairs:
        name, _, value = pair.partition("=")
        if name not in names or not value:
            raise click.BadParameter(f"{pair!r}: expected NAME=VALUE with NAME one of {', '.join(sorted(names))}")
        kw[name] = float(value)
    return refine.Priors(**kw)


def des19(method, samples, des19_dir, out):
    rel = []
    for name, photo, gt in samples:
        stored = method(photo.permute(1, 2, 0).numpy())
        lin = cv.decode_maps(chw(stored), axis=0)
        write_map_set(os.path.join(out, name), {k: v.permute(1, 2, 0).numpy() for k, v in lin.items()})
        rel.append(held_out_relight(lin, gt))
    maps, _ = score(des19_dir, out)
    return {**maps, "relight_held_out": float(np.mean(rel))}


def capture_seconds(model, refine_n, repeat, size=1024):
    """Median wall time of ``svbrdf capture`` on the bundled sample (a fresh process each run)."""
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    sample = os.path.join(root, "examples", "glazed_tiles.jpg")
    times = []
    for _ in range(repeat):
        with tempfile.TemporaryDirectory() as out:
            cmd = [sys.executable, "-m", "svbrdf_cli.cli.main", "capture", sample, "-o", out, "--model", model,
                   "--size", str(size), "--quiet", "--refine", str(refine_n)]
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, capture_output=True)
            times.append(time.perf_counter() - t0)
    return float(np.median(times))


def run(names=None, iterations=refine.DEFAULT_ITERATIONS, limit=None, repeat=3, log=print, extra=None, generated=0,
        priors=None):
    root = shared_root() / "data"
    des19_dir = str(root / "validation" / "des19")
    samples = load_des19(des19_dir)[:limit] if limit else load_des19(des19_dir)
    if limit:
        sub = tempfile.mkdtemp(prefix="svbrdf-des19-")
        for name, _, _ in samples:
            os.symlink(os.path.join(des19_dir, name), os.path.join(sub, name))
        des19_dir = sub
    nine = NineLights(str(root / "real" / "card_blue_9lights"))
    card_in = nine.network_input()
    work = tempfile.mkdtemp(prefix="svbrdf-refine-")
    rows = []
    if generated:
        from export.studies.auto_calibration import generated as generate

        photos = generate(generated, seed=GENERATED_SEED)
    # (method, what `svbrdf capture --model` takes for it)
    zoo = [(m, m.name) for m in method_zoo.available(threads=1)
           if m.name not in ("floor", "auto", "e2e") and (not names or m.name in names)]
    zoo += [(method_zoo.Network(os.path.basename(os.path.normpath(d)), d, threads=1), d) for d in extra or ()]
    for m, model_arg in zoo:
        for n in (0, iterations):
            t = []
            f = refined(m, n, t, priors)
            r = {"method": m.name, "refine": n, "card_relight": nine.relight_rmse(f(card_in))}
            r.update(des19(f, samples, des19_dir, os.path.join(work, f"{m.name}-{n}")))
            if generated:
                r[f"generated{generated}_relight"] = generated_relight(f, photos)
            if n:
                r["refine_s_256"] = float(np.median(t))
            if repeat:
                r["capture_s_1024"] = capture_seconds(model_arg, n, repeat)
            rows.append(r)
            log("  ".join(f"{k}={v:.4f}" if isinstance(v, float) else f"{k}={v}" for k, v in r.items()))
    return rows


def figure(photos, path, iterations=refine.DEFAULT_ITERATIONS, tile=192, side_light=(1.4, 0.9, cv.CAMERA_HEIGHT)):
    """Before/after figure: for each photo (as ``svbrdf capture --crop none`` feeds it), the physical
    estimate's and the refined diffuse, normal and roughness, and both rendered under a side light."""
    from export.render.figure import captioned_tile
    from svbrdf_cli.imageio import read_image, write_image
    from svbrdf_cli.infer.exposure import network_input
    from svbrdf_cli.imageops import resize
    from svbrdf_cli.shading import render_maps

    method = method_zoo.Physical()
    rows = []
    for photo_path in photos:
        lin = cv.srgb_to_linear(read_image(photo_path)[..., :3])
        side = min(lin.shape[:2])
        y0, x0 = (lin.shape[0] - side) // 2, (lin.shape[1] - side) // 2
        image = network_input(resize(lin[y0:y0 + side, x0:x0 + side], 256))
        before = method(image)
        geo = geometry.estimate(image, height=method.chain.found["flash_height"])
        after = refine.refine(image, before, geo, iterations).stored
        cells = [("photo", image)]
        for k in ("diffuse", "normal", "roughness"):
            cells += [(f"{k}, physical", before[k]), (f"{k}, refined", after[k])]
        for label, st in (("side light, physical", before), ("side light, refined", after)):
            lin_maps = cv.decode_maps(st)
            k = refine.fit_intensity(cv.image_to_linear(image), refine.parameters(st), geo)
            cells.append((label, cv.image_to_encoded(render_maps(lin_maps, light=side_light, intensity=k))))
        rows.append(np.concatenate([captioned_tile(img, title, tile) for title, img in cells], 1))
    write_image(path, np.concatenate(rows, 0).astype(np.float32) / 255)


@click.command()
@click.option("--methods", default=None, help="Comma-separated method names (default: physical and every installed tier).")
@click.option("--iterations", default=refine.DEFAULT_ITERATIONS, show_default=True)
@click.option("--limit", type=int, default=None, help="Only the first N Des19 samples.")
@click.option("--repeat", default=3, show_default=True, help="Runs per timing (median); 0: no capture timing.")
@click.option("--model-dir", "extra", multiple=True, type=click.Path(exists=True, file_okay=False),
              help="Also an exported model folder (e.g. a training run's export), named after the folder.")
@click.option("--json", "json_out", type=click.Path(dir_okay=False), default=None)
@click.option("--figure", "figure_out", type=click.Path(dir_okay=False), default=None,
              help="Only draw the before/after figure of --photo files into this PNG.")
@click.option("--photo", "photos", multiple=True, type=click.Path(exists=True, dir_okay=False))
@click.option("--generated", default=0, show_default=True,
              help="Also the held-out relighting of N photos from the data engine (seed GENERATED_SEED).")
@click.option("--prior", "prior_pairs", multiple=True, metavar="NAME=VALUE",
              help="A --refine prior weight other than the default's (svbrdf_cli.infer.refine.Priors), e.g. specular=10; "
                   "repeatable. The capture timings still run the default's.")
def cli(methods, iterations, limit, repeat, json_out, figure_out, photos, extra, generated, prior_pairs):
    torch.set_num_threads(1)
    priors = parse_priors(prior_pairs)
    if figure_out:
        with command_errors():
            figure(photos, figure_out, iterations)
        return
    with command_errors():
        rows = run(methods.split(",") if methods else None, iterations, limit, repeat, log=click.echo, extra=extra,
                   generated=generated, priors=priors)
    if json_out:
        with open(json_out, "w") as f:
            json.dump(rows, f, indent=2)


if __name__ == "__main__":
    cli()
