"""Test-time refinement (svbrdf_cli.infer.refine), its renderer's gradient (svbrdf_cli.shading) and the
capture geometry (svbrdf_cli.infer.geometry)."""

import math

import cv2
import numpy as np
import pytest

from svbrdf_cli import conventions as cv
from svbrdf_cli import shading
from svbrdf_cli.infer import geometry
from svbrdf_cli.infer import refine


def _random_maps(rng, size, dtype=np.float64):
    return (rng.normal(0, 0.3, (size, size, 2)).astype(dtype), rng.uniform(0.05, 0.9, (size, size, 3)).astype(dtype),
            rng.uniform(0.1, 0.9, (size, size, 1)).astype(dtype), rng.uniform(0.02, 0.6, (size, size, 3)).astype(dtype))


@pytest.mark.parametrize("camera", [None, (0.1, 0.05, 2.2)])
def test_render_with_gradient_matches_render_and_finite_differences(camera):
    rng = np.random.default_rng(0)
    maps = _random_maps(rng, 6)
    light = shading.Lighting(6, 6, (0.3, -0.2, 2.0), camera)
    radiance, backward = shading.render_with_gradient(*maps, light)
    ref = shading.render(shading.tilt_to_normal(maps[0]), *maps[1:], light=(0.3, -0.2, 2.0), camera=camera)
    assert np.allclose(radiance, ref, rtol=1e-5, atol=1e-6)
    weights = rng.normal(size=radiance.shape)
    grads = backward(weights)
    names = ("tilt", "diffuse", "roughness", "specular")
    for i, name in enumerate(names):
        num = np.zeros_like(maps[i])
        for idx in np.ndindex(maps[i].shape):
            plus, minus = [m.copy() for m in maps], [m.copy() for m in maps]
            plus[i][idx] += 1e-6
            minus[i][idx] -= 1e-6
            num[idx] = ((shading.render_with_gradient(*plus, light)[0] - shading.render_with_gradient(*minus, light)[0])
                        * weights).sum() / 2e-6
        assert np.allclose(grads[name], num, rtol=1e-4, atol=1e-6 * np.abs(num).max()), name


def test_tilt_round_trip():
    n = cv.normalize(np.array([[0.3, -0.2, 0.9], [0.0, 0.0, 1.0], [-0.5, 0.1, 0.4]]))
    assert np.allclose(shading.tilt_to_normal(shading.normal_to_tilt(n)), n, atol=1e-6)


def _photo(light, camera=(0.0, 0.0, 2.4), roughness=0.25, size=256, textured=True, seed=0, specular=0.04):
    rng = np.random.default_rng(seed)
    n = np.zeros((size, size, 3), np.float32)
    n[..., 2] = 1
    d = np.full((size, size, 3), 0.3, np.float32)
    if textured:
        noise = cv2.GaussianBlur(rng.uniform(0, 1, (size, size)).astype(np.float32), (0, 0), 3)
        noise = (noise - noise.min()) / (noise.max() - noise.min())
        d = d * (0.4 + 1.2 * noise[..., None])
    r = np.full((size, size, 1), roughness, np.float32)
    s = np.full((size, size, 3), specular, np.float32)
    lin = shading.render(n, d, r, s, light=light, camera=camera, intensity=cv.FLASH_INTENSITY) * 0.5
    return cv.image_to_encoded(lin).astype(np.float32), {"normal": n, "diffuse": d, "roughness": r, "specular": s}


@pytest.mark.parametrize("offset", [(0.3, -0.2), (-0.4, 0.1), (0.0, 0.0), (0.5, 0.45)])
@pytest.mark.parametrize("roughness", [0.15, 0.3])
def test_highlight_centre_of_an_off_centre_flash_within_2_percent(offset, roughness):
    photo, _ = _photo((offset[0], offset[1], 2.4), roughness=roughness)
    hx, hy = geometry.highlight_centre(photo)
    # equal heights: the mirror point is half-way between the camera's foot (0, 0) and the flash's
    width = 2 * cv.SURFACE_HALF_SIZE
    assert abs(hx - offset[0] / 2) <= 0.02 * width and abs(hy - offset[1] / 2) <= 0.02 * width


def test_geometry_recovers_the_flash_from_the_highlight_and_the_photo_centre():
    # a 600 x 400 photo whose 400 px crop sits 100 px right of the photo's centre: camera foot at x = -0.5
    photo, _ = _photo((-0.5 + 0.3, 0.2, 2.4), camera=(-0.5, 0.0, 2.4))
    geo = geometry.estimate(photo, height=2.4, photo_size=(600, 400), box=(200, 0, 400, 400))
    assert geo.camera[:2] == pytest.approx((-0.5, 0.0), abs=1e-6)
    assert geo.light[0] == pytest.approx(-0.2, abs=0.04) and geo.light[1] == pytest.approx(0.2, abs=0.04)
    assert geo.sources == {"height": "falloff fit", "camera": "photo centre", "light": "highlight"}
    # a crop with no box (rectified): the flash is taken to be at the lens, over the highlight
    geo = geometry.estimate(photo)
    assert geo.camera == geo.light and geo.light[2] == pytest.approx(cv.CAMERA_HEIGHT)


