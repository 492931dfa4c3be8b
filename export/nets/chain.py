"""The paper's three-stage model (section III-E), as one module with named stages.

* **masks**: ``M_b`` and ``M_h`` from the photo ``I``, each by a backbone UNet
  (:class:`export.nets.backbone.BackboneUNet`, Lite0 encoder).
* **aux**: ``I_bf`` from (I, M_b) by a GAD-UNet; ``I_hr`` and ``I_hr2`` from
  (I, M_b, M_h) by a second GAD-UNet with six output channels (the paper
  leaves open whether the two share a network; sharing halves the cost).
* **maps**: N from (I, I - I_bf); D and S together from (I, I_hr, I_hr2);
  R from (I, I_hr, I_hr2), each by a plain UNet.

Images and masks are in [0, 1] (encoded); the maps come out in their stored
encoding (:func:`svbrdf_cli.conventions.encode_maps`): normals xyz*0.5+0.5
(renormalised), diffuse and specular gamma-encoded, roughness linear. Every
input is centred to [-1, 1] for the UNets; the backbone normalises its own.

Tiers scale every network's width; :func:`build` makes one. The ``lite``
tier (:data:`E2E_TIERS`) is not a chain: one small UNet from the photo to
the maps, the cheapest model ``svbrdf capture --model auto`` starts from.

Two ablations of the paper's Table IV are variants of the same interface
(``run_masks``, ``run_aux``, ``run_maps``, ``stage``), so training,
evaluation and export treat them alike (:data:`VARIANTS`):

* ``nomask``: :class:`SVBRDFNet` with ``use_masks=False``: the aux networks
  get zero masks (input -> aux -> maps without the mask stage);
* ``e2e``: :class:`EndToEndNet`, one UNet from the photo straight to the
  maps, as wide as makes its parameter count that of the whole chain.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch
from torch import nn

from export.nets.backbone import BackboneUNet
from export.nets.gad import GADUNet
from export.nets.unet import UNet
from svbrdf_cli import conventions as cv

STAGES = ("masks", "aux", "maps")
#: Variant -> the stages it trains (see the module docstring).
VARIANTS = {"chain": STAGES, "nomask": ("aux", "maps"), "e2e": ("maps",)}


@dataclasses.dataclass(frozen=True)
class Tier:
    """Widths of one model size."""

    mask_width: float   # BackboneUNet decoder width multiplier
    aux_base: int       # GAD-UNet base channels
    map_base: int       # UNet base channels
    depth: int = 5


TIERS = {
    "fast": Tier(mask_width=0.25, aux_base=16, map_base=16),
    "balanced": Tier(mask_width=0.5, aux_base=32, map_base=32),
    "best": Tier(mask_width=1.0, aux_base=48, map_base=48),
}
#: Tiers that are one end-to-end UNet of this base width (the ``e2e`` variant, no intermediate targets).
E2E_TIERS = {"lite": 16}
#: Refining end-to-end tiers also have a UNet of this base width (depth 4) of their own for the normals'
#: tilt: sharing the maps UNet, the normals never learned (its features went to the easier diffuse,
#: roughness and specular corrections, and the normal head stayed at zero; docs/training.md).
E2E_NORMAL_BASE = 16
#: That normal branch trains at this multiple of the learning rate.
NORMAL_LR_SCALE = 5.0
#: Every tier, cheapest first.
ALL_TIERS = tuple(E2E_TIERS) + tuple(TIERS)


def tier_variant(tier, variant=None):
    """The variant a tier trains: its own for an end-to-end tier, else ``variant`` (default: the chain)."""
    if tier in E2E_TIERS:
        if variant not in (None, "e2e"):
            raise ValueError(f"the {tier} tier is an end-to-end network; it has no {variant!r} variant")
        return "e2e"
    return variant or "chain"


def _centre(x):
    return x * 2.0 - 1.0


#: Channels of the physical estimate as the networks take it: its stored maps stacked
#: (normal 3, diffuse 3, roughness 1, specular 3), the runtime's ``physical`` input.
PHYSICAL_CHANNELS = 10


def physical_input(photo):
    """(B, 3, H, W) encoded photos -> (B, 10, H, W) physical estimates (:mod:`svbrdf_cli.infer.physical`, numpy,
    no gradient), exactly what the runtime feeds an exported model's ``physical`` input."""
    from svbrdf_cli.infer.physical import network_input

    arr = photo.detach().float().permute(0, 2, 3, 1).cpu().numpy()
    return torch.from_numpy(np.stack([network_input(a)[0] for a in arr])).permute(0, 3, 1, 2).to(photo)


