"""Flash-photo simulator: what a phone or camera makes of a lit material.

A rendered flash image is the clean, ideal photo. Real captures differ in
ways a network must survive, so training inputs go through a camera model:

* **geometry**: field of view 20-75 degrees (the surface always fills the
  square image, so the camera height is ``1 / tan(fov / 2)`` surface
  half-widths: a square cropped from the middle of a phone photo sees a
  narrow field, a close-up a wide one); the lens off the surface centre (the
  highlight is not centred); the flash a little beside the lens;
* **exposure**: either the flash power of the validation inputs
  (:data:`svbrdf_cli.conventions.FLASH_INTENSITY`, compensated for the camera's distance and
  jittered with the spread fitted on the Des19 inputs: they are rendered at one power, not
  exposed per image), or auto exposure to a jittered mean brightness around
  :data:`svbrdf_cli.conventions.AUTO_EXPOSURE_MEAN` (what ``svbrdf capture`` does to a photo);
* **colour**: white-balance error (per-channel gains);
* **optics**: vignetting (radial gain) and softening (Gaussian blur);
* **sensor**: shot noise (variance proportional to the signal) and read
  noise, then clipping at the sensor's white level;
* **processing**: tone curve (the renderer's gamma 2.2, sRGB, or sRGB with a
  contrast S-curve), 8-bit quantisation, optional JPEG compression.

The ground truth (maps and the paper's intermediate targets) is rendered from
the clean maps with the same geometry and exposure, without the camera's
degradations: ``I`` is the clean flash image, ``photo`` the network's input.

Two steps, so tests and callers can fix any parameter:
:func:`sample_capture` draws per-sample parameters from a seeded generator,
:func:`photograph` applies them.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch
import torch.nn.functional as F

from export.render import targets
from export.render.brdf import render_maps, surface_positions
from svbrdf_cli import conventions as cv

#: Tone curves, by code in ``capture["tone"]``.
TONE_CURVES = ("gamma", "srgb", "srgb+contrast")


@dataclasses.dataclass(frozen=True)
class CaptureRanges:
    """Ranges the capture parameters are drawn from (uniform unless said)."""

    fov_degrees: tuple = (20.0, 75.0)
    #: Lens position off the surface centre, in surface half-widths (x and y
    #: each uniform in +-this). The Des19 inputs' flashes sit within +-0.35;
    #: real phone photos put the highlight up to ~0.6 off centre.
    centre_offset: float = 0.5
    #: Lens-to-flash distance as a fraction of the camera height (a phone's
    #: flash is 0.5-2 cm from its lens, shooting from 15-40 cm).
    flash_offset: tuple = (0.0, 0.1)
    #: Auto-exposure target: log-normal around ``exposure_mean``, clamped to
    #: the range the Des19 inputs span. The mean sits between the Des19
    #: median (conventions.AUTO_EXPOSURE_MEAN, 0.32) and the median of the
    #: real flash photos (0.39, ``python -m export.data realism``).
    exposure_mean: float = 0.36
    exposure_log_sigma: float = 0.25
    exposure_range: tuple = (0.11, 0.6)
    #: Fraction of photos auto-exposed (the rest are lit at the flash power below).
    auto_exposure_fraction: float = 0.5
    #: Flash power: conventions.FLASH_INTENSITY x (camera height / the conventions') ^ 2 (the
    #: same irradiance under the lens at any distance) x a log-normal jitter. Sigma 0.31 is the
    #: spread of the Des19 inputs' fitted power (p10-p90 6.3-14.0 around the median 10.35,
    #: ``python -m export.studies.physical_eval --fit-flash``).
    power_log_sigma: float = 0.31
    #: Optical softening (lens, demosaicing, downscaling): Gaussian sigma in
    #: pixels at 256² (scaled with the image size).
    blur: tuple = (0.0, 1.2)
    #: Log-normal per-channel white-balance gain error (green fixed at 1).
    wb_log_sigma: float = 0.08
    #: Corner darkening (gain at the corners is 1 - vignetting).
    vignetting: tuple = (0.0, 0.3)
    #: Shot-noise variance per unit of linear signal (log-uniform).
    shot_noise: tuple = (1e-5, 3e-3)
    #: Read-noise standard deviation in linear units (log-uniform).
    read_noise: tuple = (1e-4, 4e-3)
    #: Probabilities of the tone curves in :data:`TONE_CURVES`.
    tone_probabilities: tuple = (0.4, 0.3, 0.3)
    #: Strength of the contrast S-curve when chosen.
    contrast: tuple = (0.1, 0.5)
    jpeg_probability: float = 0.5
    jpeg_quality: tuple = (60, 95)


DEFAULT_RANGES = CaptureRanges()

#: No degradation at all: the photo equals the clean gamma-2.2 flash image
#: (up to 8-bit quantisation). Geometry and exposure still vary.
CLEAN = dataclasses.replace(
    DEFAULT_RANGES, wb_log_sigma=0.0, vignetting=(0.0, 0.0), blur=(0.0, 0.0), shot_noise=(0.0, 0.0), read_noise=(0.0, 0.0),
    tone_probabilities=(1.0, 0.0, 0.0), jpeg_probability=0.0)

#: The paper's setting: flash at the lens, 45 degrees, centred, fixed exposure target.
PAPER = dataclasses.replace(
    CLEAN, fov_degrees=(45.0, 45.0), centre_offset=0.0, flash_offset=(0.0, 0.0),
    exposure_mean=cv.AUTO_EXPOSURE_MEAN, exposure_log_sigma=0.0, auto_exposure_fraction=1.0)


def _uniform(g, n, lo, hi, log=False):
    u = torch.rand(n, generator=g, device=g.device, dtype=torch.float64)
    if log and lo > 0:
        return torch.exp(math.log(lo) + u * (math.log(hi) - math.log(lo)))
    return lo + u * (hi - lo)


def sample_capture(g, batch, ranges=DEFAULT_RANGES):
    """Draw per-sample capture parameters.

    Args:
        g: ``torch.Generator`` (its device is used).
        batch: number of samples.
        ranges: :class:`CaptureRanges`.

    Returns:
        dict of float64 tensors on ``g.device``: ``fov`` (B,) degrees,
        ``camera`` and ``light`` (B, 3) positions, ``power`` (B,) flash
        intensity (0: auto exposure instead), ``exposure`` (B,) the auto-exposure target
        mean, ``wb`` (B, 3) gains, ``vignetting``, ``blur`` (pixels at 256²), ``shot_noise``,
        ``read_noise``, ``contrast`` (B,), ``tone`` (B,) codes into
        :data:`TONE_CURVES`, ``jpeg`` (B,) quality (0: none).
    """
    r = ranges
    fov = _uniform(g, batch, *r.fov_degrees)
    height = cv.camera_height(torch.tan(torch.deg2rad(fov) / 2))
    xy = (torch.rand(batch, 2, generator=g, device=g.device, dtype=torch.float64) * 2 - 1) * r.centre_offset
    camera = torch.cat([xy, height[:, None]], 1)
    phi = _uniform(g, batch, 0.0, 2 * math.pi)
    off = _uniform(g, batch, *r.flash_offset) * height
    light = camera + torch.stack([off * phi.cos(), off * phi.sin(), torch.zeros_like(off)], 1)
    jitter = torch.randn(batch, generator=g, device=g.device, dtype=torch.float64) * r.exposure_log_sigma
    exposure = (r.exposure_mean * jitter.exp()).clamp(*r.exposure_range)
    wb = (torch.randn(batch, 3, generator=g, device=g.device, dtype=torch.float64) * r.wb_log_sigma).exp()
    wb[:, 1] = 1.0
    probs = torch.tensor(r.tone_probabilities, dtype=torch.float64, device=g.device)
    tone = torch.multinomial(probs.expand(batch, -1), 1, generator=g)[:, 0]
    use_jpeg = torch.rand(batch, generator=g, device=g.device, dtype=torch.float64) < r.jpeg_probability
    quality = _uniform(g, batch, *r.jpeg_quality).round()
    auto = torch.rand(batch, generator=g, device=g.device, dtype=torch.float64) < r.auto_exposure_fraction
    power_jitter = (torch.randn(batch, generator=g, device=g.device, dtype=torch.float64) * r.power_log_sigma).exp()
    power = cv.FLASH_INTENSITY * (height / cv.CAMERA_HEIGHT) ** 2 * power_jitter
    return {
        "power": torch.where(auto, torch.zeros_like(power), power),
        "fov": fov, "camera": camera, "light": light, "exposure": exposure, "wb": wb,
        "vignetting": _uniform(g, batch, *r.vignetting),
        "blur": _uniform(g, batch, *r.blur),
        "shot_noise": _uniform(g, batch, *r.shot_noise, log=True),
        "read_noise": _uniform(g, batch, *r.read_noise, log=True),
        "contrast": _uniform(g, batch, *r.contrast),
        "tone": tone.to(torch.float64),
        "jpeg": torch.where(use_jpeg, quality, torch.zeros_like(quality)),
    }


def _col(x, like):
    return x.to(device=like.device, dtype=like.dtype).reshape(-1, 1, 1, 1)


def tone_curve(linear, tone, contrast):
    """Linear [0, 1] -> encoded, per sample: gamma 2.2, sRGB or sRGB + S-curve."""
    tone = _col(tone, linear)
    srgb = cv.linear_to_srgb(linear)
    c = _col(contrast, linear)
    s_curve = (1 - c) * srgb + c * srgb * srgb * (3 - 2 * srgb)
    out = torch.where(tone == 0, cv.image_to_encoded(linear), srgb)
    return torch.where(tone == 2, s_curve, out)


def gaussian_blur(images, sigma):
    """Separable Gaussian blur with a per-sample ``sigma`` (B,) in pixels (0: untouched)."""
    if not bool((sigma > 0).any()):
        return images
    radius = max(1, int(math.ceil(3 * float(sigma.max()))))
    t = torch.arange(-radius, radius + 1, dtype=images.dtype, device=images.device)
    sigma = sigma.to(images)
    s = sigma.reshape(-1, 1).clamp_min(1e-3)
    k = torch.exp(-0.5 * (t / s) ** 2)
    k = torch.where(sigma.reshape(-1, 1) > 0, k, (t == 0).to(k))
    k = k / k.sum(1, keepdim=True)  # (B, taps)
    b, c, h, w = images.shape
    x = images.reshape(1, b * c, h, w)
    kk = k.repeat_interleave(c, 0)
    x = F.conv2d(F.pad(x, (radius, radius, 0, 0), mode="reflect"), kk.reshape(b * c, 1, 1, -1), groups=b * c)
    x = F.conv2d(F.pad(x, (0, 0, radius, radius), mode="reflect"), kk.reshape(b * c, 1, -1, 1), groups=b * c)
    return x.reshape(b, c, h, w)


def jpeg(images, quality):
    """JPEG round trip per sample (quality 0: untouched); (B, 3, H, W) in [0, 1]."""
    import cv2

    if not bool((quality > 0).any()):
        return images
    out = images.clone()
    cpu = (images.detach().clamp(0, 1) * 255).round().to(torch.uint8).permute(0, 2, 3, 1).cpu().numpy()
    for i, q in enumerate(quality.tolist()):
        if q <= 0:
            continue
        ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(cpu[i, ..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, int(q)])
        dec = cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1].astype(np.float32) / 255.0
        out[i] = torch.from_numpy(np.ascontiguousarray(dec)).permute(2, 0, 1).to(images)
    return out


def photograph(maps, capture, g=None, quantize=True):
    """Simulate the flash photo of a batch of materials.

    Args:
        maps: dict of linear maps (B, C, H, W).
        capture: parameters from :func:`sample_capture` (any may be edited).
        g: generator for the sensor noise (needed when noise is non-zero).
        quantize: round to 8 bits (JPEG implies it).

    Returns:
        dict: ``photo`` (B, 3, H, W) encoded in [0, 1], the network input;
        ``I`` the clean encoded flash image (same geometry and exposure);
        ``intensity`` (B,) the flash intensity auto exposure chose (for
        rendering the other targets).
    """
    d = maps["diffuse"]
    cam = capture["camera"].to(d)
    light = capture["light"].to(d)
    intensity = targets.auto_exposure(maps, light=light, camera=cam, target=capture["exposure"].to(d))
    if "power" in capture:  # lit at a known flash power where one is given (> 0)
        power = capture["power"].to(d)
        intensity = torch.where(power > 0, power.reshape(intensity.shape), intensity)
    linear = render_maps(maps, light=light, camera=cam, intensity=intensity)
    clean = cv.image_to_encoded(linear)
    p = surface_positions(d.shape[-2], d.shape[-1], d)
    r2 = (p[:, :2] ** 2).sum(1, keepdim=True) / (2 * cv.SURFACE_HALF_SIZE ** 2)  # 1 at the corners
    x = linear * (1 - _col(capture["vignetting"], d) * r2) * capture["wb"].to(d).reshape(-1, 3, 1, 1)
    x = gaussian_blur(x, capture["blur"].to(d) * (d.shape[-1] / 256))
    shot, read = _col(capture["shot_noise"], d), _col(capture["read_noise"], d)
    if bool((shot > 0).any() or (read > 0).any()):
        if g is None:
            raise ValueError("photograph: a generator is needed for sensor noise")
        n = torch.randn(x.shape, generator=g, device=g.device, dtype=x.dtype).to(x.device)
        x = x + (shot * x.clamp_min(0) + read * read).sqrt() * n
    photo = tone_curve(x.clamp(0.0, 1.0), capture["tone"], capture["contrast"])
    if quantize:
        photo = (photo * 255).round() / 255
    photo = jpeg(photo, capture["jpeg"])
    return {"photo": photo, "I": clean, "intensity": intensity}
