"""The swift chain's runtime steps that need no network: the flash's trends taken off its maps."""

import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli.infer.swift import flatten_flash_trends


def _rho(n=96, foot=(0.2, -0.1)):
    y, x = np.mgrid[0:n, 0:n]
    x, y = (x + 0.5) / n * 2 - 1, 1 - (y + 0.5) / n * 2
    return np.sqrt((x - foot[0]) ** 2 + (y - foot[1]) ** 2)


def _grain(n, seed):
    """(n, n) fine grain, unit standard deviation."""
    from svbrdf_cli.imageops import blur

    grain = blur(np.random.default_rng(seed).standard_normal((n, n)).astype(np.float32), 0.7)
    return grain / grain.std()


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


def test_a_pale_f0_disc_at_the_flash_is_taken_off_as_the_runtime_runs_it():
    """The runtime flattens the specular too (``FLATTENED``): a pale F0 disc round the flash was a
    metallic disc and a bright base colour in the glTF preset."""
    from svbrdf_cli.infer.swift import FLATTENED

    rho = _rho()
    g = np.random.default_rng(2)
    stored = _stored(np.full(rho.shape + (3,), 0.3), np.full(rho.shape + (1,), 0.4))
    speckle = 0.04 * (1 + 0.3 * g.standard_normal(rho.shape))[..., None]
    f0 = speckle * (1 + 3.0 * np.exp(-(rho / 0.3) ** 2))[..., None]
    stored["specular"] = cv.albedo_to_stored(np.repeat(f0, 3, -1)).astype(np.float32)
    out = flatten_flash_trends(stored, rho, FLATTENED)
    s = cv.albedo_to_linear(out["specular"])[..., 0]
    near, far = rho < 0.2, rho > 0.8
    assert "specular" in FLATTENED and 0.9 < s[near].mean() / s[far].mean() < 1.1  # it was about 3.5x
    assert np.corrcoef(s.ravel(), speckle[..., 0].ravel())[0, 1] > 0.9  # the speckle stays


def test_maps_without_a_flash_trend_are_kept():
    rho = _rho()
    g = np.random.default_rng(1)
    diffuse = (0.2 + 0.1 * g.random(rho.shape))[..., None].repeat(3, -1)
    rough = np.full(rho.shape + (1,), 0.45)
    out = flatten_flash_trends(_stored(diffuse, rough), rho)
    assert np.abs(cv.albedo_to_linear(out["diffuse"]) - diffuse).max() < 0.02
    assert np.abs(out["roughness"] - 0.45).max() < 1e-4


def test_a_pale_line_of_another_colour_through_the_flash_spot_is_not_read_as_the_flashs_trend():
    """Blue tiles with a pale yellow grout line through the flash's foot: the line covers more of the rings
    near the foot than far from it. Read from all the pixels at once, that was a trend, and dividing it
    out darkened the tiles and the grout round the flash (``paper_real`` IMG_6830); with a level for each
    colour, the maps are kept. A pale spot the chain left on both colours is still taken off."""
    rho = _rho(foot=(0.0, 0.0))
    n = rho.shape[0]
    g = np.random.default_rng(5)
    x = (np.arange(n) + 0.5) / n * 2 - 1
    grout = np.broadcast_to(np.abs(x) < 0.08, rho.shape)
    colour = np.where(grout[..., None], np.float32([0.7, 0.6, 0.3]), np.float32([0.08, 0.1, 0.35]))
    albedo = colour * (1 + 0.05 * g.standard_normal(rho.shape))[..., None]
    near, far = rho < 0.25, rho > 0.7
    kept = cv.albedo_to_linear(flatten_flash_trends(_stored(albedo, np.full(rho.shape + (1,), 0.4)), rho)["diffuse"])
    for part in (grout, ~grout):  # with one level for all: 0.50 (grout) and 0.66 (tiles) near the foot
        assert 0.95 < kept[near & part].mean() / albedo[near & part].mean() < 1.05
        assert 0.95 < kept[far & part].mean() / albedo[far & part].mean() < 1.05
    spot = 1 + 0.5 * np.exp(-(rho / 0.3) ** 2)
    flat = cv.albedo_to_linear(flatten_flash_trends(_stored(albedo * spot[..., None],
                                                            np.full(rho.shape + (1,), 0.4)), rho)["diffuse"])
    for part in (grout, ~grout):  # 1.4 left in; 0.50 and 0.65 with one level for all
        ratio = flat[near & part].mean() / flat[far & part].mean()
        assert 0.93 < ratio / (albedo[near & part].mean() / albedo[far & part].mean()) < 1.07