def refined_maps(physical, correction):
    """The physical estimate (B, 10) plus a network's correction (B, 10) -> stored-encoding maps.

    Normals add as vectors (the estimate's decoded normal plus the correction's xyz, renormalised, z
    kept >= 1e-3); diffuse, roughness and specular add in the stored encoding and are clipped to
    [0, 1]. A zero correction returns the estimate exactly.
    """
    n = cv.decode_normals(physical[:, :3], axis=1) + correction[:, :3]
    n = torch.cat([n[:, :2], n[:, 2:3].clamp_min(1e-3)], 1)
    rest = (physical[:, 3:] + correction[:, 3:]).clamp(0.0, 1.0)
    return {"normal": cv.encode_normals(cv.normalize(n, axis=1)), "diffuse": rest[:, 0:3],
            "roughness": rest[:, 3:4], "specular": rest[:, 4:7]}


def _correction_unet(in_channels, out_channels, base, depth):
    """A UNet whose output is a correction: no activation, and a zero head, so that before training
    it corrects nothing (the chain returns the physical estimate)."""
    net = UNet(in_channels, out_channels, base=base, depth=depth, out_activation=None)
    nn.init.zeros_(net.decoder.head.weight)
    nn.init.zeros_(net.decoder.head.bias)
    return net


class SVBRDFNet(nn.Module):
    """All stages; ``forward(photo)`` runs the whole chain."""

    def __init__(self, tier="fast", pretrained=True, use_masks=True, refine=True):
        super().__init__()
        t = TIERS[tier] if isinstance(tier, str) else tier
        self.tier = tier if isinstance(tier, str) else "custom"
        self.use_masks = use_masks
        self.refine = refine
        self.variant = "chain" if use_masks else "nomask"
        self.masks = nn.ModuleDict({
            "M_b": BackboneUNet(3, width=t.mask_width, pretrained=pretrained),
            "M_h": BackboneUNet(3, width=t.mask_width, pretrained=pretrained),
        })
        for net in self.masks.values():  # masks are mostly 0: start there (sigmoid(-4) = 0.018)
            nn.init.constant_(net.head.bias, -4.0)
        self.aux = nn.ModuleDict({
            "I_bf": GADUNet(6, 3, base=t.aux_base, depth=t.depth),
            "I_hr": GADUNet(9, 6, base=t.aux_base, depth=t.depth),
        })
        if refine:  # the maps UNets also see the physical estimate and predict corrections to it
            p = PHYSICAL_CHANNELS
            self.maps = nn.ModuleDict({
                "normal": _correction_unet(6 + p, 3, t.map_base, t.depth),
                "diffuse_specular": _correction_unet(9 + p, 6, t.map_base, t.depth),
                "roughness": _correction_unet(9 + p, 1, t.map_base, t.depth),
            })
        else:
            self.maps = nn.ModuleDict({
                "normal": UNet(6, 3, base=t.map_base, depth=t.depth),
                "diffuse_specular": UNet(9, 6, base=t.map_base, depth=t.depth),
                "roughness": UNet(9, 1, base=t.map_base, depth=t.depth),
            })

    def stage(self, name):
        return getattr(self, name)

    def run_masks(self, photo):
        if not self.use_masks:
            zero = photo * 0.0  # masks have the photo's three channels
            return {"M_b": zero, "M_h": zero}
        return {k: net(photo) for k, net in self.masks.items()}

    def run_aux(self, photo, masks):
        x_bf = _centre(torch.cat([photo, masks["M_b"]], 1))
        x_hr = _centre(torch.cat([photo, masks["M_b"], masks["M_h"]], 1))
        hr = self.aux["I_hr"](x_hr)
        return {"I_bf": self.aux["I_bf"](x_bf), "I_hr": hr[:, :3], "I_hr2": hr[:, 3:]}

    def run_maps(self, photo, aux):
        """Maps from the photo and the aux renderings (and, for a refining net, ``aux["physical"]``:
        the physical estimate, computed here when absent)."""
        x_n = torch.cat([_centre(photo), photo - aux["I_bf"]], 1)
        x_s = _centre(torch.cat([photo, aux["I_hr"], aux["I_hr2"]], 1))
        if self.refine:
            phys = aux.get("physical")
            phys = physical_input(photo) if phys is None else phys
            x_n = torch.cat([x_n, _centre(phys)], 1)
            x_s = torch.cat([x_s, _centre(phys)], 1)
            ds = self.maps["diffuse_specular"](x_s)
            corr = torch.cat([self.maps["normal"](x_n), ds[:, :3], self.maps["roughness"](x_s), ds[:, 3:]], 1)
            return refined_maps(phys, corr)
        # Offset by N_u: an untrained (or uncertain) network gives the flat
        # normal, and z = 2 * out_z stays >= 0 (normalising a near-zero vector
        # would give random, often downward, normals with useless gradients).
        n = cv.normalize(_centre(self.maps["normal"](x_n)) + x_n.new_tensor(cv.FLAT_NORMAL).reshape(1, 3, 1, 1), axis=1)
        ds = self.maps["diffuse_specular"](x_s)
        return {"normal": cv.encode_normals(n), "diffuse": ds[:, :3],
                "roughness": self.maps["roughness"](x_s), "specular": ds[:, 3:]}

    def forward(self, photo, physical=None):
        """Photo (B, 3, H, W) in [0, 1] -> dict of stored-encoding maps (and the intermediates)."""
        masks = self.run_masks(photo)
        aux = self.run_aux(photo, masks)
        return {**masks, **aux, **self.run_maps(photo, {**aux, "physical": physical})}