def test_flash_offset_is_capped():
    photo, _ = _photo((0.5, 0.5, 2.4), camera=(0.0, 0.0, 2.4))
    geo = geometry.estimate(photo, height=2.4, photo_size=(400, 400), box=(-400, 0, 400, 400))  # camera far left
    off = math.hypot(geo.light[0] - geo.camera[0], geo.light[1] - geo.camera[1])
    assert off == pytest.approx(geometry.MAX_FLASH_OFFSET * 2.4, rel=1e-6)
    assert "capped" in geo.sources["light"]


def test_exif_focal_length_sets_the_height(tmp_path):
    import OpenImageIO as oiio

    path = str(tmp_path / "phone.jpg")
    spec = oiio.ImageSpec(64, 48, 3, "uint8")
    spec.attribute("Exif:FocalLengthIn35mmFilm", 26)
    out = oiio.ImageOutput.create(path)
    out.open(path, spec)
    out.write_image(np.full((48, 64, 3), 128, np.uint8))
    out.close()
    from svbrdf_cli.ingest.photo import load_photo

    assert load_photo(path).focal_35mm == 26.0  # read along with the pixels
    # 26 mm on a 4000 x 3000 photo: f = 26 * 5000 / 43.27 px; a 2000 px crop is 1000 px either side
    z = geometry.crop_height(26.0, (4000, 3000), 2000)
    assert z == pytest.approx(26.0 * 5000 / math.hypot(36, 24) / 1000, rel=1e-9)
    photo, _ = _photo((0.0, 0.0, 2.4))
    geo = geometry.estimate(photo, height=1.0, focal=26.0, photo_size=(4000, 3000), box=(1000, 500, 2000, 2000))
    assert geo.light[2] == pytest.approx(z) and geo.sources["height"] == "exif"


def _stored(maps):
    out = cv.encode_maps(maps)
    return {k: np.asarray(v, np.float32) for k, v in out.items()}


def test_refinement_fits_the_photo_better_and_relights_better():
    light = (0.2, -0.1, 2.4)
    photo, truth = _photo(light, camera=light, roughness=0.3, seed=3)
    # the start has a dark hole in its diffuse round the highlight (what a flash does to an estimate)
    p = cv.surface_positions(256, 256)
    hole = 1.0 - 0.5 * np.exp(-((p[..., 0] - 0.1) ** 2 + (p[..., 1] + 0.05) ** 2) / (2 * 0.25 ** 2))[..., None]
    start = dict(truth, diffuse=(truth["diffuse"] * hole).astype(np.float32))
    geo = geometry.CaptureGeometry(camera=light, light=light, highlight=light[:2])
    res = refine.refine(photo, _stored(start), geo, 60)
    # (0.71; 0.64 with a roughness change per pixel instead of per albedo class, 0.57 when the tilt could
    # change broadly: the normals are flat, a broad tilt round the flash fitted the hole instead)
    assert res.report["photo_loss_after"] < 0.75 * res.report["photo_loss_before"]
    assert not res.report["kept_start"] and res.report["iterations"] == 60

    def diffuse_error(stored):  # the albedo's texture, whatever its level (the intensity is fitted)
        d, t = cv.decode_maps(stored)["diffuse"], truth["diffuse"]
        return float(np.sqrt(((d / d.mean() - t / t.mean()) ** 2).mean()))

    def relight_error(stored, other=(-0.8, 0.6, 2.4)):  # under a light the fit never saw
        k = refine.fit_intensity(cv.image_to_linear(photo), refine.parameters(stored), geo)
        a = cv.image_to_encoded(shading.render_maps(cv.decode_maps(stored), light=other, intensity=k))
        b = cv.image_to_encoded(shading.render_maps(truth, light=other, intensity=cv.FLASH_INTENSITY * 0.5))
        return float(np.sqrt(((a - b) ** 2).mean()))

    assert diffuse_error(res.stored) < diffuse_error(_stored(start))
    assert relight_error(res.stored) < relight_error(_stored(start))