def test_colours_are_told_apart_by_their_chromaticity_not_by_the_flashs_brightness():
    from svbrdf_cli.imageops import chroma_classes
    from svbrdf_cli.infer.swift import TREND_CLASSES, TREND_CLASSES_APART

    rho = _rho()
    falloff = np.exp(-rho)[..., None]  # the flash brightens one colour by 2.7x from the corner to the foot
    grey = 0.3 * falloff * np.ones(3)
    assert chroma_classes(grey, TREND_CLASSES, TREND_CLASSES_APART) is None
    two = np.where((rho < 0.5)[..., None], np.float32([0.7, 0.6, 0.3]), np.float32([0.08, 0.1, 0.35])) * falloff
    classes = chroma_classes(two, TREND_CLASSES, TREND_CLASSES_APART)
    assert classes is not None and classes.max() == 1
    assert len(set(classes[(rho < 0.5).ravel()])) == 1 and len(set(classes[(rho >= 0.5).ravel()])) == 1


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


def test_a_colour_clipped_in_some_channels_is_kept_and_a_white_clip_is_filled():
    from svbrdf_cli.infer.swift import fill_highlight

    n = 96
    hole = _rho(n, foot=(0.0, 0.0)) < 0.15
    yellow = np.float32([0.7, 0.6, 0.05])  # paint, clipped in red and green under the flash
    diffuse = np.where(hole[..., None], yellow, np.float32([0.2, 0.2, 0.2])).astype(np.float32)
    stored = cv.albedo_to_stored(diffuse).astype(np.float32)
    paint = np.where(hole[..., None], np.float32([1.0, 1.0, 0.3]), np.float32(0.5)).astype(np.float32)
    assert np.array_equal(fill_highlight(stored, paint), stored)
    white = np.where(hole[..., None], np.ones(3, np.float32), np.float32(0.5)).astype(np.float32)
    filled = cv.albedo_to_linear(fill_highlight(stored, white))
    assert np.abs(filled[hole].mean(0) - 0.2).max() < 0.05  # a white clip hid the albedo: filled from around


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


def test_white_albedo_the_camera_clipped_away_from_the_chains_highlight_is_kept():
    """A honeycomb's white grout clipped round the flash with no highlight on it (the chain's ``M_h`` near 0)
    is the albedo at least as bright as the clip level: kept, not filled from the darker tiles; the same
    clip under the chain's highlight is filled."""
    from svbrdf_cli.infer.swift import CLIPPED_NEAR_HIGHLIGHT, fill_highlight, hidden_by_highlight

    n = 128
    y, x = np.mgrid[0:n, 0:n]
    grout = ((x % 16) < 3) | ((y % 16) < 3)
    rho = _rho(n, foot=(0.0, 0.0))
    albedo = np.where(grout[..., None], 0.9, 0.05) * np.ones(3)
    photo = np.clip(albedo ** (1 / 2.2) * (1.4 - rho[..., None]), 0, 1)  # the grout clips near the flash
    clipped_grout = grout & (photo.min(-1) >= 1.0)
    assert clipped_grout.sum() > 200
    stored = cv.albedo_to_stored(albedo).astype(np.float32)
    none = np.zeros((n, n, 3))
    hidden, clipped = hidden_by_highlight(photo, none)
    assert not hidden.any() and not clipped.any()
    assert np.array_equal(fill_highlight(stored, photo, none), stored)
    # without the chain's mask, and under a highlight it reads, the clip hides the albedo
    assert hidden_by_highlight(photo)[1][clipped_grout].all()
    lit = np.where((rho < 0.5)[..., None], 2 * CLIPPED_NEAR_HIGHLIGHT, 0.0) * np.ones(3)
    hidden, clipped = hidden_by_highlight(photo, lit)
    assert clipped[clipped_grout].all()
    filled = cv.albedo_to_linear(fill_highlight(stored, photo, lit))
    assert filled[clipped_grout].mean() < 0.5


