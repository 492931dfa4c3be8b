"""The methods the benchmarks compare, behind one interface.

A method maps an encoded (H, W, 3) network input to a stored map set (HWC,
:mod:`svbrdf_cli.conventions`' encoding). :func:`available` lists what can be
run here: every installed tier (onnxruntime, exactly what ``svbrdf capture``
runs), ``--model auto`` when its rule is installed, the end-to-end baseline
when its export is present, the physical estimate and the floor. The paper has no runnable model here; its published
Des19 outputs are scored where the benchmarks need them.
"""

from __future__ import annotations

import os
import time

import numpy as np

from svbrdf_cli import conventions as cv

#: Where exported baselines live (not shipped in the package: they are for comparison only).
BASELINES_DIR = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "weights", "baselines")
#: The paper's published time per image (GPU, 256²), quoted beside its accuracy.
PAPER_GPU_SECONDS = 0.107
TIER_LABELS = {"lite": "lite tier (one small end-to-end UNet)",
               "swift": "swift: the trained masks -> aux -> maps chain, on the photo and its half turn"}


class Floor:
    """Flat normal, diffuse = 0.6 x the linear input, roughness 0.5, dielectric F0 = 0.04: four lines
    every method must beat (the floor of ``../shared/data/README.md``)."""

    name, label = "floor", "floor (flat normal, diffuse = 0.6 x linear input, r = 0.5, F0 = 0.04)"
    #: Diffuse albedo per unit of linear input.
    DIFFUSE_GAIN = 0.6

    def __call__(self, image):
        h, w = image.shape[:2]
        spec = float(cv.albedo_to_stored(np.float32(cv.DIELECTRIC_F0)))
        diffuse = cv.albedo_to_stored(self.DIFFUSE_GAIN * cv.image_to_linear(np.asarray(image, np.float32)))
        return {"normal": np.broadcast_to(np.float32(cv.FLAT_NORMAL_ENCODED), (h, w, 3)).copy(),
                "diffuse": diffuse.astype(np.float32),
                "roughness": np.full((h, w, 1), 0.5, np.float32),
                "specular": np.full((h, w, 3), spec, np.float32)}


class Physical:
    """``--model physical``: the maps from the flash physics alone (:mod:`svbrdf_cli.infer.physical`)."""

    name, label = "physical", "physical estimate (flash falloff, highlight fit, dielectric F0; no network)"

    def __init__(self):
        from svbrdf_cli.infer.physical import PhysicalModel

        self.chain = PhysicalModel()

    def __call__(self, image):
        out = self.chain(image)
        return {k: out[k] for k in cv.MAP_NAMES}


class Network:
    """An exported model folder run as the runtime runs it (:func:`svbrdf_cli.infer.registry.load_model`:
    per-stage networks, or a swift ``chain.onnx``)."""

    def __init__(self, name, folder, label=None, threads=0):
        from svbrdf_cli.infer.registry import load_model

        self.name, self.label = name, label or name
        self.chain = load_model(os.fspath(folder), threads=threads)

    def __call__(self, image):
        out = self.chain(image)
        return {k: out[k] for k in cv.MAP_NAMES}


class Auto:
    """``--model auto`` (:class:`svbrdf_cli.infer.auto.AutoModel`) with the shipped rule."""

    name, label = "auto", "auto (per photo, the cheapest tier the shipped rule finds good enough)"

    def __init__(self, rule, threads=0):
        from svbrdf_cli.infer.auto import AutoModel
        from svbrdf_cli.infer.registry import load_model

        self.model = AutoModel(load_model, rule, threads=threads)

    def __call__(self, image):
        out = self.model(image)
        return {k: out[k] for k in cv.MAP_NAMES}


class Refined:
    """``method`` followed by ``--refine`` (:func:`svbrdf_cli.infer.refine.refine`) under the photo's estimated
    geometry, as ``svbrdf capture`` runs it on a photo without EXIF (the height from the physical
    estimate's falloff fit). ``timings`` collects the refinement's own seconds; ``priors``: a
    :class:`svbrdf_cli.infer.refine.Priors` (default weights when None)."""

    def __init__(self, method, iterations, timings=None, priors=None):
        self.method, self.iterations, self.timings, self.priors = method, int(iterations), timings, priors
        self.name = f"{method.name}+refine"
        self.label = f"{method.label}, then --refine {self.iterations}"
        self.chain = getattr(method, "chain", None)

    def _flash_height(self, image):
        from svbrdf_cli.infer.physical import estimate

        found = getattr(self.chain, "found", None) or estimate(image)[1]
        return found["flash_height"]

    def __call__(self, image):
        from svbrdf_cli.infer import geometry
        from svbrdf_cli.infer import refine

        stored = self.method(image)
        geo = geometry.estimate(image, height=self._flash_height(image))
        t0 = time.perf_counter()
        res = refine.refine(image, stored, geo, self.iterations, priors=self.priors)
        if self.timings is not None:
            self.timings.append(time.perf_counter() - t0)
        return {k: res.stored[k] for k in cv.MAP_NAMES}


def auto_rule():
    """The shipped ``--model auto`` rule, or None when it or a tier it needs is not installed."""
    from svbrdf_cli.infer.auto import load_rule
    from svbrdf_cli.infer.chain import ModelError

    try:
        return load_rule()
    except ModelError:
        return None


def available(threads=0, refined=False):
    """Runnable methods, cheapest kind first: floor, the physical estimate (and, with ``refined``, the
    physical estimate with ``--refine``'s default steps: ``--model physical``), the end-to-end baseline,
    every installed tier (with ``refined``, each also followed by ``--refine``'s default steps: for the
    default tier, what ``svbrdf capture`` runs by default), auto."""
    from svbrdf_cli.infer.chain import MODELS_DIR, installed_tiers

    out = [Floor(), Physical()]
    if refined:
        from svbrdf_cli.infer.refine import DEFAULT_ITERATIONS

        out.append(Refined(Physical(), DEFAULT_ITERATIONS))
    e2e = os.path.join(BASELINES_DIR, "e2e-fast")
    if os.path.isfile(os.path.join(e2e, "maps.onnx")):
        out.append(Network("e2e", e2e, "end-to-end UNet (input -> maps, fast-tier parameters)", threads))
    for t in installed_tiers():
        out.append(Network(t, os.path.join(MODELS_DIR, t), TIER_LABELS.get(t, f"chain, {t} tier"), threads))
        if refined:
            out.append(Refined(out[-1], DEFAULT_ITERATIONS))
    rule = auto_rule()
    if rule is not None:
        out.append(Auto(rule, threads))
    return out
