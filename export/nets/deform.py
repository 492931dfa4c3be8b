"""Deformable convolution (DCNv1, Dai et al. 2017) in plain torch, exportable to ONNX.

The paper's GAD-Conv appends "a deformable convolution block" to a gated convolution. This
module provides that block without torchvision or a compiled extension.

Sampling convention (the one of ONNX ``DeformConv`` and of torchvision): for output pixel
``(oy, ox)`` and kernel tap ``(i, j)`` the input is read at::

    y = oy * stride - padding + i * dilation + offset[n, 2 * (i * kW + j),     oy, ox]
    x = ox * stride - padding + j * dilation + offset[n, 2 * (i * kW + j) + 1, oy, ox]

with bilinear interpolation whose four corners each read zero outside the image (so a tap
between -1 and 0 still gets part of row/column 0). The offset tensor is
``(N, 2 * kH * kW, oH, oW)``, laid out (dy, dx) per tap, taps in row-major order.

Implementation: the kH*kW sampling grids are stacked along the height axis and read with a
single ``F.grid_sample`` (bilinear, zero padding, ``align_corners=False``, pixel coordinates
mapped to ``(2p + 1) / size - 1``), which gives ``(N, C, kH*kW, oH, oW)`` sampled copies of the
input; one matmul with the weights finishes the convolution. Memory is kH*kW times the input,
which is fine at the sizes used here.

The op is wrapped in a ``torch.autograd.Function`` (:class:`DeformConv2dFunction`) so that

* the legacy (TorchScript) ONNX exporter, ``torch.onnx.export(..., dynamo=False)``, emits one
  ONNX ``DeformConv`` node (opset >= 19) through :meth:`DeformConv2dFunction.symbolic`;
  onnxruntime's CPU provider runs it;
* the backward pass recomputes the sampling instead of keeping the K-times-larger sampled
  tensor alive between forward and backward (gradient checkpointing of this one op). This
  costs one extra forward of the op in training and saves most of its activation memory.
  Double backward is not supported.

Fallback export route: set ``export_as="gridsample"`` on the modules (see
:func:`set_deform_export`) and the exporter traces the plain torch implementation instead,
giving standard ``GridSample`` (opset 16+) + ``MatMul`` nodes, for runtimes without
``DeformConv``.

Only ``groups=1`` and ``offset_groups=1`` are implemented.
"""

from __future__ import annotations

import warnings

import torch
import torch.nn.functional as F
from torch import nn

__all__ = [
    "DeformConv2d",
    "DeformConv2dFunction",
    "deform_conv2d",
    "deform_conv2d_torch",
    "set_deform_export",
]


def _pair(v) -> tuple[int, int]:
    if isinstance(v, (tuple, list)):
        if len(v) != 2:
            raise ValueError(f"expected an int or a pair, got {v!r}")
        return int(v[0]), int(v[1])
    return int(v), int(v)


def _out_size(size: int, k: int, s: int, p: int, d: int) -> int:
    return (size + 2 * p - d * (k - 1) - 1) // s + 1