def _encode_maps_head(out, photo):
    """A 10-channel head (normal offset, diffuse, roughness, specular) -> stored-encoding maps."""
    n = cv.normalize(_centre(out[:, :3]) + photo.new_tensor(cv.FLAT_NORMAL).reshape(1, 3, 1, 1), axis=1)
    return {"normal": cv.encode_normals(n), "diffuse": out[:, 3:6], "roughness": out[:, 6:7], "specular": out[:, 7:10]}


class EndToEndNet(nn.Module):
    """Table IV's baseline: input -> maps by one UNet, no intermediate targets.

    ``base`` defaults to the width whose parameter count is closest to the
    whole chain of ``tier`` (:func:`e2e_base`).
    """

    def __init__(self, tier="fast", base=None, depth=5, refine=True, normal_base=E2E_NORMAL_BASE):
        super().__init__()
        self.tier = tier if isinstance(tier, str) else "custom"
        self.variant = "e2e"
        self.refine = refine
        self.base = base or e2e_base(tier)
        self.maps = nn.ModuleDict({"all": _correction_unet(3 + PHYSICAL_CHANNELS, 10, self.base, depth) if refine
                                   else UNet(3, 10, base=self.base, depth=depth)})
        if refine and normal_base:  # the normals' tilt (x, y) from a UNet of their own
            self.maps["normal"] = _correction_unet(3 + PHYSICAL_CHANNELS, 2, normal_base, 4)

    def stage(self, name):
        if name != "maps":
            raise KeyError(f"the end-to-end baseline has only the maps stage, not {name!r}")
        return self.maps

    def run_masks(self, photo):
        return {}

    def run_aux(self, photo, masks):
        return {}

    def run_maps(self, photo, aux=None):
        if self.refine:
            phys = (aux or {}).get("physical")
            phys = physical_input(photo) if phys is None else phys
            x = torch.cat([_centre(photo), _centre(phys)], 1)
            corr = self.maps["all"](x)
            if "normal" in self.maps:
                corr = torch.cat([corr[:, :2] + self.maps["normal"](x), corr[:, 2:]], 1)
            return refined_maps(phys, corr)
        return _encode_maps_head(self.maps["all"](_centre(photo)), photo)

    def forward(self, photo, physical=None):
        return self.run_maps(photo, {"physical": physical})


