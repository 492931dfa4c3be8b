import math

import numpy as np
import pytest
import torch

from export.data import augment
from export.data.cc0 import normals_from_height
from svbrdf_cli import conventions as cv


def _height(size=32, seed=0):
    """A smooth periodic height field (so finite differences wrap cleanly)."""
    g = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size] * (2 * np.pi / size)
    h = sum(g.uniform(0.2, 1) * np.sin(kx * x + ky * y + g.uniform(0, 6))
            for kx, ky in [(1, 0), (0, 2), (1, 1), (2, -1), (3, 1)])
    return ((h - h.min()) / (h.max() - h.min())).astype(np.float64)


def _material(h, depth=0.3):
    n = torch.from_numpy(normals_from_height(h, depth=depth)).permute(2, 0, 1)[None].double()
    t = torch.from_numpy(h)[None, None]
    return {"normal": n, "height": t, "diffuse": t.expand(1, 3, -1, -1) * 0.5,
            "roughness": t * 0.5 + 0.2, "specular": torch.full((1, 3) + h.shape, 0.04, dtype=torch.float64)}


def _normals_of(height_tensor, depth=0.3):
    return torch.from_numpy(normals_from_height(height_tensor[0, 0].numpy(), depth=depth)).permute(2, 0, 1)[None].double()


@pytest.mark.parametrize("k", [1, 2, 3])
def test_rot90_rotates_normals_like_the_surface(k):
    m = _material(_height())
    r = augment.rot90(m, k)
    # The normals of the rotated height field are the rotated normals.
    assert torch.allclose(r["normal"], _normals_of(r["height"]), atol=1e-5)


def test_rot90_is_counter_clockwise_as_displayed():
    """A slope rising to the right (+x) rises upward (+y, towards row 0) after a quarter turn."""
    ramp = np.tile(np.linspace(0, 1, 16), (16, 1))
    m = _material(ramp)
    r = augment.rot90(m, 1)
    assert r["height"][0, 0, 0, 8] > r["height"][0, 0, -1, 8]  # higher at the top
    assert r["normal"][0, 1, 8, 8] < -0.1  # tilts away from the slope: towards -y
    assert abs(float(r["normal"][0, 0, 8, 8])) < 1e-6


@pytest.mark.parametrize("horizontal", [True, False])
def test_flip_negates_the_matching_component(horizontal):
    m = _material(_height(seed=1))
    f = augment.flip(m, horizontal)
    assert torch.allclose(f["normal"], _normals_of(f["height"]), atol=1e-5)


def test_affine_crop_quarter_turn_equals_rot90():
    m = _material(_height(seed=2))
    b = torch.zeros(1, 2, dtype=torch.float64)
    a = augment.affine_crop(m, torch.tensor([math.pi / 2]), torch.tensor([1.0]), b, 32)
    r = augment.rot90(m, 1)
    for k in ("normal", "height", "diffuse"):
        assert torch.allclose(a[k], r[k], atol=1e-5), k


@pytest.mark.parametrize("angle", [0.3, 1.0, 2.5, -0.8])
def test_free_rotation_rotates_a_tilted_plane_normal(angle):
    """A constant normal (a tilted plane) turns by the angle the material turns."""
    n0 = cv.normalize(torch.tensor([0.4, -0.2, 1.0], dtype=torch.float64), axis=0)
    m = {"normal": n0.reshape(1, 3, 1, 1).expand(1, 3, 16, 16).clone(),
         "diffuse": torch.full((1, 3, 16, 16), 0.5, dtype=torch.float64),
         "roughness": torch.full((1, 1, 16, 16), 0.5, dtype=torch.float64),
         "specular": torch.full((1, 3, 16, 16), 0.04, dtype=torch.float64)}
    out = augment.affine_crop(m, torch.tensor([angle]), torch.tensor([0.5]), torch.zeros(1, 2), 8)
    c, s = math.cos(angle), math.sin(angle)
    expect = torch.tensor([c * n0[0] - s * n0[1], s * n0[0] + c * n0[1], n0[2]], dtype=torch.float64)
    assert torch.allclose(out["normal"][0, :, 4, 4], expect, atol=1e-6)


