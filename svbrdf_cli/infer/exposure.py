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


def network_input(linear, gain_ev=None):
    """A linear square crop -> what the networks take: :data:`NETWORK_SIZE`², exposed by ``gain_ev``
    stops (None: :func:`auto_exposure_gain`), encoded."""
    low = resize(linear, NETWORK_SIZE)
    if gain_ev is None:
        gain_ev = auto_exposure_gain(low)
    return ingest.encode_for_network(low, 2.0 ** gain_ev)
