"""What an artist gets from ``svbrdf capture``: a plausible albedo level, no flash hole in the diffuse, no
metal on a dielectric, a flat height where the normals are flat (issue "What an artist gets from a real
photo")."""

import json

import numpy as np
import pytest

from svbrdf_cli import conventions as cv
from svbrdf_cli.imageio import read_image, write_image
from svbrdf_cli.imageops import blur, luminance
from svbrdf_cli.shading import normal_to_tilt

from .clitools import ROOT, SAMPLE, run


def _linear_diffuse(folder):
    return cv.albedo_to_linear(read_image(folder / "diffuse.png"))


def test_the_sample_albedo_is_read_at_the_convention_flash_power(tmp_path):
    # the bundled sample was rendered 1.15 stops under the convention's exposure (a white surface at 0.8
    # under the flash, not WHITE_UNDER_FLASH): as shot it reads at half its true level, and at
    # --exposure 1.15 at its true level (0.285 linear on average); the capture used to give 0.052
    truth = cv.albedo_to_linear(read_image(f"{ROOT}/examples/glazed_tiles/diffuse.png"))
    code, out = run("capture", SAMPLE, "-o", tmp_path / "auto", "--size", 256, "--no-preview")
    assert code == 0, out
    got = _linear_diffuse(tmp_path / "auto" / "glazed_tiles")
    assert 0.35 < got.mean() / truth.mean() < 0.65
    rec = json.loads((tmp_path / "auto" / "glazed_tiles" / "material.json").read_text())
    assert rec["albedo_level"]["scale"] > 0 and "flash power" in rec["albedo_level"]["convention"]
    code, out = run("capture", SAMPLE, "-o", tmp_path / "lifted", "--size", 256, "--no-preview", "--exposure", "1.15")
    assert code == 0, out
    lifted = _linear_diffuse(tmp_path / "lifted" / "glazed_tiles")
    assert 0.8 < lifted.mean() / truth.mean() < 1.25
    # per channel too: the level, not a tint
    np.testing.assert_allclose(lifted.mean((0, 1)) / truth.mean((0, 1)), lifted.mean() / truth.mean(), rtol=0.2)
    # the photo's level, not the tool's exposure: the photo as shot (--exposure 0) gives the same albedo as
    # the automatic exposure, and one stop more doubles it
    # (the physical estimate is linear in the photo; the default chain nearly: 1.80 measured)
    for model, tolerance in (("physical", 0.15), (None, 0.3)):
        for stops in ("0", "1"):
            args = ["--model", model] if model else []
            code, out = run("capture", SAMPLE, "-o", tmp_path / f"{model}{stops}", "--size", 256, "--no-preview",
                            "--exposure", stops, *args)
            assert code == 0, out
        zero, one = (_linear_diffuse(tmp_path / f"{model}{s}" / "glazed_tiles") for s in ("0", "1"))
        if model is None:
            assert abs(zero.mean() / got.mean() - 1) < 0.1  # (the fits see other clipping at another exposure)
        ok = one < 0.9  # (not clipped)
        assert abs(np.median(one[ok] / np.maximum(zero[ok], 1e-4)) - 2.0) < tolerance, model


def _walnut_photo(path, side=384, seed=3, colour=(0.30, 0.13, 0.05), f0=(0.04, 0.04, 0.04), roughness=0.25,
                  power=1.6, grain_blur=1.0):
    """A flash photo of a brown, finely grained, glossy dielectric: the highlight clips in the middle
    (``colour``, ``f0``, ``roughness``: another material; ``power``: the flash's, times the convention's;
    ``grain_blur``: the grain's size in pixels)."""
    from svbrdf_cli.shading import render_maps

    rng = np.random.default_rng(seed)
    grain = blur(rng.normal(0.0, 1.0, (side, side)).astype(np.float32), grain_blur)
    grain = grain / grain.std()
    albedo = np.array(colour, np.float32) * (1.0 + 0.25 * grain)[..., None]
    maps = {"normal": np.tile(np.float32([0, 0, 1]), (side, side, 1)), "diffuse": albedo.astype(np.float32),
            "roughness": np.full((side, side, 1), roughness, np.float32),
            "specular": np.broadcast_to(np.float32(f0), (side, side, 3)).copy()}
    lin = render_maps(maps, light=cv.FLASH_POSITION, intensity=cv.LIGHT_INTENSITY * power)
    write_image(path, cv.linear_to_srgb(np.clip(lin, 0.0, 1.0)).astype(np.float32))
    return path, grain


def _spot_over_ring(base, spot_radius=0.08, ring=(0.12, 0.2)):
    """(fine detail, brightness) of a base colour in a disc at its centre (``spot_radius`` of its side) over a
    ring round it (``ring``), as ``export.studies.artist_check`` measures them."""
    lum = luminance(base)
    side = lum.shape[0]
    yy, xx = np.mgrid[:side, :side]
    r = np.hypot(yy - side / 2, xx - side / 2)
    spot, ring = r < spot_radius * side, (r > ring[0] * side) & (r < ring[1] * side)
    hp = lum - blur(lum, side / 256.0)
    fine = np.sqrt(np.mean(hp[spot] ** 2)) / np.sqrt(np.mean(hp[ring] ** 2))
    lin = luminance(cv.srgb_to_linear(base))
    return fine, lin[spot].mean() / lin[ring].mean()


