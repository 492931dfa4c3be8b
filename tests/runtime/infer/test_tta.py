"""Test-time augmentation: the dihedral transforms of photos and map sets, and the confidence maps."""

import numpy as np
import pytest

from svbrdf_cli import conventions as cv
from svbrdf_cli.infer import tta


def _maps(seed=0, n=12):
    rng = np.random.default_rng(seed)
    normal = cv.normalize(rng.normal(size=(n, n, 3)) + [0, 0, 2])
    return {"normal": cv.encode_normals(normal).astype(np.float32),
            "diffuse": rng.random((n, n, 3), dtype=np.float32),
            "roughness": rng.random((n, n, 1), dtype=np.float32),
            "specular": rng.random((n, n, 3), dtype=np.float32)}


@pytest.mark.parametrize("k,mirror", tta.DIHEDRAL)
def test_untransform_inverts_transform(k, mirror):
    m = _maps()
    back = tta.untransform_maps(tta.transform_maps(m, k, mirror), k, mirror)
    for name in cv.MAP_NAMES:
        np.testing.assert_allclose(back[name], m[name], atol=1e-6)


def test_quarter_turn_turns_the_normal_vectors():
    # A ramp rising to the right (normal leaning left, -X); turned a quarter counter-clockwise it
    # rises upwards (towards row 0), so its normal leans down (-Y, with +Y up).
    n = np.zeros((4, 4, 3), np.float32)
    n[...] = cv.normalize(np.array([-0.5, 0.0, 1.0]))
    t = tta.transform_maps({"normal": cv.encode_normals(n), "diffuse": n, "roughness": n[..., :1], "specular": n},
                           1, False)
    v = cv.decode_normals(t["normal"])[0, 0]
    assert v[1] < -0.4 and abs(v[0]) < 1e-6
    m = tta.transform_maps({"normal": cv.encode_normals(n), "diffuse": n, "roughness": n[..., :1], "specular": n},
                           0, True)
    assert cv.decode_normals(m["normal"])[0, 0, 0] > 0.4  # mirrored left-right: leans right


def test_transform_image_moves_pixels_as_displayed():
    img = np.zeros((3, 3, 1), np.float32)
    img[0, 2] = 1  # top right
    assert tta.transform_image(img, 1, False)[0, 0, 0] == 1  # a quarter counter-clockwise: top left
    assert tta.transform_image(img, 0, True)[0, 0, 0] == 1  # mirrored: top left


class _Equivariant:
    """A 'network' that is exactly rotation-equivariant: the maps of a photo are fixed functions of it."""

    def __call__(self, img):
        g = img.mean(-1, keepdims=True)
        return {"normal": cv.encode_normals(np.broadcast_to(np.float32([0, 0, 1]), img.shape).copy()),
                "diffuse": img, "roughness": g, "specular": img * 0.5}


class _Biased(_Equivariant):
    """Adds a fixed, not rotating pattern to the diffuse map on the left half of its input."""

    def __call__(self, img):
        out = super().__call__(img)
        out["diffuse"] = out["diffuse"].copy()
        out["diffuse"][:, : img.shape[1] // 2] += 0.3
        return out


def test_confidence_is_high_for_an_equivariant_model_and_lower_where_passes_disagree():
    img = np.random.default_rng(1).random((16, 16, 3)).astype(np.float32)
    res = tta.passes(_Equivariant(), img)
    assert len(res) == len(tta.CONFIDENCE_PASSES)
    conf = tta.confidence(res)
    for name in cv.MAP_NAMES:
        assert conf[name].shape == (16, 16) and np.allclose(conf[name], 1, atol=1e-5)
    biased = tta.confidence(tta.passes(_Biased(), img))
    assert biased["diffuse"].mean() < 0.2 and np.allclose(biased["roughness"], 1, atol=1e-5)
