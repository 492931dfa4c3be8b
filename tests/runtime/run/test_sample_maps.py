"""The bundled sample's maps stay what they were before the capture was made faster (issue 19):
reduced decoding, OpenCV's JPEG decoder and PNG encoder, the native set written without the round
trip through linear units, in-place upsampling. ``tests/data/sample_maps/`` holds the maps of
``svbrdf capture examples/glazed_tiles.jpg --model fast --refine 0 --size 512`` as the tool wrote
them before those changes (commit 3aec325); the fast chain, no refinement: the physical estimate and
``--refine`` change with their own versions."""

import os

import numpy as np
import pytest

from svbrdf_cli import conventions as cv
from svbrdf_cli.imageio import read_image

from tests.runtime.cli.clitools import ROOT, SAMPLE, run

GOLDEN = os.path.join(ROOT, "tests", "data", "sample_maps")


@pytest.mark.parametrize("preview", [True, False])
def test_sample_maps_unchanged_within_one_level(tmp_path, preview):
    code, out = run("capture", SAMPLE, "-o", tmp_path, "--model", "fast", "--refine", "0", "--size", "512", "-q",
                    *([] if preview else ["--no-preview"]))
    assert code == 0, out
    # the golden maps predate the albedo level of docs/conventions.md ("The albedo level"): the diffuse is
    # compared at the level the model wrote it, the recorded scale undone (one more rounding: 1.5 levels)
    import json

    scale = json.loads((tmp_path / "glazed_tiles" / "material.json").read_text())["albedo_level"]["scale"]
    for name in cv.MAP_NAMES:
        got, want = read_image(tmp_path / "glazed_tiles" / f"{name}.png"), read_image(os.path.join(GOLDEN, f"{name}.png"))
        slack = 0.0
        if name == "diffuse":
            got = cv.albedo_to_stored(cv.albedo_to_linear(got) / scale)
            ok = cv.albedo_to_linear(want) * scale < 1.0  # (what the level clipped is lost)
            got, want, slack = got[ok], want[ok], 0.5
        assert got.shape == want.shape, name
        diff = np.abs(got - want) * 255
        assert diff.max() <= 1.0 + slack + 1e-4, (name, diff.max())
        assert (diff > 0.5 + slack).mean() < 0.001, (name, (diff > 0.5).mean())  # a few rounding flips at most


@pytest.mark.parametrize("isal", [True, False])
def test_png_encoder_writes_openimageio_pixels(tmp_path, monkeypatch, isal):
    """PNGs are encoded here (Up filter, ISA-L's deflate or zlib's); the samples are those
    OpenImageIO writes for the same floats (ties rounded to even), at 8 and 16 bits, grey, grey and
    alpha, RGB and RGBA; colour files carry the sRGB chunk."""
    import sys

    import cv2
    import OpenImageIO as oiio

    from svbrdf_cli.imageio import write_image

    if not isal:
        monkeypatch.setitem(sys.modules, "isal", None)  # import fails: the zlib fallback
    rng = np.random.default_rng(1)
    for c in (1, 2, 3, 4):
        for bits in (8, 16):
            top = 255 if bits == 8 else 65535
            a = rng.uniform(-0.1, 1.1, (19, 23, c)).astype(np.float32)
            a[0, :4, 0] = np.array([0.5, 1.5, 126.5, 127.5], np.float32) / top
            write_image(tmp_path / "ours.png", a, bits=bits, colour=True)
            spec = oiio.ImageSpec(23, 19, c, "uint8" if bits == 8 else "uint16")
            spec.attribute("oiio:UnassociatedAlpha", 1)
            out = oiio.ImageOutput.create(str(tmp_path / "oiio.png"))
            assert out.open(str(tmp_path / "oiio.png"), spec) and out.write_image(a.clip(0, 1))
            out.close()
            if c == 2:  # OpenCV reads no grey-and-alpha PNG: compare through OpenImageIO
                ours, theirs = (read_image(tmp_path / n) for n in ("ours.png", "oiio.png"))
            else:
                ours, theirs = (cv2.imread(str(tmp_path / n), cv2.IMREAD_UNCHANGED) for n in ("ours.png", "oiio.png"))
            assert ours.dtype == theirs.dtype and ours.shape == theirs.shape and (ours == theirs).all(), (c, bits)
            assert b"sRGB" in (tmp_path / "ours.png").read_bytes()[:100]
    write_image(tmp_path / "data.png", a, colour=False)
    assert b"sRGB" not in (tmp_path / "data.png").read_bytes()[:100]
    pil = pytest.importorskip("PIL.Image")
    with pil.open(tmp_path / "data.png") as im:  # a strict reader: chunk CRCs, the zlib stream
        im.load()
        assert im.size == (23, 19)


def test_jpeg_decoded_as_openimageio_decodes_it():
    """The bundled sample through OpenCV's decoder and the sRGB table: exactly OpenImageIO's float
    decoding followed by the sRGB formula."""
    from svbrdf_cli.ingest.photo import load_photo

    fast = load_photo(SAMPLE).linear
    slow = cv.srgb_to_linear(read_image(SAMPLE)).astype(np.float32)
    assert fast.shape == slow.shape and (fast == slow).all()