@pytest.mark.parametrize("case", ["extreme maps", "noise photo", "black photo", "clipped photo"])
def test_refinement_never_returns_nan_or_a_worse_fit(case):
    rng = np.random.default_rng(1)
    size = 64
    photo, truth = _photo((0.0, 0.0, 2.4), size=size)
    maps = dict(truth)
    if case == "extreme maps":
        maps = {"normal": cv.normalize(np.concatenate([rng.normal(0, 3, (size, size, 2)), np.full((size, size, 1), 0.01)],
                                                      -1)),
                "diffuse": rng.uniform(0, 1, (size, size, 3)), "roughness": np.zeros((size, size, 1)),
                "specular": np.ones((size, size, 3))}
    elif case == "noise photo":
        photo = rng.uniform(0, 1, photo.shape).astype(np.float32)
    elif case == "black photo":
        photo = np.zeros_like(photo)
    else:
        photo = np.minimum(photo * 4.0, 1.0)
    geo = geometry.CaptureGeometry(camera=(0, 0, 2.4), light=(0, 0, 2.4), highlight=(0, 0))
    res = refine.refine(photo, _stored(maps), geo, 30)
    assert all(np.isfinite(v).all() and v.min() >= 0 and v.max() <= 1 for v in res.stored.values())
    assert res.stored["roughness"].shape == (size, size, 1)
    assert res.report["photo_loss_after"] <= res.report["photo_loss_before"]


def test_progress_is_called_once_per_step():
    photo, truth = _photo((0.0, 0.0, 2.4), size=32)
    steps = []
    geo = geometry.CaptureGeometry(camera=(0, 0, 2.4), light=(0, 0, 2.4), highlight=(0, 0))
    res = refine.refine(photo, _stored(truth), geo, 10, progress=steps.append)
    assert steps == list(range(1, 11)) and res.report["iterations"] == 10


def test_transfer_carries_the_change_to_another_size():
    photo, truth = _photo((0.0, 0.0, 2.4), size=64)
    start = _stored(truth)
    refined = dict(start, roughness=np.clip(start["roughness"] + 0.1, 0, 1),
                   diffuse=cv.albedo_to_stored(cv.albedo_to_linear(start["diffuse"]) * 0.5).astype(np.float32))
    big = {k: cv2.resize(v, (128, 128), interpolation=cv2.INTER_LINEAR).reshape(128, 128, -1) for k, v in start.items()}
    same = refine.transfer(start, start, big)
    for k in big:
        assert np.allclose(same[k], big[k], atol=2e-3), k
    moved = refine.transfer(start, refined, big)
    assert moved["roughness"].shape == (128, 128, 1)
    assert np.allclose(moved["roughness"], big["roughness"] + 0.1, atol=2e-3)
    ratio = cv.albedo_to_linear(moved["diffuse"]) / np.maximum(cv.albedo_to_linear(big["diffuse"]), 1e-6)
    assert np.allclose(np.median(ratio), 0.5, atol=0.01)


def test_specular_changes_only_grey_or_in_the_diffuse_colour():
    brown = np.array([[[1.5, 1.0, 0.5]]], np.float32)  # a diffuse's tint (unit channel mean)
    metal = np.array([[0.5]], np.float32)              # F0 at a metal's level: its colour may follow the diffuse
    gold = np.array([[[0.3, 0.2, 0.1]]], np.float32)   # a change along that tint: kept
    assert np.allclose(refine._spec_change(gold, brown, metal), gold, atol=1e-6)
    grey = np.full((1, 1, 3), 0.05, np.float32)        # a grey change: kept
    assert np.allclose(refine._spec_change(grey, brown, metal), grey, atol=1e-6)
    blue = np.array([[[-0.1, 0.0, 0.1]]], np.float32)   # against the tint: no blue F0 on brown wood
    out = refine._spec_change(blue, brown, metal)
    assert np.ptp(out) < 1e-6 and abs(float(out.mean())) < 1e-6
    flat = refine._spec_change(blue, np.ones((1, 1, 3), np.float32), metal)  # grey diffuse: grey changes only
    assert np.ptp(flat) < 1e-6


def test_a_dielectrics_specular_change_is_grey():
    # at a dielectric's F0 level a change along the diffuse's colour keeps its size but loses its colour:
    # a wood's F0 does not turn orange (pink highlights, and metal once converted)
    brown = np.array([[[1.5, 1.0, 0.5]]], np.float32)
    gold = np.array([[[0.03, 0.02, 0.01]]], np.float32)
    out = refine._spec_change(gold, brown, np.array([[0.06]], np.float32))
    assert np.ptp(out) < 1e-7 and abs(float(out.mean()) - 0.02) < 1e-7


def test_a_coloured_highlight_lets_a_dielectric_level_f0_take_its_colour():
    # where the photo's highlight is the material's own colour (own: highlight.metal_share), F0 may follow
    # the diffuse's tint at a dielectric's level, up to that share of its level
    brown = np.array([[[1.5, 1.0, 0.5]]], np.float32)
    gold = np.array([[[0.03, 0.02, 0.01]]], np.float32)
    level = np.array([[0.06]], np.float32)
    assert np.allclose(refine._spec_change(gold, brown, level, np.array([[1.0]], np.float32)), gold, atol=1e-7)
    out = refine._spec_change(3 * gold, brown, level, np.array([[0.5]], np.float32))
    assert np.allclose(out, 0.03 + 0.03 * brown, atol=1e-7)  # the tint bounded at 0.5 x 0.06, the rest grey
    none = refine._spec_change(gold, brown, level, np.array([[0.0]], np.float32))
    assert np.ptp(none) < 1e-7


