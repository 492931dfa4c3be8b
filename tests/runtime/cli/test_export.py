"""``svbrdf export``: re-target a map set; never over an existing folder without ``--force``."""

import os

import numpy as np
import pytest

from svbrdf_cli import conventions as cv
from svbrdf_cli.imageio import read_image
from svbrdf_cli.write import mapset, readback

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
    orm = read_image(out / "T_maps_ORM.png")
    np.testing.assert_allclose(right(orm), [1.0, 0.7, 1.0], atol=2e-3)
    assert read_image(out / "T_maps_N.png")[..., 1].max() < 0.4

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


def _relief(n=64):
    """A known relief (surface units; the surface is 2 units wide) and its normals."""
    p = cv.surface_positions(n, n)
    x, y = p[..., 0], p[..., 1]
    g = np.exp(-((x - 0.2) ** 2 + (y + 0.1) ** 2) / 0.08)
    h = 0.04 * g + 0.01 * np.sin(3 * np.pi * x)
    dx = 0.04 * g * (-2 * (x - 0.2) / 0.08) + 0.03 * np.pi * np.cos(3 * np.pi * x)
    dy = 0.04 * g * (-2 * (y + 0.1) / 0.08)
    return h, cv.normalize(np.stack([-dx, -dy, np.ones_like(h)], -1)).astype(np.float32)


def test_height_is_the_relief_at_a_fixed_scale_and_flat_normals_are_flat(tmp_path):
    from svbrdf_cli.write.derive import HEIGHT_SPAN
    import json

    flat = dict(_maps(64, 64), normal=np.tile(np.float32([0, 0, 1]), (64, 64, 1)))
    h, normals = _relief()
    for name, maps in (("flat", flat), ("relief", dict(flat, normal=normals))):
        mapset.write_map_set(tmp_path / name, maps, bits=16)
        code, output = run("export", tmp_path / name, "-o", tmp_path / f"{name}_gltf", "--preset", "gltf")
        assert code == 0, output
    # mid-grey; the 16-bit normal file's rounding (0.5 is not a 16-bit value) is not stretched to 0-1
    flat_height = read_image(tmp_path / "flat_gltf" / "height.png")
    assert np.abs(flat_height - 0.5).max() < 1e-3
    meta = json.loads((tmp_path / "relief_gltf" / "material.gltf").read_text())["materials"][0]["extras"]["height"]
    assert meta["scale_to_width"] == HEIGHT_SPAN and meta["midlevel"] == 0.5
    got = (read_image(tmp_path / "relief_gltf" / "height.png")[..., 0] - 0.5) * HEIGHT_SPAN  # texture widths
    want = (h - h.mean()) / 2.0
    assert np.corrcoef(got.ravel(), want.ravel())[0, 1] > 0.98
    assert abs(np.ptp(got) / np.ptp(want) - 1) < 0.1


def test_export_names_files_after_the_material_not_the_output_folder(tmp_path):
    mapset.write_map_set(tmp_path / "oak", _maps(), bits=16)
    code, output = run("export", tmp_path / "oak", "-o", tmp_path / "exp" / "oak_ue", "--preset", "unreal")
    assert code == 0, output
    assert "T_oak_BC.png" in os.listdir(tmp_path / "exp" / "oak_ue")  # not T_oak_ue_BC.png
    # the Blender preset keeps the name as it is (Node Wrangler splits at _ and - alike)
    mapset.write_map_set(tmp_path / "wood_walnut", _maps(), bits=16)
    code, output = run("export", tmp_path / "wood_walnut", "-o", tmp_path / "b", "--preset", "blender")
    assert code == 0, output
    assert "wood_walnut_BaseColor.png" in os.listdir(tmp_path / "b")


@pytest.mark.parametrize("preset", ["gltf", "unreal", "unity-hdrp", "blender"])
def test_view_render_and_export_accept_a_presets_set(tmp_path, preset):
    maps = _maps()
    mapset.write_map_set(tmp_path / "oak", maps, bits=16)
    code, output = run("export", tmp_path / "oak", "-o", tmp_path / preset, "--preset", preset, "--bits", 16)
    assert code == 0, output
    # read back: the same maps (16-bit rounding aside)
    back = readback.read_any_set(tmp_path / preset)
    for k in ("diffuse", "specular", "roughness"):
        np.testing.assert_allclose(back[k][..., :maps[k].shape[-1] if maps[k].ndim == 3 else 1],
                                   maps[k] if maps[k].ndim == 3 else maps[k][..., None], atol=0.01, err_msg=k)
    np.testing.assert_allclose(back["normal"], maps["normal"], atol=0.01)
    code, output = run("render", tmp_path / preset, "-o", tmp_path / "relit.png", "--force")
    assert code == 0, output
    code, output = run("render", tmp_path / "oak", "-o", tmp_path / "relit_native.png")
    assert code == 0, output
    assert np.abs(read_image(tmp_path / "relit.png") - read_image(tmp_path / "relit_native.png")).max() < 0.02
    code, output = run("view", tmp_path / preset, "--no-open")
    assert code == 0 and (tmp_path / preset / "viewer.html").is_file(), output
    code, output = run("export", tmp_path / preset, "-o", tmp_path / "again", "--preset", "svbrdf", "--force")
    assert code == 0, output


def test_a_folder_that_is_no_set_is_refused_naming_what_is_accepted(tmp_path):
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "a.txt").write_text("x")
    for args in (["view", tmp_path / "photos", "--no-open"], ["render", tmp_path / "photos", "-o", tmp_path / "r.png"],
                 ["export", tmp_path / "photos", "-o", tmp_path / "e", "--preset", "gltf"]):
        code, output = run(*args)
        assert code == 1 and "native set" in output and "--preset gltf, unreal, unity-hdrp or blender" in output, output


def test_a_grey_f0_short_of_halfway_to_a_metals_is_a_dielectric_in_the_engine_sets(tmp_path):
    # black plastic read at F0 0.2 (a chain's hedge between a dielectric's 0.04 and a grey metal's 0.56,
    # more likely the dielectric) is not metal; iron at 0.56 is; nothing in between jumps
    h, w = 8, 48
    level = np.repeat(np.linspace(0.04, 0.6, w)[None], h, 0)[..., None] * np.ones(3, np.float32)
    maps = {"normal": np.tile(np.float32([0, 0, 1]), (h, w, 1)), "diffuse": np.full((h, w, 3), 0.004, np.float32),
            "roughness": np.full((h, w, 1), 0.4, np.float32), "specular": level.astype(np.float32)}
    mapset.write_map_set(tmp_path / "case", maps, bits=16)
    code, output = run("export", tmp_path / "case", "-o", tmp_path / "g", "--preset", "gltf")
    assert code == 0, output
    metallic = read_image(tmp_path / "g" / "metallicRoughness.png")[..., 2].mean(0)
    f0 = level[0, :, 0]
    assert metallic[f0 < 0.21].max() == 0.0 and metallic[f0 > 0.39].min() > 0.98
    assert np.abs(np.diff(metallic)).max() < 0.35  # a ramp over the band, not a step
