"""The swift chain as one ONNX graph for the torch-free runtime.

    python -m export.engine onnx --run runs/swift --out weights/swift

``chain.onnx``: inputs ``photo`` (1, 3, H, W) encoded, ``context`` (1, 4, H, W) and ``base``
(1, 10, H, W) (:mod:`export.engine.flash`; the runtime computes them with the numpy twins);
outputs ``masks`` (1, 6, H, W), ``aux`` (1, 9, H, W) and ``maps`` (1, 10, H, W): normal (3),
diffuse (3), roughness (1), specular (3) in the stored encoding. H and W are dynamic, multiples of
32 (a depth-4 UNet at half size). fp32 throughout (the training's bf16 is for speed only); the
graph matches torch in fp32 (``tests/export/test_engine.py``). Its metadata holds the conventions
version, the size multiple and the run's provenance (samples seen, CPU hours, the last Des19
scores); :class:`svbrdf_cli.infer.swift.SwiftModel` runs it.

The graph scales the predicted normals' tilt by ``tilt_gain`` (:func:`tilt_gain`, fitted on the
run's generated validation): an L1-trained network predicts the tilt's pattern but, where its sign
is uncertain, too little of its depth (L1's median), and one factor gives back the depth on average.
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


def scale_tilt(normal, gain):
    """Stored normals (B, 3, H, W) with their tilt (x, y) times ``gain``, renormalised."""
    n = cv.decode_normals(normal, axis=1)
    return cv.encode_normals(cv.normalize(torch.cat([n[:, :2] * gain, n[:, 2:]], 1), axis=1))


@torch.no_grad()
def tilt_gain(net, batches, low=1.0, high=8.0):
    """The factor on the predicted tilt that best fits the true tilt (least squares over ``batches``
    of the maps stage: dicts with ``photo``, ``context``, ``base`` and the stored ``normal``),
    within [low, high]; 1 where the network predicts no tilt."""
    net.eval()
    num = den = 0.0
    for b in batches:
        _, _, maps = net(b["photo"], b["context"], b["base"])
        p = cv.decode_normals(maps["normal"].float(), axis=1)[:, :2]
        t = cv.decode_normals(b["normal"], axis=1)[:, :2]
        num += float((p * t).sum())
        den += float((p * p).sum())
    return float(min(max(num / den, low), high)) if den > 1e-12 and num > 0 else 1.0


class _Graph(nn.Module):
    def __init__(self, net, gain=1.0):
        super().__init__()
        self.net = net
        self.gain = float(gain)

    def forward(self, photo, context, base):
        masks, aux, maps = self.net(photo, context, base)
        if self.gain != 1.0:
            maps = dict(maps, normal=scale_tilt(maps["normal"], self.gain))
        return masks, aux.clamp(0.0, 1.0), torch.cat([maps[k] for k in cv.MAP_NAMES], 1)


def export(net, path, provenance=None, size=128, gain=1.0):
    """Write ``net`` (eval mode, fp32) to ``path`` as ONNX, its normals' tilt times ``gain``."""
    net = net.eval().float()
    x = (torch.rand(1, 3, size, size), torch.zeros(1, 4, size, size), torch.rand(1, 10, size, size))
    dyn = {k: {2: "height", 3: "width"} for k in INPUTS + OUTPUTS}
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    torch.onnx.export(_Graph(net, gain), x, path, input_names=list(INPUTS), output_names=list(OUTPUTS),
                      dynamic_axes=dyn, opset_version=OPSET, dynamo=False)
    import onnx

    model = onnx.load(path)
    meta = {"conventions": cv.CONVENTIONS_VERSION, "size_multiple": str(SIZE_MULTIPLE), "tier": "swift",
            "tilt_gain": repr(float(gain)),
            "provenance": json.dumps(provenance or {})}
    for key, value in meta.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.save(model, path)
    return path
