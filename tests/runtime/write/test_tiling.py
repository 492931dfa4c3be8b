"""Seamless maps (--tileable): the wrap matches the interior, every map gets the same blend, normals stay unit."""

import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli.write.tiling import make_tileable, weights, wrap_ratio


def _maps(n=128, seed=0):
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:n, 0:n] / n
    noise = rng.random((n, n)).astype(np.float32)
    ramp = (0.2 + 0.6 * x + 0.1 * noise)[..., None]  # a falloff across the map: far from periodic
    tilt = np.stack([0.3 * x + 0.05 * noise, 0.2 * y, np.ones_like(x)], -1)
    return {"normal": cv.normalize(tilt).astype(np.float32), "diffuse": np.repeat(ramp, 3, -1).astype(np.float32),
            "roughness": (0.3 + 0.4 * y[..., None]).astype(np.float32), "specular": np.full((n, n, 3), 0.04, np.float32)}


def test_the_wrap_becomes_like_the_interior():
    maps = _maps()
    out = make_tileable(maps)
    for k in ("diffuse", "roughness"):
        assert wrap_ratio(maps[k]) > 5 and wrap_ratio(out[k]) <= 1.5, k
    assert wrap_ratio(out["normal"][..., 0]) <= 1.5
    np.testing.assert_allclose(np.linalg.norm(out["normal"], axis=-1), 1.0, atol=1e-5)
    np.testing.assert_allclose(out["specular"], 0.04, atol=1e-7)  # a constant map stays itself


def test_the_centre_is_the_photos_own_and_weights_are_smooth():
    maps = _maps()
    out = make_tileable(maps)
    n = 128
    c = slice(n // 2 - 8, n // 2 + 8)
    np.testing.assert_array_equal(out["diffuse"][c, c], maps["diffuse"][c, c])
    w = weights(n, n)
    assert w.min() >= 0 and w.max() == 1 and w[0].max() < 0.05 and w[n // 2, n // 2] == 1
