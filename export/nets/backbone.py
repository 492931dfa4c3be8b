"""Backbone UNet (paper §III-E): ImageNet-pretrained EfficientNet-Lite0 encoder, conv decoder
with skip connections at 5 scales, sigmoid output. Used for the bumpiness mask M_b and the
highlight mask M_h.

Decoder, from the stride-32 encoder output down to full resolution::

    for each of 5 decoder blocks (strides 16, 8, 4, 2, 1):
        bilinear upsample x2 -> concat skip -> (conv3x3 + norm + ReLU) x 2
    conv3x3 -> out_channels -> sigmoid

The skips are the encoder maps at strides 16, 8, 4, 2 and, at full resolution, the input
image itself. Decoder widths are ``(256, 128, 64, 32, 16) * width`` (at least 8).
Works for any H, W divisible by 32 and exports to ONNX (opset 19, ``dynamo=False``) with
only Conv, BatchNormalization, Slice, Clip, Add, Sub, Div, Resize, Concat, Relu, Sigmoid
(no shape-dependent subgraphs).
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

from .lite0 import Lite0Encoder

BASE_DECODER_CHANNELS = (256, 128, 64, 32, 16)
MIN_CHANNELS = 8


def decoder_channels(width: float) -> tuple[int, ...]:
    return tuple(max(MIN_CHANNELS, int(round(c * width))) for c in BASE_DECODER_CHANNELS)


def _norm(kind: str, channels: int) -> nn.Module:
    if kind == "bn":
        return nn.BatchNorm2d(channels)
    if kind == "gn":
        groups = 8 if channels % 8 == 0 else 1
        return nn.GroupNorm(groups, channels)
    if kind == "none":
        return nn.Identity()
    raise ValueError(f"norm must be 'bn', 'gn' or 'none', not {kind!r}")


class ConvNormAct(nn.Sequential):
    def __init__(self, cin: int, cout: int, norm: str = "bn"):
        super().__init__(
            nn.Conv2d(cin, cout, 3, padding=1, bias=norm == "none"),
            _norm(norm, cout),
            nn.ReLU(),
        )


class DecoderBlock(nn.Module):
    """Upsample x2 (bilinear), concat the skip, two conv3x3+norm+ReLU."""

    def __init__(self, cin: int, cskip: int, cout: int, norm: str = "bn"):
        super().__init__()
        self.conv1 = ConvNormAct(cin + cskip, cout, norm)
        self.conv2 = ConvNormAct(cout, cout, norm)

    def forward(self, x: torch.Tensor, skip: torch.Tensor | None) -> torch.Tensor:
        x = F.interpolate(x, scale_factor=2.0, mode="bilinear", align_corners=False)
        if skip is not None:
            x = torch.cat([x, skip], 1)
        return self.conv2(self.conv1(x))


class BackboneUNet(nn.Module):
    """Lite0-encoder UNet: ``forward(x)`` maps (N, in_channels, H, W) in [0, 1] to
    (N, out_channels, H, W) in [0, 1]; H and W must be divisible by 32."""

    def __init__(
        self,
        out_channels: int = 3,
        width: float = 1.0,
        in_channels: int = 3,
        pretrained: bool = True,
        norm: str = "bn",
    ):
        super().__init__()
        self.in_channels, self.out_channels, self.width = in_channels, out_channels, width
        self.encoder = Lite0Encoder(in_channels, pretrained)
        enc = self.encoder.channels  # strides 2, 4, 8, 16, 32
        skips = (enc[3], enc[2], enc[1], enc[0], in_channels)  # strides 16, 8, 4, 2, 1
        blocks = []
        cin = enc[4]
        for cskip, cout in zip(skips, decoder_channels(width)):
            blocks.append(DecoderBlock(cin, cskip, cout, norm))
            cin = cout
        self.decoder = nn.ModuleList(blocks)
        self.head = nn.Conv2d(cin, out_channels, 3, padding=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        f2, f4, f8, f16, f32 = self.encoder(x)
        y = f32
        for block, skip in zip(self.decoder, (f16, f8, f4, f2, x)):
            y = block(y, skip)
        return torch.sigmoid(self.head(y))