def test_no_flash_hole_and_no_false_metal(tmp_path):
    photo, _ = _walnut_photo(tmp_path / "walnut.png")
    code, out = run("capture", photo, "-o", tmp_path / "o", "--preset", "gltf", "--no-preview")
    assert code == 0, out
    folder = tmp_path / "o" / "walnut"
    fine, bright = _spot_over_ring(read_image(folder / "baseColor.png"))
    assert fine >= 0.5, fine  # the grain goes on under the highlight (it was a smooth disc)
    assert 0.8 <= bright <= 1.25, bright
    metallic = read_image(folder / "metallicRoughness.png")[..., 2]
    assert metallic.max() == 0.0  # a dielectric: no metal anywhere, its F0 tinted or not
    # its specular stays grey: no orange F0 to render pink highlights
    code, out = run("capture", photo, "-o", tmp_path / "n", "--no-preview")
    assert code == 0, out
    spec = cv.albedo_to_linear(read_image(tmp_path / "n" / "walnut" / "specular.png"))
    assert np.abs(spec - spec.mean(-1, keepdims=True)).max() < 0.005


def test_a_clipped_highlight_gets_the_grain_beside_it_at_the_output_size(tmp_path):
    # a strong flash clips a wide core: the photo shows nothing of the grain there, and the chain's fill at
    # its own 128 px, brought to 1024 px, was a smooth disc (0.36 of the ring's fine detail)
    photo, _ = _walnut_photo(tmp_path / "walnut.png", side=1024, roughness=0.35, power=6.0, grain_blur=0.5)
    lum = luminance(read_image(photo))
    assert (lum[472:552, 472:552] >= 0.99).all()  # the photo's core is clipped
    code, out = run("capture", photo, "-o", tmp_path / "o", "--preset", "gltf", "--no-preview", "--size", "1024")
    assert code == 0, out
    fine, bright = _spot_over_ring(read_image(tmp_path / "o" / "walnut" / "baseColor.png"), 0.08, (0.16, 0.24))
    assert fine >= 0.5, fine
    assert 0.8 <= bright <= 1.25, bright


def _chroma(folder):
    spec = cv.albedo_to_linear(read_image(folder / "specular.png"))
    return spec, float((spec.max(-1) - spec.min(-1)).mean())


def test_a_foil_whose_highlight_is_its_colour_keeps_a_coloured_specular(tmp_path):
    # a gold foil at a dielectric's F0 level (0.06): its highlight is gold in the photo, not white, so
    # --refine lets its F0 take the colour (the card_blue_9lights foil scales relight better so); the
    # walnut beside it, the same level and a white highlight, stays grey
    gold = np.float32([1.0, 0.72, 0.25])
    f0 = 0.06 * gold / luminance(gold[None])[0]
    foil, _ = _walnut_photo(tmp_path / "foil.png", colour=0.12 * gold, f0=f0, roughness=0.3)
    walnut, _ = _walnut_photo(tmp_path / "walnut.png")
    for photo in (foil, walnut):
        code, out = run("capture", photo, "-o", tmp_path / "o", "--no-preview")
        assert code == 0, out
    spec, chroma = _chroma(tmp_path / "o" / "foil")
    red, _, blue = spec.mean((0, 1))
    assert chroma > 0.006 and red > blue + 0.006, (chroma, spec.mean((0, 1)))  # gold: red over blue
    _, chroma = _chroma(tmp_path / "o" / "walnut")
    assert chroma < 0.002, chroma
    # the glTF set of the foil has no metal: its F0 is a dielectric's level, whatever its colour
    code, out = run("capture", foil, "-o", tmp_path / "g", "--preset", "gltf", "--no-preview")
    assert code == 0, out
    assert read_image(tmp_path / "g" / "foil" / "metallicRoughness.png")[..., 2].max() == 0.0


