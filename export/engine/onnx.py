"""The swift chain as one ONNX graph for the torch-free runtime.

    python -m export.engine onnx --run runs/swift --out weights/swift

``chain.onnx``: inputs ``photo`` (1, 3, H, W) encoded, ``context`` (1, 4, H, W) and ``base``
(1, 10, H, W) (:mod:`export.engine.flash`; the runtime computes them with the numpy twins);
outputs ``masks`` (1, 6, H, W), ``aux`` (1, 9, H, W) and ``maps`` (1, 10, H, W): normal (3),
diffuse (3), roughness (1), specular (3) in the stored encoding. H and W are dynamic, multiples of
32 (a depth-4 UNet at half size). fp32 throughout (the training's bf16 is for speed only); the
graph matches torch in fp32 (``tests/export/test_engine.py``). Its metadata holds the conventions
version, the size multiple, ``run_size`` (the image size the run trained at: the scale of flash
spot and texture the chain learned, at which the runtime runs it) and the run's provenance (samples
seen, CPU hours, the last Des19 scores); :class:`svbrdf_cli.infer.swift.SwiftModel` runs it.
"""

from __future__ import annotations

import json
import os

import torch
from torch import nn

from svbrdf_cli import conventions as cv

OPSET = 19
SIZE_MULTIPLE = 32
INPUTS = ("photo", "context", "base")
OUTPUTS = ("masks", "aux", "maps")


class _Graph(nn.Module):
    def __init__(self, net):
        super().__init__()
        self.net = net

    def forward(self, photo, context, base):
        masks, aux, maps = self.net(photo, context, base)
        return masks, aux.clamp(0.0, 1.0), torch.cat([maps[k] for k in cv.MAP_NAMES], 1)


def export(net, path, provenance=None, size=128, run_size=None, specular_level="absolute"):
    """Write ``net`` (eval mode, fp32) to ``path`` as ONNX; ``run_size``: the training's image size,
    recorded for the runtime (None: the runtime runs it at the size it is given); ``specular_level``:
    the F0 the maps stage was trained on (:data:`svbrdf_cli.conventions.SPECULAR_LEVELS`), recorded when
    it is at the photo's level, so that the runtime scales it as the diffuse."""
    net = net.eval().float()
    x = (torch.rand(1, 3, size, size), torch.zeros(1, 4, size, size), torch.rand(1, 10, size, size))
    dyn = {k: {2: "height", 3: "width"} for k in INPUTS + OUTPUTS}
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    torch.onnx.export(_Graph(net), x, path, input_names=list(INPUTS), output_names=list(OUTPUTS),
                      dynamic_axes=dyn, opset_version=OPSET, dynamo=False)
    import onnx

    model = onnx.load(path)
    meta = {"conventions": cv.CONVENTIONS_VERSION, "size_multiple": str(SIZE_MULTIPLE), "tier": "swift",
            "provenance": json.dumps(provenance or {})}
    if run_size:
        meta["run_size"] = str(int(run_size))
    if specular_level != "absolute":
        meta["specular_level"] = specular_level
    for key, value in meta.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.save(model, path)
    return path
