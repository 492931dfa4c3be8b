import numpy as np
import pytest

from svbrdf_cli import conventions as cv
from svbrdf_cli import shading


def test_golden_table(golden):
    f = shading.brdf(golden["n"], golden["l"], golden["v"], golden["diffuse"], golden["roughness"], golden["specular"])
    np.testing.assert_allclose(f, golden["f"], rtol=1e-10, atol=1e-12)


def test_golden_components(golden):
    h = cv.normalize(golden["l"] + golden["v"])
    a = cv.roughness_to_alpha(golden["roughness"][:, 0])
    np.testing.assert_allclose(shading.ndf_ggx((golden["n"] * h).sum(-1), a), golden["D"], rtol=1e-10)
    vis = shading.visibility_smith_schlick((golden["n"] * golden["l"]).sum(-1), (golden["n"] * golden["v"]).sum(-1), a)
    np.testing.assert_allclose(vis, golden["vis"], rtol=1e-10)
    np.testing.assert_allclose(shading.fresnel_schlick((golden["v"] * h).sum(-1, keepdims=True), golden["specular"]),
                               golden["F"], rtol=1e-10)


@pytest.mark.parametrize("alpha", [0.2, 0.5, 1.0])
def test_ggx_is_normalised(alpha):
    # Projected-area normalisation: the integral of D(h) cos(theta_h) over the hemisphere is 1
    # (for alphas where the Des18 denominator floor does not bind).
    t = np.linspace(0, np.pi / 2, 20001)
    integrand = shading.ndf_ggx(np.cos(t), alpha) * np.cos(t) * np.sin(t) * 2 * np.pi
    assert np.trapezoid(integrand, t) == pytest.approx(1.0, rel=1e-4)


def test_lambertian_radiance():
    # White Lambertian (s = 0) facing the flash: radiance = I / d^2 at the centre.
    n = np.zeros((3, 3, 3))
    n[..., 2] = 1
    img = shading.render(n, np.ones((3, 3, 3)), np.ones((3, 3, 1)), np.zeros((3, 3, 3)), intensity=2.0)
    d2 = cv.CAMERA_HEIGHT ** 2 + 0  # centre pixel sits at (0, 0)
    assert img[1, 1, 0] == pytest.approx(2.0 / d2)
    assert (img[0, 0] < img[1, 1]).all()  # falls off towards the corners


def _random_maps(rng, h=16, w=16):
    n = cv.normalize(rng.normal(size=(h, w, 3)) * 0.5 + [0, 0, 1])
    return n, rng.uniform(size=(h, w, 3)), rng.uniform(size=(h, w, 1)), rng.uniform(size=(h, w, 3))


@pytest.mark.parametrize("r", [0.0, 1.0, 0.5])
def test_no_negative_or_nan_at_extremes(r):
    rng = np.random.default_rng(1)
    n, d, _, s = _random_maps(rng)
    rough = np.full((16, 16, 1), r)
    # normals at and beyond the horizon, lights at grazing angles
    n[0] = [1.0, 0.0, 0.0]
    n[1] = cv.normalize(np.array([1.0, 0.0, -0.2]))
    for light in ([0, 0, cv.CAMERA_HEIGHT], [50.0, 0.0, 1e-3], [0.0, 3.0, 0.0], [0.0, 0.0, -1.0]):
        img = shading.render(n, d, rough, s, light=light)
        assert np.isfinite(img).all() and (img >= 0).all()
    assert (shading.render(n, d, rough, s, light=[0, 0, -1.0]) == 0).all()  # light under the surface


def test_render_float32_stays_float32():
    rng = np.random.default_rng(2)
    maps = [m.astype(np.float32) for m in _random_maps(rng)]
    assert shading.render(*maps).dtype == np.float32
