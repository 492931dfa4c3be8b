"""Texture-set presets: conversions, channel layouts, colour spaces, glTF, atomic writes, CLI."""

import base64
import json
import os

import numpy as np
import pytest

from svbrdf_cli import conventions as cv
from svbrdf_cli import imageio
from svbrdf_cli.write import derive, mapset
from svbrdf_cli.write import presets
from svbrdf_cli.errors import ImageWriteError
from svbrdf_cli.imageio import read_image

F0 = cv.DIELECTRIC_F0
METAL = np.array([0.9, 0.6, 0.3], np.float32)
OPENGL = ("svbrdf", "gltf", "unity-hdrp", "blender")


def metalness_forward(colour, m):
    """export.data.cc0.metalness_to_specular's model, inline (no import from export/)."""
    return colour * (1.0 - m), F0 + (colour - F0) * m


@pytest.fixture
def maps():
    """16x16: left half a dielectric (diffuse 0.2, r 0.3), right half a pure metal (r 0.7).

    Normals tilt toward +Y everywhere.
    """
    h, w = 16, 16
    m = np.zeros((h, w, 1), np.float32)
    m[:, w // 2:] = 1.0
    colour = np.where(m > 0, METAL, np.float32(0.2)).astype(np.float32)
    diffuse, specular = metalness_forward(colour, m)
    rough = np.where(m > 0, 0.7, 0.3).astype(np.float32)
    normal = np.broadcast_to(cv.normalize(np.array([0.0, 0.5, 1.0])), (h, w, 3)).astype(np.float32)
    return {"normal": normal, "diffuse": diffuse.astype(np.float32), "roughness": rough,
            "specular": specular.astype(np.float32)}


def read_rgba(path):
    """A 4-channel data file as stored."""
    return read_image(path)


def left(img):
    return img[:, :8].reshape(-1, img.shape[-1]).mean(0)


def right(img):
    return img[:, 8:].reshape(-1, img.shape[-1]).mean(0)


# --------------------------------------------------------------------------
# specular -> metallic
# --------------------------------------------------------------------------

@pytest.mark.parametrize("m", [0.0, 1.0])
def test_solve_metallic_round_trips_pure_materials(m):
    # (a metal's colour brighter than METAL_CALL_F0: dimmer "metals" are read as dielectrics, below)
    colour = np.random.default_rng(1).uniform(0.4, 1.0, (200, 3))
    diffuse, specular = metalness_forward(colour, m)
    base, metallic = derive.specular_to_metallic(diffuse, specular)
    assert metallic.shape == (200, 1)
    np.testing.assert_allclose(metallic, m, atol=1e-5)
    np.testing.assert_allclose(base, colour, atol=1e-5)


def test_solve_metallic_inverts_its_forward_model_for_grey():
    # The spec-gloss extension's forward model: diffuse (1 - max(spec)) = base (1 - F0) (1 - m).
    b, m = np.meshgrid(np.linspace(0.1, 1.0, 10), np.linspace(0.05, 0.95, 10))
    base, m = b.reshape(-1, 1).repeat(3, 1), m.reshape(-1, 1)
    specular = F0 + (base - F0) * m
    clear = specular[:, 0] >= cv.METAL_CALL_F0[1]  # (below it the metallic root is faded out: see the next tests)
    base, m, specular = base[clear], m[clear], specular[clear]
    assert len(m) >= 6
    diffuse = base * (1 - F0) * (1 - m) / (1 - specular.max(-1, keepdims=True))
    b, got = derive.specular_to_metallic(diffuse, specular)
    np.testing.assert_allclose(got, m, atol=1e-5)
    np.testing.assert_allclose(b, base, atol=1e-4)


def test_dark_dielectric_stays_dielectric_after_quantisation():
    # 0.04 stored in 8-bit gamma 2.2 and rounded up: the quadratic's other root would say "metal".
    spec = np.full((1, 3), (round(F0 ** (1 / cv.ALBEDO_GAMMA) * 255) + 0.4) / 255) ** cv.ALBEDO_GAMMA
    assert F0 < spec[0, 0] < F0 + 1e-3
    base, m = derive.specular_to_metallic(np.full((1, 3), 0.01), spec)
    assert m[0, 0] == 0.0 and abs(base[0, 0] - 0.01) < 1e-3


@pytest.mark.parametrize("diffuse", [(0.02, 0.02, 0.02), (0.30, 0.12, 0.04), (0.25, 0.02, 0.03)])
def test_dielectric_specular_tinted_by_its_diffuse_is_not_metal(diffuse):
    # black plastic, walnut, red lacquer: F0 raised and tinted towards the diffuse's colour, still in a
    # dielectric's range. The quadratic alone gives black plastic with F0 0.045 a metallic of 0.58.
    d = np.asarray(diffuse, np.float64)
    tint = d / d.mean()
    luma = np.array([0.299, 0.587, 0.114])  # the conversion's perceived brightness
    spec = []
    for level in np.linspace(F0, 0.075, 8):
        for a in np.linspace(0.0, 1.0, 5):  # grey .. fully the diffuse's colour
            c = 1.0 + a * (tint - 1.0)
            spec.append(c * level / np.sqrt((luma * c * c).sum()))
    spec = np.array(spec)
    base, m = derive.specular_to_metallic(np.broadcast_to(d, spec.shape), spec)
    assert m.max() == 0.0
    np.testing.assert_allclose(base, d * (1 - spec.max(-1, keepdims=True)) / (1 - F0), atol=1e-6)


def test_metallic_fades_in_without_a_step():
    # a grey metal brightening from a dielectric's F0 to a metal's: metallic rises smoothly, never jumps
    s = np.linspace(F0, 0.6, 400)[:, None].repeat(3, 1)
    _, m = derive.specular_to_metallic(np.zeros_like(s), s)
    m = m[:, 0]
    assert m[s[:, 0] <= cv.METAL_CALL_F0[0]].max() == 0.0 and m[s[:, 0] >= cv.METAL_CALL_F0[1]].min() > 0.99
    assert np.all(np.diff(m) >= -1e-6) and np.abs(np.diff(m)).max() < 0.05  # (a step would be 1)


# --------------------------------------------------------------------------
# height from normals
# --------------------------------------------------------------------------

def periodic_height(n=64):
    p = cv.surface_positions(n, n)
    x, y = p[..., 0], p[..., 1]   # period 2 = the surface width: tileable
    return 0.05 * np.sin(np.pi * x) * np.cos(2 * np.pi * y) + 0.03 * np.cos(np.pi * (x + 3 * y)) + 0.02 * np.sin(np.pi * y)


def analytic_normals(n=64):
    p = cv.surface_positions(n, n)
    x, y = p[..., 0], p[..., 1]
    dx = 0.05 * np.pi * np.cos(np.pi * x) * np.cos(2 * np.pi * y) - 0.03 * np.pi * np.sin(np.pi * (x + 3 * y))
    dy = (-0.1 * np.pi * np.sin(np.pi * x) * np.sin(2 * np.pi * y) - 0.09 * np.pi * np.sin(np.pi * (x + 3 * y))
          + 0.02 * np.pi * np.cos(np.pi * y))
    return cv.normalize(np.stack([-dx, -dy, np.ones_like(dx)], -1))


@pytest.mark.parametrize("tileable", [True, False])
def test_height_from_analytic_normals(tileable):
    h = periodic_height()
    got = derive.normals_to_height(analytic_normals(), tileable=tileable)
    assert got.shape == h.shape
    assert np.corrcoef(got.ravel(), h.ravel())[0, 1] > 0.99
    # the scale is right too: depth recorded for the PNG matches the true relief
    assert abs(np.ptp(got) / np.ptp(h) - 1) < 0.05


def test_height_from_finite_difference_normals():
    h = periodic_height()
    px = 2.0 / h.shape[1]
    dx = (np.roll(h, -1, 1) - np.roll(h, 1, 1)) / (2 * px)
    dy = -(np.roll(h, -1, 0) - np.roll(h, 1, 0)) / (2 * px)   # row 0 is +Y
    n = cv.normalize(np.stack([-dx, -dy, np.ones_like(h)], -1))
    got = derive.normals_to_height(n, tileable=True)
    assert np.corrcoef(got.ravel(), h.ravel())[0, 1] > 0.99


def test_height_of_a_non_tileable_ramp_and_bump():
    p = cv.surface_positions(64, 64)
    x, y = p[..., 0], p[..., 1]
    h = 0.1 * y + 0.05 * np.exp(-((x - 0.3) ** 2 + y ** 2) / 0.1)   # rises toward the top row
    dx = 0.05 * np.exp(-((x - 0.3) ** 2 + y ** 2) / 0.1) * (-2 * (x - 0.3) / 0.1)
    dy = 0.1 + 0.05 * np.exp(-((x - 0.3) ** 2 + y ** 2) / 0.1) * (-2 * y / 0.1)
    n = cv.normalize(np.stack([-dx, -dy, np.ones_like(h)], -1))
    got = derive.normals_to_height(n)
    assert np.corrcoef(got.ravel(), h.ravel())[0, 1] > 0.99
    assert got[0].mean() > got[-1].mean()


def test_flat_normals_give_mid_grey():
    unit = derive.height_to_map(derive.normals_to_height(np.tile([0.0, 0.0, 1.0], (8, 8, 1))), 2.0)
    assert np.all(unit == derive.HEIGHT_MIDLEVEL)


# --------------------------------------------------------------------------
# preset layouts
# --------------------------------------------------------------------------

def normal_file(preset):
    return {"svbrdf": "normal.png", "gltf": "normal.png", "unity-hdrp": "set_Normal.png",
            "unreal": "T_set_N.png", "blender": "set_Normal.png"}[preset]


@pytest.mark.parametrize("preset", list(presets.PRESETS))
def test_normal_green_follows_the_engine(maps, tmp_path, preset):
    out = tmp_path / "set"
    paths = presets.write_preset(preset, out, maps)
    assert all(os.path.isfile(p) for p in paths)
    g = read_image(out / normal_file(preset))[..., 1]
    if preset in OPENGL:
        assert g.min() > 0.6
    else:
        assert g.max() < 0.4


def test_svbrdf_preset_is_exactly_the_native_set(maps, tmp_path):
    out = tmp_path / "native"
    paths = presets.write_svbrdf(out, maps, bits=16)
    names = sorted([n + ".png" for n in cv.MAP_NAMES] + ["texture_set.json"])  # the json marks it as ours
    assert sorted(os.listdir(out)) == names
    assert sorted(paths) == sorted(str(out / n) for n in names)
    back = mapset.read_map_set(out)
    for k in cv.MAP_NAMES:
        np.testing.assert_allclose(back[k], maps[k], atol=2e-3)


def test_gltf_layout(maps, tmp_path):
    out = tmp_path / "g"
    presets.write_gltf(out, maps, ao=False)
    assert sorted(os.listdir(out)) == ["baseColor.png", "height.png", "material.gltf",
                                       "metallicRoughness.png", "normal.png", "texture_set.json"]
    base = read_image(out / "baseColor.png")
    assert abs(left(base) - 0.4845).max() <= 1 / 255          # linear 0.2, sRGB-encoded
    np.testing.assert_allclose(right(base), cv.linear_to_srgb(METAL), atol=1 / 255)
    mr = read_image(out / "metallicRoughness.png")
    assert mr.shape[-1] == 3
    np.testing.assert_allclose(left(mr), [1.0, 0.3, 0.0], atol=1 / 255)   # G roughness, B metallic
    np.testing.assert_allclose(right(mr), [1.0, 0.7, 1.0], atol=1 / 255)
    assert read_image(out / "height.png").shape == (16, 16, 1)


def test_unreal_layout(maps, tmp_path):
    out = tmp_path / "ue"
    presets.write_unreal(out, maps, bits=16, ao=False)
    assert sorted(os.listdir(out)) == ["T_ue_BC.png", "T_ue_H.png", "T_ue_N.png", "T_ue_ORM.png", "texture_set.json"]
    presets.write_unreal(tmp_path / "other", maps, name="Oak Planks #2")
    assert "T_Oak_Planks_2_BC.png" in os.listdir(tmp_path / "other")
    orm = read_image(out / "T_ue_ORM.png")
    np.testing.assert_allclose(left(orm), [1.0, 0.3, 0.0], atol=1e-3)
    np.testing.assert_allclose(right(orm), [1.0, 0.7, 1.0], atol=1e-3)
    assert abs(left(read_image(out / "T_ue_BC.png")) - 0.4845).max() <= 1 / 255
    n = read_image(out / "T_ue_N.png")
    np.testing.assert_allclose(n[0, 0], cv.encode_normals(maps["normal"][0, 0] * [1, -1, 1]), atol=1e-3)


def test_unity_hdrp_layout(maps, tmp_path):
    out = tmp_path / "u"
    presets.write_unity_hdrp(out, maps, ao=False)
    assert sorted(os.listdir(out)) == ["texture_set.json", "u_BaseMap.png", "u_Height.png", "u_MaskMap.png", "u_Normal.png"]
    mask = read_rgba(out / "u_MaskMap.png")
    assert mask.shape[-1] == 4
    # R metallic, G AO, B detail mask, A smoothness = 1 - roughness
    np.testing.assert_allclose(left(mask), [0.0, 1.0, 1.0, 0.7], atol=1 / 255)
    np.testing.assert_allclose(right(mask), [1.0, 1.0, 1.0, 0.3], atol=1 / 255)
    assert abs(left(read_image(out / "u_BaseMap.png")) - 0.4845).max() <= 1 / 255


def test_unity_mask_map_keeps_data_under_partial_alpha(tmp_path):
    # metallic 0.5 with smoothness 0.5: a writer that treats A as opacity would store R = 1.
    base, m = np.full((4, 4, 3), 0.8), 0.5  # (F0 0.42: past METAL_CALL_F0, a metal's)
    specular = F0 + (base - F0) * m
    diffuse = base * (1 - F0) * (1 - m) / (1 - specular.max(-1, keepdims=True))
    maps = {"normal": np.tile(np.float32([0, 0, 1]), (4, 4, 1)), "diffuse": diffuse.astype(np.float32),
            "roughness": np.full((4, 4, 1), 0.5, np.float32), "specular": specular.astype(np.float32)}
    presets.write_unity_hdrp(tmp_path / "u", maps, bits=16)
    np.testing.assert_allclose(read_rgba(tmp_path / "u" / "u_MaskMap.png")[0, 0], [0.5, 1, 1, 0.5], atol=1e-4)
    presets.write_unity_hdrp(tmp_path / "e", maps, fmt="exr")
    np.testing.assert_allclose(read_rgba(tmp_path / "e" / "e_MaskMap.exr")[0, 0], [0.5, 1, 1, 0.5], atol=1e-5)


def test_blender_layout_and_node_wrangler_names(maps, tmp_path):
    out = tmp_path / "set"
    presets.write_blender(out, maps)
    names = sorted(os.listdir(out))
    assert names == ["set_AO.png", "set_BaseColor.png", "set_Height.png", "set_Metallic.png", "set_Normal.png",
                     "set_Roughness.png", "texture_set.json"]
    presets.write_blender(tmp_path / "noao", maps, ao=False)
    assert "noao_AO.png" not in os.listdir(tmp_path / "noao")
    assert abs(left(read_image(out / "set_BaseColor.png")) - 0.4845).max() <= 1 / 255
    rough, metal = read_image(out / "set_Roughness.png"), read_image(out / "set_Metallic.png")
    assert rough.shape[-1] == 1 and metal.shape[-1] == 1
    assert abs(left(rough)[0] - 0.3) <= 1 / 255 and abs(right(metal)[0] - 1.0) <= 1 / 255 and left(metal)[0] == 0
    # Each file carries exactly one Node Wrangler tag group.
    groups = {"base": {"base", "color", "basecolor"}, "rough": {"roughness"}, "metal": {"metallic"},
              "normal": {"normal"}, "height": {"height"}, "ao": {"ao"}}
    for name in names[:-1]:
        hits = [g for g, tags in groups.items() if set(presets.name_components(name)) & tags]
        assert len(hits) == 1, (name, hits)


def test_blender_prefix_avoids_node_wrangler_tags(tmp_path):
    assert presets.blender_prefix(tmp_path / "oak_planks") == "oak_planks"  # the name kept
    assert presets.blender_prefix(tmp_path / "oak planks (2)") == "oak-planks-2"
    assert presets.blender_prefix(tmp_path / "RustyMetal") == "material"
    assert presets.blender_prefix(tmp_path / "tile_2k_rough") == "material"


def test_exr_for_linear_data(maps, tmp_path):
    out = tmp_path / "ue"
    presets.write_unreal(out, maps, fmt="exr", ao=False)
    assert sorted(os.listdir(out)) == ["T_ue_BC.png", "T_ue_H.exr", "T_ue_N.exr", "T_ue_ORM.exr", "texture_set.json"]
    orm = read_image(out / "T_ue_ORM.exr")
    np.testing.assert_allclose(right(orm), [1.0, 0.7, 1.0], atol=1e-6)
    with pytest.raises(ValueError, match="PNG only"):
        presets.write_gltf(tmp_path / "g", maps, fmt="exr")


def test_texture_set_json_records_the_height_scale(tmp_path):
    h = periodic_height(32)
    maps = {"normal": analytic_normals(32).astype(np.float32), "diffuse": np.full((32, 32, 3), 0.5, np.float32),
            "roughness": np.full((32, 32, 1), 0.5, np.float32), "specular": np.full((32, 32, 3), F0, np.float32)}
    presets.write_unreal(tmp_path / "ue", maps)
    meta = json.loads((tmp_path / "ue" / "texture_set.json").read_text())
    assert meta["preset"] == "unreal" and meta["normal_map"].startswith("DirectX")
    assert meta["height"]["file"] == "T_ue_H.png" and meta["files"]["T_ue_H.png"]["bits"] == 16
    assert meta["height"]["scale_to_width"] == derive.HEIGHT_SPAN and meta["height"]["midlevel"] == 0.5
    # the relief, in texture widths (the surface is 2 units wide), read back from the file at that scale
    got = (read_image(tmp_path / "ue" / "T_ue_H.png")[..., 0] - 0.5) * derive.HEIGHT_SPAN
    assert abs(np.ptp(got) / (np.ptp(h) / 2.0) - 1) < 0.1
    assert abs(meta["height"]["relief_to_width"] / (np.ptp(h) / 2.0) - 1) < 0.1
    assert meta["files"]["T_ue_BC.png"]["colour_space"] == "sRGB"
    assert meta["files"]["T_ue_ORM.png"]["colour_space"] == "linear"


# --------------------------------------------------------------------------
# glTF document
# --------------------------------------------------------------------------

def test_gltf_document_is_structurally_valid(maps, tmp_path):
    out = tmp_path / "g"
    presets.write_gltf(out, maps)
    doc = json.loads((out / "material.gltf").read_text())
    assert doc["asset"]["version"] == "2.0"
    buf = doc["buffers"][0]
    prefix = "data:application/octet-stream;base64,"
    assert buf["uri"].startswith(prefix)
    blob = base64.b64decode(buf["uri"][len(prefix):])
    assert len(blob) == buf["byteLength"]

    sizes = {5126: 4, 5123: 2}
    ncomp = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}

    def read(i):
        acc = doc["accessors"][i]
        view = doc["bufferViews"][acc["bufferView"]]
        assert view["byteOffset"] % sizes[acc["componentType"]] == 0
        assert view["byteOffset"] + view["byteLength"] <= buf["byteLength"]
        assert view["byteLength"] == acc["count"] * ncomp[acc["type"]] * sizes[acc["componentType"]]
        dt = "<f4" if acc["componentType"] == 5126 else "<u2"
        a = np.frombuffer(blob, dt, acc["count"] * ncomp[acc["type"]], view["byteOffset"])
        return acc, a.reshape(acc["count"], -1)

    prim = doc["meshes"][0]["primitives"][0]
    assert prim["mode"] == 4 and set(prim["attributes"]) == {"POSITION", "NORMAL", "TANGENT", "TEXCOORD_0"}
    acc, pos = read(prim["attributes"]["POSITION"])
    assert acc["count"] == 4 and acc["type"] == "VEC3"
    assert acc["min"] == pos.min(0).tolist() and acc["max"] == pos.max(0).tolist()
    assert acc["min"] == [-1, -1, 0] and acc["max"] == [1, 1, 0]
    for key, n in (("NORMAL", 3), ("TANGENT", 4), ("TEXCOORD_0", 2)):
        acc, a = read(prim["attributes"][key])
        assert acc["count"] == 4 and a.shape == (4, n)
    _, nrm = read(prim["attributes"]["NORMAL"])
    _, tan = read(prim["attributes"]["TANGENT"])
    _, uv = read(prim["attributes"]["TEXCOORD_0"])
    acc, idx = read(prim["indices"])
    assert acc["type"] == "SCALAR" and acc["count"] == 6 and idx.max() < 4
    # UV (0, 0) is the image's top-left: the vertex at top-left (-1, +1) in the +Y-up quad
    top_left = np.argmin(pos[:, 0] - pos[:, 1])
    assert pos[top_left, :2].tolist() == [-1, 1] and uv[top_left].tolist() == [0, 0]
    assert np.all(uv[:, 1] == (1 - pos[:, 1]) / 2) and np.all(uv[:, 0] == (pos[:, 0] + 1) / 2)
    # triangles face +Z (counter-clockwise), the way the normals point
    for t in idx.reshape(-1, 3):
        a, b, c = pos[t]
        assert np.cross(b - a, c - a)[2] > 0
    assert np.all(nrm == [0, 0, 1])
    assert np.allclose(np.cross(nrm, tan[:, :3]) * tan[:, 3:], [0, 1, 0])   # bitangent +Y: OpenGL normals

    mat = doc["materials"][prim["material"]]
    def uri(ref):
        return doc["images"][doc["textures"][ref["index"]]["source"]]["uri"]

    assert uri(mat["pbrMetallicRoughness"]["baseColorTexture"]) == "baseColor.png"
    assert uri(mat["pbrMetallicRoughness"]["metallicRoughnessTexture"]) == "metallicRoughness.png"
    assert uri(mat["normalTexture"]) == "normal.png"
    assert all((out / im["uri"]).is_file() for im in doc["images"])
    assert doc["nodes"][doc["scenes"][doc["scene"]]["nodes"][0]]["mesh"] == 0