def e2e_base(tier="fast"):
    """UNet width of an end-to-end ``tier``; for a chain tier, the width giving the chain's parameter count."""
    from export.nets.cost import count_parameters

    if tier in E2E_TIERS:
        return E2E_TIERS[tier]

    target = count_parameters(SVBRDFNet(tier, pretrained=False))
    return min(range(8, 129, 4), key=lambda b: abs(count_parameters(UNet(3, 10, base=b)) - target))


def build(tier="fast", pretrained=True, variant=None, refine=True):
    """A network of ``tier`` and ``variant`` (a key of :data:`VARIANTS`; default: the tier's own);
    ``refine``: its maps stage corrects the physical estimate (False: the paper's plain maps UNets)."""
    variant = tier_variant(tier, variant) if isinstance(tier, str) else (variant or "chain")
    if variant == "e2e":
        return EndToEndNet(tier, refine=refine)
    if variant not in VARIANTS:
        raise ValueError(f"unknown variant {variant!r}; choose one of {', '.join(VARIANTS)}")
    return SVBRDFNet(tier, pretrained=pretrained, use_masks=variant == "chain", refine=refine)


def tier_costs(size=256):
    """{tier: {stage: (parameters, MACs)}} for one sample at ``size``² (an end-to-end tier has one stage, maps)."""
    from export.nets.cost import count_macs, count_parameters

    out = {}
    for name in E2E_TIERS:
        net = EndToEndNet(name)
        out[name] = {"maps": (count_parameters(net), count_macs(
            net, (torch.zeros(1, 3, size, size), torch.zeros(1, PHYSICAL_CHANNELS, size, size))))}
    for name in TIERS:
        net = SVBRDFNet(name, pretrained=False)
        x = torch.zeros(1, 3, size, size)
        row = {}
        for stage in STAGES:
            module = net.stage(stage)
            if stage == "masks":
                def fn(photo, _net=net):
                    return _net.run_masks(photo)
            elif stage == "aux":
                def fn(photo, _net=net):
                    return _net.run_aux(photo, {"M_b": photo, "M_h": photo})
            else:
                def fn(photo, _net=net):
                    zero = photo.new_zeros(photo.shape[0], PHYSICAL_CHANNELS, *photo.shape[2:])
                    return _net.run_maps(photo, {"I_bf": photo, "I_hr": photo, "I_hr2": photo, "physical": zero})
            wrapper = _StageCall(module, fn)
            row[stage] = (count_parameters(module), count_macs(wrapper, (x,)))
        out[name] = row
    return out


class _StageCall(nn.Module):
    """Lets :func:`count_macs` hook one stage's layers while a chain method runs it."""

    def __init__(self, module, fn):
        super().__init__()
        self.module, self.fn = module, fn

    def forward(self, x):
        return self.fn(x)


if __name__ == "__main__":
    for tier, row in tier_costs().items():
        params = sum(p for p, _ in row.values())
        macs = sum(m for _, m in row.values())
        stages = ", ".join(f"{s} {p / 1e6:.2f}M/{m / 1e9:.1f}G" for s, (p, m) in row.items())
        print(f"{tier:9s} {params / 1e6:6.2f}M params {macs / 1e9:6.1f} GMACs at 256²  ({stages})")