def test_the_specular_maps_mean_never_falls_under_a_dielectrics_f0(monkeypatch):
    # a photo whose highlight is weaker than the start's F0 = 0.04 explains: the fit lowers F0
    light = (0.1, 0.0, 2.4)
    photo, truth = _photo(light, camera=light, roughness=0.15, seed=5, specular=0.0)
    start = _stored(dict(truth, specular=np.full_like(truth["specular"], cv.DIELECTRIC_F0)))
    geo = geometry.CaptureGeometry(camera=light, light=light, highlight=light[:2])

    def mean_f0(stored):
        return float((cv.decode_maps(stored)["specular"] @ np.asarray(cv.LUMA, np.float32)).mean())

    monkeypatch.setattr(refine, "SPECULAR_FLOOR", 0.0)
    assert mean_f0(refine.refine(photo, start, geo, 100).stored) < cv.DIELECTRIC_F0 - 8e-4  # without the floor
    monkeypatch.setattr(refine, "SPECULAR_FLOOR", cv.DIELECTRIC_F0)
    res = refine.refine(photo, start, geo, 100)
    assert mean_f0(res.stored) >= cv.DIELECTRIC_F0 - 1e-4 and not res.report["kept_start"]


def test_the_floor_lifts_the_whole_map_and_keeps_its_variation():
    spec = np.zeros((4, 4, 3), np.float32)
    spec[:2] = [0.01, 0.02, 0.03]  # a tinted half and a black half: mean luminance 0.01
    p = {"tilt": np.zeros((4, 4, 2), np.float32), "diffuse": np.full((4, 4, 3), -1.0, np.float32),
         "roughness": np.full((4, 4, 1), 0.5, np.float32), "specular": spec.copy()}
    refine._project(p)
    assert float((p["specular"] @ np.asarray(cv.LUMA, np.float32)).mean()) == pytest.approx(cv.DIELECTRIC_F0, abs=1e-6)
    assert np.allclose(p["specular"] - spec, p["specular"][3, 3, 0] - spec[3, 3, 0], atol=1e-6)  # the same grey everywhere
    high = dict(p, specular=np.full((4, 4, 3), 0.5, np.float32))
    refine._project(high)
    assert np.allclose(high["specular"], 0.5)  # a map above the floor is left alone


def test_a_start_whose_f0_is_under_the_floor_is_refined_from_the_floor_not_kept():
    # a chain's F0 of 0 on a varnished wood: raised to the floor at the first step, it had doubled the
    # photo's loss against the start's, and the start was kept (no refinement at all); the start is now
    # held at the floor before the light's fit and the loss to beat
    light = (0.1, 0.0, 2.4)
    photo, truth = _photo(light, camera=light, roughness=0.3, seed=4)
    # the chain's way: no lobe, its light in a brighter diffuse (the photo's at each pixel)
    black = np.zeros_like(truth["specular"])
    without = shading.render_maps(dict(truth, specular=black), light=light)
    lobe_in = shading.render_maps(truth, light=light) / np.maximum(without, 1e-6)
    start = _stored(dict(truth, specular=black, diffuse=np.clip(truth["diffuse"] * lobe_in, 0.0, 1.0)))
    geo = geometry.CaptureGeometry(camera=light, light=light, highlight=light[:2])
    res = refine.refine(photo, start, geo, 30)
    assert not res.report["kept_start"]
    assert res.report["photo_loss_after"] < 0.9 * res.report["photo_loss_before"]
    f0 = cv.decode_maps(res.stored)["specular"] @ np.asarray(cv.LUMA, np.float32)
    assert float(f0.mean()) >= cv.DIELECTRIC_F0 - 1e-4


def test_the_radial_trend_is_taken_out_and_the_rest_kept():
    side = 64
    radial = refine._Rings(side, (0.2, -0.1))
    rho = radial.rho
    disc = (0.1 * np.exp(-(rho / 0.4) ** 2))[..., None].astype(np.float32)  # darker, rougher where the flash was
    p = cv.surface_positions(side, side)
    stripes = (0.05 * np.sign(np.sin(p[..., 0] * 40.0)))[..., None].astype(np.float32)  # texture, not radial
    out = refine._without_radial_trend(disc + stripes + 0.02, radial)
    assert float(out.mean()) == pytest.approx(float((disc + stripes + 0.02).mean()), abs=1e-5)  # the level kept
    centre, outside = rho < 0.2, rho > 1.0
    assert abs(float(out[centre].mean() - out[outside].mean())) < 0.01  # the disc (0.09 deep) is gone
    assert float(np.abs(out - disc.mean() - 0.02 - stripes).mean()) < 0.015  # the stripes are still there


