import numpy as np
import pytest

from svbrdf_cli import conventions as cv


def test_normal_encoding_round_trip():
    rng = np.random.default_rng(0)
    n = cv.normalize(rng.normal(size=(50, 3)) + [0, 0, 2])
    assert np.allclose(cv.decode_normals(cv.encode_normals(n)), n, atol=1e-12)
    assert np.allclose(cv.decode_normals(np.array(cv.FLAT_NORMAL_ENCODED)), cv.FLAT_NORMAL)


@pytest.mark.parametrize("enc,dec", [(cv.albedo_to_stored, cv.albedo_to_linear),
                                     (cv.image_to_encoded, cv.image_to_linear),
                                     (cv.linear_to_srgb, cv.srgb_to_linear)])
def test_colour_round_trips(enc, dec):
    x = np.linspace(0.001, 1.0, 200)
    assert np.allclose(dec(enc(x)), x, atol=1e-6)


def test_srgb_reference_values():
    # IEC 61966-2-1: 0.5 linear encodes to 0.7354; 0.0031308 is the knee.
    assert cv.linear_to_srgb(np.array(0.5)) == pytest.approx(0.735356, abs=1e-5)
    assert cv.linear_to_srgb(np.array(0.002)) == pytest.approx(0.002 * 12.92)
    assert cv.srgb_to_linear(np.array(0.735356)) == pytest.approx(0.5, abs=1e-5)


def test_albedo_gamma_is_des18_pure_power():
    assert cv.albedo_to_linear(np.array(0.5)) == pytest.approx(0.5 ** 2.2)


def test_roughness_to_alpha():
    assert cv.roughness_to_alpha(np.array(0.5)) == pytest.approx(0.25)
    assert cv.roughness_to_alpha(np.array(0.0)) == pytest.approx(cv.MIN_ROUGHNESS ** 2)
    assert cv.roughness_to_alpha(0.7) == pytest.approx(0.49)


def test_surface_positions_orientation():
    p = cv.surface_positions(4, 8)
    assert p.shape == (4, 8, 3)
    assert p[0, 0, 0] < 0 < p[0, -1, 0]       # column 0 is x = -1 side
    assert p[0, 0, 1] > 0 > p[-1, 0, 1]       # row 0 is y = +1 (top)
    assert np.allclose(p[..., 2], 0)
    assert abs(p[..., 0]).max() < cv.SURFACE_HALF_SIZE


def test_camera_height_gives_45_degree_fov():
    assert np.degrees(2 * np.arctan(cv.SURFACE_HALF_SIZE / cv.CAMERA_HEIGHT)) == pytest.approx(45.0)


def test_aux_lights_cover_disc_evenly():
    p = cv.aux_light_positions()
    assert p.shape == (cv.AUX_LIGHT_COUNT, 3)
    r = np.hypot(p[:, 0], p[:, 1])
    assert r.max() <= cv.AUX_LIGHT_RADIUS and np.allclose(p[:, 2], cv.CAMERA_HEIGHT)
    # equal-area rings: half the lights inside radius R / sqrt(2)
    assert abs((r < cv.AUX_LIGHT_RADIUS / np.sqrt(2)).sum() - cv.AUX_LIGHT_COUNT / 2) <= 1
    assert abs(p[:, 0].mean()) < 0.05 and abs(p[:, 1].mean()) < 0.05


def test_aux_light_intensities_match_flash_irradiance_at_centre():
    p = cv.aux_light_positions()
    e = cv.aux_light_intensities(p, 2.0)
    d = np.linalg.norm(p, axis=1)
    irradiance = e * (p[:, 2] / d) / d ** 2
    assert np.allclose(irradiance, 2.0 / cv.CAMERA_HEIGHT ** 2)


def test_clip_level_finds_a_clipped_highlight_the_exposure_darkened():
    rng = np.random.default_rng(0)
    photo = rng.uniform(0.1, 0.6, (128, 128, 3)).astype(np.float32)
    assert cv.clip_level(photo) == 1.0  # nothing clipped
    photo[50:60, 50:60] = 1.0  # clipped at the camera's white
    assert cv.clip_level(photo) == 1.0
    darker = photo * np.float32(0.7)  # then darkened: the plateau moves down with it
    assert cv.clip_level(darker) == pytest.approx(0.7)
    peak = photo.copy()
    peak[50:60, 50:60] = 0.6 + 0.002 * rng.random((10, 10, 3))  # a smooth bright area is no plateau
    peak[55, 55] = 0.65
    assert cv.clip_level(peak) == 1.0
