import numpy as np
import pytest

from svbrdf_cli import conventions as cv
from svbrdf_cli.errors import ImageReadError
from svbrdf_cli.imageio import write_image
from svbrdf_cli.ingest.photo import load_photo


def _write_oriented_jpeg(path, img, orientation):
    import OpenImageIO as oiio

    h, w, c = img.shape
    spec = oiio.ImageSpec(w, h, c, "uint8")
    spec.attribute("Orientation", orientation)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec) and out.write_image((img * 255).round().astype(np.uint8))
    out.close()


def test_exif_orientation_is_applied(tmp_path):
    img = np.zeros((40, 64, 3), np.float32)
    img[:, :8] = 1.0  # a bright left edge
    _write_oriented_jpeg(tmp_path / "r.jpg", img, 6)  # "rotate 90 CW to display"
    p = load_photo(tmp_path / "r.jpg")
    assert p.linear.shape == (64, 40, 3)
    assert p.linear[:4].mean() > 0.5 and p.linear[-4:].mean() < 0.1  # the left edge is now on top


def test_srgb_files_are_decoded_to_linear(tmp_path):
    write_image(tmp_path / "g.png", np.full((40, 40, 3), 0.5, np.float32), bits=16)
    p = load_photo(tmp_path / "g.png")
    assert p.kind == "encoded" and p.bits == 16
    assert np.allclose(p.linear, cv.srgb_to_linear(np.float32(0.5)), atol=1e-4)
    write_image(tmp_path / "l.exr", np.full((40, 40, 3), 0.25, np.float32), bits=32)
    assert np.allclose(load_photo(tmp_path / "l.exr").linear, 0.25)


def test_grey_and_alpha_become_rgb(tmp_path):
    write_image(tmp_path / "grey.png", np.full((40, 40, 1), 0.2, np.float32))
    write_image(tmp_path / "rgba.png", np.concatenate([np.full((40, 40, 3), 0.6), np.ones((40, 40, 1))], -1))
    for name in ("grey.png", "rgba.png"):
        assert load_photo(tmp_path / name).linear.shape == (40, 40, 3), name


@pytest.mark.parametrize("case", ["missing", "empty", "text", "truncated", "tiny"])
def test_bad_files_get_one_line_errors(tmp_path, case):
    p = tmp_path / "photo.png"
    if case == "empty":
        p.write_bytes(b"")
    elif case == "text":
        p.write_text("not an image at all\n" * 10)
    elif case == "truncated":
        write_image(p, np.random.default_rng(0).random((256, 256, 3)).astype(np.float32))
        p.write_bytes(p.read_bytes()[:2000])
    elif case == "tiny":
        write_image(p, np.zeros((8, 8, 3), np.float32))
    with pytest.raises(ImageReadError) as e:
        load_photo(p)
    msg = str(e.value)
    assert "photo.png" in msg and "\n" not in msg


def test_real_raw_files(shared_data):
    raw = shared_data / "raw"
    p = load_photo(raw / "imageio_test_images" / "Blackmagic_PocketCinema4K_12bit.dng")
    assert p.kind == "raw" and p.linear.shape == (2176, 4128, 3)
    assert np.isfinite(p.linear).all() and 0.01 < p.linear.mean() < 0.9
    with pytest.raises(ImageReadError, match="GOPR0024_HERO6.GPR.*Convert it"):
        load_photo(raw / "gopro_gpr" / "GOPR0024_HERO6.GPR")


def test_decoding_stops_at_the_size_the_output_needs(tmp_path):
    """A photo at least twice what the output needs is decoded at 1/2, 1/4 ... (JPEG: DCT scaling), and
    the reduced photo matches the full one area-averaged."""
    import cv2

    y, x = np.mgrid[0:1800, 0:2400]
    img = (0.3 + 0.2 * np.sin(x / 40.0) * np.cos(y / 55.0))[..., None] * np.float32([1.0, 0.8, 0.6])
    write_image(tmp_path / "p.jpg", img.astype(np.float32))
    full = load_photo(tmp_path / "p.jpg")
    assert full.scale == 1.0 and full.linear.shape == (1800, 2400, 3)
    half = load_photo(tmp_path / "p.jpg", min_side=800)
    assert half.scale == 0.5 and half.linear.shape == (900, 1200, 3)
    assert load_photo(tmp_path / "p.jpg", min_side=1000).scale == 1.0  # 900 px would be too few
    ref = cv2.resize(cv.linear_to_srgb(full.linear), (1200, 900), interpolation=cv2.INTER_AREA)
    assert np.abs(cv.linear_to_srgb(half.linear) - ref).mean() < 2 / 255
