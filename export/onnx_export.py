"""Export the trained stages to ONNX for the torch-free runtime.

    python -m export.onnx_export --run runs/fast --out EXPORT       # then: svbrdf capture PHOTO --model EXPORT

One file per stage of the run's variant, each a function of named tensors (NCHW
float32, values in [0, 1]; maps in their stored encoding, see ``svbrdf_cli.conventions``):

* ``masks.onnx``: photo -> M_b, M_h
* ``aux.onnx``: photo, M_b, M_h -> I_bf, I_hr, I_hr2
* ``maps.onnx``: photo, I_bf, I_hr, I_hr2 -> normal, diffuse, roughness, specular

An end-to-end run (the ``lite`` tier, the e2e baseline) has the maps stage only: one
``maps.onnx`` taking the photo. A refining run's maps stage also takes the physical estimate.

Height and width are dynamic (multiples of :data:`SIZE_MULTIPLE`). Each
model carries metadata: conventions version, tier, stage, input and output
names, size multiple and the run's provenance (JSON). The deformable
convolutions export as the standard ONNX ``DeformConv`` (opset 19).
"""

from __future__ import annotations

import json
import os

import click
import torch
from torch import nn

from export.nets.chain import VARIANTS
from svbrdf_cli import conventions as cv
from svbrdf_cli.infer.chain import PHYSICAL_INPUT
from svbrdf_cli.errors import SvbrdfError
from svbrdf_cli.infer.physical import PHYSICAL_VERSION

OPSET = 19
SIZE_MULTIPLE = 32
IO = {
    "masks": (("photo",), ("M_b", "M_h")),
    "aux": (("photo", "M_b", "M_h"), ("I_bf", "I_hr", "I_hr2")),
    "maps": (("photo", "I_bf", "I_hr", "I_hr2"), cv.MAP_NAMES),
}


class StageModule(nn.Module):
    """One stage of an :class:`SVBRDFNet` as a function of positional tensors."""

    def __init__(self, net, stage):
        super().__init__()
        self.net, self.stage = net, stage

    def forward(self, *xs):
        ins, outs = stage_io(self.net, self.stage)
        named = dict(zip(ins, xs))
        if self.stage == "masks":
            out = self.net.run_masks(named["photo"])
        elif self.stage == "aux":
            out = self.net.run_aux(named["photo"], named)
        else:
            out = self.net.run_maps(named["photo"], named)
        return tuple(out[k] for k in outs)


#: The physical estimate's input name (the runtime computes the estimate and feeds it under this name).
PHYSICAL = PHYSICAL_INPUT


def stage_io(net, stage):
    """(input names, output names) of ``stage`` of ``net``; the end-to-end baseline's maps take the photo
    only; a refining net's maps also take the physical estimate."""
    ins, outs = IO[stage]
    if getattr(net, "variant", "chain") == "e2e":
        ins = ("photo",)
    if stage == "maps" and getattr(net, "refine", False):
        ins = ins + (PHYSICAL,)
    return ins, outs


def export_stage(net, stage, path, size=256, metadata=None, weights="float32"):
    """Write one stage as ONNX; returns the path.

    ``weights``: "float32", "float16" (:func:`store_float16`) or "int8"
    (:func:`store_int8`).
    """
    import onnx

    ins, outs = stage_io(net, stage)
    module = StageModule(net.eval(), stage).eval()
    from export.nets.chain import PHYSICAL_CHANNELS

    dummy = tuple(torch.rand(1, PHYSICAL_CHANNELS if n == PHYSICAL else 3, size, size) for n in ins)
    dyn = {n: {0: "batch", 2: "height", 3: "width"} for n in ins + tuple(outs)}
    tmp = path + ".part"
    with torch.no_grad():
        torch.onnx.export(module, dummy, tmp, input_names=list(ins), output_names=list(outs),
                          dynamic_axes=dyn, opset_version=OPSET, dynamo=False)
    model = onnx.load(tmp)
    meta = {"conventions": cv.CONVENTIONS_VERSION, "stage": stage, "tier": getattr(net, "tier", "custom"),
            "variant": getattr(net, "variant", "chain"),
            "inputs": ",".join(ins), "outputs": ",".join(outs), "size_multiple": str(SIZE_MULTIPLE),
            **({"physical_version": PHYSICAL_VERSION} if PHYSICAL in ins else {}),
            "layout": "NCHW float32 in [0, 1]; maps in the stored encoding"}
    meta.update({k: v if isinstance(v, str) else json.dumps(v) for k, v in (metadata or {}).items()})
    for k, v in meta.items():
        p = model.metadata_props.add()
        p.key, p.value = k, v
    if weights != "float32":
        {"float16": store_float16, "int8": store_int8}[weights](model)
        p = model.metadata_props.add()
        p.key, p.value = "weights", f"{weights} (computed in float32)"
    onnx.save(model, tmp)
    os.replace(tmp, path)
    return path


