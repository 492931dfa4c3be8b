"""``svbrdf export``: re-target a map set; never over an existing folder without ``--force``."""

import os

import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli.write import mapset
from svbrdf_cli.imageio import read_image

from .clitools import run


def _maps(h=16, w=16):
    """Left half a dielectric (diffuse 0.2, r 0.3), right half white metal (r 0.7); normals tilt to +Y."""
    metal = np.zeros((h, w, 1), np.float32)
    metal[:, w // 2:] = 1.0
    diffuse = np.where(metal > 0, 0.0, 0.2).astype(np.float32) * np.ones((h, w, 3), np.float32)
    specular = np.where(metal > 0, 1.0, cv.DIELECTRIC_F0).astype(np.float32) * np.ones((h, w, 3), np.float32)
    normal = np.broadcast_to(cv.normalize(np.array([0.0, 0.5, 1.0])), (h, w, 3)).astype(np.float32)
    return {"normal": normal, "diffuse": diffuse, "roughness": np.where(metal > 0, 0.7, 0.3).astype(np.float32),
            "specular": specular}


def right(img):
    return img[:, img.shape[1] // 2:].reshape(-1, img.shape[-1]).mean(0)


def test_cli_export(tmp_path):
    mapset.write_map_set(tmp_path / "maps", _maps(), bits=16)
    out = tmp_path / "ue"
    args = ["export", str(tmp_path / "maps"), "-o", str(out), "--preset", "unreal", "--bits", "16", "--no-ao"]
    code, output = run(*args)
    assert code == 0, output
    orm = read_image(out / "T_ue_ORM.png")
    np.testing.assert_allclose(right(orm), [1.0, 0.7, 1.0], atol=2e-3)
    assert read_image(out / "T_ue_N.png")[..., 1].max() < 0.4

    code, output = run(*args)
    assert code == 1
    msg = output.strip()
    assert "\n" not in msg and "already exists" in msg and "--force" in msg and str(out) in msg

    assert run(*args, "--force")[0] == 0

    code, output = run("export", tmp_path / "maps", "-o", tmp_path / "g", "--preset", "gltf", "--format", "exr")
    assert code == 2 and "PNG only" in output
    code, output = run("export", tmp_path / "nothing", "-o", tmp_path / "x", "--preset", "gltf")
    assert code == 1 and "normal.png" in output


def test_name_names_the_engine_files(tmp_path):
    mapset.write_map_set(tmp_path / "maps", _maps())
    code, output = run("export", tmp_path / "maps", "-o", tmp_path / "u", "--preset", "unity-hdrp", "--name", "Oak")
    assert code == 0, output
    assert {"Oak_BaseMap.png", "Oak_MaskMap.png", "Oak_Normal.png", "Oak_Height.png"} <= set(os.listdir(tmp_path / "u"))
