"""Plain UNet ("the original UNet of [15]", Ronneberger et al. 2015) for the third stage.

The paper maps (I, I - I_bf) to the normal map and (I, I_hr, I_hr2) to diffuse/specular and to
roughness with UNets "in their original form [15], except for differences in hyperparameters",
with base width 48 (Sec. IV-F: a third-stage UNet has about 15M parameters).

Layout, for ``depth`` downsamplings (input sides must be divisible by ``2**depth``):

* encoder level 0: two conv3x3-norm-LeakyReLU(0.2) blocks, ``in_channels -> base``;
* encoder level i = 1..depth: 2x2 max-pool, then two conv blocks, width
  ``base * 2**min(i, log2(max_mult))``;
* decoder level i = depth..1: bilinear x2 upsample, concatenation with the encoder's level i-1
  skip, two conv blocks down to the level i-1 width;
* head: 1x1 conv to ``out_channels`` and ``out_activation`` ("sigmoid", "tanh" or None).

Widths are capped at ``max_mult * base`` (default 8x, like Des18's cap of 512 = 8 x 64): with
``depth=5``, ``base=48`` and 9 input channels this gives 17.7M parameters (the paper: "15M";
its exact hyperparameters are in a supplement we do not have).

Normalization (``norm``): ``"none"`` (default), ``"group"`` or ``"instance"``. All three behave
identically in train and eval mode at any batch size (no running statistics) and export to
ONNX (opset 19: GroupNorm as InstanceNormalization plus reshapes). The default is no
normalization because

* it is the original form of [15] that the paper says it uses;
* per-image normalization (instance or group norm) makes every layer after it nearly
  invariant to a global scale and offset of its input, so the network loses the absolute
  intensity of the image. These networks regress absolute quantities (albedo, a rendering
  whose brightness must equal the input's); Des18 uses instance norm but has to re-inject
  per-image means through its global-feature track for exactly this reason, and image
  restoration nets (EDSR, DeepFill) drop normalization for the same "range flexibility";
* with He initialisation for LeakyReLU and skip connections, a 20-odd-layer UNet trains
  fine without normalization under Adam (the paper's lr 2e-4, betas 0.5/0.9).

``norm="group"`` is there for experiments (GroupNorm with up to 32 groups of >= 2 channels).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["UNet", "ConvBlock", "DoubleConv", "UpBlock", "make_norm", "level_widths"]

_NEG_SLOPE = 0.2


def make_norm(kind: str | None, ch: int) -> nn.Module:
    """``"none"``/None -> Identity, ``"group"`` -> GroupNorm, ``"instance"`` -> InstanceNorm."""
    if kind in (None, "none"):
        return nn.Identity()
    if kind == "group":
        groups = next(g for g in (32, 16, 8, 4, 2, 1) if ch % g == 0 and (ch // g >= 2 or g == 1))
        return nn.GroupNorm(groups, ch)
    if kind == "instance":
        return nn.InstanceNorm2d(ch, affine=True, track_running_stats=False)
    raise ValueError(f"unknown norm {kind!r} (none, group, instance)")


def init_conv_(conv: nn.Conv2d, slope: float = _NEG_SLOPE) -> None:
    """He-normal init for a conv followed by LeakyReLU(slope); zero bias."""
    nn.init.kaiming_normal_(conv.weight, a=slope, mode="fan_in", nonlinearity="leaky_relu")
    if conv.bias is not None:
        nn.init.zeros_(conv.bias)


def level_widths(base: int, depth: int, max_mult: int = 8) -> list[int]:
    """Channel width of each of the ``depth + 1`` levels."""
    if base < 1 or depth < 0 or max_mult < 1:
        raise ValueError("base >= 1, depth >= 0 and max_mult >= 1 required")
    cap = int(math.log2(max_mult))
    return [base * 2 ** min(i, cap) for i in range(depth + 1)]


class ConvBlock(nn.Sequential):
    """conv3x3 (stride 1 or 2) -> norm -> LeakyReLU(0.2)."""

    def __init__(self, in_ch: int, out_ch: int, stride: int = 1, norm: str | None = "none"):
        conv = nn.Conv2d(in_ch, out_ch, 3, stride, 1, bias=norm in (None, "none"))
        init_conv_(conv)
        super().__init__(conv, make_norm(norm, out_ch), nn.LeakyReLU(_NEG_SLOPE, inplace=True))


class DoubleConv(nn.Sequential):
    """Two :class:`ConvBlock` (the first may have stride 2)."""

    def __init__(self, in_ch: int, out_ch: int, stride: int = 1, norm: str | None = "none"):
        super().__init__(
            ConvBlock(in_ch, out_ch, stride, norm), ConvBlock(out_ch, out_ch, 1, norm)
        )


class UpBlock(nn.Module):
    """Bilinear x2 upsample, concatenate the skip, :class:`DoubleConv` to ``out_ch``."""

    def __init__(self, in_ch: int, skip_ch: int, out_ch: int, norm: str | None = "none"):
        super().__init__()
        self.conv = DoubleConv(in_ch + skip_ch, out_ch, 1, norm)

    def forward(self, x: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
        x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
        return self.conv(torch.cat([x, skip], dim=1))


class Decoder(nn.Module):
    """The UNet decoder shared by :class:`UNet` and the GAD-UNet: from the
    deepest of ``skips`` (one per level, widths ``widths``) up through
    :class:`UpBlock` blocks to a 1x1 head (no activation)."""

    def __init__(self, widths, out_channels, norm=None):
        super().__init__()
        d = len(widths) - 1
        self.up = nn.ModuleList(UpBlock(widths[i], widths[i - 1], widths[i - 1], norm) for i in range(d, 0, -1))
        self.head = nn.Conv2d(widths[0], out_channels, 1)
        nn.init.xavier_uniform_(self.head.weight)
        nn.init.zeros_(self.head.bias)

    def forward(self, skips):
        skips = list(skips)
        y = skips.pop()
        for up in self.up:
            y = up(y, skips.pop())
        return self.head(y)


def apply_activation(x: torch.Tensor, kind: str | None) -> torch.Tensor:
    if kind is None or kind == "none":
        return x
    if kind == "sigmoid":
        return torch.sigmoid(x)
    if kind == "tanh":
        return torch.tanh(x)
    raise ValueError(f"unknown out_activation {kind!r} (sigmoid, tanh, None)")


class UNet(nn.Module):
    """Plain UNet; see the module docstring. Input (N, in_channels, H, W) with H, W divisible
    by ``2**depth``; output (N, out_channels, H, W)."""

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        base: int = 32,
        depth: int = 5,
        out_activation: str | None = "sigmoid",
        norm: str | None = "none",
        max_mult: int = 8,
    ):
        super().__init__()
        apply_activation(torch.zeros(1), out_activation)  # validate early
        self.in_channels = int(in_channels)
        self.out_channels = int(out_channels)
        self.depth = int(depth)
        self.out_activation = out_activation
        w = level_widths(base, depth, max_mult)
        self.widths = w
        self.inc = DoubleConv(in_channels, w[0], 1, norm)
        self.down = nn.ModuleList(
            nn.Sequential(nn.MaxPool2d(2), DoubleConv(w[i - 1], w[i], 1, norm))
            for i in range(1, depth + 1)
        )
        self.decoder = Decoder(w, out_channels, norm)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = [self.inc(x)]
        for down in self.down:
            skips.append(down(skips[-1]))
        return apply_activation(self.decoder(skips), self.out_activation)