def test_a_highlight_mask_over_most_of_the_image_fills_nothing():
    from svbrdf_cli.infer.swift import MAX_MASK_SHARE, fill_highlight

    n = 64
    g = np.random.default_rng(5)
    diffuse = cv.albedo_to_stored(0.2 + 0.1 * g.random((n, n, 3))).astype(np.float32)
    photo = 0.3 + 0.3 * g.random((n, n, 3))
    mask = np.zeros((n, n, 3))
    mask[: int(n * (MAX_MASK_SHARE + 0.1))] = 0.9
    assert np.array_equal(fill_highlight(diffuse, photo, mask), diffuse)


def _highlight(n=128, centre=(0.55, 0.45), radius=0.18):
    """A highlight mask M_h (encoded RGB) round ``centre`` (shares of the side)."""
    y, x = np.mgrid[0:n, 0:n] / n
    h = np.exp(-((x - centre[0]) ** 2 + (y - centre[1]) ** 2) / (2 * radius ** 2)) * 0.6
    return np.repeat(h[..., None], 3, -1).astype(np.float32)


def test_the_roughness_the_highlight_showed_is_carried_to_the_rest_of_the_material():
    from svbrdf_cli.infer.swift import observed_share, roughness_from_observed

    n = 128
    g = np.random.default_rng(2)
    wood = cv.albedo_to_stored(0.25 * (1 + 0.1 * g.standard_normal((n, n, 1))) * np.array([1.0, 0.6, 0.35]))
    y, x = np.mgrid[0:n, 0:n] / n
    d = np.hypot(x - 0.55, y - 0.45)
    highlight = _highlight(n)
    seen = observed_share(highlight)
    # the chain's reading of one varnish: 0.3 where the highlight shows it, drifting away from it with
    # the flash's falloff: glossy in the dark corners, rough where the falloff is bright (the wood of the
    # real previews)
    drift = np.clip(1 - seen / 0.5, 0, 1) * (1.2 * np.clip(1.0 - 1.6 * d, 0, 1) - 0.2)
    read = (0.3 + drift)[..., None].astype(np.float32)
    out = roughness_from_observed(read, wood.astype(np.float32), highlight)[..., 0]
    away = seen < 0.1
    assert np.abs(out[away] - 0.3).mean() < 0.4 * np.abs(read[..., 0][away] - 0.3).mean()  # 0.025 against 0.084
    assert np.abs(out[seen > 0.99] - 0.3).max() < 0.01 and out.dtype == np.float32  # kept where it showed


def test_albedo_classes_keep_their_own_roughness_and_no_highlight_changes_nothing():
    from svbrdf_cli.infer.swift import roughness_from_observed

    n = 128
    y, x = np.mgrid[0:n, 0:n]
    grout = ((x % 32) < 5) | ((y % 32) < 5)
    albedo = np.where(grout[..., None], [0.5, 0.5, 0.5], [0.05, 0.2, 0.3])
    truth = np.where(grout, 0.9, 0.2)
    # seen right under the highlight; away from it the chain drifts glossier
    highlight = _highlight(n, radius=0.15)
    drift = 0.25 * np.clip(np.hypot(x / n - 0.55, y / n - 0.45) - 0.3, 0, None)
    read = np.clip(truth - drift, 0, 1)[..., None].astype(np.float32)
    out = roughness_from_observed(read, cv.albedo_to_stored(albedo).astype(np.float32), highlight)[..., 0]
    far = np.hypot(x / n - 0.55, y / n - 0.45) > 0.45
    for cls, want in ((grout, 0.9), (~grout, 0.2)):
        assert abs(out[far & cls].mean() - want) < abs(read[..., 0][far & cls].mean() - want) / 2, want
    flat = np.zeros_like(highlight)
    assert np.array_equal(roughness_from_observed(read, cv.albedo_to_stored(albedo).astype(np.float32), flat), read)


def test_grout_under_the_highlight_mask_stays_where_the_chain_put_it():
    """Tiles under the chain's highlight mask: the chain saw the grout lines through the highlight but at
    a wrong level; the fill keeps the lines where they are (the texture moved from beside the mask, 7 px
    off the period, doubled them: correlation with the true lines -0.36 against -0.84)."""
    from svbrdf_cli.infer.swift import fill_highlight

    n, period = 128, 20
    y, x = np.mgrid[0:n, 0:n]
    grout = ((x % period) < 3) | ((y % period) < 3)
    albedo = np.where(grout, 0.1, 0.4)[..., None] * np.array([0.6, 0.8, 0.9])
    spot = np.hypot(x - 64, y - 64) < 22
    diffuse = np.where(spot[..., None], albedo * 0.5 + 0.1, albedo)  # lines seen, a pale wash over them
    photo = 0.3 + 0.3 * np.random.default_rng(5).random((n, n, 3))  # bright but not clipped
    mask = np.where(spot[..., None], 0.8, 0.0) * np.ones(3)
    out = cv.albedo_to_linear(fill_highlight(cv.albedo_to_stored(diffuse).astype(np.float32), photo, mask))
    lum = out.mean(-1)
    inside = spot & (np.hypot(x - 64, y - 64) < 18)
    assert lum[inside & grout].mean() < 0.75 * lum[inside & ~grout].mean()  # the lines are still there
    assert np.corrcoef(lum[inside], grout[inside])[0, 1] < -0.7  # and where they were


