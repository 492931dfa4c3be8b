"""The swift chain's runtime steps that need no network: the flash's trends taken off its maps."""

import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli.infer.swift import flatten_flash_trends


def _rho(n=96, foot=(0.2, -0.1)):
    y, x = np.mgrid[0:n, 0:n]
    x, y = (x + 0.5) / n * 2 - 1, 1 - (y + 0.5) / n * 2
    return np.sqrt((x - foot[0]) ** 2 + (y - foot[1]) ** 2)


def _stored(diffuse, roughness):
    n = diffuse.shape[0]
    return {"normal": np.full((n, n, 3), 0.5, np.float32), "diffuse": cv.albedo_to_stored(diffuse).astype(np.float32),
            "roughness": roughness.astype(np.float32), "specular": np.full((n, n, 3), 0.2, np.float32)}


def test_a_pale_spot_and_a_glossy_blob_at_the_flash_are_taken_off_and_the_texture_kept():
    rho = _rho()
    g = np.random.default_rng(0)
    texture = 0.3 * (1 + 0.2 * g.standard_normal(rho.shape))[..., None] * np.array([1.0, 0.8, 0.6])
    spot = 1 + 0.6 * np.exp(-(rho / 0.3) ** 2)
    blob = 0.6 - 0.3 * np.exp(-(rho / 0.4) ** 2)
    out = flatten_flash_trends(_stored(texture * spot[..., None], blob[..., None]), rho)
    d = cv.albedo_to_linear(out["diffuse"])
    near, far = rho < 0.2, rho > 0.8
    assert 0.95 < d[near].mean() / d[far].mean() < 1.05  # the spot is gone (it was 1.5x)
    assert np.corrcoef(d[..., 0].ravel(), texture[..., 0].ravel())[0, 1] > 0.95  # the texture stays
    r = out["roughness"][..., 0]
    assert abs(r[near].mean() - r[far].mean()) < 0.03  # the blob is gone (it was 0.27)
    assert out["diffuse"].dtype == out["roughness"].dtype == np.float32


def test_maps_without_a_flash_trend_are_kept():
    rho = _rho()
    g = np.random.default_rng(1)
    diffuse = (0.2 + 0.1 * g.random(rho.shape))[..., None].repeat(3, -1)
    rough = np.full(rho.shape + (1,), 0.45)
    out = flatten_flash_trends(_stored(diffuse, rough), rho)
    assert np.abs(cv.albedo_to_linear(out["diffuse"]) - diffuse).max() < 0.02
    assert np.abs(out["roughness"] - 0.45).max() < 1e-4


def test_the_diffuse_under_a_clipped_highlight_is_filled_from_around_it():
    from svbrdf_cli.infer.swift import fill_highlight

    n = 96
    rho = _rho(n, foot=(0.0, 0.0))
    g = np.random.default_rng(2)
    albedo = (0.25 * (1 + 0.1 * g.standard_normal((n, n))))[..., None] * np.array([0.9, 0.7, 0.5])
    hole = rho < 0.15
    diffuse = np.where(hole[..., None], 0.05, albedo)  # a dark disc where the photo was white
    photo = np.where(hole[..., None], 1.0, 0.5 * np.ones((n, n, 3)))
    out = cv.albedo_to_linear(fill_highlight(cv.albedo_to_stored(diffuse).astype(np.float32), photo))
    assert 0.8 < out[hole].mean() / albedo[hole].mean() < 1.25  # filled at its surroundings' level
    assert out[hole].std(0).mean() > 0.3 * albedo[hole].std(0).mean()  # with texture, not a blot
    far = rho > 0.4
    assert np.abs(out[far] - albedo[far]).max() < 1e-2  # the rest is kept
    photo = np.where(hole[..., None], 1.0, 0.3 + 0.3 * g.random((n, n, 3)))
    darkened = cv.albedo_to_linear(fill_highlight(cv.albedo_to_stored(diffuse).astype(np.float32), photo * 0.6))
    assert 0.8 < darkened[hole].mean() / albedo[hole].mean() < 1.25  # clipped, then darkened by the exposure
    unclipped = 0.3 + 0.3 * g.random((n, n, 3))
    same = fill_highlight(cv.albedo_to_stored(diffuse).astype(np.float32), unclipped)
    assert np.array_equal(same, cv.albedo_to_stored(diffuse).astype(np.float32))


def test_the_diffuse_under_the_chains_highlight_mask_is_filled_too():
    from svbrdf_cli.infer.swift import fill_highlight

    n = 96
    rho = _rho(n, foot=(0.1, 0.1))
    g = np.random.default_rng(4)
    albedo = (0.3 * (1 + 0.1 * g.standard_normal((n, n))))[..., None] * np.array([0.8, 0.5, 0.3])
    spot = rho < 0.15
    diffuse = np.where(spot[..., None], 0.12, albedo)  # the grey disc the aux stage leaves
    photo = 0.3 + 0.3 * g.random((n, n, 3))  # bright but not clipped
    mask = np.where(spot[..., None], 0.8, 0.0) * np.ones(3)
    stored = cv.albedo_to_stored(diffuse).astype(np.float32)
    kept = cv.albedo_to_linear(fill_highlight(stored, photo))
    out = cv.albedo_to_linear(fill_highlight(stored, photo, mask))
    assert abs(kept[spot].mean() - 0.12) < 0.01  # nothing clipped, no mask: kept as it is
    assert 0.8 < out[spot].mean() / albedo[spot].mean() < 1.25
    assert np.abs(out[rho > 0.4] - albedo[rho > 0.4]).max() < 1e-2


def test_a_highlight_mask_over_most_of_the_image_fills_nothing():
    from svbrdf_cli.infer.swift import MAX_MASK_SHARE, fill_highlight

    n = 64
    g = np.random.default_rng(5)
    diffuse = cv.albedo_to_stored(0.2 + 0.1 * g.random((n, n, 3))).astype(np.float32)
    photo = 0.3 + 0.3 * g.random((n, n, 3))
    mask = np.zeros((n, n, 3))
    mask[: int(n * (MAX_MASK_SHARE + 0.1))] = 0.9
    assert np.array_equal(fill_highlight(diffuse, photo, mask), diffuse)
