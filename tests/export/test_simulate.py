import math

import pytest
import torch

from export.data import simulate
from export.render import targets
from svbrdf_cli import conventions as cv


def _flat(b=2, size=64, diffuse=0.4, rough=0.6, spec=0.04):
    z = torch.zeros(b, 3, size, size)
    z[:, 2] = 1
    return {"normal": z, "diffuse": torch.full((b, 3, size, size), diffuse),
            "roughness": torch.full((b, 1, size, size), rough), "specular": torch.full((b, 3, size, size), spec)}


def _capture(b, **fixed):
    c = simulate.sample_capture(torch.Generator().manual_seed(0), b, simulate.PAPER)
    for k, v in fixed.items():
        c[k] = torch.as_tensor(v, dtype=torch.float64).expand_as(c[k]).clone()
    return c


def test_capture_parameters_are_in_range_and_deterministic():
    g1, g2 = torch.Generator().manual_seed(5), torch.Generator().manual_seed(5)
    a, b = simulate.sample_capture(g1, 256), simulate.sample_capture(g2, 256)
    for k in a:
        assert torch.equal(a[k], b[k]), k
    r = simulate.DEFAULT_RANGES
    assert a["fov"].min() >= r.fov_degrees[0] and a["fov"].max() <= r.fov_degrees[1]
    # The square sees exactly the surface: camera height = 1 / tan(fov / 2).
    assert torch.allclose(a["camera"][:, 2] * torch.tan(torch.deg2rad(a["fov"]) / 2), torch.ones(256, dtype=torch.float64))
    off = (a["light"] - a["camera"]).norm(dim=1) / a["camera"][:, 2]
    assert off.max() <= r.flash_offset[1] + 1e-9
    assert a["camera"][:, :2].abs().max() <= r.centre_offset
    assert a["exposure"].min() >= r.exposure_range[0] and a["exposure"].max() <= r.exposure_range[1]
    assert set(a["tone"].tolist()) == {0.0, 1.0, 2.0}
    assert 0 < (a["jpeg"] > 0).float().mean() < 1


def test_photo_in_unit_range_and_deterministic():
    maps = _flat(4, rough=0.2)
    cap = simulate.sample_capture(torch.Generator().manual_seed(1), 4)
    p1 = simulate.photograph(maps, cap, torch.Generator().manual_seed(2))
    p2 = simulate.photograph(maps, cap, torch.Generator().manual_seed(2))
    assert torch.equal(p1["photo"], p2["photo"])
    for k in ("photo", "I"):
        assert p1[k].min() >= 0 and p1[k].max() <= 1 and torch.isfinite(p1[k]).all()


def test_paper_setting_photo_is_the_clean_flash_image():
    maps = _flat(2, rough=0.3)
    cap = simulate.sample_capture(torch.Generator().manual_seed(0), 2, simulate.PAPER)
    shot = simulate.photograph(maps, cap)
    assert torch.allclose(shot["photo"], shot["I"], atol=0.5 / 255 + 1e-6)
    expect = targets.flash_image(maps, intensity=shot["intensity"])
    assert torch.allclose(shot["I"], expect, atol=1e-5)
    assert abs(float(shot["I"].mean()) - cv.AUTO_EXPOSURE_MEAN) < 2e-3


@pytest.mark.parametrize("read", [0.005, 0.02])
def test_read_noise_has_the_requested_level(read):
    maps = _flat(1, size=128, diffuse=0.3, rough=1.0)
    cap = _capture(1, read_noise=read, shot_noise=0.0, exposure=0.5)
    shot = simulate.photograph(maps, cap, torch.Generator().manual_seed(3), quantize=False)
    res = cv.image_to_linear(shot["photo"]) - cv.image_to_linear(shot["I"])
    inside = (cv.image_to_linear(shot["I"]) > 5 * read) & (cv.image_to_linear(shot["I"]) < 1 - 5 * read)
    assert abs(float(res[inside].std()) / read - 1) < 0.05


