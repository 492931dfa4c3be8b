"""Maps brought to the output size: guided and bicubic upsampling."""

import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli import imageops
from svbrdf_cli.infer import upsample


def _pattern(side, freq):
    y, x = np.mgrid[0:side, 0:side] / side
    return (0.5 + 0.3 * np.sin(2 * np.pi * freq * x) * np.sin(2 * np.pi * freq * y)).astype(np.float32)


def test_guided_upsampling_recovers_detail_that_follows_the_photo():
    """A map that is a linear function of the photo's brightness gets the detail back; bicubic cannot."""
    high = _pattern(512, 20) + 0.1 * _pattern(512, 180)       # fine detail above 256 px's reach
    low = imageops.resize(high[..., None], 256)[..., 0]
    truth = 0.2 + 0.5 * high[..., None]
    guided = upsample.guided_upsample(imageops.resize(truth, 256), low, high)
    bicubic = imageops.resize(imageops.resize(truth, 256), 512)
    err_g, err_b = (np.sqrt(((x - truth) ** 2).mean()) for x in (guided, bicubic))
    assert err_g < 0.5 * err_b


def test_guided_upsampling_is_bicubic_where_the_map_ignores_the_photo():
    high = _pattern(512, 3) + 0.1 * _pattern(512, 180)
    low = imageops.resize(high[..., None], 256)[..., 0]
    flat = np.full((256, 256, 1), 0.4, np.float32)
    assert np.allclose(upsample.guided_upsample(flat, low, high), 0.4, atol=1e-3)


def test_upsample_maps_keeps_valid_encodings():
    rng = np.random.default_rng(1)
    stored = {"normal": cv.encode_normals(cv.normalize(rng.normal([0, 0, 3], 1, (64, 64, 3)))).astype(np.float32),
              "diffuse": rng.uniform(0, 1, (64, 64, 3)).astype(np.float32),
              "roughness": rng.uniform(0, 1, (64, 64, 1)).astype(np.float32),
              "specular": rng.uniform(0, 1, (64, 64, 3)).astype(np.float32)}
    low = rng.uniform(0, 1, (64, 64, 3)).astype(np.float32)
    high = imageops.resize(low, 200)
    for method in ("guided", "bicubic"):
        up = upsample.upsample_maps(stored, low, high, method)
        assert up["normal"].shape == (200, 200, 3) and up["roughness"].shape == (200, 200, 1)
        n = cv.decode_normals(up["normal"])
        assert np.allclose(np.linalg.norm(n, axis=-1), 1, atol=1e-4) and (n[..., 2] > 0).all()
        assert all(v.min() >= 0 and v.max() <= 1 for v in up.values())