def test_a_dark_patterns_change_is_not_read_as_a_trend_of_the_diffuse():
    # black spots (albedo 0.003) in the outer rings only, white plaster (0.04) elsewhere; the fit's log change
    # is -1.1 on the spots and -0.16 on the plaster (the spotted plaster of tests/runtime/cli/test_artist.py)
    side = 64
    radial = refine._Rings(side, (0.0, 0.0))
    rho = radial.rho
    rng = np.random.default_rng(0)
    spots = (rho > 0.6) & (rng.uniform(size=rho.shape) < 0.25)
    albedo = np.repeat(np.where(spots, 0.003, 0.04)[..., None], 3, -1).astype(np.float32)
    change = np.repeat(np.where(spots, -1.1, -0.16)[..., None], 3, -1).astype(np.float32)
    plaster = ~spots

    def lift(out):  # the plaster's change in the spotted rings over its change at the centre
        return float(out[plaster & (rho > 0.6), 0].mean() - out[rho < 0.4, 0].mean())

    assert lift(refine._without_radial_trend(change, radial)) > 0.15  # equal weights: a disc in the plaster
    out = refine._without_radial_trend(change, radial, refine._radial_weight("diffuse", {"diffuse": np.log(albedo)}))
    assert abs(lift(out)) < 0.03
    # a trend alike on every pixel (vignetting) goes with the weights as without them
    vignetting = (change - 0.2 * rho[..., None] ** 2).astype(np.float32)
    out = refine._without_radial_trend(vignetting, radial, np.exp(np.log(albedo)))
    assert abs(lift(out)) < 0.03


def test_refinement_leaves_no_disc_in_roughness_round_the_highlight():
    light = (0.1, 0.0, 2.4)
    photo, truth = _photo(light, camera=light, roughness=0.2, seed=7)
    start = _stored(dict(truth, roughness=np.full_like(truth["roughness"], 0.45)))  # the start's lobe too broad
    geo = geometry.CaptureGeometry(camera=light, light=light, highlight=light[:2])
    rho = refine._Rings(256, light[:2]).rho

    def disc(res):
        change = cv.decode_maps(res.stored)["roughness"][..., 0] - 0.45
        return abs(float(change[rho < 0.25].mean() - change[rho > 0.8].mean()))

    res = refine.refine(photo, start, geo, 40)
    assert disc(res) < 0.003 and not res.report["kept_start"]  # 0.01 and more when the change keeps its trend


def test_refinement_leaves_the_cameras_vignetting_out_of_the_diffuse(monkeypatch):
    light = (0.0, 0.0, 2.4)
    photo, truth = _photo(light, camera=light, seed=3)
    rho = refine._Rings(256, light[:2]).rho
    vignetting = (1.0 - 0.25 * (rho / rho.max()) ** 2)[..., None]  # the lens darkens the corners, not the material
    photo = cv.image_to_encoded(cv.image_to_linear(photo) * vignetting).astype(np.float32)
    # the start is off by a pattern with no radial trend, so the refinement has something to mend:
    # started from the true maps it can keep its start and then tells nothing of the vignetting
    yy, xx = np.mgrid[0:256, 0:256] * (2 * np.pi / 64)
    pattern = (1.0 + 0.3 * np.sin(xx) * np.sin(yy))[..., None].astype(np.float32)
    start = _stored(dict(truth, diffuse=truth["diffuse"] * pattern))
    geo = geometry.CaptureGeometry(camera=light, light=light, highlight=light[:2])

    def edges_darker(res):
        change = np.log(cv.decode_maps(res.stored)["diffuse"].mean(-1) / truth["diffuse"].mean(-1))
        return float(change[rho < 0.3].mean() - change[rho > 1.0].mean())

    monkeypatch.setattr(refine, "_without_planar_trend", lambda start, p: p)  # the radial step alone
    monkeypatch.setattr(refine, "RADIAL_FREE", ("roughness", "specular"))
    free = edges_darker(refine.refine(photo, start, geo, 40))
    monkeypatch.setattr(refine, "RADIAL_FREE", ("diffuse", "roughness", "specular"))
    res = refine.refine(photo, start, geo, 40)
    assert free > 0.04 and abs(edges_darker(res)) < 0.3 * free and not res.report["kept_start"]


def _problem(rng, side=12, priors=None, weight=None):
    tilt, diffuse, rough, spec = _random_maps(rng, side, np.float32)
    photo = rng.uniform(0.05, 0.6, (side, side, 3)).astype(np.float32)
    init = {"tilt": tilt, "diffuse": np.log(diffuse), "roughness": rough, "specular": spec}
    geo = geometry.CaptureGeometry(camera=(0.1, 0.0, 2.4), light=(0.1, 0.0, 2.4), highlight=(0.1, 0.0))
    return refine._Problem(photo, init, geo, 3.0, priors or refine.Priors(), side, weight), init


