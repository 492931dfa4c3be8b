"""The network input: auto exposure."""

import numpy as np
import pytest

from svbrdf_cli import conventions as cv
from svbrdf_cli.errors import SvbrdfError
from svbrdf_cli.infer import exposure


def test_auto_exposure_reaches_the_training_brightness():
    rng = np.random.default_rng(0)
    lin = rng.uniform(0.0, 0.02, (64, 64, 3)).astype(np.float32)  # a dark RAW
    ev = exposure.auto_exposure_gain(lin)
    assert ev > 3
    assert abs(cv.image_to_encoded(lin * 2.0 ** ev).mean() - cv.AUTO_EXPOSURE_MEAN) < 1e-3


def test_black_photo_is_an_error():
    with pytest.raises(SvbrdfError, match="black"):
        exposure.auto_exposure_gain(np.zeros((8, 8, 3), np.float32))
