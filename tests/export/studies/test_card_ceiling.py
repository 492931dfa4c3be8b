"""The per-class refit of ``python -m export.studies.card_ceiling``, on a made-up capture under known lights."""

import numpy as np
import torch

from export.render.brdf import render_maps
from export.studies import card_ceiling as cc
from svbrdf_cli import conventions as cv
from svbrdf_cli.write.mapset import linear_to_stored

SIDE = 32
INTENSITY = 3.0
LIGHTS = [(0.0, 0.0, 2.0), (0.4, 0.0, 2.0), (-0.3, 0.3, 2.1), (0.0, -0.4, 1.9)]


class _Capture:
    """What :func:`export.studies.card_ceiling.refit` reads of :class:`export.render.relight.NineLights`."""

    def __init__(self, truth):
        self.lights = LIGHTS
        self.photos = [np.clip(cv.image_to_encoded(INTENSITY * self._render(truth, i)), 0, 1).astype(np.float32)
                       for i in range(len(LIGHTS))]

    def _render(self, lin, i):  # at unit intensity, as NineLights renders
        m = {k: torch.from_numpy(np.ascontiguousarray(v, np.float32)).permute(2, 0, 1)[None] for k, v in lin.items()}
        return render_maps(m, light=self.lights[i], camera=self.lights[i], intensity=1.0)[0].permute(1, 2, 0).numpy()

    def relight(self, lin):
        return float(np.mean([np.sqrt(((cv.image_to_encoded(INTENSITY * self._render(lin, i)) - self.photos[i]) ** 2)
                                      .mean()) for i in range(len(LIGHTS))]))


def _two_materials():
    left = np.zeros((SIDE, SIDE), bool)
    left[:, : SIDE // 2] = True
    diffuse = np.where(left[..., None], np.float32([0.5, 0.2, 0.1]), np.float32([0.1, 0.3, 0.5]))
    return left, {"normal": np.dstack([np.zeros((SIDE, SIDE, 2)), np.ones((SIDE, SIDE, 1))]).astype(np.float32),
                  "diffuse": diffuse.astype(np.float32),
                  "roughness": np.where(left, 0.25, 0.6)[..., None].astype(np.float32),
                  "specular": np.where(left[..., None], np.float32([0.9, 0.6, 0.2]), np.float32(0.04)).astype(np.float32)}


def test_the_classes_follow_the_diffuse_colours():
    left, truth = _two_materials()
    p = cc.soft_classes(truth["diffuse"], 2)
    assert p.shape == (SIDE * SIDE, 2) and np.allclose(p.sum(1), 1.0)
    label = p.argmax(1).reshape(SIDE, SIDE)
    assert len(np.unique(label[left])) == 1 and len(np.unique(label[~left])) == 1 and label[0, 0] != label[0, -1]


def test_a_refit_on_every_photo_finds_each_materials_gloss_and_relights_better():
    left, truth = _two_materials()
    cap = _Capture(truth)
    start = dict(truth, roughness=np.full((SIDE, SIDE, 1), 0.5, np.float32),
                 specular=np.full((SIDE, SIDE, 3), 0.04, np.float32))
    maps, values = cc.refit(cap, start, cc.soft_classes(truth["diffuse"], 2), range(len(LIGHTS)))
    assert cap.relight(maps) < 0.5 * cap.relight(start), (cap.relight(maps), cap.relight(start))
    rough = maps["roughness"][..., 0]
    assert rough[left].mean() < rough[~left].mean() - 0.1  # the glossy metal told from the rough dielectric
    f0 = maps["specular"]
    assert f0[left].mean() > 1.5 * f0[~left].mean()
    red, blue = f0[left].mean(0)[[0, 2]]
    assert red > 2 * blue  # the gold's own colour (its truth: 0.9, 0.6, 0.2)
    assert set(values) == {"F0", "roughness", "diffuse factor"} and values["F0"].shape == (2, 3)
    assert all(np.isfinite(v).all() for v in linear_to_stored(maps).values())


def test_the_swaps_score_each_map_of_the_reference_in_the_capture_and_back():
    """``swaps``: the capture with one or two of the reference's maps, the reference with one of the
    capture's; the score sees which map is swapped (here the sum of each map's mean over its channels)."""
    ours = {n: np.full((4, 4, c), v, np.float32)
            for (n, c), v in zip((("normal", 3), ("diffuse", 3), ("roughness", 1), ("specular", 3)), (1, 2, 4, 8))}
    reference = {n: np.zeros_like(v) for n, v in ours.items()}

    def score(maps):
        return float(sum(v.mean() for v in maps.values()))

    out = cc.swaps(score, ours, reference)
    assert out["capture"] == 15 and out["reference"] == 0
    assert out["capture with the reference's roughness"] == 11
    assert out["capture with the reference's normal and specular"] == 6
    assert out["reference with the capture's diffuse"] == 2
    assert len(out) == 2 + 4 + 6 + 4