def _flash_photo(colour, side=128, seed=4, roughness=0.3):
    """A dielectric under the conventions' flash (encoded) and its true linear albedo."""
    from svbrdf_cli.imageops import blur
    from svbrdf_cli.shading import render_maps

    g = np.random.default_rng(seed)
    grain = blur(g.normal(0.0, 1.0, (side, side)).astype(np.float32), 1.5)
    albedo = (np.float32(colour) * (1.0 + 0.2 * grain / grain.std())[..., None]).astype(np.float32)
    maps = {"normal": np.tile(np.float32([0, 0, 1]), (side, side, 1)), "diffuse": albedo,
            "roughness": np.full((side, side, 1), roughness, np.float32),
            "specular": np.full((side, side, 3), cv.DIELECTRIC_F0, np.float32)}
    lin = render_maps(maps, light=cv.FLASH_POSITION, intensity=cv.FLASH_INTENSITY)
    return cv.image_to_encoded(np.clip(lin, 0.0, 1.0)).astype(np.float32), albedo


def test_the_diffuse_level_goes_halfway_to_the_estimates_and_keeps_the_chains_pattern():
    """A chain's diffuse read up to twice too bright, per channel, comes back to the geometric mean of
    its level and the physical estimate's (which reads this plain photo near the truth); its
    pattern is kept; weight 0 changes nothing, weight 1 takes the estimate's level."""
    from svbrdf_cli.infer import physical
    from svbrdf_cli.infer.swift import level_with_estimate

    photo, albedo = _flash_photo((0.20, 0.15, 0.08))
    est = cv.albedo_to_linear(physical.estimate(photo)[0]["diffuse"]).reshape(-1, 3).mean(0)
    truth = albedo.reshape(-1, 3).mean(0)
    assert np.all(np.abs(est / truth - 1) < 0.2)  # the estimate reads this photo's level (0.88 of it)
    chain = albedo * np.float32([2.0, 1.5, 1.0])  # the chain's own reading: too bright, and not alike per channel
    out = cv.albedo_to_linear(level_with_estimate(cv.albedo_to_stored(chain), photo))
    got = out.reshape(-1, 3).mean(0)
    own = chain.reshape(-1, 3).mean(0)
    assert np.allclose(got, np.sqrt(own * est), rtol=0.02)
    for c in range(3):
        assert np.corrcoef(out[..., c].ravel(), albedo[..., c].ravel())[0, 1] > 0.999  # the pattern is the chain's
    same = level_with_estimate(cv.albedo_to_stored(chain), photo, weight=0.0)
    assert np.allclose(cv.albedo_to_linear(same), chain, atol=2e-3)
    full = cv.albedo_to_linear(level_with_estimate(cv.albedo_to_stored(chain), photo, weight=1.0))
    assert np.allclose(full.reshape(-1, 3).mean(0), est, rtol=0.02)


def test_the_estimates_level_is_read_at_the_networks_size():
    """With ``size`` the estimate reads the photo area-shrunk to the chain's size: the level is the same."""
    from svbrdf_cli.infer.swift import level_with_estimate

    photo, albedo = _flash_photo((0.25, 0.25, 0.25), side=256)
    chain = cv.albedo_to_stored(albedo * 2.0)
    big = cv.albedo_to_linear(level_with_estimate(chain, photo)).mean()
    small = cv.albedo_to_linear(level_with_estimate(chain, photo, size=128)).mean()
    assert abs(small / big - 1) < 0.05


