"""Generated captures under known lights: the card's relighting test (``card_blue_9lights``,
:class:`export.render.relight.NineLights`) on materials the data engine makes, photographed by its
camera model with the flash, then under :data:`LIGHTS` more lights round the lens.

Here, below the studies, so that the training run scores its chain on them too (``known_lights`` in
``curve.jsonl``, :func:`export.engine.run.score_known_lights`); ``python -m export.studies.known_lights``
scores every method on them (its docstring says how they are made).
"""

from __future__ import annotations

import math
import os
import time

import numpy as np
import torch

from export.data import procedural, simulate
from export.engine import bank as bank_mod
from export.engine import batches
from export.render.brdf import render_maps
from export.render.relight import fit_intensity
from svbrdf_cli import conventions as cv
from svbrdf_cli.imageops import resize
from svbrdf_cli.infer.exposure import network_gain, network_input, photo_level, to_photo_level
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


def generate(index, seed=SEED, size=SIZE, ranges=simulate.DEFAULT_RANGES, colocated=False):
    """Capture ``index`` of ``seed``: ``photos`` (1 + LIGHTS, size, size, 3) uint8, photo 0 by the flash;
    ``lights`` and ``cameras`` (1 + LIGHTS, 3), where each photo was lit and taken from; ``truth`` the
    material's maps, stored encoding (HWC, 8 bits as a map file holds them)."""
    g = torch.Generator().manual_seed(seed * 1_000_003 + index)
    with torch.no_grad():
        maps = material(g, size)
        capture = {k: v.float() for k, v in simulate.sample_capture(g, 1, ranges).items()}
        lights = torch.cat([capture["light"].double(), ring(g, capture["camera"][0].double())])
        # uncapped (batches.highlight_cap): the captures stay those of earlier runs' curves, and every photo
        # keeps photo 0's exposure
        first = batches.photograph(maps, capture, g, cap=False)
        fixed = dict(capture, power=first["intensity"].float().reshape(1))  # the same exposure for every photo
        # colocated: each photo taken from its light (the card's rig: a phone's flash moved with its lens, the
        # photos rectified), the view moving with the highlight; else from photo 0's camera
        views = [light[None].float() if colocated else capture["camera"] for light in lights[1:]]
        photos = [first["photo"]] + [batches.photograph(maps, dict(fixed, light=light[None].float(), camera=view), g,
                                                        cap=False)["photo"] for light, view in zip(lights[1:], views)]
        cameras = torch.cat([capture["camera"].double(), lights[1:]]) if colocated else \
            capture["camera"].double().repeat(len(lights), 1)
    photos = torch.cat(photos).permute(0, 2, 3, 1).numpy()
    truth = cv.encode_maps({k: v[0].permute(1, 2, 0).numpy() for k, v in maps.items()})
    return {"photos": np.round(photos * 255).astype(np.uint8),
            "lights": lights.numpy(), "cameras": cameras.numpy(),
            "truth": {k: np.round(np.clip(truth[k], 0, 1) * 255).astype(np.uint8) for k in cv.MAP_NAMES}}


def cache_path(seed, count, size, cache_dir=CACHE_DIR, colocated=False):
    name = f"{seed}_{count}" + ("" if size == SIZE else f"_{size}") + ("_colocated" if colocated else "")
    return os.path.join(cache_dir, name + ".npz")


def captures(count=COUNT, seed=SEED, size=SIZE, cache_dir=CACHE_DIR, log=None, colocated=False):
    """Captures 0 .. ``count`` - 1 of ``seed`` (:func:`generate`, ``colocated`` or not), from the cache in ``cache_dir`` when
    it holds them (made and kept there otherwise; ``cache_dir`` None: no cache)."""
    path = cache_path(seed, count, size, cache_dir, colocated) if cache_dir else None
    if path and os.path.isfile(path):
        with np.load(path) as z:
            if int(z["version"]) == VERSION:
                return [{"photos": z["photos"][i], "lights": z["lights"][i], "cameras": z["cameras"][i],
                         "truth": {k: z[f"truth_{k}"][i] for k in cv.MAP_NAMES}} for i in range(count)]
    t0 = time.perf_counter()
    out = []
    for i in range(count):
        out.append(generate(i, seed, size, colocated=colocated))
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
    """:func:`relight_rmse` of ``stored`` maps on one capture of :func:`captures`, as they are (the true
    maps; a method's: :func:`score_as_shot`)."""
    return relight_rmse(stored, capture["photos"], capture["lights"], capture["cameras"])


def photo_input(capture):
    """Photo 0 as ``svbrdf capture`` feeds it to a method (auto exposure, 256², encoded)."""
    return network_input(cv.image_to_linear(encoded(capture["photos"][0])))


def photo_gain(capture):
    """The stops ``svbrdf capture``'s auto exposure adds to photo 0 (:func:`photo_input`'s)."""
    return network_gain(cv.image_to_linear(encoded(capture["photos"][0])))


def as_shot(stored, capture, specular=False):
    """A method's ``stored`` maps of :func:`photo_input` as ``svbrdf capture`` writes them: the diffuse (with
    ``specular``, for a model whose F0 is read at the photo's level, the F0 too) brought back to photo 0 as
    shot (:func:`svbrdf_cli.infer.exposure.photo_level`, ``docs/conventions.md``, "The albedo level")."""
    return to_photo_level(stored, photo_level(photo_gain(capture)), specular=specular)


def score_as_shot(stored, capture, specular=False):
    """:func:`score` of a method's maps of :func:`photo_input` as the command writes them (:func:`as_shot`).
    Relighting fits one intensity, so only the diffuse's level against the F0's counts: a photo exposed
    as the convention assumes reads the ratio right, one exposed otherwise reads it off by as much."""
    return score(as_shot(stored, capture, specular), capture)
