"""The physical estimate (svbrdf_cli.infer.physical) on constructed photos whose maps are known."""

import numpy as np
import pytest

from svbrdf_cli import conventions as cv
from svbrdf_cli.infer import physical
from svbrdf_cli.shading import render

SIZE = 128


def _photo(diffuse, specular, roughness, normal=None, light=cv.FLASH_POSITION, intensity=cv.FLASH_INTENSITY):
    """The encoded flash photo of a flat material (constant maps unless ``normal`` is given)."""
    n = np.zeros((SIZE, SIZE, 3)) + [0.0, 0.0, 1.0] if normal is None else normal
    img = render(n, np.broadcast_to(np.asarray(diffuse, float), (SIZE, SIZE, 3)),
                 np.full((SIZE, SIZE, 1), float(roughness)),
                 np.broadcast_to(np.asarray(specular, float), (SIZE, SIZE, 3)), light=light, intensity=intensity)
    return cv.image_to_encoded(img).astype(np.float32)


def _linear(stored):
    return cv.decode_maps({k: v[..., :cv.MAP_CHANNELS[k]] for k, v in stored.items()})


def test_flat_matte_plane_gives_its_albedo_back():
    """The nearest our BRDF has to a Lambertian plane: a dielectric (every surface the estimate
    assumes has F0 = 0.04) at roughness 1."""
    stored, found = physical.estimate(_photo([0.3, 0.3, 0.3], cv.DIELECTRIC_F0, 1.0))
    d = _linear(stored)["diffuse"]
    assert np.abs(d.mean((0, 1)) / 0.3 - 1).max() < 0.02
    assert d.std() < 0.01  # no flash disc left in it


def test_lambertian_plane_gives_its_albedo_over_the_dielectric_share():
    """A plane with no specular at all (F0 = 0): the estimate reads every surface as at least a
    dielectric, whose diffuse term is d (1 - 0.04), so the albedo comes back as 0.3 / 0.96 (2 %)."""
    stored, found = physical.estimate(_photo([0.3, 0.3, 0.3], 0.0, 0.5))
    d = _linear(stored)["diffuse"]
    assert abs(d.mean() / (0.3 / (1 - cv.DIELECTRIC_F0)) - 1) < 0.02 and d.std() < 0.01


@pytest.mark.parametrize("roughness", [0.25, 0.5, 0.8])
def test_dielectric_plane_gives_albedo_f0_and_roughness(roughness):
    albedo = np.array([0.35, 0.2, 0.08])
    photo = _photo(albedo, cv.DIELECTRIC_F0, roughness)
    stored, found = physical.estimate(photo)
    lin = _linear(stored)
    assert np.abs(lin["diffuse"].mean((0, 1)) / albedo - 1).max() < 0.03
    # its maps re-render the photo
    again = render(lin["normal"], lin["diffuse"], lin["roughness"], lin["specular"], intensity=cv.FLASH_INTENSITY)
    assert abs(cv.image_to_linear(photo).mean() / again.clip(0, 1).mean() - 1) < 0.03  # the photo clips
    assert np.allclose(lin["specular"], cv.DIELECTRIC_F0, atol=1e-3)
    assert abs(found["roughness"] - roughness) < 0.05
    assert np.allclose(lin["roughness"], found["roughness"])


def test_a_metal_is_given_a_dielectrics_f0():
    stored, _ = physical.estimate(_photo(0.0, [0.9, 0.7, 0.3], 0.3))
    assert np.allclose(_linear(stored)["specular"], cv.DIELECTRIC_F0, atol=1e-3)


def test_perfect_mirror_stays_finite():
    stored, _ = physical.estimate(_photo(0.0, 1.0, 0.3))
    assert all(np.isfinite(v).all() for v in stored.values())


def test_off_centre_flash_is_found():
    stored, found = physical.estimate(_photo(0.3, cv.DIELECTRIC_F0, 0.4, light=(0.3, -0.2, cv.CAMERA_HEIGHT)))
    x, y = found["flash_foot"]
    # within 2 % of the image width (the surface spans 2 units)
    assert abs(x - 0.3) < 0.04 and abs(y + 0.2) < 0.04


def test_the_normals_are_flat():
    """Read as tilt, the shading raised the normal error (albedo texture shades as a tilt does)."""
    stored, _ = physical.estimate(_photo(0.4, cv.DIELECTRIC_F0, 0.6))
    assert np.array_equal(stored["normal"], np.broadcast_to(np.float32([0.5, 0.5, 1.0]), stored["normal"].shape))


