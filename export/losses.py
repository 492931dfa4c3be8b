"""Training losses of the paper (section III-F).

* masks: L2 (Eq. 13, as a mean squared error);
* auxiliary renderings: L1 (Eq. 14) + 1e-3 WGAN-GP (Eq. 15, lambda = 10) +
  0.1 perceptual (Eq. 16). The paper's perceptual features are VGG16
  pool1-3, which cannot be downloaded here: we use the first three scales
  (strides 2, 4, 8) of the ImageNet-pretrained EfficientNet-Lite0 encoder,
  frozen (:class:`export.nets.lite0.Lite0Features`), each scale's error
  relative to the target features' magnitude (see :func:`perceptual_loss`);
* maps: L1 on the stored encoding + 0.5 rendering loss (Eq. 18): the
  predicted map, with the *ground-truth* other maps, rendered under 9
  random lights and views, against the ground truth rendered the same way
  (compared as log(x + 0.01) as in Des18, ref. [14], so highlights do not
  dominate).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from export.render.brdf import render
from svbrdf_cli import conventions as cv

AUX_WEIGHTS = {"rec": 1.0, "adv": 1e-3, "percep": 0.1}
GP_LAMBDA = 10.0
MAP_WEIGHTS = {"rec": 1.0, "render": 0.5}
RENDER_LIGHTS = 9


def mask_loss(pred, target):
    return F.mse_loss(pred, target)


class Critic(nn.Module):
    """WGAN-GP critic (the convolutional critic of Gulrajani et al., ref. [71]):
    strided 4x4 convolutions with leaky ReLU, no batch norm (it would break
    the per-sample gradient penalty), a linear score."""

    def __init__(self, in_channels=3, base=32, levels=4):
        super().__init__()
        layers, c = [], in_channels
        for i in range(levels):
            layers += [nn.Conv2d(c, base * 2 ** i, 4, 2, 1), nn.LeakyReLU(0.2)]
            c = base * 2 ** i
        self.body = nn.Sequential(*layers)
        self.score = nn.Conv2d(c, 1, 3, padding=1)

    def forward(self, x):
        return self.score(self.body(x * 2 - 1)).mean((1, 2, 3))


def gradient_penalty(critic, real, fake):
    eps = torch.rand(real.shape[0], 1, 1, 1, device=real.device, dtype=real.dtype)
    mix = (eps * real + (1 - eps) * fake).requires_grad_(True)
    grad, = torch.autograd.grad(critic(mix).sum(), mix, create_graph=True)
    return ((grad.flatten(1).norm(dim=1) - 1) ** 2).mean()


def critic_loss(critic, real, fake):
    """Eq. 15 for the critic: E[D(fake)] - E[D(real)] + lambda * GP."""
    fake = fake.detach()
    return critic(fake).mean() - critic(real).mean() + GP_LAMBDA * gradient_penalty(critic, real, fake)


def perceptual_loss(features, pred, target):
    """Eq. 16 with ``features`` (a frozen extractor returning a list of maps).

    Each scale's L1 is divided by the mean magnitude of the target's
    features at that scale (detached): Lite0's activations are ~5 on average,
    so the raw L1 came out 30-80x the image L1 and, even at weight 0.1,
    drowned it (the networks then ignored overall brightness and colour,
    which these features barely see). Normalised, the term is a relative
    feature error of order 0.1-1, beside an image L1 of order 0.05-0.1.
    """
    fp, ft = features(pred), features(target)
    return sum(F.l1_loss(a, b) / b.detach().abs().mean().clamp_min(1e-6) for a, b in zip(fp, ft)) / len(fp)


def aux_loss(pred, target, features=None, critic=None):
    """Eq. 17 for one auxiliary rendering; returns (total, parts)."""
    parts = {"rec": F.l1_loss(pred, target)}
    if features is not None:
        parts["percep"] = perceptual_loss(features, pred, target)
    if critic is not None:
        parts["adv"] = -critic(pred).mean()
    total = sum(AUX_WEIGHTS[k] * v for k, v in parts.items())
    return total, parts


def random_light_views(batch, count=RENDER_LIGHTS, generator=None, device="cpu", dtype=torch.float32):
    """(count, B, 3) light and camera positions: directions cosine-distributed
    over the hemisphere at distances 2-5 surface half-widths (Des18-like)."""
    def draw():
        u = torch.rand(count, batch, 3, generator=generator, device=generator.device if generator else device)
        r, phi = u[..., 0].sqrt(), u[..., 1] * 2 * math.pi
        d = torch.stack([r * phi.cos(), r * phi.sin(), (1 - r * r).clamp_min(0.05).sqrt()], -1)
        return (cv.normalize(d, axis=-1) * (2 + 3 * u[..., 2:3])).to(device=device, dtype=dtype)
    return draw(), draw()


def _log_renders(maps, lights, cameras):
    return [torch.log(render(maps["normal"], maps["diffuse"], maps["roughness"], maps["specular"],
                             light=light, camera=cam, intensity=cv.LIGHT_INTENSITY) + 0.01)
            for light, cam in zip(lights, cameras)]


def rendering_loss(pred_linear, target_linear, lights, cameras, target_renders=None):
    """Eq. 18: mean L1 of log renderings over the lights; maps are linear dicts
    (``target_renders``: the target's log renderings, when already made)."""
    b = target_renders if target_renders is not None else _log_renders(target_linear, lights, cameras)
    a = _log_renders(pred_linear, lights, cameras)
    return sum(F.l1_loss(x, y) for x, y in zip(a, b)) / len(lights)


def map_losses(pred_stored, target_stored, lights, cameras, names=cv.MAP_NAMES):
    """Eq. 19 for each map in ``names``: L1 on the stored encoding + 0.5 times the
    rendering loss of that map with the ground-truth others. Returns (total, parts)."""
    target_linear = cv.decode_maps(target_stored, axis=1)
    pred_linear = cv.decode_maps(pred_stored, axis=1)
    parts = {}
    total = 0
    with torch.no_grad():  # the target's renderings are the same for every map: once
        target_renders = _log_renders(target_linear, lights, cameras)
    for name in names:
        rec = F.l1_loss(pred_stored[name], target_stored[name])
        mixed = dict(target_linear)
        mixed[name] = pred_linear[name]
        ren = rendering_loss(mixed, target_linear, lights, cameras, target_renders)
        parts[name] = rec
        parts[name + "_render"] = ren
        total = total + MAP_WEIGHTS["rec"] * rec + MAP_WEIGHTS["render"] * ren
    return total, parts