def test_the_objectives_gradient_matches_finite_differences():
    rng = np.random.default_rng(7)
    prob, init = _problem(rng)
    p = {k: (v + rng.normal(0, 0.05, v.shape)).astype(np.float32) for k, v in init.items()}
    _, _, g = prob(p)
    for key in p:
        for _ in range(3):
            idx = tuple(int(rng.integers(0, s)) for s in p[key].shape)
            eps = 1e-3
            hi, lo = {k: v.astype(np.float64) for k, v in p.items()}, {k: v.astype(np.float64) for k, v in p.items()}
            hi[key][idx] += eps
            lo[key][idx] -= eps
            numeric = (prob(hi)[0] - prob(lo)[0]) / (2 * eps)
            assert g[key][idx] == pytest.approx(numeric, rel=0.05, abs=2e-6), (key, idx)


def test_the_dielectric_prior_holds_f0s_level_not_its_colour():
    rng = np.random.default_rng(2)
    only = refine.Priors(**dict({f: 0.0 for f in refine.Priors.__dataclass_fields__}, dielectric=1.0))
    prob, init = _problem(rng, priors=only, weight=np.zeros((12, 12, 1), np.float32))  # the dielectric prior alone
    luma = np.asarray(cv.LUMA, np.float32)
    teal = np.array([0.01, 0.05, 0.045], np.float32)
    teal *= cv.DIELECTRIC_F0 / float(teal @ luma)  # a coloured F0 at a dielectric's level
    def prior(spec):
        total, _, g = prob(dict(init, specular=np.broadcast_to(spec, init["specular"].shape).astype(np.float32)))
        return total, g["specular"]

    cost, grad = prior(teal)
    assert cost == pytest.approx(0.0, abs=1e-9)  # no pull on its colour ...
    cost, _ = prior(np.full(3, 0.1, np.float32))
    assert cost > 1e-3                          # ... but on its level
    _, grad = prior(np.full(3, 0.1, np.float32) * teal / teal.mean())
    # the pull lowers the level (gradient along the luminance weights, all positive)
    assert np.all(grad > 0)


def test_highlight_centre_is_not_pulled_by_bright_coloured_texture():
    # a teal surface, its white flash highlight at (0.15, -0.1), and a bright yellow patch (gold foil)
    # far from it: brighter in luminance than the highlight's shoulder, but with no blue in it
    photo, _ = _photo((0.3, -0.2, 2.4), roughness=0.3, textured=False)
    lin = cv.image_to_linear(photo) * np.float32([0.35, 1.0, 1.0])  # teal: little red anywhere...
    p = cv.surface_positions(*lin.shape[:2])
    patch = np.hypot(p[..., 0] + 0.5, p[..., 1] - 0.5) < 0.25
    lin[patch] = [1.0, 1.0, 0.02]  # ...and a yellow patch, luminance 0.93
    image = cv.image_to_encoded(lin).astype(np.float32)
    luma = cv2.GaussianBlur(lin @ np.asarray(cv.LUMA, np.float32), (0, 0), 4.0)
    assert patch[np.unravel_index(int(np.argmax(luma)), luma.shape)]  # by luminance the patch is the peak
    hx, hy = geometry.highlight_centre(image)
    assert abs(hx - 0.15) <= 0.04 and abs(hy + 0.1) <= 0.04


def test_what_the_photo_clipped_takes_the_surroundings_change():
    # the start's diffuse is 0.6x the truth on a checkerboard's dark squares (neither one level, which the
    # fitted intensity takes, nor a ring round the flash, which the radial rule takes out): the fit raises
    # it wherever it sees the photo; a clipped disc (no photo term there) takes the same rise from its
    # surroundings, not the start's level
    light = (0.0, 0.0, 2.4)
    photo, truth = _photo(light, camera=light, roughness=0.25, size=128, seed=3, textured=False)
    p = cv.surface_positions(128, 128)
    off = np.hypot(p[..., 0] - 0.5, p[..., 1] - 0.5)  # a clipped blob away from the highlight (a sparkle, a label)
    disc = off < 0.15
    photo = photo.copy()
    photo[disc] = 1.0
    dark = (np.floor((p[..., 0] - 0.25) / 0.5) + np.floor((p[..., 1] - 0.25) / 0.5)) % 2 == 0  # the blob's square too
    start = _stored(dict(truth, diffuse=truth["diffuse"] * np.where(dark, 0.6, 1.0)[..., None].astype(np.float32)))
    geo = geometry.CaptureGeometry(camera=light, light=light, highlight=light[:2])
    unobserved = refine._unclipped(cv.image_to_linear(photo))[..., 0] == 0

    def rise(res):
        d = cv.decode_maps(res.stored)["diffuse"][..., 1] / (0.6 * truth["diffuse"][..., 1])
        ring = ~unobserved & (off < 0.4)
        return float(d[unobserved & dark].mean()), float(d[ring & dark].mean())

    inside, around = rise(refine.refine(photo, start, geo, 40))
    assert around > 1.05 and inside - 1.0 > 0.5 * (around - 1.0)  # filled