def test_the_photos_fine_detail_under_a_highlight_reaches_the_diffuse():
    from svbrdf_cli.imageops import blur, luminance
    from svbrdf_cli.infer.physical import photo_detail_under_highlight

    n = 128
    rho, grain = _rho(n, foot=(0.0, 0.0)), _grain(n, 5)
    albedo = (0.3 * (1 + 0.15 * grain))[..., None] * np.array([0.8, 0.6, 0.4], np.float32)
    shading = 1.2 - 0.3 * rho  # the flash's falloff
    lobe = 0.6 * np.exp(-(rho / 0.2) ** 2)  # a smooth white highlight, not clipped
    photo = cv.image_to_encoded(np.clip(albedo * shading[..., None] + lobe[..., None], 0, 1))
    spot = rho < 0.2
    diffuse = np.where(spot[..., None], blur(albedo, 6.0), albedo)  # a model's smooth fill under it
    stored = cv.albedo_to_stored(diffuse).astype(np.float32)
    out = cv.albedo_to_linear(photo_detail_under_highlight(stored, photo, spot))

    def fine(x):
        lum = luminance(x)
        return lum - blur(lum, 2.0)

    truth, before, after = fine(albedo)[spot], fine(diffuse)[spot], fine(out)[spot]
    assert np.corrcoef(truth, after)[0, 1] > 0.8  # the albedo's own grain, read through the highlight
    assert after.std() > 3 * before.std() and after.std() < 1.5 * truth.std()  # no more than round it
    assert abs(luminance(out)[spot].mean() / luminance(diffuse)[spot].mean() - 1) < 0.05  # the level kept
    np.testing.assert_array_equal(out[~spot], cv.albedo_to_linear(stored)[~spot])  # the rest as it was
    none = photo_detail_under_highlight(stored, photo, np.zeros((n, n), bool))
    np.testing.assert_array_equal(none, stored)


def test_where_the_photo_clipped_the_diffuse_gets_the_texture_beside_and_keeps_its_level():
    import cv2

    from svbrdf_cli.imageops import blur, luminance
    from svbrdf_cli.infer.physical import texture_beside_clipped

    n = 256
    g = np.random.default_rng(4)
    grain = 0.3 * (1 + 0.2 * g.standard_normal((n, n)).astype(np.float32))
    y, x = np.mgrid[0:n, 0:n]
    clipped = np.hypot(x - n / 2, y - n / 2) < 0.15 * n
    diffuse = np.where(clipped, blur(grain, 4.0), grain)[..., None] * np.float32([1.0, 0.8, 0.6])  # a smooth fill
    stored = cv.albedo_to_stored(diffuse).astype(np.float32)
    small = clipped[::4, ::4]  # the chain's mask, at its own size
    out = cv.albedo_to_linear(texture_beside_clipped(stored, small))

    def fine(im):
        lum = luminance(im)
        return lum - blur(lum, 1.0)

    core = np.hypot(x - n / 2, y - n / 2) < 0.12 * n
    assert fine(out)[core].std() > 0.7 * fine(diffuse)[~clipped].std() > 3 * fine(diffuse)[core].std()
    assert abs(luminance(out)[core].mean() / luminance(diffuse)[core].mean() - 1) < 0.05  # the level kept
    np.testing.assert_allclose(out / out[..., :1], diffuse / diffuse[..., :1], rtol=1e-3)  # and the colour
    big = cv2.resize(small.astype(np.uint8), (n, n), interpolation=cv2.INTER_NEAREST).astype(bool)
    np.testing.assert_allclose(out[~big], diffuse[~big], rtol=1e-4)  # the rest as it was
    none = texture_beside_clipped(stored, np.zeros_like(small))
    np.testing.assert_array_equal(none, stored)