def _store_weights(model, keep, encode):
    """Replace each float32 initializer ``w`` with ``keep(w)`` by what ``encode(name, w)`` returns:
    (stored initializers, the node that rebuilds ``name`` in float32 at load); nodes go first."""
    import onnx
    from onnx import TensorProto, numpy_helper

    graph = model.graph
    decoders = []
    for i, init in enumerate(list(graph.initializer)):
        if init.data_type != TensorProto.FLOAT:
            continue
        w = numpy_helper.to_array(init)
        if not keep(w):
            continue
        stored, node = encode(init.name, w)  # ``init`` is the stored proto: use it before replacing it
        graph.initializer[i].CopyFrom(stored[0])
        graph.initializer.extend(stored[1:])
        decoders.append(node)
    nodes = decoders + list(graph.node)
    del graph.node[:]
    graph.node.extend(nodes)
    onnx.checker.check_model(model)
    return model


def store_float16(model, min_elements=16):
    """Store float32 weights as float16 and cast them back to float32 at load.

    Halves the file; the arithmetic stays float32 (onnxruntime folds the
    casts once per session), so the only change is float16 rounding of the
    weights. Small tensors (biases, shapes) stay float32.
    """
    from onnx import TensorProto, helper, numpy_helper

    def encode(name, w):
        return ([numpy_helper.from_array(w.astype("float16"), name + "__fp16")],
                helper.make_node("Cast", [name + "__fp16"], [name], to=TensorProto.FLOAT, name=name + "__cast"))

    return _store_weights(model, lambda w: w.size >= min_elements, encode)


def store_int8(model, min_elements=1024):
    """Store conv and linear weights as int8, one scale per output channel, dequantised at load.

    A quarter of the float32 file. Each weight tensor W becomes
    ``DequantizeLinear(q, scale, 0, axis=0)`` with ``scale = max|W[c]| / 127``
    per output channel ``c``; the arithmetic stays float32, so the only
    change is the rounding of the weights (measure it on Des19 before using
    it). Tensors under ``min_elements`` (biases, norms) stay float32.
    """
    import numpy as np
    from onnx import helper, numpy_helper

    def encode(name, w):
        scale = (np.abs(w).reshape(w.shape[0], -1).max(1) / 127.0).astype(np.float32)
        scale[scale == 0] = 1.0
        q = np.clip(np.round(w / scale.reshape(-1, *([1] * (w.ndim - 1)))), -127, 127).astype(np.int8)
        stored = [numpy_helper.from_array(q, name + "__q"), numpy_helper.from_array(scale, name + "__scale"),
                  numpy_helper.from_array(np.zeros(w.shape[0], np.int8), name + "__zero")]
        return stored, helper.make_node("DequantizeLinear", [t.name for t in stored], [name], axis=0,
                                        name=name + "__dequantize")

    return _store_weights(model, lambda w: w.size >= min_elements and w.ndim >= 2, encode)


def export_run(run, out, size=256, weights="float16"):
    """Export every stage of a trained run (see :func:`export.train.load_trained`).

    Beside the models, ``provenance.json`` holds the run's provenance (data,
    steps, device, time, validation), the export settings and each file's
    size and SHA-256; ``python -m export.studies.evaluate --onnx OUT --record`` adds
    the Des19 scores of the exported chain.
    """
    import hashlib
    import time

    from export.files import read_json, write_json
    from export.train import load_trained

    net = load_trained(run)
    prov = read_json(os.path.join(run, "provenance.json"))
    trained_on = {s.get("physical_version") for s in prov.get("stages", {}).values() if s.get("refine")}
    if trained_on - {PHYSICAL_VERSION}:  # the runtime would feed it another estimate than it learnt to refine
        raise SvbrdfError(f"{run}: trained to refine version {', '.join(sorted(map(str, trained_on)))} of the "
                          f"physical estimate; this tool computes version {PHYSICAL_VERSION}. Train it on this "
                          "version (python -m export.train --init-from RUN ...) before exporting it.")
    os.makedirs(out, exist_ok=True)
    stages = VARIANTS[getattr(net, "variant", "chain")]
    paths = [export_stage(net, s, os.path.join(out, f"{s}.onnx"), size, {"provenance": prov}, weights=weights)
             for s in stages]
    files = {}
    for p in paths:
        with open(p, "rb") as f:
            files[os.path.basename(p)] = {"bytes": os.path.getsize(p), "sha256": hashlib.sha256(f.read()).hexdigest()}
    write_json(os.path.join(out, "provenance.json"), {
        "training": prov,
        "export": {"opset": OPSET, "weights": f"{weights} storage, float32 compute",
                   "trace_size": size, "torch": torch.__version__, "conventions": cv.CONVENTIONS_VERSION,
                   "exported": time.strftime("%Y-%m-%dT%H:%M:%S"), "files": files,
                   "command": f"python -m export.onnx_export --run {run} --out {out} --weights {weights}"},
    })
    return paths


@click.command()
@click.option("--run", type=click.Path(exists=True, file_okay=False), required=True)
@click.option("--out", type=click.Path(file_okay=False), required=True)
@click.option("--size", default=256, show_default=True, help="Trace size (the graphs stay size-dynamic).")
@click.option("--weights", type=click.Choice(["float16", "float32", "int8"]), default="float16", show_default=True,
              help="How weights are stored (computation is float32 in every case).")
@click.option("--float32", "full", is_flag=True, help="Same as --weights float32.")
def cli(run, out, size, weights, full):
    """Export a trained run's stages to ONNX."""
    for p in export_run(run, out, size, weights="float32" if full else weights):
        click.echo(f"{p} ({os.path.getsize(p) / 1e6:.1f} MB)")


if __name__ == "__main__":
    cli()
