"""How well do a method's maps relight generated captures under known lights? The card's test on made-up cards.

    python -m export.studies.known_lights                      # physical + every installed tier, --refine 0 and 60
    python -m export.studies.known_lights --methods physical --model-dir svbrdf_cli/models/swift
    python -m export.studies.known_lights --count 8 --refine 0 --json known_lights.json
    python -m export.studies.known_lights --colocated   # each photo from its light, as the card's rig

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
  with its own sensor noise. With ``--colocated`` each of them is taken from its light, as the card's
  were (a phone moved with its flash, the photos rectified), so the view moves with the highlight;
* **the maps**: from photo 0 as ``svbrdf capture`` makes them (:mod:`export.studies.methods`: the photo
  exposed for the networks, the geometry estimated from the photo alone, ``--refine`` with
  :class:`export.studies.methods.Refined`), exactly as ``refine_eval`` scores the card;
* **the score**: :func:`relight_rmse`, :meth:`export.render.relight.NineLights.relight_rmse` with the
  camera where it was: one intensity fitted on photo 0 (:func:`export.render.relight.fit_intensity`),
  then the RMSE of the encoded renders against photos 1-8, lit as they were, saturated pixels left
  out; a method's maps (the floor's too) scored as the command writes them, the diffuse brought back to
  photo 0 as shot (:func:`export.engine.known_lights.score_as_shot`): relighting fits one intensity, so
  what counts is the diffuse's level against the F0's, which the albedo convention sets. Beside the
  methods: the floor (:class:`export.studies.methods.Floor`) on the same input, and the true maps
  (``truth``: what the photos' noise, tone curve and white balance leave unexplained).

The captures are kept in ``~/.cache/svbrdf/known_lights/<seed>_<count>.npz`` (:func:`captures`);
a re-run only runs the methods. Prints a table and writes it as JSON with ``--json``.
"""

from __future__ import annotations

import json
import os
import time

import click
import numpy as np
import torch

from export.engine.known_lights import (CACHE_DIR, COUNT, LIGHTS, SEED, SIZE, captures, photo_input,
                                        score, score_as_shot)
from export.files import command_errors
from export.studies import methods as method_zoo
from svbrdf_cli.infer.refine import DEFAULT_ITERATIONS

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


def run(caps, zoo, settings=(0, DEFAULT_ITERATIONS), log=print, priors=None):
    """Rows (:func:`row`) of the floor, the true maps and each method of ``zoo`` at each ``--refine``
    setting of ``settings`` on the captures ``caps`` (``priors``: :class:`svbrdf_cli.infer.refine.Priors`
    other than the default's)."""
    images = [photo_input(c) for c in caps]
    floor = [score_as_shot(method_zoo.Floor()(im), c) for im, c in zip(images, caps)]
    rows = [row("floor", None, floor, None), row("truth", None, [score(c["truth"], c) for c in caps], floor)]
    for m in zoo:
        once, t0 = Once(m), time.perf_counter()
        runners = [(n, method_zoo.Refined(once, n, priors=priors) if n else once) for n in settings]
        errors = {n: [] for n in settings}
        specular = getattr(getattr(m, "chain", None), "specular_level", "absolute") == "photo"
        for im, c in zip(images, caps):
            for n, f in runners:
                errors[n].append(score_as_shot(f(im), c, specular))
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
@click.option("--colocated", is_flag=True,
              help="Each photo taken from its own light (the card's rig: the view moves with the light), "
                   "not from photo 0's camera.")
@click.option("--json", "json_out", type=click.Path(dir_okay=False), default=None)
@click.option("--cache", "cache_dir", default=CACHE_DIR, show_default=True, type=click.Path(file_okay=False),
              help="Where the captures are kept between runs.")
@click.option("--prior", "prior_pairs", multiple=True, metavar="NAME=VALUE",
              help="A --refine prior weight other than the default's (svbrdf_cli.infer.refine.Priors); repeatable.")
def cli(count, methods, extra, steps, seed, colocated, json_out, cache_dir, prior_pairs):
    from export.studies.refine_eval import parse_priors

    torch.set_num_threads(1)
    priors = parse_priors(prior_pairs)
    t0 = time.perf_counter()
    with command_errors():
        zoo = methods_to_run(methods.split(",") if methods else None, extra)
        caps = captures(count, seed, SIZE, cache_dir, log=click.echo, colocated=colocated)
        click.echo(f"{count} captures of seed {seed} ready in {time.perf_counter() - t0:.0f} s")
        rows = run(caps, zoo, (0, steps) if steps else (0,), log=click.echo, priors=priors)
    click.echo(table(rows))
    click.echo(f"({time.perf_counter() - t0:.0f} s in all)")
    if json_out:
        with open(json_out, "w") as f:
            json.dump({"seed": seed, "count": count, "size": SIZE, "lights": LIGHTS, "colocated": colocated, "rows": rows},
                      f, indent=2)


if __name__ == "__main__":
    cli()