def test_the_photo_weight_fades_in_round_a_clipped_pixel_over_a_round_rim():
    side = 256
    photo = np.full((side, side, 3), 0.2, np.float32)
    photo[128, 128] = 1.0  # one clipped pixel
    w = refine._unclipped(cv.image_to_linear(photo))[..., 0]
    r = refine.CLIP_MARGIN * side
    yy, xx = np.mgrid[:side, :side]
    dist = np.hypot(yy - 128, xx - 128)
    assert (w[dist <= r - 0.5] == 0).all() and (w[dist >= 2 * r + 1] == 1).all()
    ramp = w[(dist > r + 0.5) & (dist < 2 * r - 0.5)]
    assert ramp.size and ((ramp > 0) & (ramp < 1)).all()
    # round, not a square kernel's: the corners of the square round the pixel are weighted
    assert w[128 + int(r), 128 + int(r)] > 0


def test_the_fill_gives_the_clipped_region_its_surroundings_tilt_too():
    side = 64
    start = {"tilt": np.zeros((side, side, 2), np.float32), "diffuse": np.full((side, side, 3), np.log(0.3), np.float32),
             "roughness": np.full((side, side, 1), 0.3, np.float32), "specular": np.full((side, side, 3), 0.04, np.float32)}
    p = {k: v.copy() for k, v in start.items()}
    p["tilt"][..., 0] = 0.1  # the fit tilted everything it saw...
    unobserved = np.zeros((side, side), bool)
    unobserved[24:40, 24:40] = True
    p["tilt"][unobserved] = 0.0  # ...but not what the photo clipped
    out = refine._fill_unobserved(start, p, unobserved, refine._Rings(side, (0.0, 0.0)))
    assert np.allclose(out["tilt"][unobserved, 0], 0.1, atol=1e-3)  # no outline of the clipped region left


def test_the_tilt_priors_hold_the_starts_relief_not_flatness():
    """A start with relief (the chain's) costs nothing to keep: no prior pulls it towards up; a broad
    change of tilt away from any start costs more than a fine one of the same size."""
    rng = np.random.default_rng(3)
    side = 32
    tilts = refine.Priors(**dict({f: 0.0 for f in refine.Priors.__dataclass_fields__}, normal=1.0, broad_tilt=10.0))
    prob, init = _problem(rng, side=side, priors=tilts, weight=np.zeros((side, side, 1), np.float32))  # the priors alone
    y, x = np.mgrid[0:side, 0:side] / side
    bump = np.stack([np.sin(2 * np.pi * x), np.cos(2 * np.pi * y)], -1).astype(np.float32) * 0.3
    init["tilt"] = prob.init["tilt"] = bump
    cost, _, g = prob(dict(init))
    assert cost == pytest.approx(0.0, abs=1e-9) and np.abs(g["tilt"]).max() < 1e-9
    fine = np.where((np.indices((side, side)).sum(0) % 2)[..., None] == 0, 0.1, -0.1).astype(np.float32)
    broad = np.full_like(fine, 0.1)
    cost_fine = prob(dict(init, tilt=bump + fine))[0]
    cost_broad = prob(dict(init, tilt=bump + broad))[0]
    assert cost_broad > 3 * cost_fine > 0


def test_refinement_draws_no_cross_through_the_highlight():
    # per pixel, Adam turned the tilt's small gradients, of opposite signs either side of the highlight's
    # row and column, into whole steps: a line across and one down the normals (then a seam in a tiling)
    light = (0.1, 0.2, 2.4)
    photo, truth = _photo(light, camera=light, roughness=0.3, seed=5)
    p = cv.surface_positions(256, 256)
    hole = 1.0 - 0.5 * np.exp(-((p[..., 0] - 0.1) ** 2 + (p[..., 1] - 0.2) ** 2) / (2 * 0.25 ** 2))[..., None]
    start = dict(truth, diffuse=(truth["diffuse"] * hole).astype(np.float32))
    geo = geometry.CaptureGeometry(camera=light, light=light, highlight=light[:2])
    res = refine.refine(photo, _stored(start), geo, 30)
    change = refine.parameters(res.stored)["tilt"] - refine.parameters(_stored(start))["tilt"]
    across = np.abs(np.diff(change[..., 0].mean(0))).max()  # tilt x, column to column
    down = np.abs(np.diff(change[..., 1].mean(1))).max()  # tilt y, row to row
    assert across < 0.002 and down < 0.002, (across, down)  # (per pixel: 0.0040 and 0.0023)