# --------------------------------------------------------------------------
# atomic sets
# --------------------------------------------------------------------------

def test_refuses_to_overwrite_and_force_replaces(maps, tmp_path):
    out = tmp_path / "ue"
    presets.write_unreal(out, maps)
    with pytest.raises(ImageWriteError, match="already exists"):
        presets.write_unreal(out, maps)
    (out / "notes.txt").write_text("the user's")
    presets.write_gltf(out, maps, force=True)
    # the unreal files (ours) replaced by glTF's, the user's file kept (issue 35)
    assert sorted(os.listdir(out)) == ["baseColor.png", "height.png", "material.gltf", "metallicRoughness.png",
                                       "normal.png", "notes.txt", "texture_set.json"]
    assert os.listdir(tmp_path) == ["ue"]


@pytest.mark.parametrize("preset", list(presets.PRESETS))
def test_failure_midway_leaves_nothing(maps, tmp_path, monkeypatch, preset):
    real, calls = imageio.write_image, []

    def flaky(path, pixels, bits=8, colour=True):
        calls.append(path)
        if len(calls) == 2:
            raise ImageWriteError(f"Could not write '{path}': disk full.")
        return real(path, pixels, bits=bits)

    monkeypatch.setattr(imageio, "write_image", flaky)  # (imageio.write_images, used by every preset, calls it)
    with pytest.raises(ImageWriteError):
        presets.write_preset(preset, tmp_path / "out", maps)
    assert len(calls) >= 2 and os.listdir(tmp_path) == []  # (the maps are written at once: the others too)


