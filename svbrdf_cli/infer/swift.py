"""The trained ``swift`` chain (masks -> auxiliary renderings -> maps) on onnxruntime (no torch).

A model folder holding ``chain.onnx``, as ``python -m export.engine onnx`` writes it: one graph with
inputs ``photo`` (1, 3, H, W) encoded, ``context`` (1, 4, H, W) and ``base`` (1, 10, H, W)
(:mod:`svbrdf_cli.infer.flash_fields`), outputs ``masks`` (M_b, M_h), ``aux`` (I_bf, I_hr, I_hr²)
and ``maps`` (stored encoding, the correction of the base already applied). Its metadata holds the
training run's provenance.

Where the flash was comes from the physical estimate's fit of the photo (the foot of the flash and
its height, :func:`svbrdf_cli.infer.physical.fit_flash`), as the training's flash context comes from
the true flash moved by the error such a fit makes (``export/engine/batches.py``).
"""

from __future__ import annotations

import json
import os
import time

import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli.infer import flash_fields
from svbrdf_cli.infer.chain import ModelError, padding, session

#: The file a folder holds when it is a swift chain.
FILE = "chain.onnx"
OUTPUTS = {"masks": ("M_b", "M_h"), "aux": ("I_bf", "I_hr", "I_hr2")}


def is_swift(folder):
    """Whether ``folder`` holds a swift chain (else a folder of per-stage networks)."""
    return os.path.isfile(os.path.join(folder, FILE))


class SwiftModel:
    """``chain.onnx`` as a :class:`svbrdf_cli.infer.model.Model`."""

    #: Runs at the network size: the capture upsamples its maps.
    any_size = False

    def __init__(self, folder, threads=0):
        self.folder = os.fspath(folder)
        path = os.path.join(self.folder, FILE)
        self.session = session(path, threads)
        meta = self.session.get_modelmeta().custom_metadata_map
        if meta.get("conventions") != cv.CONVENTIONS_VERSION:
            raise ModelError(f"'{path}' was made for conventions version {meta.get('conventions')!r}, "
                             f"this tool uses {cv.CONVENTIONS_VERSION!r}; re-export it (python -m export.engine onnx).")
        names = {i.name for i in self.session.get_inputs()}
        if names != {"photo", "context", "base"}:
            raise ModelError(f"'{path}' takes {', '.join(sorted(names))}, not a swift chain's photo, context "
                             "and base; re-export it (python -m export.engine onnx).")
        self.multiple = int(meta.get("size_multiple", "32"))
        self.provenance = json.loads(meta.get("provenance", "{}"))
        self.tier = meta.get("tier", "swift")
        self.timings = {}
        self.found = None

    @property
    def used(self):
        """Itself (a :class:`svbrdf_cli.infer.model.Model`)."""
        return self

    def describe(self):
        """What ``material.json`` records: the folder, the flash found, how much training is behind it."""
        p = self.provenance
        return {"tier": self.tier, "folder": os.path.abspath(self.folder), "found": self.found,
                "trained": {k: p[k] for k in ("samples", "cpu_hours", "step") if k in p}}

    def flash(self, image):
        """The flash position (3,) in surface units, from the physical estimate's fit of ``image``."""
        from svbrdf_cli.infer import physical

        fit = physical.fit_flash(image)
        self.found = {"flash_foot": [round(fit.foot[0], 4), round(fit.foot[1], 4)],
                      "flash_height": round(fit.fit.height, 4)}
        foot = self.found["flash_foot"]
        return np.array([foot[0], foot[1], self.found["flash_height"]], np.float64)

    def __call__(self, image):
        """(H, W, 3) encoded photo -> the maps (stored encoding) and the masks and auxiliary
        renderings (encoded images) for ``--debug``."""
        img = np.asarray(image, dtype=np.float32)
        if img.ndim != 3 or img.shape[-1] != 3:
            raise ValueError(f"expected an (H, W, 3) image, got shape {img.shape}")
        h, w = img.shape[:2]
        t0 = time.perf_counter()
        light = self.flash(img)
        ctx = flash_fields.context(light, h, w)
        base = flash_fields.base(img, light)
        t1 = time.perf_counter()
        m, pad, mode = padding(h, w, self.multiple)

        def feed(x):
            return np.ascontiguousarray(np.pad(x, pad, mode=mode).transpose(2, 0, 1)[None], dtype=np.float32)

        masks, aux, maps = self.session.run(["masks", "aux", "maps"],
                                            {"photo": feed(img), "context": feed(ctx), "base": feed(base)})
        self.timings = {"physical": t1 - t0, "chain": time.perf_counter() - t1}

        def crop(x):
            return np.ascontiguousarray(x[0].transpose(1, 2, 0)[m:m + h, m:m + w])

        maps = crop(maps)
        out = dict(zip(cv.MAP_NAMES, np.split(maps, [3, 6, 7], axis=-1)))
        for name, x in (("masks", masks), ("aux", aux)):
            x = crop(x)
            out.update({k: x[..., 3 * i:3 * i + 3] for i, k in enumerate(OUTPUTS[name])})
        return out

