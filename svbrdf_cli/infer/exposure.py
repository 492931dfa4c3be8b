"""What the networks take: the crop at :data:`NETWORK_SIZE`², exposed to the mean they were trained on."""

from __future__ import annotations

import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli.errors import SvbrdfError
from svbrdf_cli.imageops import resize
from svbrdf_cli.ingest import plausible
from svbrdf_cli.ingest import photo as ingest

#: The networks' working resolution (exported and validated at it; trained on 128 px crops).
NETWORK_SIZE = 256
#: The most ``--exposure`` may change a photo, in stops either way (2^20: beyond any real photo's need).
MAX_EXPOSURE_STOPS = 20.0


def auto_exposure_gain(linear, target=cv.AUTO_EXPOSURE_MEAN):
    """Gain making the encoded image's mean ``target`` (what the networks were trained on)."""
    lo, hi = -plausible.EXPOSURE_LIMIT, plausible.EXPOSURE_LIMIT
    flat = linear.reshape(-1, 3)[:: max(1, linear.size // 3 // 65536)]
    if float(flat.max()) <= 0:
        raise SvbrdfError("the crop is black")
    for _ in range(30):
        mid = (lo + hi) / 2
        if cv.image_to_encoded(flat * np.float32(2.0 ** mid)).mean() < target:
            lo = mid
        else:
            hi = mid
    return (lo + hi) / 2


def network_gain(linear):
    """The stops :func:`network_input` adds to a linear square crop by auto exposure (at :data:`NETWORK_SIZE`²)."""
    return auto_exposure_gain(resize(linear, NETWORK_SIZE))


def network_input(linear, gain_ev=None):
    """A linear square crop -> what the networks take: :data:`NETWORK_SIZE`², exposed by ``gain_ev``
    stops (None: :func:`network_gain`), encoded."""
    low = resize(linear, NETWORK_SIZE)
    if gain_ev is None:
        gain_ev = auto_exposure_gain(low)
    return ingest.encode_for_network(low, 2.0 ** gain_ev)


#: The albedo convention of ``svbrdf capture`` (``docs/conventions.md``, "The albedo level"): the photo as
#: shot read at the flash power :data:`svbrdf_cli.conventions.FLASH_INTENSITY` (the Des19 inputs' own, the
#: paper's and MaterialGAN's reading). A white diffuse surface straight under that flash photographs at
#: this linear value (its shading there, ``1 / CAMERA_HEIGHT^2``, times the flash power and the share
#: ``1 - F0`` the diffuse lobe keeps): a photo's value ``v`` under the flash reads as albedo
#: ``v / WHITE_UNDER_FLASH``.
WHITE_UNDER_FLASH = cv.FLASH_INTENSITY * (1.0 - cv.DIELECTRIC_F0) / cv.CAMERA_HEIGHT ** 2


def photo_level(gain_ev, manual=False):
    """The factor taking a diffuse read at the convention's flash power from the photo exposed by
    ``gain_ev`` stops back to the photo as shot (``2^-gain_ev``), or with ``manual``
    (``--exposure STOPS``) keeping the photo as the user exposed it (1)."""
    return float(1.0 if manual else 2.0 ** -gain_ev)


def to_photo_level(stored, scale, specular=False):
    """``stored`` maps with the diffuse (and with ``specular`` the F0, for a model that reads it at the
    photo's level) in the stored encoding scaled by ``scale`` in linear units, clipped to 1."""
    out = dict(stored)
    for k in ("diffuse", "specular") if specular else ("diffuse",):
        lin = cv.albedo_to_linear(np.asarray(stored[k], np.float32)) * np.float32(scale)
        out[k] = cv.albedo_to_stored(np.clip(lin, 0.0, 1.0)).astype(np.float32)
    return out