def test_failure_with_force_keeps_the_old_set(maps, tmp_path, monkeypatch):
    presets.write_unreal(tmp_path / "ue", maps)
    before = sorted(os.listdir(tmp_path / "ue"))

    def broken(path, pixels, bits=8, colour=True):
        raise ImageWriteError("boom")

    monkeypatch.setattr(imageio, "write_image", broken)
    with pytest.raises(ImageWriteError):
        presets.write_unreal(tmp_path / "ue", maps, force=True)
    assert os.listdir(tmp_path) == ["ue"] and sorted(os.listdir(tmp_path / "ue")) == before


def _png_chunks(path):
    """The chunk types of a PNG file."""
    import struct

    data, i, kinds = open(path, "rb").read(), 8, []
    while i + 8 <= len(data):
        n, kind = struct.unpack(">I4s", data[i:i + 8])
        kinds.append(kind.decode("latin-1"))
        i += 12 + n
    return kinds


@pytest.mark.parametrize("preset", list(presets.PRESETS))
def test_data_maps_are_untagged_and_colour_maps_srgb(maps, tmp_path, preset):
    """What texture_set.json calls linear carries no sRGB/gAMA/cHRM chunk (no viewer applies a colour
    transform to it); what it calls sRGB carries the sRGB chunk."""
    presets.write_preset(preset, tmp_path / "set", maps)
    meta = json.loads((tmp_path / "set" / "texture_set.json").read_text())
    spaces = set()
    for name, info in meta["files"].items():
        if not name.endswith(".png"):
            continue
        chunks = _png_chunks(tmp_path / "set" / name)
        spaces.add(info["colour_space"])
        if info["colour_space"] == "sRGB":
            assert "sRGB" in chunks, (name, chunks)
        else:
            assert not {"sRGB", "gAMA", "cHRM", "iCCP"} & set(chunks), (name, chunks)
    assert "linear" in spaces


