"""``svbrdf view``: a self-contained viewer.html, rendered by headless Chromium like our numpy renderer."""

import os
import shutil
import subprocess

import numpy as np
import pytest

from svbrdf_cli import conventions as cv
from svbrdf_cli.imageio import read_image
from svbrdf_cli.write.mapset import read_map_set, write_map_set
from svbrdf_cli.shading import render_maps

from .clitools import run

BROWSER = next((b for b in ("chromium", "chromium-browser", "google-chrome") if shutil.which(b)), None)


def _set(folder, n=128):
    y, x = np.mgrid[0:n, 0:n] / n
    bumps = np.stack([0.3 * np.sin(x * 25), 0.3 * np.cos(y * 25), np.ones((n, n))], -1)
    write_map_set(folder, {"normal": cv.normalize(bumps).astype(np.float32),
                           "diffuse": (np.stack([0.5 * x, 0.3 + 0 * x, 0.5 * y], -1) + 0.1).astype(np.float32),
                           "roughness": (0.2 + 0.6 * x)[..., None].astype(np.float32),
                           "specular": np.full((n, n, 3), 0.04, np.float32)})
    return folder


def test_view_writes_a_self_contained_page(tmp_path):
    folder = _set(tmp_path / "set")
    code, out = run("view", folder, "--size", 256, "--no-open")
    assert code == 0, out
    page = (folder / "viewer.html").read_text()
    assert page.count("data:image/png;base64,") == 4 and "http://" not in page and "https://" not in page
    assert oct(os.stat(folder / "viewer.html").st_mode & 0o777) != "0o600"
    (tmp_path / "other").mkdir()
    code, out = run("view", tmp_path / "other", "--no-open")
    assert code == 1 and "normal.png" in out and "native set" in out


def _shot(url, out, width, height, webgl=True):
    gl = (["--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"] if webgl
          else ["--disable-webgl", "--disable-3d-apis"])
    subprocess.run([BROWSER, "--headless", "--no-sandbox", "--disable-gpu", *gl, "--hide-scrollbars",
                    f"--window-size={width},{height}", "--virtual-time-budget=5000", f"--screenshot={out}", url],
                   check=True, capture_output=True, timeout=120)
    return read_image(out)[:height, :width, :3]


def _screenshot(page, light, out, size=256):
    """The canvas alone (``?bare``) filling a square window."""
    return _shot(f"file://{page}?bare&light={','.join(map(str, light))}", out, size, size)


@pytest.mark.skipif(BROWSER is None, reason="no Chromium (apt-get install chromium; .ci/run installs it)")
def test_the_viewer_renders_like_the_numpy_renderer(tmp_path):
    folder = _set(tmp_path / "set")
    assert run("view", folder, "--size", 256, "--no-open")[0] == 0
    m = read_map_set(folder)
    peaks = []
    for i, light in enumerate([(0.8, 0.5, 1.2), (-0.7, -0.6, 1.2)]):
        shot = _screenshot(folder / "viewer.html", light, tmp_path / f"shot{i}.png")
        assert shot.std() > 0.02, "a blank canvas"
        ref = cv.image_to_encoded(render_maps(m, light=light, camera=cv.FLASH_POSITION))
        ref = np.asarray(ref, np.float32)
        import cv2

        ref = cv2.resize(ref, (256, 256), interpolation=cv2.INTER_LINEAR)
        assert np.abs(shot - ref).mean() < 0.01, np.abs(shot - ref).mean()
        lum = cv2.GaussianBlur(shot.mean(-1), (0, 0), 8)
        peaks.append(np.unravel_index(np.argmax(lum), lum.shape))
    (r0, c0), (r1, c1) = peaks
    assert c0 > 128 > c1 and r0 < 128 < r1  # the highlight follows the light: up-right, then down-left


@pytest.mark.skipif(BROWSER is None, reason="no Chromium (apt-get install chromium; .ci/run installs it)")
def test_the_viewer_has_a_title_a_hint_and_fills_the_window(tmp_path):
    folder = _set(tmp_path / "oak")
    assert run("view", folder, "--no-open")[0] == 0
    page = (folder / "viewer.html").read_text()
    assert "<h1>oak</h1>" in page and "Move the mouse over the material to move the light." in page
    for w, h in ((900, 700), (700, 900)):
        shot = _shot(f"file://{folder / 'viewer.html'}", tmp_path / f"page{w}.png", w, h)
        lit = np.abs(shot - shot[-1, -1]).max(-1) > 0.05  # not the page's background (its corner)
        rows, cols = np.nonzero(lit[h // 3:])  # below the header
        # the canvas is the largest square the window leaves (not a fixed 512 px square at the top left)
        side = min(w, h - 80)
        assert cols.max() - cols.min() > 0.85 * side and abs((cols.max() + cols.min()) / 2 - w / 2) < 0.05 * w, (w, h)
        assert rows.max() + h // 3 > h - 0.1 * h, (w, h)


@pytest.mark.skipif(BROWSER is None, reason="no Chromium (apt-get install chromium; .ci/run installs it)")
def test_without_webgl_the_viewer_says_so(tmp_path):
    folder = _set(tmp_path / "oak")
    assert run("view", folder, "--no-open")[0] == 0
    shot = _shot(f"file://{folder / 'viewer.html'}", tmp_path / "nogl.png", 800, 600, webgl=False)
    text = shot[120:, :].max(-1) > 0.6  # light text below the header, on the dark page
    assert text.mean() > 0.002, "a blank page without WebGL"
    assert "needs WebGL" in (folder / "viewer.html").read_text()
