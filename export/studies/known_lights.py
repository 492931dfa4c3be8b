"""How well do a method's maps relight generated captures under known lights? The card's test on made-up cards.

    python -m export.studies.known_lights                      # physical + every installed tier, --refine 0 and 60
    python -m export.studies.known_lights --methods physical --model-dir svbrdf_cli/models/swift
    python -m export.studies.known_lights --count 8 --refine 0 --json known_lights.json

``card_blue_9lights`` (:class:`export.render.relight.NineLights`) is one real material photographed
under 9 known lights; this study makes :data:`COUNT` such captures from the data engine, so that a
score on real-like held-out lights does not rest on one card:

* **the materials**: fresh procedural materials (:func:`export.data.procedural.random_materials`, the
  bank's share of metals), changed as the training batches change the bank's (relief, tint, gloss:
  :mod:`export.engine.batches`). Capture ``i`` draws everything from a generator seeded with
  ``seed * 1_000_003 + i`` with ``seed`` = :data:`SEED` (424242): the material bank grows from seed 0
  (shards 0, 1, 2, ...: ``export/engine/bank.py``), the runs' validation and ``refine_eval``'s
  generated photos use 12345, so none of these materials is one a model trained or was chosen on.
  Capture ``i`` is the same whatever ``--count``;
* **the photos**: a camera of the engine's (:func:`export.data.simulate.sample_capture`: field of view
  20-75 degrees, the lens off the surface's centre, the flash a little beside it, auto exposure or
  a fixed flash power, white balance, vignetting, blur, noise, tone curve, JPEG) takes photo 0 with
  its flash by the engine's own simulation (:func:`export.engine.batches.photograph`), then
  :data:`LIGHTS` more at the same exposure and with the same camera, the light moved to known
  positions round the lens as the card's were (:func:`ring`): the card's 8 other lights sit 0.11-0.22
  of the camera's height from photo 00's, from 2 % below to 13 % above it. Every photo at 256²,
  with its own sensor noise;
* **the maps**: from photo 0 as ``svbrdf capture`` makes them (:mod:`export.studies.methods`: the photo
  exposed for the networks, the geometry estimated from the photo alone, ``--refine`` with
  :class:`export.studies.methods.Refined`), exactly as ``refine_eval`` scores the card;
* **the score**: :func:`relight_rmse`, :meth:`export.render.relight.NineLights.relight_rmse` with the
  camera where it was: one intensity fitted on photo 0 (:func:`export.render.relight.fit_intensity`),
  then the RMSE of the encoded renders against photos 1-8, lit as they were, saturated pixels left
  out. Beside the methods: the floor (:class:`export.studies.methods.Floor`) on the same input, and
  the true maps (``truth``: what the photos' noise, tone curve and white balance leave unexplained).

The captures are kept in ``~/.cache/svbrdf/known_lights/<seed>_<count>.npz`` (:func:`captures`);
a re-run only runs the methods. Prints a table and writes it as JSON with ``--json``.
"""

from __future__ import annotations

import json
import math
import os
import time

import click
import numpy as np
import torch

from export.data import procedural, simulate
from export.engine import bank as bank_mod
from export.engine import batches
from export.files import command_errors
from export.render.brdf import render_maps
from export.render.relight import fit_intensity
from export.studies import methods as method_zoo
from svbrdf_cli import conventions as cv
from svbrdf_cli.imageops import resize
from svbrdf_cli.infer.exposure import network_input
from svbrdf_cli.infer.refine import DEFAULT_ITERATIONS
from svbrdf_cli.write.mapset import stored_to_linear

#: Seed of the captures (none of the bank's, the runs' validation's nor ``refine_eval``'s: see above).
SEED = 424242
COUNT = 48
SIZE = 256
#: Photos under known lights besides photo 0 (the card's 8).
LIGHTS = 8
#: The known lights' distance from the lens and their height, as fractions of the camera's height
#: (``card_blue_9lights``: 1.85-3.73 cm beside photo 00's light at 16.7 cm, -0.35 to +2.11 cm above it).
RING_RADIUS = (0.11, 0.22)
RING_HEIGHT = (0.98, 1.13)
#: Each light's angle off an even spread round the lens, radians either way.
RING_JITTER = 0.3
#: Encoded photo values at or above this are saturated and left out (as the card's scorer does).
SATURATED = 0.98
#: Bumped when the captures change: an older cache is made again.
VERSION = 1
CACHE_DIR = os.path.join(os.path.expanduser("~"), ".cache", "svbrdf", "known_lights")


