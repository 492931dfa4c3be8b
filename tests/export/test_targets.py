import torch

from export.render import targets
from svbrdf_cli import conventions as cv


def _maps(b=2, h=64, w=64, rough=None, seed=0, bumpy=True):
    g = torch.Generator().manual_seed(seed)
    n = torch.zeros(b, 3, h, w, dtype=torch.float64)
    n[:, 2] = 1
    if bumpy:
        yy, xx = torch.meshgrid(torch.linspace(0, 8 * torch.pi, h, dtype=torch.float64),
                                torch.linspace(0, 8 * torch.pi, w, dtype=torch.float64), indexing="ij")
        n[:, 0] = 0.6 * torch.sin(xx)
        n[:, 1] = 0.6 * torch.cos(yy)
        n = cv.normalize(n, axis=1)
    r = torch.rand(b, 1, h, w, generator=g, dtype=torch.float64) * 0.3 + 0.1 if rough is None \
        else torch.full((b, 1, h, w), rough, dtype=torch.float64)
    return {"normal": n, "diffuse": torch.rand(b, 3, h, w, generator=g, dtype=torch.float64) * 0.5,
            "roughness": r, "specular": torch.rand(b, 3, h, w, generator=g, dtype=torch.float64) * 0.3 + 0.1}


def test_shapes_and_ranges():
    out = targets.intermediate_targets(_maps())
    assert set(out) == set(targets.TARGET_NAMES)
    for k, v in out.items():
        assert v.shape == (2, 3, 64, 64), k
        assert torch.isfinite(v).all() and v.min() >= 0 and v.max() <= 1, k


def test_bumpiness_flattened_equals_input_for_flat_normals():
    maps = _maps(bumpy=False)
    torch.testing.assert_close(targets.bumpiness_flattened(maps), targets.flash_image(maps))


def test_bumpiness_flattened_differs_for_bumpy_normals():
    maps = _maps()
    assert (targets.bumpiness_flattened(maps) - targets.flash_image(maps)).abs().mean() > 0.01


def test_masks_zero_where_nothing_is_suppressed():
    # r = 1: D = 1/pi everywhere for flat normals, between delta_s and delta_h: nothing changes.
    maps = _maps(rough=1.0, bumpy=False)
    assert cv.LOWLIGHT_NDF_THRESHOLD < 1 / torch.pi < cv.HIGHLIGHT_NDF_THRESHOLD
    assert targets.highlight_mask(maps).abs().max() == 0
    assert targets.bumpiness_mask(maps).abs().max() == 0


def test_masks_are_zero_exactly_at_untouched_pixels():
    from export.render.brdf import ndf_ggx, surface_positions

    maps = _maps(rough=0.35)
    p = surface_positions(64, 64, maps["normal"])
    l = cv.normalize(torch.tensor(cv.FLASH_POSITION, dtype=torch.float64).view(1, 3, 1, 1) - p, axis=1)
    d = ndf_ggx((maps["normal"] * l).sum(1, keepdim=True), cv.roughness_to_alpha(maps["roughness"]))
    mh, mb = targets.highlight_mask(maps), targets.bumpiness_mask(maps)
    hi = (d > cv.HIGHLIGHT_NDF_THRESHOLD).expand_as(mh)
    lo = (d < cv.LOWLIGHT_NDF_THRESHOLD).expand_as(mb)
    assert hi.any() and lo.any()
    assert mh[~hi].abs().max() == 0 and mb[~lo].abs().max() == 0
    assert mh[hi].mean() > 0.01 and mb[lo].mean() > 0.001


def test_highlight_removed_has_no_highlight_on_glossy():
    maps = _maps(rough=0.15, bumpy=False)
    maps["specular"].fill_(0.5)
    i_bf, i_hr = targets.bumpiness_flattened(maps), targets.highlight_removed(maps)
    # glossy: I_bf has a saturated highlight at the centre, I_hr none
    assert i_bf.amax() > 0.99 and i_hr.amax() < 0.8 * i_bf.amax()
    assert i_hr.var() < 0.5 * i_bf.var()
    centre = i_hr[..., 28:36, 28:36].mean()
    assert centre < 1.2 * i_hr.mean()