def test_clipped_highlight_is_filled_not_baked_in():
    img = _photo([0.3, 0.3, 0.3], cv.DIELECTRIC_F0, 0.12, intensity=3 * cv.FLASH_INTENSITY)
    assert (img >= physical.CLIPPED).any()
    stored, _ = physical.estimate(img)
    d = _linear(stored)["diffuse"]
    centre = d[SIZE // 2 - 4:SIZE // 2 + 4, SIZE // 2 - 4:SIZE // 2 + 4]
    assert abs(centre.mean() / np.median(d) - 1) < 0.1


def test_extreme_inputs_stay_finite():
    for img in (np.zeros((64, 64, 3), np.float32), np.ones((64, 64, 3), np.float32),
                np.random.default_rng(0).random((64, 96, 3)).astype(np.float32)):
        stored, _ = physical.estimate(img)
        for k, v in stored.items():
            assert v.shape[:2] == img.shape[:2] and np.isfinite(v).all() and v.min() >= 0 and v.max() <= 1, k


def test_model_interface_matches_the_chain():
    from svbrdf_cli.infer.registry import check_model, load_model

    check_model("physical")
    m = load_model("physical")
    out = m(_photo(0.3, cv.DIELECTRIC_F0, 0.5))
    assert set(cv.MAP_NAMES) <= set(out) and m.used is m
    assert m.describe()["tier"] == "physical" and "roughness" in m.describe()["found"]
    assert "physical" in m.timings


def _tiles_in_grout():
    """Glossy teal tiles (roughness 0.2) in matte grey grout (roughness 1), as a flash photo, and the
    masks of grout, of the pixels near the highlight and of those far from it."""
    yy, xx = np.mgrid[:SIZE, :SIZE]
    grout = ((yy % 16) < 3) | ((xx % 16) < 3)
    diffuse = np.where(grout[..., None], [0.3, 0.3, 0.3], [0.08, 0.3, 0.4])
    roughness = np.where(grout, 1.0, 0.2)[..., None]
    n = np.zeros((SIZE, SIZE, 3)) + [0.0, 0.0, 1.0]
    img = render(n, diffuse, roughness, np.full((SIZE, SIZE, 3), cv.DIELECTRIC_F0), intensity=0.5 * cv.FLASH_INTENSITY)
    rho = np.hypot(xx - SIZE / 2, yy - SIZE / 2)
    return cv.image_to_encoded(img).astype(np.float32), grout, rho < 20, rho > 45


def test_glossy_tiles_lose_their_highlight_and_matte_grout_keeps_its_level():
    """One smooth lobe cannot say that the tiles shine and the grout does not; the tiles' colour can
    (the dichromatic model). Without it (the estimate before it), the grout under the flash came out
    28 % darker than elsewhere (a dark cross in the diffuse) and the tiles kept the highlight as a
    pale disc (red channel 1.7x)."""
    img, grout, near, far = _tiles_in_grout()
    d = _linear(physical.estimate(img)[0])["diffuse"]
    grout_ratio = d[grout & near].mean(0) / d[grout & far].mean(0)
    tile_ratio = d[~grout & near].mean(0) / d[~grout & far].mean(0)
    assert grout_ratio.min() > 0.85 and tile_ratio.max() < 1.3, (grout_ratio, tile_ratio)


def test_colour_separation_reads_a_diffuse_under_white_from_the_same_hue_elsewhere():
    """Half a coloured material as it is, half with white added (a highlight): the diffuse of the second
    half comes back from the first's whiteness, and a grey patch (no colour to read) is not trusted."""
    h, w = 64, 64
    colour = np.array([0.1, 0.3, 0.5], np.float32)
    lin = np.broadcast_to(colour, (h, w, 3)).copy()
    share = np.zeros((h, w), np.float32)
    lin[:, 40:] += 0.3
    share[:, 40:] = 0.6
    lin[:8, :8] = 0.4  # a grey patch
    diffuse, trust = physical.separate_by_colour(lin, share, np.ones(3, np.float32), np.zeros((h, w), bool))
    assert np.allclose(diffuse[20:, 44:], colour, rtol=0.02)
    assert (trust[20:, 44:] > 0.99).all()
    assert (trust[:6, :6] < 0.01).all()
    assert np.allclose(diffuse[20:, :36], colour, rtol=1e-4)  # untouched where there was no highlight


def test_clipped_highlight_darkened_by_the_exposure_is_filled_too():
    """``svbrdf capture`` exposes the photo before the estimate: a highlight the camera clipped then
    sits as a flat plateau under 1.0, and is still a clipped highlight, not a grey disc of albedo."""
    img = _photo([0.04, 0.1, 0.14], cv.DIELECTRIC_F0, 0.12, intensity=3 * cv.FLASH_INTENSITY)
    assert 0.003 < (img >= 0.999).all(-1).mean() and (img >= 0.95).any(-1).mean() < 0.1  # the highlight clipped
    darker = cv.image_to_encoded(cv.image_to_linear(img) * np.float32(0.6)).astype(np.float32)
    for photo in (img, darker):
        stored, found = physical.estimate(photo)
        d = _linear(stored)["diffuse"]
        centre = d[SIZE // 2 - 3:SIZE // 2 + 3, SIZE // 2 - 3:SIZE // 2 + 3].reshape(-1, 3)
        assert np.abs(centre.mean(0) / np.median(d.reshape(-1, 3), 0) - 1).max() < 0.15


def _coated(clear_coat, gradient=1.2, light=cv.FLASH_POSITION):
    """A textured brown surface, darker towards one side (so the falloff's peak is not the highlight's),
    with a rough base lobe and, if ``clear_coat``, a second, sharp one (a clear coat: the one-lobe fit
    measures the broad lobe and leaves the sharp peak, as on a real speckled worktop)."""
    rng = np.random.default_rng(0)
    y = cv.surface_positions(SIZE, SIZE)[..., 1:2]
    tex = 0.2 * (0.8 + 0.4 * rng.uniform(0, 1, (SIZE, SIZE, 1))) * np.exp(gradient * y)
    base = render(np.zeros((SIZE, SIZE, 3)) + [0.0, 0.0, 1.0], tex * [1.0, 0.7, 0.45], np.full((SIZE, SIZE, 1), 0.7),
                  np.full((SIZE, SIZE, 3), cv.DIELECTRIC_F0), light=light, intensity=cv.FLASH_INTENSITY)
    if clear_coat:
        base = base + render(np.zeros((SIZE, SIZE, 3)) + [0.0, 0.0, 1.0], np.zeros((SIZE, SIZE, 3)),
                             np.full((SIZE, SIZE, 1), 0.25), np.full((SIZE, SIZE, 3), 0.01), light=light,
                             intensity=cv.FLASH_INTENSITY)
    return cv.image_to_encoded(np.clip(0.4 * base, 0, 1)).astype(np.float32), tex[..., 0]


def test_a_highlight_sharper_than_the_fit_is_not_left_in_the_diffuse():
    img, tex = _coated(True)
    d = _linear(physical.estimate(img)[0])["diffuse"].mean(-1)  # (its white is what gives the glint away)
    c = SIZE // 2
    spot = d[c - 3:c + 4, c - 3:c + 4].mean() / np.median(d)
    assert abs(spot - 1) < 0.15


def test_the_residue_fill_leaves_a_surface_the_fit_explains_alone():
    img, _ = _coated(False, gradient=0.0)  # one lobe, the falloff's peak at the highlight
    diffuse = _linear(physical.estimate(img)[0])["diffuse"]
    assert not physical.highlight_residue(diffuse, physical.highlight.find(img)).any()


def test_a_bright_patch_of_the_materials_own_colour_under_the_flash_is_kept():
    # a matte brown surface with a brighter brown fleck where the flash points: albedo, not highlight (the
    # residue fill leaves it as the rest of the estimate makes it)
    p = cv.surface_positions(SIZE, SIZE)
    fleck = (np.hypot(p[..., 0], p[..., 1]) < 0.08)[..., None]
    albedo = np.where(fleck, 0.5, 0.2) * np.array([1.0, 0.7, 0.45])
    img = cv.image_to_encoded(0.4 * render(np.zeros((SIZE, SIZE, 3)) + [0.0, 0.0, 1.0], albedo,
                                           np.full((SIZE, SIZE, 1), 0.9), np.full((SIZE, SIZE, 3), cv.DIELECTRIC_F0),
                                           intensity=cv.FLASH_INTENSITY)).astype(np.float32)
    assert not physical.highlight_residue(_linear(physical.estimate(img)[0])["diffuse"], physical.highlight.find(img)).any()