def ring(g, camera, count=LIGHTS):
    """``count`` light positions (count, 3) round the lens at ``camera`` (3,), as the card's: evenly
    round it from a random start (each jittered by :data:`RING_JITTER`), at :data:`RING_RADIUS` and
    :data:`RING_HEIGHT` of the camera's height."""
    def draw(lo, hi, n=count):
        return lo + torch.rand(n, generator=g, dtype=torch.float64) * (hi - lo)

    h = float(camera[2])
    angle = draw(0.0, 2 * math.pi, 1) + 2 * math.pi * torch.arange(count, dtype=torch.float64) / count
    angle = angle + draw(-RING_JITTER, RING_JITTER)
    r, z = draw(*RING_RADIUS) * h, draw(*RING_HEIGHT) * h
    return torch.stack([camera[0] + r * angle.cos(), camera[1] + r * angle.sin(), z], 1)


def material(g, size):
    """One procedural material (linear maps (1, C, size, size)) as a training batch changes a bank's."""
    m = procedural.random_materials(g, 1, size, device="cpu", metal_fraction=bank_mod.METAL_FRACTION)
    stored = {"normal": m["normal"], "roughness": m["roughness"],
              **{k: m[k].clamp(0, 1) ** (1 / cv.ALBEDO_GAMMA) for k in ("diffuse", "specular")}}
    maps = batches.tint(bank_mod.linearize(batches.relief_scale(stored, g)), g)
    maps["roughness"] = batches.gloss_scale(maps["roughness"], g).clamp(0.02, 1.0)
    return {k: maps[k].float().contiguous() for k in cv.MAP_NAMES}


def generate(index, seed=SEED, size=SIZE, ranges=simulate.DEFAULT_RANGES):
    """Capture ``index`` of ``seed``: ``photos`` (1 + LIGHTS, size, size, 3) uint8, photo 0 by the flash;
    ``lights`` and ``cameras`` (1 + LIGHTS, 3), where each photo was lit and taken from; ``truth`` the
    material's maps, stored encoding (HWC, 8 bits as a map file holds them)."""
    g = torch.Generator().manual_seed(seed * 1_000_003 + index)
    with torch.no_grad():
        maps = material(g, size)
        capture = {k: v.float() for k, v in simulate.sample_capture(g, 1, ranges).items()}
        lights = torch.cat([capture["light"].double(), ring(g, capture["camera"][0].double())])
        first = batches.photograph(maps, capture, g)
        fixed = dict(capture, power=first["intensity"].float().reshape(1))  # the same exposure for every photo
        photos = [first["photo"]] + [batches.photograph(maps, dict(fixed, light=light[None].float()), g)["photo"]
                                     for light in lights[1:]]
    photos = torch.cat(photos).permute(0, 2, 3, 1).numpy()
    truth = cv.encode_maps({k: v[0].permute(1, 2, 0).numpy() for k, v in maps.items()})
    return {"photos": np.round(photos * 255).astype(np.uint8),
            "lights": lights.numpy(), "cameras": np.repeat(capture["camera"].double().numpy(), len(lights), 0),
            "truth": {k: np.round(np.clip(truth[k], 0, 1) * 255).astype(np.uint8) for k in cv.MAP_NAMES}}


def cache_path(seed, count, size, cache_dir=CACHE_DIR):
    return os.path.join(cache_dir, f"{seed}_{count}.npz" if size == SIZE else f"{seed}_{count}_{size}.npz")


