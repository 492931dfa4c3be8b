"""``svbrdf markers``: the sheet, replacing it, and a capture with ``--crop markers``."""

import json

import numpy as np

from svbrdf_cli.imageio import read_image, write_image

from .clitools import SAMPLE, run


def test_marker_capture_end_to_end(tmp_path):
    """Print the sheet, 'photograph' it in perspective with a texture in the window, capture with --crop markers."""
    import cv2

    code, _ = run("markers", tmp_path / "sheet.png", "--cell", 64)
    assert code == 0
    sheet = read_image(tmp_path / "sheet.png")[..., :1].repeat(3, -1)
    s = sheet.shape[0]
    lo, hi = 2 * 64, 9 * 64
    sheet[lo:hi, lo:hi] = np.random.default_rng(0).uniform(0.2, 0.6, (hi - lo, hi - lo, 3))
    m = cv2.getPerspectiveTransform(np.float32([[0, 0], [s, 0], [s, s], [0, s]]) - 0.5,
                                    np.float32([[200, 120], [900, 160], [860, 780], [170, 720]]))
    photo = cv2.warpPerspective(sheet, m, (1000, 900), borderValue=(0.3, 0.3, 0.3))
    write_image(tmp_path / "shot.png", photo)
    code, out = run("capture", tmp_path / "shot.png", "-o", tmp_path / "o", "--crop", "markers")
    assert code == 0, out
    rec = json.loads((tmp_path / "o" / "shot" / "material.json").read_text())
    assert rec["crop"]["mode"] == "markers" and len(rec["crop"]["tags"]) == 16
    code, out = run("capture", SAMPLE, "-o", tmp_path / "o2", "--crop", "markers")
    assert code == 1 and "marker tags" in out and "error:" in out



def test_markers_never_replaces_a_file_without_force(tmp_path):
    out = tmp_path / "sheet.png"
    out.write_bytes(b"keep")
    code, output = run("markers", out)
    assert code == 1 and "--force" in output and str(out) in output and "Traceback" not in output
    assert out.read_bytes() == b"keep"
    code, _ = run("markers", out, "--cell", 24, "--force")
    assert code == 0 and read_image(out).shape[:2] == (11 * 24, 11 * 24)