def deform_conv2d_torch(
    x: torch.Tensor,
    offset: torch.Tensor,
    weight: torch.Tensor,
    bias: torch.Tensor | None = None,
    stride=1,
    padding=1,
    dilation=1,
) -> torch.Tensor:
    """Deformable convolution from differentiable torch ops (grid_sample + matmul).

    ``x`` (N, C, H, W), ``offset`` (N, 2*kH*kW, oH, oW), ``weight`` (O, C, kH, kW),
    ``bias`` (O,) or None. See the module docstring for the sampling convention.
    """
    sh, sw = _pair(stride)
    ph, pw = _pair(padding)
    dh, dw = _pair(dilation)
    # Python ints: when the ONNX exporter traces the autograd.Function the sizes are baked in
    # (its recorded sub-graph is replaced by DeformConv anyway; traced size arithmetic inside
    # that sub-graph trips the exporter). A "gridsample" export is therefore size-specific.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", torch.jit.TracerWarning)
        n, c, h, w = (int(v) for v in x.shape)
        o, cw, kh, kw = (int(v) for v in weight.shape)
        oc, oh, ow = (int(v) for v in offset.shape[1:])
    if cw != c:
        raise ValueError(f"weight expects {cw} input channels, input has {c} (groups=1 only)")
    k = kh * kw
    if oc != 2 * k:
        raise ValueError(f"offset needs {2 * k} channels (offset_groups=1), got {oc}")

    dev, dt = x.device, x.dtype
    # Base sampling positions, (K, oH, 1) for y and (K, 1, oW) for x.
    ty = (torch.arange(kh, device=dev, dtype=dt) * dh).repeat_interleave(kw)
    tx = (torch.arange(kw, device=dev, dtype=dt) * dw).repeat(kh)
    by = ty.view(k, 1, 1) + (torch.arange(oh, device=dev, dtype=dt) * sh - ph).view(1, oh, 1)
    bx = tx.view(k, 1, 1) + (torch.arange(ow, device=dev, dtype=dt) * sw - pw).view(1, 1, ow)

    off = offset.reshape(n, k, 2, oh, ow)
    py = by + off[:, :, 0]  # (N, K, oH, oW)
    px = bx + off[:, :, 1]
    # Pixel coordinate p -> grid_sample's normalised coordinate with align_corners=False.
    gy = (2.0 * py + 1.0) / h - 1.0
    gx = (2.0 * px + 1.0) / w - 1.0
    grid = torch.stack((gx, gy), dim=-1).reshape(n, k * oh, ow, 2)
    cols = F.grid_sample(x, grid, mode="bilinear", padding_mode="zeros", align_corners=False)
    # (N, C, K*oH, oW) -> (N, C*K, oH*oW); weight (O, C, kH, kW) -> (O, C*K): same (c, tap) order.
    cols = cols.reshape(n, c * k, oh * ow)
    out = torch.matmul(weight.reshape(o, c * k), cols).reshape(n, o, oh, ow)
    if bias is not None:
        out = out + bias.view(1, o, 1, 1)
    return out


class DeformConv2dFunction(torch.autograd.Function):
    """Autograd wrapper: torch forward, recomputing backward, ONNX ``DeformConv`` symbolic.

    ``apply(x, offset, weight, bias, sh, sw, ph, pw, dh, dw)`` with Python ints for stride,
    padding and dilation; ``bias`` may be None.
    """

    @staticmethod
    def forward(ctx, x, offset, weight, bias, sh, sw, ph, pw, dh, dw):
        ctx.conf = ((sh, sw), (ph, pw), (dh, dw))
        ctx.has_bias = bias is not None
        if bias is None:
            ctx.save_for_backward(x, offset, weight)
        else:
            ctx.save_for_backward(x, offset, weight, bias)
        return deform_conv2d_torch(x, offset, weight, bias, *ctx.conf)

    @staticmethod
    def backward(ctx, grad_out):
        saved = ctx.saved_tensors
        x, offset, weight = saved[:3]
        bias = saved[3] if ctx.has_bias else None
        needs = ctx.needs_input_grad[:4]
        with torch.enable_grad():
            xs = x.detach().requires_grad_(needs[0])
            offs = offset.detach().requires_grad_(needs[1])
            ws = weight.detach().requires_grad_(needs[2])
            bs = bias.detach().requires_grad_(needs[3]) if bias is not None else None
            out = deform_conv2d_torch(xs, offs, ws, bs, *ctx.conf)
            wrt = [t for t, need in zip((xs, offs, ws, bs), needs) if need and t is not None]
            grads = iter(torch.autograd.grad(out, wrt, grad_out) if wrt else ())
        result = [
            next(grads) if (need and t is not None) else None
            for t, need in zip((xs, offs, ws, bs), needs)
        ]
        return (*result, None, None, None, None, None, None)

    @staticmethod
    def symbolic(g, x, offset, weight, bias, sh, sw, ph, pw, dh, dw):
        sizes = weight.type().sizes()
        if sizes is None or len(sizes) != 4:
            raise RuntimeError("DeformConv export needs a weight of known 4-D shape")
        kh, kw = int(sizes[2]), int(sizes[3])
        inputs = [x, weight, offset]
        if bias is not None and not (hasattr(bias, "node") and bias.node().mustBeNone()):
            inputs.append(bias)
        return g.op(
            "DeformConv",
            *inputs,
            kernel_shape_i=[kh, kw],
            strides_i=[sh, sw],
            pads_i=[ph, pw, ph, pw],
            dilations_i=[dh, dw],
            group_i=1,
            offset_group_i=1,
        )