def test_shot_noise_grows_with_the_signal():
    shot_var = 1e-3
    maps = _flat(1, size=128, diffuse=0.3, rough=1.0)
    cap = _capture(1, read_noise=0.0, shot_noise=shot_var, exposure=0.5)
    shot = simulate.photograph(maps, cap, torch.Generator().manual_seed(4), quantize=False)
    clean = cv.image_to_linear(shot["I"])
    res = cv.image_to_linear(shot["photo"]) - clean
    inside = (clean > 0.05) & (clean < 0.8)
    z = res[inside] / clean[inside].sqrt()
    assert abs(float(z.std()) / math.sqrt(shot_var) - 1) < 0.05


def test_clipping_white_balance_and_vignetting():
    maps = _flat(1, size=64, diffuse=0.02, rough=0.2, spec=0.5)  # dark, with a strong highlight
    cap = _capture(1, exposure=0.5)
    shot = simulate.photograph(maps, cap)
    assert float(shot["photo"].max()) == 1.0  # the highlight clips
    cap = _capture(1, wb=[1.2, 1.0, 0.8])
    cap["wb"] = torch.tensor([[1.2, 1.0, 0.8]], dtype=torch.float64)
    shot = simulate.photograph(_flat(1), cap)
    r, g, b = shot["photo"][0].mean((1, 2)).tolist()
    assert r > g > b
    cap = _capture(1, vignetting=0.3)
    shot = simulate.photograph(_flat(1, rough=1.0), cap, quantize=False)
    ratio = cv.image_to_linear(shot["photo"]) / cv.image_to_linear(shot["I"])
    assert abs(float(ratio[0, 0, 0, 0]) - (1 - 0.3 * (1 - 1 / 64) ** 2)) < 1e-3  # corner pixel centre
    assert abs(float(ratio[0, 0, 32, 32]) - 1) < 1e-3


def test_tone_curves():
    x = torch.linspace(0, 1, 11).reshape(1, 1, 1, 11).expand(3, 3, 1, 11)
    tone = torch.tensor([0.0, 1.0, 2.0], dtype=torch.float64)
    y = simulate.tone_curve(x, tone, torch.full((3,), 0.5, dtype=torch.float64))
    assert torch.allclose(y[0], cv.image_to_encoded(x[0]))
    assert torch.allclose(y[1], cv.linear_to_srgb(x[1]))
    dark, light = (y[1] > 0.02) & (y[1] < 0.45), (y[1] > 0.55) & (y[1] < 0.98)
    assert (y[2][dark] < y[1][dark]).all() and (y[2][light] > y[1][light]).all()  # an S-curve
    assert y.min() >= 0 and y.max() <= 1


def test_jpeg_changes_images_only_when_asked():
    img = torch.rand(2, 3, 32, 32, generator=torch.Generator().manual_seed(0))
    out = simulate.jpeg(img, torch.tensor([0.0, 60.0]))
    assert torch.equal(out[0], img[0])
    assert not torch.allclose(out[1], img[1], atol=1 / 255)
    assert out.min() >= 0 and out.max() <= 1


def test_off_axis_flash_moves_the_highlight():
    maps = _flat(1, size=64, diffuse=0.1, rough=0.15, spec=0.5)
    cap = _capture(1)
    cap["camera"] = torch.tensor([[0.5, 0.0, cv.CAMERA_HEIGHT]], dtype=torch.float64)
    cap["light"] = cap["camera"].clone()
    img = simulate.photograph(maps, cap)["photo"][0].mean(0)
    col = int(img.max(0)[0].argmax())
    assert 40 < col < 56  # mirror point below the lens, x = 0.5 -> column 48


def test_blur_keeps_constants_and_softens_edges():
    img = torch.zeros(2, 3, 32, 32)
    img[..., 16:] = 1
    out = simulate.gaussian_blur(img, torch.tensor([0.0, 1.0], dtype=torch.float64))
    assert torch.equal(out[0], img[0])
    assert 0.2 < float(out[1, 0, 5, 15]) < 0.5 and 0.5 < float(out[1, 0, 5, 16]) < 0.8
    flat = simulate.gaussian_blur(torch.full((1, 3, 16, 16), 0.3), torch.tensor([2.0]))
    assert torch.allclose(flat, torch.full_like(flat, 0.3), atol=1e-6)
