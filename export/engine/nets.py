"""The ``swift`` chain: the paper's three stages as small UNets behind a space-to-depth stem.

Each stage is a :class:`export.nets.unet.UNet` that works at half the image size: a pixel-unshuffle
stem folds every 2x2 block of the input into channels, and a pixel-shuffle head unfolds the output
(4x fewer positions for the convolutions; measured 4x faster per sample on one core).

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
from export.nets.unet import UNet

STAGES = ("masks", "aux", "maps")
IN_CHANNELS = {"masks": 3 + CONTEXT_CHANNELS, "aux": 3 + 6 + CONTEXT_CHANNELS,
               "maps": 3 + 6 + 9 + BASE_CHANNELS + CONTEXT_CHANNELS}
OUT_CHANNELS = {"masks": 6, "aux": 9, "maps": 10}


@dataclasses.dataclass(frozen=True)
class Widths:
    """Base width and depth of each stage's UNet (at half resolution)."""

    masks: tuple = (16, 4)
    aux: tuple = (16, 4)
    maps: tuple = (24, 4)


TIERS = {"swift": Widths()}


class S2DNet(nn.Module):
    """A UNet at half resolution between a pixel-unshuffle stem and a pixel-shuffle head."""

    def __init__(self, in_channels, out_channels, base, depth, zero_head=False):
        super().__init__()
        self.out_channels = out_channels
        self.unet = UNet(in_channels * 4, out_channels * 4, base=base, depth=depth, out_activation=None)
        if zero_head:
            nn.init.zeros_(self.unet.decoder.head.weight)
            nn.init.zeros_(self.unet.decoder.head.bias)

    def forward(self, x):
        x = F.pixel_unshuffle(x, 2).contiguous(memory_format=torch.channels_last)
        return F.pixel_shuffle(self.unet(x), 2).contiguous()


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