def deform_conv2d(x, offset, weight, bias=None, stride=1, padding=1, dilation=1):
    """Functional deformable convolution through :class:`DeformConv2dFunction`."""
    return DeformConv2dFunction.apply(
        x, offset, weight, bias, *_pair(stride), *_pair(padding), *_pair(dilation)
    )


class DeformConv2d(nn.Module):
    """Deformable convolution (DCNv1) with its own offset-predicting convolution.

    The offset conv has the same kernel, stride, padding and dilation as the main conv and
    outputs ``2 * kH * kW`` channels (dy, dx per tap). It is initialised to zero, so a fresh
    module is exactly an ordinary ``nn.Conv2d`` (same weight init as ``nn.Conv2d``).

    ``export_as``: ``"deformconv"`` (default) exports one ONNX ``DeformConv`` node (opset 19,
    legacy exporter); ``"gridsample"`` lets the exporter trace the torch implementation.
    """

    def __init__(
        self,
        in_ch: int,
        out_ch: int,
        kernel_size=3,
        stride=1,
        padding=1,
        dilation=1,
        bias: bool = True,
    ):
        super().__init__()
        self.in_channels = int(in_ch)
        self.out_channels = int(out_ch)
        self.kernel_size = _pair(kernel_size)
        self.stride = _pair(stride)
        self.padding = _pair(padding)
        self.dilation = _pair(dilation)
        self.export_as = "deformconv"
        ref = nn.Conv2d(in_ch, out_ch, kernel_size, stride, padding, dilation, bias=bias)
        self.weight = nn.Parameter(ref.weight.detach().clone())
        self.bias = nn.Parameter(ref.bias.detach().clone()) if bias else None
        kh, kw = self.kernel_size
        self.offset = nn.Conv2d(
            in_ch, 2 * kh * kw, kernel_size, stride, padding, dilation, bias=True
        )
        nn.init.zeros_(self.offset.weight)
        nn.init.zeros_(self.offset.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        offset = self.offset(x)
        if self.export_as == "gridsample" and torch.onnx.is_in_onnx_export():
            return deform_conv2d_torch(
                x, offset, self.weight, self.bias, self.stride, self.padding, self.dilation
            )
        return DeformConv2dFunction.apply(
            x, offset, self.weight, self.bias, *self.stride, *self.padding, *self.dilation
        )

    def output_size(self, h: int, w: int) -> tuple[int, int]:
        kh, kw = self.kernel_size
        return (
            _out_size(h, kh, self.stride[0], self.padding[0], self.dilation[0]),
            _out_size(w, kw, self.stride[1], self.padding[1], self.dilation[1]),
        )

    def extra_repr(self) -> str:
        return (
            f"{self.in_channels}, {self.out_channels}, kernel_size={self.kernel_size}, "
            f"stride={self.stride}, padding={self.padding}, dilation={self.dilation}, "
            f"bias={self.bias is not None}"
        )


def set_deform_export(model: nn.Module, mode: str = "deformconv") -> nn.Module:
    """Choose how every :class:`DeformConv2d` in ``model`` exports: ``"deformconv"`` (one ONNX
    DeformConv node, opset 19) or ``"gridsample"`` (GridSample + MatMul, opset 16+)."""
    if mode not in ("deformconv", "gridsample"):
        raise ValueError(f"unknown export mode {mode!r}")
    for m in model.modules():
        if isinstance(m, DeformConv2d):
            m.export_as = mode
    return model