def test_the_flash_spot_gets_the_photos_fine_detail_the_diffuse_lacks_and_keeps_its_edges():
    from svbrdf_cli.imageops import blur, luminance
    from svbrdf_cli.infer.physical import photo_detail_in_spot, spot_weight

    n = 128
    rho, grain = _rho(n, foot=(0.0, 0.0)), _grain(n, 8)
    y, x = np.mgrid[0:n, 0:n]
    hole = np.hypot(x - 0.62 * n, y - 0.5 * n) < 0.09 * n  # a black spot on white plaster, half in the spot
    albedo = np.where(hole, 0.02, 0.7 * (1 + 0.1 * grain))[..., None] * np.ones(3, np.float32)
    shading = 1.0 + 0.5 * np.exp(-(rho / 0.5) ** 2)  # the flash's falloff: no highlight on the matte plaster
    photo = cv.image_to_encoded(np.clip(albedo * 0.6 * shading[..., None], 0, 1)).astype(np.float32)
    weight = spot_weight(photo, np.zeros((n, n), bool))
    assert weight.max() == 1.0 and weight[rho > 0.9].max() == 0.0  # the spot, fading to nothing beyond it
    # the model's diffuse: the plaster's grain smoothed under the flash's centre, the black spot's edge kept
    smooth = np.where(hole, 0.02, 0.7)[..., None] * np.ones(3, np.float32)
    diffuse = np.where((rho < 0.45)[..., None], smooth, albedo)
    stored = cv.albedo_to_stored(diffuse).astype(np.float32)
    out = cv.albedo_to_linear(photo_detail_in_spot(stored, photo, weight))

    def fine(im):
        lum = np.log(luminance(im) + 0.01)
        return lum - blur(lum, 2.0)

    centre = (rho < 0.3) & ~blur(hole.astype(np.float32), 3.0).astype(bool)  # the plaster at the flash's centre
    truth, before, after = fine(albedo)[centre], fine(diffuse)[centre], fine(out)[centre]
    assert np.corrcoef(truth, after)[0, 1] > 0.8 and after.std() > 3 * before.std()
    near = blur(hole.astype(np.float32), 2.0)  # the black spot's edge stays sharp: no grey smeared into it
    assert luminance(out)[hole & (near < 0.95)].max() < 0.04 and luminance(out)[~hole & (near > 0.05)].min() > 0.45
    np.testing.assert_allclose(out[weight == 0], cv.albedo_to_linear(stored)[weight == 0], rtol=1e-5)
    hidden = rho < 0.3  # where the highlight hid the albedo: the fill's, not this step's
    assert spot_weight(photo, hidden)[hidden].max() == 0.0


def test_where_the_chain_guessed_a_metal_its_maps_are_read_as_a_dielectrics():
    from svbrdf_cli.imageops import luminance
    from svbrdf_cli.infer.swift import read_as_dielectric

    f0 = np.full((4, 8, 3), 0.04, np.float32)
    f0[:, 4:] = np.float32([0.6, 0.45, 0.2])  # a guess at a gold metal, its diffuse black
    diffuse = np.where(f0 > 0.05, 0.0, 0.3).astype(np.float32)
    stored = {"diffuse": cv.albedo_to_stored(diffuse).astype(np.float32),
              "specular": cv.albedo_to_stored(f0).astype(np.float32)}
    estimate = np.full((2, 4, 3), 0.5, np.float32)  # the physical estimate's diffuse (stored), any size
    out = read_as_dielectric(stored, estimate)
    np.testing.assert_array_equal(out["specular"][:, :4], stored["specular"][:, :4])  # a dielectric's: kept
    np.testing.assert_array_equal(out["diffuse"][:, :4], stored["diffuse"][:, :4])
    got = cv.albedo_to_linear(out["specular"][:, 4:])
    np.testing.assert_allclose(luminance(got), cv.DIELECTRIC_MAX_F0, rtol=1e-4)
    np.testing.assert_allclose(got / got[..., :1], f0[:, 4:] / f0[:, 4:, :1], rtol=1e-4)  # the hue kept
    # the photo's light, not black, at the chain's level (the dielectric half's 0.3), not the estimate's own
    np.testing.assert_allclose(cv.albedo_to_linear(out["diffuse"][:, 4:]), 0.3, rtol=1e-4)
    assert read_as_dielectric({k: v[:, :4] for k, v in stored.items()}, estimate) == {}
    # a map read as a metal nearly everywhere has too little of the chain's level: the estimate's own
    gold = np.broadcast_to(np.float32([0.6, 0.45, 0.2]), f0.shape)
    allmetal = {"diffuse": stored["diffuse"], "specular": cv.albedo_to_stored(gold).astype(np.float32)}
    np.testing.assert_allclose(read_as_dielectric(allmetal, estimate)["diffuse"], 0.5, atol=1e-6)