def test_free_rotation_content_and_vectors_agree():
    """Rotate a ramp height field by an arbitrary angle: the rotated normals
    match those derived from the rotated height field (interior pixels)."""
    size = 64
    y, x = np.mgrid[0:size, 0:size] / size
    h = 0.5 * x + 0.2 * (1 - y)  # rises to the right and to the top
    m = _material(h)
    out = augment.affine_crop(m, torch.tensor([0.7]), torch.tensor([0.5]), torch.zeros(1, 2, dtype=torch.float64), size)
    # Zooming in (window half as wide) spreads half the height swing over the
    # whole surface: the same slopes need twice the depth.
    derived = _normals_of(out["height"], depth=0.3 / 0.5)
    inner = (slice(None), slice(None), slice(4, -4), slice(4, -4))
    assert torch.allclose(out["normal"][inner], derived[inner], atol=2e-3)


def test_normals_stay_unit_after_every_augmentation():
    g = torch.Generator().manual_seed(3)
    m = _material(_height(seed=3))
    m = {k: v.expand(4, -1, -1, -1).float().clone() for k, v in m.items()}
    other = augment.rot90(m, 1)
    mask = torch.rand(4, 1, 32, 32, generator=g)
    for out in (augment.rot90(m, 3), augment.flip(m), augment.flip(m, False), augment.random_geometry(m, g, 24),
                augment.blend(m, other, mask), augment.jitter_colour(m, g)):
        assert torch.allclose(out["normal"].norm(dim=1), torch.ones(1), atol=1e-5)
        assert (out["normal"][:, 2] > 0).all()


def test_blend_normals_are_renormalised_vectors():
    a = {"normal": torch.tensor([1.0, 0, 1]).reshape(1, 3, 1, 1) / math.sqrt(2),
         "diffuse": torch.zeros(1, 3, 1, 1), "roughness": torch.zeros(1, 1, 1, 1), "specular": torch.zeros(1, 3, 1, 1)}
    b = {k: v.clone() for k, v in a.items()}
    b["normal"] = torch.tensor([-1.0, 0, 1]).reshape(1, 3, 1, 1) / math.sqrt(2)
    b["diffuse"] += 1
    out = augment.blend(a, b, torch.full((1, 1, 1, 1), 0.5))
    assert torch.allclose(out["normal"].flatten(), torch.tensor([0.0, 0, 1]), atol=1e-6)
    assert torch.allclose(out["diffuse"], torch.full((1, 3, 1, 1), 0.5))


def test_colour_jitter_stays_physical():
    g = torch.Generator().manual_seed(0)
    d = torch.rand(8, 3, 16, 16, generator=g) * 0.85
    spec = torch.full((8, 3, 16, 16), 0.04)
    spec[:4] = torch.tensor([0.95, 0.64, 0.54]).reshape(1, 3, 1, 1)  # copper
    m = {"normal": torch.tensor([0.0, 0, 1]).reshape(1, 3, 1, 1).expand(8, 3, 16, 16), "diffuse": d,
         "roughness": torch.rand(8, 1, 16, 16, generator=g), "specular": spec}
    for _ in range(5):
        out = augment.jitter_colour(m, g, hue=0.1, saturation=(0.5, 2.0), brightness=0.8)
        assert out["diffuse"].min() >= 0 and out["diffuse"].max() <= augment.MAX_ALBEDO + 1e-6
        assert out["specular"].min() >= 0 and out["specular"].max() <= 1
        assert torch.equal(out["specular"][4:], spec[4:])  # grey dielectric F0 untouched
    assert not torch.allclose(out["specular"][:4], spec[:4])


def test_hsv_round_trip():
    x = torch.rand(2, 3, 8, 8, generator=torch.Generator().manual_seed(1))
    assert torch.allclose(augment.hsv_to_rgb(*augment.rgb_to_hsv(x)), x, atol=1e-6)


def test_runtime_tta_transforms_match_the_training_augmentation():
    """svbrdf_cli.infer.tta (numpy, the runtime) turns normals exactly as export.data.augment (torch) does."""
    from svbrdf_cli.infer import tta

    g = torch.Generator().manual_seed(3)
    n = cv.normalize(torch.randn(1, 3, 8, 8, generator=g) + torch.tensor([0, 0, 2.0]).reshape(1, 3, 1, 1), axis=1)
    stored = {"normal": cv.encode_normals(n[0].permute(1, 2, 0).numpy()).astype(np.float32),
              "diffuse": np.zeros((8, 8, 3), np.float32), "roughness": np.zeros((8, 8, 1), np.float32),
              "specular": np.zeros((8, 8, 3), np.float32)}
    for k, mirror in tta.DIHEDRAL:
        ref = {"normal": n}
        ref = augment.rot90(augment.flip(ref, True) if mirror else ref, k)["normal"][0].permute(1, 2, 0).numpy()
        got = cv.decode_normals(tta.transform_maps(stored, k, mirror)["normal"])
        np.testing.assert_allclose(got, ref, atol=1e-5)