def captures(count=COUNT, seed=SEED, size=SIZE, cache_dir=CACHE_DIR, log=None):
    """Captures 0 .. ``count`` - 1 of ``seed`` (:func:`generate`), from the cache in ``cache_dir`` when
    it holds them (made and kept there otherwise; ``cache_dir`` None: no cache)."""
    path = cache_path(seed, count, size, cache_dir) if cache_dir else None
    if path and os.path.isfile(path):
        with np.load(path) as z:
            if int(z["version"]) == VERSION:
                return [{"photos": z["photos"][i], "lights": z["lights"][i], "cameras": z["cameras"][i],
                         "truth": {k: z[f"truth_{k}"][i] for k in cv.MAP_NAMES}} for i in range(count)]
    t0 = time.perf_counter()
    out = []
    for i in range(count):
        out.append(generate(i, seed, size))
        if log and (i + 1) % 16 == 0:
            log(f"captures: {i + 1}/{count} ({time.perf_counter() - t0:.0f} s)")
    if path:
        os.makedirs(cache_dir, exist_ok=True)
        tmp = path + ".tmp.npz"
        np.savez(tmp, version=VERSION, **{k: np.stack([c[k] for c in out]) for k in ("photos", "lights", "cameras")},
                 **{f"truth_{k}": np.stack([c["truth"][k] for c in out]) for k in cv.MAP_NAMES})
        os.replace(tmp, path)
    return out


def encoded(x):
    """Photos or stored maps as floats in [0, 1] (uint8 ones divided by 255)."""
    x = np.asarray(x)
    return x.astype(np.float32) / 255 if x.dtype == np.uint8 else x.astype(np.float32)


def render_at(lin, light, camera):
    """Linear HWC ``lin`` maps rendered at unit intensity under ``light`` seen from ``camera`` (HWC)."""
    m = {k: torch.from_numpy(np.ascontiguousarray(v)).permute(2, 0, 1)[None].float() for k, v in lin.items()}
    return render_maps(m, light=tuple(map(float, light)), camera=tuple(map(float, camera)),
                       intensity=1.0)[0].permute(1, 2, 0).numpy()


def relight_rmse(stored, photos, lights, cameras):
    """Mean RMSE over photos 1.. of ``stored`` maps (HWC, float or uint8; resized to the photos' side)
    rendered as each photo was lit and taken, at the intensity fitted on photo 0; pixels a photo
    saturated left out."""
    photos, stored = encoded(photos), {k: encoded(v) for k, v in stored.items()}
    side = photos.shape[1]
    lin = {k: resize(np.asarray(v, np.float32)[..., :cv.MAP_CHANNELS[k]], side).reshape(side, side, -1)
           for k, v in stored_to_linear(stored).items()}
    lin["normal"] = cv.normalize(lin["normal"])
    k = fit_intensity(render_at(lin, lights[0], cameras[0]), photos[0])
    errs = []
    for i in range(1, len(photos)):
        ok = (photos[i] < SATURATED).all(-1)
        pred = cv.image_to_encoded(render_at(lin, lights[i], cameras[i]) * k)
        errs.append(float(np.sqrt(((pred - photos[i])[ok] ** 2).mean())))
    return float(np.mean(errs))


def score(stored, capture):
    """:func:`relight_rmse` of ``stored`` maps on one capture of :func:`captures`."""
    return relight_rmse(stored, capture["photos"], capture["lights"], capture["cameras"])


def photo_input(capture):
    """Photo 0 as ``svbrdf capture`` feeds it to a method (auto exposure, 256², encoded)."""
    return network_input(cv.image_to_linear(encoded(capture["photos"][0])))


class Once:
    """``method`` whose maps of the last image are made once: its plain and ``--refine`` settings share them."""

    def __init__(self, method):
        self.method, self.name, self.label = method, method.name, getattr(method, "label", method.name)
        self.chain = getattr(method, "chain", None)
        self.last = None

    def __call__(self, image):
        if self.last is None or self.last[0] is not image:
            self.last = (image, self.method(image))
        return {k: v.copy() for k, v in self.last[1].items()}