def test_the_estimates_level_is_left_out_where_its_flash_height_fit_ran_to_the_top_of_its_grid():
    """The estimate's level divides by the fall-off of its fitted height; at the grid's top (the flattest
    fall-off it may read) it comes out darkest, and the chain's own level is kept."""
    from svbrdf_cli.infer.physical import HEIGHT_GRID
    from svbrdf_cli.infer.swift import ESTIMATE_LEVEL, estimate_weight, level_with_estimate

    top, bottom = HEIGHT_GRID[-1] * cv.CAMERA_HEIGHT, HEIGHT_GRID[0] * cv.CAMERA_HEIGHT
    assert estimate_weight(round(top, 4)) == 0.0
    assert estimate_weight(bottom) == estimate_weight(cv.CAMERA_HEIGHT) == ESTIMATE_LEVEL > 0
    g = np.random.default_rng(3)
    chain = cv.albedo_to_stored(0.3 * (0.8 + 0.4 * g.random((32, 32, 3)))).astype(np.float32)
    estimate = cv.albedo_to_stored(np.full((32, 32, 3), 0.075)).astype(np.float32)  # two stops darker
    kept = level_with_estimate(chain, None, weight=estimate_weight(top), estimate=estimate)
    halfway = level_with_estimate(chain, None, weight=estimate_weight(bottom), estimate=estimate)
    level = lambda x: float(cv.albedo_to_linear(x).mean())  # noqa: E731
    assert abs(level(kept) / level(chain) - 1) < 0.01
    assert 0.4 < level(halfway) / level(chain) < 0.6  # a stop darker: halfway in log


def _speckled_photo(n=256, seed=3):
    """An encoded photo of a speckled albedo (granite-like, detail down to single pixels) under a smooth
    flash fall-off, and its albedo's luminance."""
    g = np.random.default_rng(seed)
    albedo = np.clip(0.45 + 0.15 * g.standard_normal((n, n)), 0.05, 0.95).astype(np.float32)
    y, x = np.mgrid[0:n, 0:n] / n - 0.5
    shade = (1.0 / (1.0 + 3.0 * (x * x + y * y))).astype(np.float32)
    photo = np.repeat((albedo * shade)[..., None], 3, -1) ** (1 / 2.2)
    return photo.astype(np.float32), albedo


def _high_pass(a, sigma=1.0):
    import cv2

    return a - cv2.GaussianBlur(a, (0, 0), sigma)


def test_the_chains_diffuse_comes_to_the_photos_size_with_the_photos_own_detail():
    """The chain runs at half the photo's size: its diffuse comes back with the photo's fine detail (a
    speckled granite relit at 0.158 against the floor's 0.094 when it came back bicubic), its roughness
    bicubic, and a photo that is not square bicubic throughout."""
    import cv2

    from svbrdf_cli.imageops import shrink_longest
    from svbrdf_cli.infer.swift import GUIDED, to_photo_size

    assert set(GUIDED) == {"normal", "diffuse"}
    photo, albedo = _speckled_photo()
    small = shrink_longest(photo, 128)
    # the chain's reading at its size: the albedo it sees (the photo's own, less the fall-off), and a
    # roughness that follows it too
    low_albedo = cv2.resize(albedo, (128, 128), interpolation=cv2.INTER_AREA)
    maps = {"diffuse": np.repeat(low_albedo[..., None], 3, -1) ** (1 / 2.2), "roughness": low_albedo[..., None]}
    out = to_photo_size(maps, small, photo)
    bicubic = cv2.resize(maps["diffuse"], (256, 256), interpolation=cv2.INTER_CUBIC)
    truth = _high_pass(albedo ** (1 / 2.2)).ravel()

    def fine(d):
        return float(np.corrcoef(_high_pass(d[..., 0]).ravel(), truth)[0, 1])

    assert out["diffuse"].shape == (256, 256, 3) and out["diffuse"].dtype == np.float32
    assert fine(bicubic) < 0.5 < 0.8 < fine(out["diffuse"])
    r_bicubic = cv2.resize(maps["roughness"], (256, 256), interpolation=cv2.INTER_CUBIC)
    assert np.allclose(out["roughness"][..., 0], np.clip(r_bicubic, 0, 1), atol=1e-6)
    # not square: bicubic
    wide = to_photo_size({"diffuse": maps["diffuse"][:, :96]}, small[:, :96], photo[:, :192])
    assert wide["diffuse"].shape == (256, 192, 3)
    assert np.allclose(wide["diffuse"], np.clip(cv2.resize(maps["diffuse"][:, :96], (192, 256),
                                                           interpolation=cv2.INTER_CUBIC), 0, 1), atol=1e-6)


