"""Parameter and multiply-accumulate (MAC) counting for the networks.

``count_macs`` runs one forward pass with hooks on the layers that do the arithmetic:

* ``nn.Conv2d``: ``N * C_out * H_out * W_out * (C_in / groups) * kH * kW``;
* ``nn.ConvTranspose2d``: ``N * C_in * H_in * W_in * (C_out / groups) * kH * kW``;
* ``nn.Linear``: ``(output elements) * in_features``;
* :class:`~export.nets.deform.DeformConv2d`: its main convolution as for Conv2d plus 4 MACs
  per bilinear sample (``N * C_in * kH * kW * H_out * W_out * 4``); its offset-predicting
  conv is an ``nn.Conv2d`` child and is counted by that hook.

Biases, normalizations, activations, pooling, resizing and element-wise ops are not counted
(they are small next to the convolutions). The result is MACs for the whole given batch.
"""

from __future__ import annotations

import time
from typing import Sequence

import torch
from torch import nn

from .deform import DeformConv2d

__all__ = ["count_parameters", "count_macs", "describe", "time_forward"]


def count_parameters(model: nn.Module, trainable_only: bool = False) -> int:
    """Number of parameters (all, or only those with ``requires_grad``)."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad or not trainable_only)


def _conv_macs(m: nn.Conv2d, out: torch.Tensor) -> int:
    kh, kw = m.kernel_size
    return out.numel() * (m.in_channels // m.groups) * kh * kw


def _hook_macs(m: nn.Module, inputs, out) -> int:
    if isinstance(m, DeformConv2d):
        kh, kw = m.kernel_size
        k = kh * kw
        n, _, oh, ow = out.shape
        return out.numel() * m.in_channels * k + 4 * n * m.in_channels * k * oh * ow
    if isinstance(m, nn.ConvTranspose2d):
        x = inputs[0]
        kh, kw = m.kernel_size
        return x.numel() * (m.out_channels // m.groups) * kh * kw
    if isinstance(m, nn.Conv2d):
        return _conv_macs(m, out)
    if isinstance(m, nn.Linear):
        return out.numel() * m.in_features
    return 0


def _make_inputs(model: nn.Module, inputs) -> tuple:
    try:
        p = next(model.parameters())
        dev, dt = p.device, p.dtype
    except StopIteration:
        dev, dt = torch.device("cpu"), torch.float32
    if isinstance(inputs, torch.Tensor):
        return (inputs,)
    if isinstance(inputs, Sequence) and all(isinstance(v, int) for v in inputs):
        return (torch.zeros(tuple(inputs), device=dev, dtype=dt),)
    if isinstance(inputs, Sequence) and all(isinstance(v, torch.Tensor) for v in inputs):
        return tuple(inputs)
    raise TypeError("pass an input shape (tuple of ints), a tensor, or a tuple of tensors")


def count_macs(model: nn.Module, input_shape_or_inputs) -> int:
    """Multiply-accumulates of one forward pass (see the module docstring), as an int.

    ``input_shape_or_inputs``: a shape such as ``(1, 6, 256, 256)`` (zeros are fed), a tensor,
    or a tuple of tensors passed positionally. Divide by 1e9 for GMACs.
    """
    args = _make_inputs(model, input_shape_or_inputs)
    total = [0]
    kinds = (nn.Conv2d, nn.ConvTranspose2d, nn.Linear, DeformConv2d)

    def hook(m, inp, out):
        total[0] += int(_hook_macs(m, inp, out))

    handles = [m.register_forward_hook(hook) for m in model.modules() if isinstance(m, kinds)]
    was_training = model.training
    try:
        model.eval()
        with torch.no_grad():
            model(*args)
    finally:
        model.train(was_training)
        for h in handles:
            h.remove()
    return total[0]


def _in_channels(model: nn.Module) -> int:
    if hasattr(model, "in_channels"):
        return int(model.in_channels)
    for m in model.modules():
        if isinstance(m, (nn.Conv2d, DeformConv2d)):
            return int(m.in_channels)
    raise ValueError("cannot tell the model's input channels")


def describe(model: nn.Module, size: int = 256) -> str:
    """One line: class name, parameters (M), GMACs for one ``size`` x ``size`` image."""
    c = _in_channels(model)
    params = count_parameters(model)
    gmacs = count_macs(model, (1, c, size, size)) / 1e9
    return (
        f"{type(model).__name__}(in={c}): {params / 1e6:.2f}M params, "
        f"{gmacs:.2f} GMACs @ {size}x{size}"
    )


def time_forward(model: nn.Module, shape, repeats: int = 3, warmup: int = 1) -> float:
    """Median wall time (s) of ``model(torch.rand(shape))`` under no_grad, eval mode."""
    p = next(model.parameters())
    x = torch.rand(tuple(shape), device=p.device, dtype=p.dtype)
    was_training = model.training
    model.eval()
    times = []
    try:
        with torch.no_grad():
            for i in range(warmup + repeats):
                t0 = time.perf_counter()
                model(x)
                if p.device.type == "cuda":
                    torch.cuda.synchronize()
                if i >= warmup:
                    times.append(time.perf_counter() - t0)
    finally:
        model.train(was_training)
    times.sort()
    return times[len(times) // 2]