def test_a_highlight_the_lobe_cannot_make_draws_no_disc_of_tilt_and_fine_relief_still_shows():
    # the photo's highlight is broader than the start's lobe (roughness 0.45 against 0.25): tilting the
    # normals round the flash would reshape it, and drew a disc of tilted quadrants on a flat leather
    size, light = 256, (0.05, 0.1, 2.4)
    rng = np.random.default_rng(11)
    fine = np.stack([cv2.GaussianBlur(rng.normal(0, 1, (size, size)).astype(np.float32), (0, 0), 1.5)
                     for _ in range(2)], -1)
    fine *= 0.08 / fine.std()
    n = shading.tilt_to_normal(fine).astype(np.float32)
    d = np.full((size, size, 3), 0.3, np.float32)
    s = np.full((size, size, 3), 0.04, np.float32)
    lin = shading.render(n, d, np.full((size, size, 1), 0.45, np.float32), s, light=light, camera=light,
                         intensity=cv.FLASH_INTENSITY) * 0.5
    photo = cv.image_to_encoded(lin).astype(np.float32)
    flat = np.dstack([np.zeros((size, size, 2)), np.ones((size, size, 1))]).astype(np.float32)
    start = {"normal": flat, "diffuse": d, "roughness": np.full((size, size, 1), 0.25, np.float32), "specular": s}
    geo = geometry.CaptureGeometry(camera=light, light=light, highlight=light[:2])
    res = refine.refine(photo, _stored(start), geo, 30)
    tilt = refine.parameters(res.stored)["tilt"]
    broad = cv2.GaussianBlur(tilt, (0, 0), size / 16)
    assert np.sqrt((broad ** 2).mean()) < 1.5e-4, np.sqrt((broad ** 2).mean())  # (0.6e-4; broad changes allowed: 3.4e-4)
    p = cv.surface_positions(size, size)
    near = np.hypot(p[..., 0] - light[0], p[..., 1] - light[1]) < 0.6  # where the highlight shows relief
    a, b = tilt[near].ravel(), fine[near].ravel()
    assert np.corrcoef(a, b)[0, 1] > 0.2, np.corrcoef(a, b)[0, 1]  # (0.25; broad changes allowed: 0.27)


def test_a_uniform_roughness_stays_uniform():
    # one material under a textured diffuse: the fit may move its roughness, not paint the highlight's
    # shape into it (a spread of 0.0054 per pixel; one value per albedo class: 0.0001)
    light = (0.1, 0.0, 2.4)
    photo, truth = _photo(light, camera=light, roughness=0.2, seed=7)
    start = _stored(dict(truth, roughness=np.full_like(truth["roughness"], 0.45)))
    geo = geometry.CaptureGeometry(camera=light, light=light, highlight=light[:2])
    res = refine.refine(photo, start, geo, 30)
    assert float(cv.decode_maps(res.stored)["roughness"].std()) < 0.001 and not res.report["kept_start"]


def test_the_roughness_change_is_one_value_per_class_read_where_the_lobe_is():
    side = 32
    diffuse = np.full((side, side, 3), 0.6, np.float32)
    diffuse[:, side // 2:] = (0.05, 0.1, 0.4)  # two albedo classes: left grey, right blue
    share = np.zeros((side, side), np.float32)
    share[:8, :8] = 1.0  # the lobe shows only on the left's corner
    basis = refine._class_basis(np.log(diffuse), share)
    change = np.zeros((side, side, 1), np.float32)
    change[:8, :8] = -0.1  # a blotch where the lobe is
    change[20:, 20:] = 0.3  # and one the photo never showed
    out = refine._per_class(change, basis)[..., 0]
    assert np.allclose(out[:, : side // 2], -0.1, atol=0.003)  # the whole class takes what the lobe showed
    assert np.allclose(out[:, side // 2:], 0.0, atol=0.003)  # a class the lobe never reached keeps none


def test_refinement_leaves_no_bowl_round_the_photos_centre_when_the_flash_is_off_it(monkeypatch):
    """Vignetting is centred on the lens, not on the highlight: with the flash off-centre the radial step
    leaves it, and the change's trend in x and y goes at the end (:func:`refine._without_planar_trend`)."""
    light = (0.7, 0.6, 2.4)
    photo, truth = _photo(light, camera=(0.0, 0.0, 2.4), seed=5)
    centre = refine._Rings(256, (0.0, 0.0)).rho
    vignetting = (1.0 - 0.5 * (centre / centre.max()) ** 2)[..., None]
    photo = cv.image_to_encoded(cv.image_to_linear(photo) * vignetting).astype(np.float32)
    yy, xx = np.mgrid[0:256, 0:256] * (2 * np.pi / 64)
    pattern = (1.0 + 0.3 * np.sin(xx) * np.sin(yy))[..., None].astype(np.float32)
    start = _stored(dict(truth, diffuse=truth["diffuse"] * pattern))
    geo = geometry.CaptureGeometry(camera=(0.0, 0.0, 2.4), light=light, highlight=(0.35, 0.3))

    def bowl(res):
        change = np.log(cv.decode_maps(res.stored)["diffuse"].mean(-1) / truth["diffuse"].mean(-1))
        return float(change[centre < 0.3].mean() - change[centre > 1.0].mean())

    with monkeypatch.context() as m:
        m.setattr(refine, "_without_planar_trend", lambda start, p: p)
        left = bowl(refine.refine(photo, start, geo, 40))
    res = refine.refine(photo, start, geo, 40)
    assert left > 0.04 and abs(bowl(res)) < 0.3 * left and not res.report["kept_start"]
