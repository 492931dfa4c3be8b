"""Warnings about a photo come with that photo's own line and name it; the highlight warning fires
only where the photo has a real highlight."""

import numpy as np

from svbrdf_cli.imageio import write_image

from .clitools import make_photo, run


def _lines(out):
    return [ln for ln in out.splitlines() if ln.strip()]


def test_each_photos_warning_follows_its_own_line_and_names_it(tmp_path):
    d = tmp_path / "shoot"
    d.mkdir()
    for name in ("a", "b", "c"):  # not square: --crop none centre-crops them, with a warning each
        make_photo(d / f"{name}.png", h=300, w=420, seed=ord(name))
    code, out = run("batch", d, "-o", tmp_path / "o", "--crop", "none", "--size", 256, "--no-preview")
    assert code == 0, out
    lines = [ln for ln in _lines(out) if " -> " in ln or ln.startswith("warning")]
    # the next photo is read (and warned about) while the previous one is in the model: its warning
    # used to come out before the previous photo's line, naming no file
    expected = []
    for name in ("a", "b", "c"):
        expected += [f"{d / name}.png -> ", f"warning: '{d / name}.png': --crop none on a 420x300 photo"]
    assert len(lines) == len(expected), out
    for line, start in zip(lines, expected):
        assert line.startswith(start), (line, start, out)


def _matte_photo(path, n=480, w=640):
    """A matte cloth under a flash aimed near the top edge: a broad brightness peak (2.0 x the
    median, near the top edge) and no highlight."""
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:n, 0:w]
    cloth = 0.25 + 0.05 * rng.random((n, w, 1))
    d = np.sqrt((x - w / 2) ** 2 + (y - 0.05 * n) ** 2 + (1.2 * n) ** 2) / (1.2 * n)
    write_image(path, np.clip(cloth * np.float32([0.5, 0.55, 0.7]) * (1.8 / d ** 3)[..., None], 0, 1).astype(np.float32))
    return path


def test_the_highlight_warning_needs_a_highlight(tmp_path):
    matte = _matte_photo(tmp_path / "wool.png")
    code, out = run("capture", matte, "-o", tmp_path / "o", "--size", 256, "--no-preview")
    assert code == 0 and "highlight is near the edge" not in out, out
    glossy = tmp_path / "lacquer.png"  # a sharp highlight near the top edge of a wide photo
    make_photo(glossy, h=300, w=420)
    img = np.zeros((300, 420, 3), np.float32) + np.float32([0.2, 0.15, 0.1])
    y, x = np.mgrid[0:300, 0:420]
    img += 0.8 * np.exp(-((x - 210) ** 2 + (y - 12) ** 2) / (2 * 8.0 ** 2))[..., None]
    write_image(glossy, np.clip(img, 0, 1))
    code, out = run("capture", glossy, "-o", tmp_path / "o", "--size", 256, "--no-preview")
    assert code == 0, out
    assert f"warning: '{glossy}': the flash highlight is near the edge of the crop" in out, out