def row(method, steps, errors, floor):
    errors = np.asarray(errors)
    return {"method": method, "refine": steps, "mean": round(float(errors.mean()), 4),
            "median": round(float(np.median(errors)), 4),
            "worse_than_floor": None if floor is None else int((errors > np.asarray(floor)).sum()),
            "count": int(len(errors)), "per_capture": [round(float(e), 5) for e in errors]}


def run(caps, zoo, settings=(0, DEFAULT_ITERATIONS), log=print):
    """Rows (:func:`row`) of the floor, the true maps and each method of ``zoo`` at each ``--refine``
    setting of ``settings`` on the captures ``caps``."""
    images = [photo_input(c) for c in caps]
    floor = [score(method_zoo.Floor()(im), c) for im, c in zip(images, caps)]
    rows = [row("floor", None, floor, None), row("truth", None, [score(c["truth"], c) for c in caps], floor)]
    for m in zoo:
        once, t0 = Once(m), time.perf_counter()
        runners = [(n, method_zoo.Refined(once, n) if n else once) for n in settings]
        errors = {n: [] for n in settings}
        for im, c in zip(images, caps):
            for n, f in runners:
                errors[n].append(score(f(im), c))
        rows += [row(m.name, n, errors[n], floor) for n in settings]
        log(f"{m.name}: {len(caps)} captures in {time.perf_counter() - t0:.0f} s")
    return rows


def table(rows):
    """The rows as a Markdown table."""
    lines = ["| method | --refine | mean relight RMSE | median | worse than the floor |", "|---|---|---|---|---|"]
    for r in rows:
        worse = "–" if r["worse_than_floor"] is None else f"{r['worse_than_floor']}/{r['count']}"
        steps = "–" if r["refine"] is None else r["refine"]
        lines.append(f"| {r['method']} | {steps} | {r['mean']:.4f} | {r['median']:.4f} | {worse} |")
    return "\n".join(lines)


def methods_to_run(names=None, extra=()):
    """Physical and every installed tier (or those of ``names``), then each exported folder of ``extra``."""
    zoo = [m for m in method_zoo.available(threads=1)
           if m.name not in ("floor", "auto", "e2e") and (not names or m.name in names)]
    missing = set(names or ()) - {m.name for m in zoo}
    if missing:
        raise click.BadParameter(f"not available here: {', '.join(sorted(missing))}", param_hint="--methods")
    return zoo + [method_zoo.Network(os.path.basename(os.path.normpath(d)), d, threads=1) for d in extra]


@click.command()
@click.option("--count", default=COUNT, show_default=True, help="Generated captures.")
@click.option("--methods", default=None, help="Comma-separated method names (default: physical and every installed tier).")
@click.option("--model-dir", "extra", multiple=True, type=click.Path(exists=True, file_okay=False),
              help="Also an exported model folder (e.g. a training run's export), named after the folder; repeatable.")
@click.option("--refine", "steps", default=DEFAULT_ITERATIONS, show_default=True, metavar="N",
              help="Each method without refinement and with --refine N (0: without only).")
@click.option("--seed", default=SEED, show_default=True, help="Seed of the captures (a fresh set: another seed).")
@click.option("--json", "json_out", type=click.Path(dir_okay=False), default=None)
@click.option("--cache", "cache_dir", default=CACHE_DIR, show_default=True, type=click.Path(file_okay=False),
              help="Where the captures are kept between runs.")
def cli(count, methods, extra, steps, seed, json_out, cache_dir):
    torch.set_num_threads(1)
    t0 = time.perf_counter()
    with command_errors():
        zoo = methods_to_run(methods.split(",") if methods else None, extra)
        caps = captures(count, seed, SIZE, cache_dir, log=click.echo)
        click.echo(f"{count} captures of seed {seed} ready in {time.perf_counter() - t0:.0f} s")
        rows = run(caps, zoo, (0, steps) if steps else (0,), log=click.echo)
    click.echo(table(rows))
    click.echo(f"({time.perf_counter() - t0:.0f} s in all)")
    if json_out:
        with open(json_out, "w") as f:
            json.dump({"seed": seed, "count": count, "size": SIZE, "lights": LIGHTS, "rows": rows}, f, indent=2)


if __name__ == "__main__":
    cli()
