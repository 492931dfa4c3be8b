import os

import numpy as np
import pytest

from svbrdf_cli.errors import ImageReadError
from svbrdf_cli.imageio import read_image, write_image


@pytest.mark.parametrize("ext,bits,tol", [(".png", 8, 1 / 255), (".png", 16, 1 / 65535), (".exr", 32, 1e-6)])
def test_round_trip(tmp_path, ext, bits, tol):
    a = np.random.default_rng(0).uniform(size=(8, 10, 3)).astype(np.float32)
    p = tmp_path / ("x" + ext)
    write_image(p, a, bits=bits)
    b = read_image(p)
    assert b.shape == a.shape and np.abs(a - b).max() <= tol
    assert [f.name for f in tmp_path.iterdir()] == ["x" + ext]  # no temporary left behind


def test_missing_and_garbage(tmp_path):
    with pytest.raises(ImageReadError, match="no such file"):
        read_image(tmp_path / "nope.png")
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"not a png")
    with pytest.raises(ImageReadError, match="bad.png"):
        read_image(bad)


def test_written_file_has_umask_mode(tmp_path):
    import os
    import stat

    old = os.umask(0o022)
    try:
        p = tmp_path / "m.png"
        write_image(p, np.zeros((2, 2, 3)))
        assert stat.S_IMODE(p.stat().st_mode) == 0o644
    finally:
        os.umask(old)


def test_write_image_accepts_strided_views(tmp_path):
    import numpy as np

    from svbrdf_cli.imageio import read_image, write_image

    chw = np.random.default_rng(0).random((3, 8, 6)).astype(np.float32)
    view = chw.transpose(1, 2, 0)  # not C-contiguous
    write_image(tmp_path / "v.png", view, bits=16)
    assert np.allclose(read_image(tmp_path / "v.png"), view, atol=1 / 65535)


def test_rgba_data_round_trips_unpremultiplied(tmp_path):
    """A 4th channel is data (a mask map's smoothness), not opacity to premultiply by."""
    import numpy as np

    from svbrdf_cli.imageio import read_image, write_image

    img = np.zeros((4, 4, 4), np.float32)
    img[..., 0], img[..., 3] = 0.5, 0.5
    for bits in (8, 16):
        write_image(tmp_path / f"m{bits}.png", img, bits=bits)
        back = read_image(tmp_path / f"m{bits}.png")
        assert np.allclose(back, img, atol=1 / 255), bits


def test_write_images_writes_every_one_then_raises(tmp_path, monkeypatch):
    from svbrdf_cli import imageio
    from svbrdf_cli.errors import ImageWriteError

    img = np.full((8, 8, 3), 0.5, np.float32)
    imageio.write_images([(tmp_path / f"{i}.png", img, 8, True) for i in range(4)])
    assert sorted(os.listdir(tmp_path)) == [f"{i}.png" for i in range(4)]
    real = imageio.write_image

    def fail_one(path, *args):
        if str(path).endswith("1.png"):
            raise ImageWriteError("disk full")
        return real(path, *args)

    monkeypatch.setattr(imageio, "write_image", fail_one)
    (tmp_path / "b").mkdir()
    with pytest.raises(ImageWriteError):
        imageio.write_images([(tmp_path / "b" / f"{i}.png", img, 8, True) for i in range(4)])
    assert sorted(os.listdir(tmp_path / "b")) == ["0.png", "2.png", "3.png"]