def test_a_bowl_across_the_map_is_taken_off_and_the_checker_kept():
    """A bowl and a tilt across the map (a flash foot the physical fit misplaced, vignetting) are no
    albedo's: :func:`flatten_planar` divides them out, keeping each colour's level and the pattern."""
    from svbrdf_cli.infer.swift import flatten_planar

    n = 96
    y, x = np.mgrid[0:n, 0:n]
    x, y = (x + 0.5) / n * 2 - 1, (y + 0.5) / n * 2 - 1
    checker = ((x * 4).astype(int) + (y * 4).astype(int)) % 2 == 0
    albedo = np.where(checker[..., None], np.float32([0.5, 0.3, 0.2]), np.float32([0.1, 0.15, 0.3]))
    albedo = albedo * (1 + 0.1 * _grain(n, 3))[..., None]
    bowl = np.exp(0.35 * (x ** 2 + y ** 2) + 0.15 * x)[..., None]
    classes = checker.ravel().astype(int)
    flat = flatten_planar((albedo * bowl).astype(np.float32), classes)
    columns = flat.mean((0, 2))
    before = (albedo * bowl).mean((0, 2))
    assert before.max() / before.min() > 1.4
    assert columns[: n // 3].mean() / columns[n // 3: 2 * n // 3].mean() < 1.04  # it was 1.26
    assert np.corrcoef(flat[..., 0].ravel(), albedo[..., 0].ravel())[0, 1] > 0.98
    assert 0.9 < flat.mean() / (albedo * bowl).mean() < 1.1


def test_colours_that_differ_only_in_a_near_black_channel_are_one_class():
    """A red lacquer whose blue is 0.003 in one place and 0.006 in another is 0.7 apart in log units:
    read as two colours, each ring of the flash's disc got its own level and the disc stayed. Their
    channels' shares of their sum tell them one colour; a teal and a blue-grey stay apart."""
    from svbrdf_cli.imageops import chroma_classes
    from svbrdf_cli.infer.swift import TREND_CLASSES, TREND_CLASSES_APART, TREND_SHARES_APART

    rho = _rho()
    red = np.where((rho < 0.5)[..., None], np.float32([0.3, 0.02, 0.003]), np.float32([0.3, 0.02, 0.006]))
    assert chroma_classes(red, TREND_CLASSES, TREND_CLASSES_APART) is not None
    assert chroma_classes(red, TREND_CLASSES, TREND_CLASSES_APART, share_apart=TREND_SHARES_APART) is None
    two = np.where((rho < 0.5)[..., None], np.float32([0.05, 0.2, 0.2]), np.float32([0.1, 0.12, 0.2]))
    classes = chroma_classes(two, TREND_CLASSES, TREND_CLASSES_APART, share_apart=TREND_SHARES_APART)
    assert classes is not None and classes.max() == 1


def test_a_gold_foil_the_chains_mask_marks_is_kept_and_a_white_highlight_on_the_paper_filled():
    """``M_h`` marks a gold foil on red paper (``paper_real`` real_cards-red_0): the photo there is gold, not
    the paper's red plus white, so the chain's gold diffuse is kept; a white highlight on the same paper,
    marked the same, is filled from the paper round it."""
    from svbrdf_cli.infer.swift import fill_highlight

    n = 96
    rho = _rho(n, foot=(0.0, 0.0))
    g = np.random.default_rng(6)
    red, gold = np.float32([0.35, 0.06, 0.05]), np.float32([0.45, 0.3, 0.08])
    spot = rho < 0.2
    grain = (1 + 0.05 * g.standard_normal((n, n)))[..., None]
    mask = np.where(spot[..., None], 0.8, 0.0) * np.ones(3, np.float32)
    foil = np.where(spot[..., None], gold, red) * grain
    photo = cv.image_to_encoded(np.where(spot[..., None], 1.6 * gold, red) * grain).astype(np.float32)
    out = cv.albedo_to_linear(fill_highlight(cv.albedo_to_stored(foil).astype(np.float32), photo, mask))
    assert np.abs(out[spot & (rho < 0.15)].mean(0) - gold).max() < 0.03  # gold, not painted red
    dim = np.where(spot[..., None], 0.5 * red, red) * grain  # the chain's darker disc under a white highlight
    photo = cv.image_to_encoded(np.where(spot[..., None], red + 0.4, red) * grain).astype(np.float32)
    out = cv.albedo_to_linear(fill_highlight(cv.albedo_to_stored(dim).astype(np.float32), photo, mask))
    assert 0.85 < out[spot].mean() / red.mean() < 1.15  # filled at the paper's level
