"""Real flash photos in the training loop: self-supervised batches, and the photos kept out of them.

A real photo has no ground truth, but it is its own target: the predicted maps, rendered under the
flash the capture estimates from the photo (:func:`svbrdf_cli.infer.geometry.for_capture`: the highlight's
centre, the EXIF or the falloff's height), must give the photo back. Each photo goes through the
runtime's own path once (decode, auto crop, :data:`svbrdf_cli.infer.exposure.NETWORK_SIZE`², auto exposure:
exactly what ``svbrdf capture`` feeds a model) and is kept in memory with its flash position; a batch
takes random windows of them (rotations and mirrors are left out: they would move the camera's foot),
with the flash position moved into each window's coordinates.

:func:`rendering_loss` compares the rendering with the photo in the encoded space, with the flash
intensity fitted in closed form (one auto-exposed photo does not give it), leaving out clipped pixels
and the highlight's core (where a clipped photo says least and the smallest error in the flash
position matters most).

**Kept out** (:func:`split`): the 12 real benchmark photos (:func:`export.files.real_photos`),
every photo of ``paper_real`` and ``card_blue_9lights`` (they are scored), and every fifth
``henzler_train`` folder (sorted), for measuring what training on real photos does on photos it has
not seen (the false-metal rate, the previews). Trained on: the rest of ``henzler_train`` and
``des18_real``.
"""

from __future__ import annotations

import os

import numpy as np
import torch

from export.render.brdf import render
from svbrdf_cli import conventions as cv

TRAIN_SETS = ("henzler_train", "des18_real")
HELD_OUT_SETS = ("paper_real", "card_blue_9lights", "luo2024")
HELD_OUT_EVERY = 5
#: Pixels of the photo above this (encoded) are clipped: no target there.
CLIPPED = 0.98
#: The highlight's core: pixels within this many surface units of the highlight's centre are left out.
CORE_RADIUS = 0.08
#: :func:`f0_floor_loss`: F0 (stored encoding, mean of its channels) under a dielectric's costs its shortfall.
#: The rendering loss leaves out the highlight's core, where a smooth material shows its lobe, and left to
#: it alone the chain took F0 down to nothing on real photos: 0.0001 (luminance, linear) on the varnished
#: wood henzler_train IMG_9438 and 0.002-0.016 on four other henzler_train photos, at 4,166k samples as at
#: the installed 2,376k, where no material has F0 under water's 0.02.
F0_FLOOR = float(cv.albedo_to_stored(np.float32(cv.DIELECTRIC_F0)))


def _photos(root, sub):
    base = os.path.join(root, sub)
    if not os.path.isdir(base):
        return []
    return sorted(os.path.join(d, f) for d, _, fs in os.walk(base) for f in fs
                  if f.lower().endswith((".jpg", ".jpeg", ".png")) and not f.startswith("paper_")
                  and "reference_maps" not in d)


def split(real_root):
    """(train, held_out) lists of photo paths under ``real_root`` (see the module docstring)."""
    from export.files import real_photos

    scored = set(real_photos(real_root))
    train, held = [], []
    for sub in TRAIN_SETS:
        folders = sorted({os.path.dirname(p) for p in _photos(real_root, sub)})
        kept_out = set(folders[::HELD_OUT_EVERY]) if sub == "henzler_train" else set()
        for p in _photos(real_root, sub):
            (held if p in scored or os.path.dirname(p) in kept_out else train).append(p)
    for sub in HELD_OUT_SETS:
        held += _photos(real_root, sub)
    return train, held


def prepare(path):
    """(encoded network input (S, S, 3) float32, flash position (3,)) of one photo, as ``svbrdf capture``
    makes them; None when the capture path refuses the photo."""
    from svbrdf_cli.errors import SvbrdfError
    from svbrdf_cli.infer import geometry
    from svbrdf_cli.infer.exposure import network_input
    from svbrdf_cli.ingest import photo as ingest
    from svbrdf_cli.rectify import crops as rectify

    try:
        photo = ingest.load_photo(path)
        crop = rectify.crop(photo.linear, "auto")
        net_in = network_input(crop.image)
        geo = geometry.for_capture(net_in, photo.focal_35mm, photo.linear.shape, crop.report)
    except (SvbrdfError, ValueError, OSError):
        return None
    return net_in.astype(np.float32), np.asarray(geo.light, np.float32)


