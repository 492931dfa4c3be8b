"""Procedural SVBRDF generator: determinism, value ranges, metals, height -> normal."""

import math

import pytest
import torch

from export.data import noise
from export.data import procedural
from svbrdf_cli import conventions as cv

SIZE = 48
BATCH = 3


def _gen(seed):
    return torch.Generator().manual_seed(seed)


@pytest.fixture(scope="module")
def materials():
    """Each family, BATCH samples at SIZE, generated once for the range checks."""
    return {name: procedural.generate(name, _gen(1), BATCH, SIZE) for name in procedural.FAMILIES}


def test_at_least_twelve_families():
    assert len(procedural.FAMILIES) >= 12
    assert set(procedural.METAL_FAMILIES) <= set(procedural.FAMILIES)


@pytest.mark.parametrize("name", sorted(procedural.FAMILIES))
def test_deterministic_per_seed(name):
    a = procedural.generate(name, _gen(7), 2, 32)
    b = procedural.generate(name, _gen(7), 2, 32)
    c = procedural.generate(name, _gen(8), 2, 32)
    for k in ("height", "normal", "diffuse", "roughness", "specular", "depth"):
        assert torch.equal(a[k], b[k]), k
    assert any(not torch.equal(a[k], c[k]) for k in ("height", "diffuse", "roughness", "specular"))


@pytest.mark.parametrize("name", sorted(procedural.FAMILIES))
def test_value_ranges(materials, name):
    m = materials[name]
    shapes = {"height": 1, "normal": 3, "diffuse": 3, "roughness": 1, "specular": 3}
    for k, ch in shapes.items():
        v = m[k]
        assert v.shape == (BATCH, ch, SIZE, SIZE), k
        assert v.dtype == torch.float32
        assert torch.isfinite(v).all(), k
        if k != "normal":
            assert v.min() >= 0.0 and v.max() <= 1.0, k
    n = m["normal"]
    assert torch.allclose(n.norm(dim=1), torch.ones(1), atol=1e-4)
    assert (n[:, 2] > 0).all()
    assert m["roughness"].min() >= 0.04
    assert m["depth"].shape == (BATCH,) and (m["depth"] > 0).all()
    # Nothing is perfectly white; the height map uses its range.
    assert m["diffuse"].max() <= 0.9
    assert (m["height"].amax((1, 2, 3)) - m["height"].amin((1, 2, 3)) > 1e-3).all()
    if name not in procedural.METAL_FAMILIES:
        spec = m["specular"]
        assert spec.min() >= 0.015 and spec.max() <= 0.1, "dielectric F0 out of range"


@pytest.mark.parametrize("name", procedural.METAL_FAMILIES)
def test_metals(materials, name):
    m = materials[name]
    assert m["diffuse"].max() < 0.05
    assert m["specular"].min() > 0.4
    assert m["specular"].max() <= 0.98 * 1.2


def test_metal_colours_are_coloured_sometimes():
    m = procedural.generate("scratched_metal", _gen(3), 24, 16)
    s = m["specular"].mean((2, 3))
    tint = s.max(1).values - s.min(1).values
    assert (tint > 0.15).any() and (tint < 0.05).any()


def test_height_to_normal_ramp():
    h_, w_ = 16, 32
    depth = 0.05
    col = torch.arange(w_, dtype=torch.float64) / (w_ - 1)
    ramp_x = col.reshape(1, 1, 1, w_).expand(1, 1, h_, w_)
    n = procedural.height_to_normal(ramp_x, depth)
    slope = depth * (1.0 / (w_ - 1)) / (2.0 * cv.SURFACE_HALF_SIZE / w_)
    want = torch.tensor([-slope, 0.0, 1.0], dtype=torch.float64) / math.sqrt(1 + slope * slope)
    assert torch.allclose(n, want.reshape(1, 3, 1, 1).expand_as(n), atol=1e-10)
    assert (n[:, 0] < 0).all()  # height increasing to +x -> normal tilts to -x

    row = torch.arange(h_, dtype=torch.float64) / (h_ - 1)
    ramp_up = (1.0 - row).reshape(1, 1, h_, 1).expand(2, 1, h_, w_)  # higher toward row 0 = world +y
    d = torch.tensor([0.02, 0.1], dtype=torch.float64)
    n = procedural.height_to_normal(ramp_up, d)
    for i in range(2):
        s = float(d[i]) * (1.0 / (h_ - 1)) / (2.0 * cv.SURFACE_HALF_SIZE / h_)
        want = torch.tensor([0.0, -s, 1.0], dtype=torch.float64) / math.sqrt(1 + s * s)
        assert torch.allclose(n[i], want.reshape(3, 1, 1).expand_as(n[i]), atol=1e-10)
    assert (n[:, 1] < 0).all()


