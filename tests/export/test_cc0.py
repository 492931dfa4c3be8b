import numpy as np
import pytest

from export.data import cc0


def test_metalness_to_specular_hand_values():
    colour = np.array([[0.8, 0.4, 0.2]])
    d, s = cc0.metalness_to_specular(colour, np.array([[0.0]]))
    np.testing.assert_allclose(d, colour)
    np.testing.assert_allclose(s, [[0.04, 0.04, 0.04]])
    d, s = cc0.metalness_to_specular(colour, np.array([[1.0]]))
    np.testing.assert_allclose(d, [[0, 0, 0]])
    np.testing.assert_allclose(s, colour)
    d, s = cc0.metalness_to_specular(colour, np.array([[0.5]]))
    np.testing.assert_allclose(d, [[0.4, 0.2, 0.1]])
    np.testing.assert_allclose(s, [[0.42, 0.22, 0.12]])


def test_normals_from_height_tilt_away_from_the_slope():
    h, w = 16, 16
    ramp_x = np.tile(np.linspace(0, 1, w), (h, 1))  # rises towards +x (right)
    n = cc0.normals_from_height(ramp_x, depth=0.5)
    inner = n[:, 2:-2]
    assert (inner[..., 0] < 0).all() and np.allclose(inner[..., 1], 0, atol=1e-6)
    ramp_up = np.tile(np.linspace(1, 0, h)[:, None], (1, w))  # rises towards row 0 = +y (up)
    inner = cc0.normals_from_height(ramp_up, depth=0.5)[2:-2]
    assert (inner[..., 1] < 0).all()
    assert np.allclose(np.linalg.norm(n, axis=-1), 1, atol=1e-6)


def test_normal_map_y_sign_detects_convention():
    rng = np.random.default_rng(0)
    import cv2

    height = cv2.GaussianBlur(rng.uniform(size=(64, 64)).astype(np.float32), (0, 0), 3)
    gl = cc0.normals_from_height(height, depth=3.0)
    dx = gl * np.array([1, -1, 1], np.float32)
    assert cc0.normal_map_y_sign(gl, height) == 1
    assert cc0.normal_map_y_sign(dx, height) == -1
    assert cc0.normal_map_y_sign(gl, np.zeros_like(height)) == 0  # flat displacement: unknown


def test_load_ambientcg(shared_data):
    m = cc0.load_ambientcg(shared_data / "materials" / "ambientcg" / "Tiles032", size=64)
    assert m["normal"].shape == (64, 64, 3) and m["roughness"].shape == (64, 64, 1)
    assert np.allclose(np.linalg.norm(m["normal"], axis=-1), 1, atol=1e-4)
    assert m["normal_source"].startswith("map") and "flipped" in m["normal_source"]  # ambientCG is DirectX
    for k in ("diffuse", "specular", "roughness"):
        assert 0 <= m[k].min() and m[k].max() <= 1
    with pytest.raises(FileNotFoundError):
        cc0.load_ambientcg(shared_data / "materials" / "ambientcg" / "Ground041")