def _roughness_of(img):
    """Mean absolute Laplacian: high-frequency energy."""
    lap = img[..., 1:-1, 2:] + img[..., 1:-1, :-2] + img[..., 2:, 1:-1] + img[..., :-2, 1:-1] - 4 * img[..., 1:-1, 1:-1]
    return lap.abs().mean()


def test_hr2_is_smoother_than_hr():
    maps = _maps()
    maps["roughness"] = torch.where(torch.rand_like(maps["roughness"]) > 0.5, 0.1, 0.6).double()
    maps["diffuse"].fill_(0.2)
    maps["specular"].fill_(0.3)
    hr, hr2 = targets.highlight_removed(maps), targets.highlight_removed(maps, high_roughness=True)
    assert _roughness_of(hr2) < 0.5 * _roughness_of(hr)


def test_highlight_removed_chunking_does_not_change_result():
    maps = _maps(b=2, h=16, w=16)
    torch.testing.assert_close(targets.highlight_removed(maps, chunk=7), targets.highlight_removed(maps, chunk=100))


def test_highlight_removed_per_sample_camera():
    maps = _maps(b=2, h=16, w=16)
    cams = torch.tensor([[0.0, 0.0, 2.0], [0.3, -0.2, 1.6]], dtype=torch.float64)
    both = targets.highlight_removed(maps, camera=cams)
    for i in range(2):
        one = targets.highlight_removed({k: v[i:i + 1] for k, v in maps.items()}, camera=cams[i])
        torch.testing.assert_close(both[i:i + 1], one)


def test_auto_exposure_hits_target():
    maps = _maps()
    e = targets.auto_exposure(maps, target=0.4)
    img = targets.flash_image(maps, intensity=e)
    assert torch.allclose(img.mean((1, 2, 3)), torch.full((2,), 0.4, dtype=torch.float64), atol=1e-3)


def test_targets_are_differentiable_in_the_maps():
    maps = {k: v[:1, :, :8, :8].clone().requires_grad_(True) for k, v in _maps().items()}
    out = targets.intermediate_targets(maps)
    sum(v.sum() for v in out.values()).backward()
    assert all(torch.isfinite(v.grad).all() for v in maps.values())


def test_highlight_removed_matches_general_renderer():
    """The flat-normal fast path equals K calls of the general renderer with N_u."""
    from export.render.brdf import render

    maps = _maps(b=2, h=12, w=12)
    cam = torch.tensor([0.2, -0.1, 2.0], dtype=torch.float64)
    for high in (False, True):
        r = torch.ones_like(maps["roughness"]) if high else maps["roughness"]
        pos = cv.aux_light_positions(20, height=2.0)  # disc at the camera's height
        power = cv.aux_light_intensities(pos, 1.5, height=2.0)
        acc = 0
        for p, e in zip(pos, power):
            light = cam + torch.tensor([p[0], p[1], 0.0], dtype=torch.float64)
            acc = acc + render(targets.flat_normal(maps["diffuse"]), maps["diffuse"], r, maps["specular"],
                               light=light, camera=cam, intensity=float(e)).clamp(0, 1)
        ref = cv.image_to_encoded(acc / 20)
        out = targets.highlight_removed(maps, camera=cam, intensity=1.5, high_roughness=high, count=20, chunk=6)
        torch.testing.assert_close(out, ref, rtol=1e-9, atol=1e-9)


def test_highlight_removed_pair_equals_separate_calls():
    maps = _maps(b=3, h=16, w=16)
    cam = torch.tensor([[0.1, 0.2, 2.0], [0.0, 0.0, 3.0], [-0.3, 0.1, 1.5]], dtype=torch.float64)
    hr, hr2 = targets.highlight_removed_pair(maps, cam, torch.tensor([1.0, 2.0, 0.5], dtype=torch.float64), count=12)
    assert torch.allclose(hr, targets.highlight_removed(maps, cam, torch.tensor([1.0, 2.0, 0.5], dtype=torch.float64), count=12))
    assert torch.allclose(hr2, targets.highlight_removed(maps, cam, torch.tensor([1.0, 2.0, 0.5], dtype=torch.float64),
                                                   high_roughness=True, count=12))
