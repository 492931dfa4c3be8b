"""The bundled sample's texture set stays what it was, within rounding, through the capture's input
and output (OpenCV's JPEG decoder and PNG encoder, the native set written from the stored maps, in-place
upsampling): ``svbrdf capture examples/glazed_tiles.jpg`` with default options (the trained chain
``swift``, ``--refine``'s default steps) writes maps whose 4x4 block sums ``python tests/checksums.py
record-sample`` keeps in ``tests/data/sample_maps.npz``. Within rounding, not bit for bit: onnxruntime
and OpenBLAS choose their kernels by the CPU's instruction set, which moves the maps' last bits; one
refinement step fewer moves them beyond it. A change that alters the maps on purpose re-records them."""

import os

import numpy as np
import pytest

from svbrdf_cli import conventions as cv
from svbrdf_cli.imageio import read_image

from tests.checksums import IMAGES, beyond_rounding, sample_differences
from tests.runtime.cli.clitools import SAMPLE, run

NAME = os.path.splitext(os.path.basename(SAMPLE))[0]


def _capture(folder, *options):
    """The folder of the set ``svbrdf capture SAMPLE -o folder -q *options`` writes."""
    code, out = run("capture", SAMPLE, "-o", folder, "-q", *options)
    assert code == 0, out
    return folder / NAME


@pytest.fixture(scope="module")
def sample_sets(tmp_path_factory):
    """{preview: the sample's set}, captured with default options and with ``--no-preview``."""
    return {p: _capture(tmp_path_factory.mktemp("preview" if p else "no-preview"), *([] if p else ["--no-preview"]))
            for p in (True, False)}


@pytest.mark.parametrize("preview", [True, False])
def test_sample_set_is_the_recorded_one_within_rounding(sample_sets, preview):
    folder = sample_sets[preview]
    differences = sample_differences(folder)
    assert not beyond_rounding(differences), differences
    got = [f.name for f in folder.parent.rglob("*") if f.is_file() and f.suffix.lower() in IMAGES]
    assert sorted(got) == sorted([f"{m}.png" for m in cv.MAP_NAMES] + (["preview.png"] if preview else []))


def test_the_preview_changes_none_of_the_maps(sample_sets):
    for m in cv.MAP_NAMES:
        assert (sample_sets[True] / f"{m}.png").read_bytes() == (sample_sets[False] / f"{m}.png").read_bytes(), m


def test_one_refinement_step_fewer_is_beyond_rounding(tmp_path):
    """``--refine 29``, one step short of the default 30, moves the maps by 0.03-0.38 levels per pixel
    on average (0.03 the normal, 0.38 the roughness): the comparison sees it."""
    differences = sample_differences(_capture(tmp_path, "--refine", "29", "--no-preview"))
    assert beyond_rounding(differences), differences


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
