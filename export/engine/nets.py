"""The ``swift`` chain: the paper's three stages as small UNets behind a space-to-depth stem.

Each stage is a UNet that works at half the image size (:class:`S2DNet`): a stride-2 stem folds
every 2x2 block of the input into channels, and a transposed head unfolds the output (4x fewer
positions for the convolutions; measured 4x faster per sample on one core than at full size).

* **masks**: photo (3) + flash context (4) -> ``M_b``, ``M_h`` (6), clipped to [0, 1].
* **aux**: photo + masks + context -> ``I_bf``, ``I_hr``, ``I_hr2`` (9), each the photo plus a
  correction (a zero head: an untrained stage returns the photo three times).
* **maps**: photo + masks + aux + base estimate (10) + context -> a correction to the base estimate
  (:func:`export.nets.chain.refined_maps`; a zero head: an untrained chain returns the estimate).

Inputs are centred to [-1, 1] where they are images (photo, masks, aux, base); the context fields
go in as they are (they are of order one).
"""

from __future__ import annotations

import dataclasses

import torch
import torch.nn.functional as F
from torch import nn

from export.engine.flash import BASE_CHANNELS, CONTEXT_CHANNELS
from export.nets.chain import refined_maps

STAGES = ("masks", "aux", "maps")
IN_CHANNELS = {"masks": 3 + CONTEXT_CHANNELS, "aux": 3 + 6 + CONTEXT_CHANNELS,
               "maps": 3 + 6 + 9 + BASE_CHANNELS + CONTEXT_CHANNELS}
OUT_CHANNELS = {"masks": 6, "aux": 9, "maps": 10}


@dataclasses.dataclass(frozen=True)
class Widths:
    """Base width and depth of each stage's UNet (at half resolution)."""

    masks: tuple = (16, 4)
    aux: tuple = (16, 4)
    maps: tuple = (22, 4)


TIERS = {"swift": Widths()}


class _Block(nn.Sequential):
    def __init__(self, cin, cout):
        super().__init__(nn.Conv2d(cin, cout, 3, padding=1), nn.LeakyReLU(0.2, inplace=True),
                         nn.Conv2d(cout, cout, 3, padding=1), nn.LeakyReLU(0.2, inplace=True))


class S2DNet(nn.Module):
    """A UNet at half resolution: a 2x2 stride-2 convolution stem (a pixel-unshuffle and a 1x1
    convolution in one), ``depth`` levels down by stride-2 3x3 convolutions (widths ``base * 2**i``,
    at most 8x), back up by nearest-neighbour doubling, concatenation with the skip and two 3x3
    convolutions, and a 2x2 stride-2 transposed-convolution head (a 1x1 convolution and a
    pixel-shuffle in one). LeakyReLU(0.2), no normalisation. Measured on one core under bf16, against
    a pixel-unshuffle around :class:`export.nets.unet.UNet` (max-pool, bilinear): 1.25x faster to train
    at base 24, 1.3x faster to run."""

    def __init__(self, in_channels, out_channels, base, depth, zero_head=False):
        super().__init__()
        w = [base * min(2 ** i, 8) for i in range(depth + 1)]
        self.out_channels = out_channels
        self.stem = nn.Sequential(nn.Conv2d(in_channels, w[0], 2, stride=2), nn.LeakyReLU(0.2, inplace=True),
                                  _Block(w[0], w[0]))
        self.down = nn.ModuleList(
            nn.Sequential(nn.Conv2d(w[i], w[i + 1], 3, stride=2, padding=1), nn.LeakyReLU(0.2, inplace=True),
                          _Block(w[i + 1], w[i + 1])) for i in range(depth))
        self.up = nn.ModuleList(_Block(w[i + 1] + w[i], w[i]) for i in reversed(range(depth)))
        self.head = nn.ConvTranspose2d(w[0], out_channels, 2, stride=2)
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, a=0.2, nonlinearity="leaky_relu")
                nn.init.zeros_(m.bias)
        if zero_head:
            nn.init.zeros_(self.head.weight)
            nn.init.zeros_(self.head.bias)

    def forward(self, x):
        if torch.is_autocast_enabled("cpu"):  # the stem casts it anyway: change the layout of half the bytes
            x = x.to(torch.get_autocast_dtype("cpu"))
        x = self.stem(x.contiguous(memory_format=torch.channels_last))
        skips = [x]
        for down in self.down:
            x = down(x)
            skips.append(x)
        skips.pop()
        for up in self.up:
            x = up(torch.cat([F.interpolate(x, scale_factor=2.0, mode="nearest"), skips.pop()], 1))
        return self.head(x).contiguous()


def _c(x):
    return x * 2.0 - 1.0


class SwiftChain(nn.Module):
    """The three stages; each ``run_<stage>`` takes what the stage needs and returns its output in
    the targets' encoding (see the module docstring)."""

    def __init__(self, widths=Widths()):
        super().__init__()
        self.masks = S2DNet(IN_CHANNELS["masks"], 6, *widths.masks)
        self.aux = S2DNet(IN_CHANNELS["aux"], 9, *widths.aux, zero_head=True)
        self.maps = S2DNet(IN_CHANNELS["maps"], 10, *widths.maps, zero_head=True)

    def run_masks(self, photo, context):
        out = self.masks(torch.cat([_c(photo), context], 1)).float()
        return out.clamp(0.0, 1.0) if not self.training else out

    def run_aux(self, photo, masks, context):
        out = self.aux(torch.cat([_c(photo), _c(masks), context], 1)).float()
        return photo.repeat(1, 3, 1, 1) + out

    def run_maps(self, photo, masks, aux, base, context):
        x = torch.cat([_c(photo), _c(masks), _c(aux), _c(base), context], 1)
        return refined_maps(base, self.maps(x).float())

    def forward(self, photo, context, base):
        masks = self.run_masks(photo, context).clamp(0.0, 1.0)
        aux = self.run_aux(photo, masks, context).clamp(0.0, 1.0)
        return masks, aux, self.run_maps(photo, masks, aux, base, context)


def build(tier="swift"):
    """The chain of ``tier``, its weights channels-last (faster convolutions on CPU)."""
    return SwiftChain(TIERS[tier]).to(memory_format=torch.channels_last)
