import numpy as np
import pytest
import torch

from export.render import brdf
from svbrdf_cli import conventions as cv
from svbrdf_cli import shading

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


def _t(x, device="cpu"):
    return torch.as_tensor(x, dtype=torch.float64, device=device)


@pytest.mark.parametrize("device", DEVICES)
def test_golden_table(golden, device):
    # Rows -> (M, 3, 1, 1) so the channel axis is 1.
    def col(k):
        return _t(golden[k], device)[..., None, None]

    f = brdf.brdf(col("n"), col("l"), col("v"), col("diffuse"), col("roughness"), col("specular"))
    np.testing.assert_allclose(f[..., 0, 0].cpu().numpy(), golden["f"], rtol=1e-10, atol=1e-12)


def _random_maps(seed, b=3, h=24, w=20):
    g = torch.Generator().manual_seed(seed)
    n = cv.normalize(torch.randn(b, 3, h, w, generator=g, dtype=torch.float64) * 0.5
                     + _t([0, 0, 1]).view(1, 3, 1, 1), axis=1)
    return {"normal": n, "diffuse": torch.rand(b, 3, h, w, generator=g, dtype=torch.float64),
            "roughness": torch.rand(b, 1, h, w, generator=g, dtype=torch.float64),
            "specular": torch.rand(b, 3, h, w, generator=g, dtype=torch.float64)}


@pytest.mark.parametrize("light,camera", [(cv.FLASH_POSITION, None), ((0.7, -0.4, 1.5), None),
                                          ((1.0, 2.0, 3.0), (0.0, -0.5, 2.0))])
def test_numpy_torch_agree_float64(light, camera):
    maps = _random_maps(0)
    t = brdf.render_maps(maps, light=light, camera=camera, intensity=3.0)
    for i in range(t.shape[0]):
        a = shading.render_maps({k: v[i].permute(1, 2, 0).numpy() for k, v in maps.items()},
                          light=light, camera=camera, intensity=3.0)
        assert np.abs(t[i].permute(1, 2, 0).numpy() - a).max() < 1e-5


def test_batched_lights_and_intensities_match_single_renders():
    maps = _random_maps(1)
    lights = _t([[0.0, 0.0, 2.0], [0.5, 0.5, 1.0], [-1.0, 0.3, 2.5]])
    power = _t([1.0, 2.0, 0.5])
    batched = brdf.render_maps(maps, light=lights, intensity=power)
    for i in range(3):
        single = brdf.render_maps({k: v[i:i + 1] for k, v in maps.items()}, light=lights[i], intensity=float(power[i]))
        torch.testing.assert_close(batched[i:i + 1], single)


def test_encode_decode_round_trip():
    maps = _random_maps(2)
    back = cv.decode_maps(cv.encode_maps(maps), axis=1)
    for k in cv.MAP_NAMES:
        torch.testing.assert_close(back[k], maps[k])


def test_gradients_finite_and_correct():
    maps = {k: v[:1, :, :6, :6].clone().requires_grad_(True) for k, v in _random_maps(3).items()}
    # roughness away from the MIN_ROUGHNESS clip so the function is smooth there
    with torch.no_grad():
        maps["roughness"].clamp_(0.2, 0.9)

    def fn(n, d, r, s):
        return brdf.render(cv.normalize(n, axis=1), d, r, s, light=(0.3, -0.2, 2.0), camera=(0.0, 0.1, 2.2))

    assert torch.autograd.gradcheck(fn, tuple(maps[k] for k in cv.MAP_NAMES), eps=1e-6, atol=1e-5)


def test_gradients_finite_at_extremes():
    maps = _random_maps(4)
    maps["roughness"] = torch.cat([torch.zeros_like(maps["roughness"][:1]), torch.ones_like(maps["roughness"][1:])])
    maps["normal"][:, :, 0] = _t([1.0, 0.0, 0.0]).view(1, 3, 1)  # a row of horizon normals
    for v in maps.values():
        v.requires_grad_(True)
    out = brdf.render_maps(maps, light=(5.0, 0.0, 0.01))
    out.sum().backward()
    assert torch.isfinite(out).all() and (out >= 0).all()
    assert all(torch.isfinite(v.grad).all() for v in maps.values())


@pytest.mark.parametrize("device", DEVICES)
def test_float32_device(device):
    maps = {k: v.float().to(device) for k, v in _random_maps(5).items()}
    out = brdf.render_maps(maps)
    assert out.dtype == torch.float32 and out.device.type == device
    ref = brdf.render_maps({k: v.double().cpu() for k, v in maps.items()})
    torch.testing.assert_close(out.double().cpu(), ref, rtol=1e-4, atol=1e-5)
