"""GAD-Conv (gated deformable convolution, Eq. 12) and GAD-UNet (second stage of the paper).

Reading of Sec. III-E, Fig. 7(b) and Eq. 12
--------------------------------------------
* A gated convolution on the input X^l has two branches: one computes the features X^l'
  (conv -> activation), the other the gate sigma (conv -> sigmoid, one gate per output channel
  and pixel, as in DeepFill v2's gated conv). Its output is ``sigma * X^l'``.
* "The output of the gated convolution, i.e. (sigma * X^l'), is further processed by a
  deformable convolution block. Denote the output of the deformable convolution block by
  X^l''." So the deformable conv runs *after* the gate, on ``sigma * X^l'`` (the modules are
  "sequentially executed", Fig. 7 caption), not in parallel on X^l.
* Eq. 12: ``X^{l+1} = sigma * X^l' + (1 - sigma) * X^l''``. Where the gate is open (valid
  content) the gated features pass through; where it is closed (highlight / bumpiness
  regions) the output is filled by the deformable branch, which can reach content further
  away ("inpaint these regions by the deformable convolution").

Note the naming: X' is the *gated-conv feature* branch and X'' the *deformable* branch (the
reverse of what a quick reading might suggest). The same sigma appears in both terms.

Details the paper leaves to its supplement, chosen here: 3x3 kernels; a stride-2 GAD-Conv
strides its gated convolution, the deformable conv then runs at stride 1 on the downsampled
gated features (so sigma, X' and X'' share one resolution); the deformable block is
deformable conv3x3 -> [norm] -> LeakyReLU(0.2); offsets start at zero.

GAD-UNet = the UNet of :mod:`export.nets.unet` with each encoder level's conv module (two
3x3 convs) replaced by one GAD-Conv, which is itself two 3x3 convs deep (gated conv, then
deformable conv): level 0 is ``GADConv(in, base)``, level i (1..depth) a stride-2 GAD-Conv
(downsampling by stride 2, no max-pool); ``blocks_per_level`` > 1 appends stride-1
GAD-Convs. Decoder and head are the plain UNet's (bilinear upsample, skip concatenation, two
conv blocks), sigmoid output in [0, 1]. With ``base=48``, ``depth=5`` and 9 input channels
this is 21.4M parameters against 17.7M for the plain UNet, near the paper's "25M" and "15M"
(Sec. IV-F; the exact widths are in the paper's supplement, which we do not have).
"""

from __future__ import annotations

import torch
from torch import nn

from .deform import DeformConv2d
from .unet import Decoder, apply_activation, init_conv_, level_widths, make_norm

__all__ = ["GADConv", "GADUNet"]

_NEG_SLOPE = 0.2


class GADConv(nn.Module):
    """Gated deformable convolution (Eq. 12): ``sigma*X' + (1-sigma)*DCN(sigma*X')``.

    ``forward(x, return_gate=False)``; with ``return_gate=True`` also returns sigma.
    """

    def __init__(self, in_ch: int, out_ch: int, stride: int = 1, norm: str | None = "none"):
        super().__init__()
        plain = norm in (None, "none")
        self.feature = nn.Conv2d(in_ch, out_ch, 3, stride, 1, bias=plain)
        self.feature_norm = make_norm(norm, out_ch)
        self.gate = nn.Conv2d(in_ch, out_ch, 3, stride, 1, bias=True)
        self.deform = DeformConv2d(out_ch, out_ch, 3, 1, 1, bias=plain)
        self.deform_norm = make_norm(norm, out_ch)
        self.act = nn.LeakyReLU(_NEG_SLOPE)
        init_conv_(self.feature)
        # Gate starts near 0.5 everywhere (small weights, zero bias).
        nn.init.normal_(self.gate.weight, std=0.01)
        nn.init.zeros_(self.gate.bias)
        nn.init.kaiming_normal_(self.deform.weight, a=_NEG_SLOPE, nonlinearity="leaky_relu")
        if self.deform.bias is not None:
            nn.init.zeros_(self.deform.bias)

    def forward(self, x: torch.Tensor, return_gate: bool = False):
        feat = self.act(self.feature_norm(self.feature(x)))  # X^l'
        sigma = torch.sigmoid(self.gate(x))
        gated = sigma * feat  # output of the gated convolution
        inpaint = self.act(self.deform_norm(self.deform(gated)))  # X^l''
        out = gated + (1.0 - sigma) * inpaint  # Eq. 12
        return (out, sigma) if return_gate else out


class GADUNet(nn.Module):
    """UNet whose encoder uses GAD-Conv; see the module docstring. Sides divisible by
    ``2**depth``. Output (N, out_channels, H, W) in [0, 1] (``out_activation="sigmoid"``)."""

    def __init__(
        self,
        in_channels: int,
        out_channels: int = 3,
        base: int = 32,
        depth: int = 5,
        norm: str | None = "none",
        max_mult: int = 8,
        out_activation: str | None = "sigmoid",
        blocks_per_level: int = 1,
    ):
        super().__init__()
        apply_activation(torch.zeros(1), out_activation)
        self.in_channels = int(in_channels)
        self.out_channels = int(out_channels)
        self.depth = int(depth)
        self.out_activation = out_activation
        w = level_widths(base, depth, max_mult)
        self.widths = w
        if blocks_per_level < 1:
            raise ValueError("blocks_per_level >= 1")
        self.enc = nn.ModuleList()
        for i in range(depth + 1):
            cin = in_channels if i == 0 else w[i - 1]
            blocks = [GADConv(cin, w[i], 1 if i == 0 else 2, norm)]
            blocks += [GADConv(w[i], w[i], 1, norm) for _ in range(blocks_per_level - 1)]
            self.enc.append(nn.Sequential(*blocks))
        self.decoder = Decoder(w, out_channels, norm)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        y = x
        for level in self.enc:
            y = level(y)
            skips.append(y)
        return apply_activation(self.decoder(skips), self.out_activation)