def test_height_to_normal_matches_cc0_inside():
    np = pytest.importorskip("numpy")
    from export.data.cc0 import normals_from_height

    h = procedural.generate("cobblestones", _gen(0), 1, 32)["height"]
    ours = procedural.height_to_normal(h, 0.1)[0].permute(1, 2, 0).numpy()
    ref = normals_from_height(h[0, 0].numpy(), depth=0.1)
    assert np.allclose(ours[1:-1, 1:-1], ref[1:-1, 1:-1], atol=1e-5)


def test_generate_uses_family_relief():
    m = procedural.generate("wood", _gen(2), 2, 32)
    again = procedural.height_to_normal(m["height"], m["depth"])
    assert torch.allclose(again, m["normal"], atol=1e-6)


def test_random_materials_mix_and_determinism():
    a = procedural.random_materials(_gen(11), 8, 32)
    b = procedural.random_materials(_gen(11), 8, 32)
    assert a["family"] == b["family"] and len(a["family"]) == 8
    assert all(f in procedural.FAMILIES for f in a["family"])
    for k in ("height", "normal", "diffuse", "roughness", "specular"):
        assert torch.equal(a[k], b[k])
        assert a[k].shape[0] == 8
    c = procedural.random_materials(_gen(5), 4, 16, families=["tiles", "foam"])
    assert set(c["family"]) <= {"tiles", "foam"}
    with pytest.raises(KeyError):
        procedural.random_materials(_gen(5), 2, 16, families=["nope"])
    with pytest.raises(KeyError):
        procedural.generate("nope", _gen(5), 1, 16)


def test_global_rng_untouched():
    torch.manual_seed(123)
    before = torch.get_rng_state()
    procedural.random_materials(_gen(4), 3, 16)
    assert torch.equal(before, torch.get_rng_state())


def test_float64_and_device_default():
    g = _gen(9)
    m = procedural.generate("fabric", g, 1, 16, dtype=torch.float64)
    assert m["diffuse"].dtype == torch.float64 and m["diffuse"].device == g.device


def test_noise_primitives():
    g = _gen(0)
    x, y = noise.coords(32, torch.device("cpu"))
    assert float(x[0, 0, 0, 0]) < 0 < float(x[0, 0, 0, -1])
    assert float(y[0, 0, 0, 0]) > 0 > float(y[0, 0, -1, 0])  # row 0 is world +y
    f = noise.fbm(g, x * 4, y * 4, 2, 4)
    assert f.shape == (2, 1, 32, 32) and 0.3 < float(f.std()) < 3.0
    w = noise.worley(g, x * 5, y * 5, 2, channels=2)
    assert (w["f2"] >= w["f1"]).all() and w["value"].shape == (2, 2, 32, 32)
    assert float(w["f1"].max()) < 1.5
    bk = noise.bricks(g, x, y, 2, 4.0, 8.0, 0.5)
    assert (bk["u"] >= 0).all() and (bk["u"] < 1).all() and (bk["edge"] >= 0).all()
    hx = noise.hexagons(g, x, y, 2, 5.0)
    assert float(hx["edge"].max()) <= 0.5 + 1e-6 and float(hx["edge"].min()) >= -1e-6
    rgb = noise.hsv_to_rgb(torch.tensor([0.0, 1 / 3, 2 / 3]).reshape(3, 1), torch.ones(3, 1), torch.ones(3, 1))
    assert torch.allclose(rgb, torch.eye(3), atol=1e-6)


def test_prints_are_colour_without_relief_and_stay_out_of_the_default_draw():
    from export.data import procedural

    assert "printed" not in procedural.FAMILIES and "printed" in procedural.EXTRA_FAMILIES
    g = torch.Generator().manual_seed(3)
    m = procedural.generate("printed", g, 6, 128)
    tilt = m["normal"][:, :2].norm(dim=1).mean((1, 2))
    assert float(tilt.max()) < 0.12
    assert float(m["diffuse"].std((2, 3)).mean(1).min()) > 0.01  # every one has a pattern
    mixed = procedural.random_materials(torch.Generator().manual_seed(0), 32, 32)
    assert "printed" not in mixed["family"]
