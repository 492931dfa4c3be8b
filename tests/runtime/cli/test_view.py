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
    assert code == 1 and "normal.png" in out


def _screenshot(page, light, out, size=256):
    subprocess.run([BROWSER, "--headless", "--no-sandbox", "--disable-gpu", "--use-gl=angle", "--use-angle=swiftshader",
                    "--enable-unsafe-swiftshader", "--hide-scrollbars", f"--window-size={size},{size}",
                    "--virtual-time-budget=5000", f"--screenshot={out}",
                    f"file://{page}?light={','.join(map(str, light))}"],
                   check=True, capture_output=True, timeout=120)
    return read_image(out)[:size, :size, :3]


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