def _spotted_plaster_photo(path, side=256, seed=5):
    """A flash photo of white plaster with dark spots all over it but for a clear disc where the flash
    points (paper_real IMG_7308); returns (path, the plaster's (H, W) bool mask)."""
    from svbrdf_cli.shading import render_maps

    rng = np.random.default_rng(seed)
    grain = blur(rng.normal(0.0, 1.0, (side, side)).astype(np.float32), 1.0)
    albedo = 0.7 * (1.0 + 0.1 * grain / grain.std())
    yy, xx = np.mgrid[:side, :side] - side / 2.0
    plaster = np.ones((side, side), bool)
    for _ in range(60):
        cy, cx = rng.uniform(-side / 2, side / 2, 2)
        if np.hypot(cy, cx) > 0.3 * side:
            plaster &= np.hypot(yy - cy, xx - cx) > 0.035 * side
    albedo = np.where(plaster, albedo, 0.03).astype(np.float32)
    maps = {"normal": np.tile(np.float32([0, 0, 1]), (side, side, 1)),
            "diffuse": np.repeat(albedo[..., None], 3, -1), "roughness": np.full((side, side, 1), 0.5, np.float32),
            "specular": np.full((side, side, 3), cv.DIELECTRIC_F0, np.float32)}
    lin = render_maps(maps, light=cv.FLASH_POSITION, intensity=cv.LIGHT_INTENSITY)
    write_image(path, cv.linear_to_srgb(np.clip(lin, 0.0, 1.0)).astype(np.float32))
    return path, plaster


def _plaster_spot_over_ring(tmp_path, *options):
    photo, plaster = _spotted_plaster_photo(tmp_path / "plaster.png")
    code, out = run("capture", photo, "-o", tmp_path / "o", "--preset", "gltf", "--no-preview", *options)
    assert code == 0, out
    lin = luminance(cv.srgb_to_linear(read_image(tmp_path / "o" / "plaster" / "baseColor.png")))
    side = lin.shape[0]
    yy, xx = np.mgrid[:side, :side] - side / 2.0
    r = np.hypot(yy, xx)
    spot, ring = (r < 0.15 * side) & plaster, (r > 0.35 * side) & (r < 0.5 * side) & plaster
    return lin[spot].mean() / lin[ring].mean()


def test_a_pattern_round_the_flash_spot_does_not_make_a_disc_of_it(tmp_path):
    # the estimate's trend with the distance to the flash is read on each ring's middle values, not its
    # mean: the dark spots in the rings round a spotless flash spot darkened the plaster there (0.51 of
    # its level in the ring here, as on paper_real IMG_7308)
    bright = _plaster_spot_over_ring(tmp_path, "--refine", "0")
    assert 0.8 <= bright <= 1.25, bright


def test_a_pattern_round_the_flash_spot_does_not_make_a_disc_of_it_with_refine(tmp_path):
    # --refine's ring means of its diffuse change are weighted by the albedo: the fit darkens the dark spots
    # far more (in the logarithm) than the plaster, and equal weights read that as a trend in the spotted
    # rings and lifted the plaster there over the spot (0.75)
    bright = _plaster_spot_over_ring(tmp_path)
    assert 0.8 <= bright <= 1.25, bright


def test_refine_draws_no_cross_nor_patch_through_a_real_leathers_highlight(tmp_path, shared_data):
    # an orange leather (henzler_train 0259/IMG_0892) whose normals the chain reads flat: --refine's change of
    # the tilt was 4x as strong along the highlight's row and column as on its diagonals, a cross that
    # relit as a dark glyph inside the highlight
    photo = shared_data / "real" / "henzler_train" / "0259" / "IMG_0892.JPG"
    if not photo.is_file():
        pytest.skip(f"{photo} is not present")
    change, r, off_axis = _leather_tilt_change(tmp_path, photo)
    near = (r > 0.02) & (r < 0.25)
    energy = (change ** 2).sum(-1)
    ratio = energy[near & (off_axis < np.pi / 16)].mean() / energy[near & (off_axis > 3 * np.pi / 16)].mean()
    assert ratio < 1.6, ratio  # (1.13 with or without the even tilt; the square step 4.08)
    # nor a patch of relief at the flash spot on a leather whose grain is the same all over: the change there
    # is at most a few times as strong as over the rest of the map
    spot = np.sqrt(energy[r < 0.05].mean()) / np.median(np.sqrt(blur(energy, change.shape[0] / 16)))
    assert spot < 3.0, spot  # (2.04; 11.0 before)


def _leather_tilt_change(tmp_path, photo):
    """The tilt's change by --refine on ``photo`` at the default size, each pixel's distance to the highlight
    (a share of the side) and its angle off the highlight's row and column."""
    for name, options in (("refined", ()), ("start", ("--refine", "0"))):
        code, out = run("capture", photo, "-o", tmp_path / name, "--no-preview", *options)
        assert code == 0, out
    folder = tmp_path / "refined" / photo.stem
    change = (normal_to_tilt(cv.decode_normals(read_image(folder / "normal.png")))
              - normal_to_tilt(cv.decode_normals(read_image(tmp_path / "start" / photo.stem / "normal.png"))))
    record = json.loads((folder / "material.json").read_text())
    x0, y0, w, h = record["crop"]["box"]
    hx, hy = record["crop"]["highlight"]
    side = change.shape[0]
    yy, xx = np.mgrid[0:side, 0:side] / side
    dx, dy = xx - (hx - x0) / w, yy - (hy - y0) / h
    return change, np.hypot(dx, dy), np.abs((np.arctan2(dy, dx) + np.pi / 4) % (np.pi / 2) - np.pi / 4)