def test_ambient_occlusion_darkens_grooves_only():
    """1 on any plane (flat or tilted) and away from relief; below 1 inside a groove; a tileable map wraps."""
    n = 128
    pixel = 2.0 * cv.SURFACE_HALF_SIZE / n
    x = np.arange(n, dtype=np.float32)[None, :] * np.ones((n, 1), np.float32)
    assert derive.ambient_occlusion(np.zeros((n, n), np.float32), pixel).min() == 1.0
    tilted = derive.ambient_occlusion(0.01 * x * pixel * 10, pixel)
    assert tilted.min() > 0.98
    groove = np.zeros((n, n), np.float32)
    groove[:, 62:66] = -0.05  # a trench 4 px wide, 0.05 deep (surface units)
    ao = derive.ambient_occlusion(groove, pixel)
    assert ao[:, 62:66].mean() < 0.8 and ao[:, :40].min() > 0.99 and 0 <= ao.min()
    wrapped = derive.ambient_occlusion(np.roll(groove, 64, axis=1), pixel, tileable=True)
    np.testing.assert_allclose(np.roll(wrapped, -64, axis=1)[8:-8], ao[8:-8], atol=1e-5)  # (rows near the
    # border differ: beyond it the wrapped map continues the groove, the other has nothing)


def test_engine_presets_write_the_occlusion(maps, tmp_path):
    bumpy = dict(maps)
    y, x = np.mgrid[0:16, 0:16]
    bumpy["normal"] = cv.normalize(np.stack([0.6 * np.sin(x / 1.5), 0.6 * np.cos(y / 1.5), np.ones((16, 16))], -1)
                                   ).astype(np.float32)
    presets.write_unreal(tmp_path / "ue", bumpy)
    orm = read_image(tmp_path / "ue" / "T_ue_ORM.png")
    assert orm[..., 0].min() < 0.95 and orm[..., 0].max() <= 1.0
    presets.write_unreal(tmp_path / "flat", bumpy, ao=False)
    assert read_image(tmp_path / "flat" / "T_flat_ORM.png")[..., 0].min() == 1.0
    presets.write_gltf(tmp_path / "g", bumpy)
    doc = json.loads((tmp_path / "g" / "material.gltf").read_text())
    assert doc["materials"][0]["occlusionTexture"] == {"index": 1}