class RealPhotos:
    """The training photos in memory: (N, 3, S, S) encoded and (N, 3) flash positions."""

    def __init__(self, paths, log=None):
        photos, lights, names = [], [], []
        for p in paths:
            r = prepare(p)
            if r is None:
                if log:
                    log(f"real photos: {p} refused by the capture path, left out")
                continue
            photos.append(torch.from_numpy(r[0]).permute(2, 0, 1))
            lights.append(torch.from_numpy(r[1]))
            names.append(p)
        if not photos:
            raise FileNotFoundError("no real training photos")
        self.photos, self.lights, self.names = torch.stack(photos), torch.stack(lights), names

    def __len__(self):
        return len(self.names)

    def batch(self, g, n, size):
        """``n`` random windows of ``size``² (a quarter to all of a photo's side), resampled to ``size``,
        with the flash position in each window's coordinates: ``photo`` (n, 3, size, size), ``light`` (n, 3)."""
        idx = torch.randint(0, len(self), (n,), generator=g)
        frac = 0.5 + 0.5 * torch.rand(n, generator=g)
        centre = (torch.rand(n, 2, generator=g) * 2 - 1) * (1 - frac)[:, None]  # in [-1, 1] image coordinates
        theta = torch.zeros(n, 2, 3)
        theta[:, 0, 0] = frac
        theta[:, 1, 1] = frac
        theta[:, :, 2] = centre
        grid = torch.nn.functional.affine_grid(theta, (n, 3, size, size), align_corners=False)
        photo = torch.nn.functional.grid_sample(self.photos[idx], grid, mode="bilinear", align_corners=False)
        light = self.lights[idx].clone()
        # image y grows downward, surface y upward: the window's centre in surface units is (cx, -cy)
        light[:, 0] = (light[:, 0] - centre[:, 0] * cv.SURFACE_HALF_SIZE) / frac
        light[:, 1] = (light[:, 1] + centre[:, 1] * cv.SURFACE_HALF_SIZE) / frac
        light[:, 2] = light[:, 2] / frac
        return {"photo": photo, "light": light}


def rendering_loss(stored, photo, light):
    """Mean L1 between the encoded photo and the maps rendered under ``light`` (camera at the flash),
    the intensity fitted per photo by least squares on the kept pixels; clipped pixels and the
    highlight's core left out.

    Args:
        stored: dict of (B, C, H, W) maps in the stored encoding (the chain's output).
        photo: (B, 3, H, W) encoded photos; light: (B, 3) flash positions.
    """
    maps = cv.decode_maps(stored, axis=1)
    unit = render(maps["normal"], maps["diffuse"], maps["roughness"], maps["specular"], light=light, intensity=1.0)
    target = cv.image_to_linear(photo)
    h, w = photo.shape[-2:]
    p = torch.from_numpy(cv.surface_positions(h, w)).to(photo).permute(2, 0, 1)[None]
    core = ((p[:, :2] - light[:, :2, None, None]) ** 2).sum(1, keepdim=True) < CORE_RADIUS ** 2
    keep = ((photo < CLIPPED).all(1, keepdim=True) & ~core).to(photo)
    with torch.no_grad():
        scale = (unit * target * keep).sum((1, 2, 3)) / (unit * unit * keep).sum((1, 2, 3)).clamp_min(1e-12)
        scale = scale.clamp_min(1e-6).reshape(-1, 1, 1, 1)
    pred = cv.image_to_encoded(unit * scale)
    return ((pred - photo).abs() * keep).sum() / (keep.sum() * 3).clamp_min(1.0)


def f0_floor_loss(specular):
    """Mean shortfall of F0 (``specular``: (B, 3, H, W), stored encoding; the mean of its channels) under
    :data:`F0_FLOOR`, a dielectric's: 0 for any F0 from a dielectric's up, metals included."""
    return torch.relu(F0_FLOOR - specular.mean(1)).mean()
