"""Relighting a real capture under its own known lights: ``card_blue_9lights`` (:class:`NineLights`),
the test a model's maps must pass on real photos (``docs/benchmarks.md``). Here, below the studies,
so that the training engine scores the card with it too (:func:`export.engine.run.score_card`).
"""

from __future__ import annotations

import json
import os

import numpy as np
import torch

from export.render.brdf import render_maps
from svbrdf_cli import conventions as cv
from svbrdf_cli.write.mapset import read_stored_maps, stored_to_linear


def fit_intensity(rendered, photo):
    """The light intensity that makes ``rendered`` (linear, at unit intensity) best reproduce ``photo``
    (encoded), both (H, W, C) arrays: least squares in linear space over the photo's unsaturated pixels."""
    ok = np.broadcast_to((photo < 0.98).all(-1, keepdims=True), rendered.shape)
    r, t = rendered[ok], cv.image_to_linear(photo)[ok]
    return float((r * t).sum()) / max(float((r * r).sum()), 1e-12)


#: MaterialGAN's roughness encoding: ``rgh.png`` = roughness^(1/this).
REFERENCE_ROUGHNESS_GAMMA = 2.2


class NineLights:
    """``card_blue_9lights``: 9 rectified photos with known light = camera positions (cm)."""

    def __init__(self, folder, size=256):
        import cv2

        from svbrdf_cli.imageio import read_image

        with open(os.path.join(folder, "parameters.json")) as f:
            p = json.load(f)
        scale = 2 * cv.SURFACE_HALF_SIZE / p["image_size"]  # cm -> the conventions' units
        self.lights = [tuple(float(c) * scale for c in pos) for pos in p["light_pos"]]
        self.photos = [cv2.resize(read_image(os.path.join(folder, f"{i:02d}.jpg")), (size, size),
                                  interpolation=cv2.INTER_AREA) for i in p["idx"]]
        self.folder = folder

    def network_input(self):
        """Photo 00 as the tool feeds it to the networks (auto exposure)."""
        from svbrdf_cli.infer.exposure import network_input

        return network_input(cv.image_to_linear(self.photos[0]))

    def _render(self, lin, i):
        m = {k: torch.from_numpy(np.ascontiguousarray(v)).permute(2, 0, 1)[None].float() for k, v in lin.items()}
        return render_maps(m, light=self.lights[i], camera=self.lights[i], intensity=1.0)[0].permute(1, 2, 0).numpy()

    def relight_rmse(self, stored, source=0):
        """Mean RMSE over the other photos of renders lit as they were, at the intensity fitted on photo
        ``source`` (the one the maps were made from; 00 by default)."""
        lin = stored_to_linear(stored)
        k = fit_intensity(self._render(lin, source), self.photos[source])
        errs = []
        for i in (j for j in range(len(self.photos)) if j != source):
            ok = (self.photos[i] < 0.98).all(-1)
            pred = cv.image_to_encoded(self._render(lin, i) * k)
            errs.append(float(np.sqrt(((pred - self.photos[i])[ok] ** 2).mean())))
        return float(np.mean(errs))

    def reference_maps(self):
        """The capture's reference maps (MaterialGAN's file names), as stored here. MaterialGAN writes its
        roughness gamma-encoded (``rgh.png`` holds roughness^(1/2.2); its renderer is the same GGX as
        ours), so it is decoded: read as linear, the maps relight the card at 0.170, decoded at 0.0815."""
        files = {"normal": "nom", "diffuse": "dif", "roughness": "rgh", "specular": "spe"}
        maps = read_stored_maps(os.path.join(self.folder, "reference_maps"), files)
        maps["roughness"] = (maps["roughness"] ** REFERENCE_ROUGHNESS_GAMMA).astype(np.float32)
        return maps
