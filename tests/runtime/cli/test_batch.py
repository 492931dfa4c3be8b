"""``svbrdf batch`` end to end: bad inputs fail one by one, accepted variants, resume after an interruption or a kill."""

import json
import os
import socket
import subprocess
import sys

import numpy as np
import pytest

from svbrdf_cli.write import ownership
from svbrdf_cli.imageio import write_image

from .clitools import make_photo, run


def _photos(tmp_path, n, *size):
    """A folder ``in`` of ``n`` generated photos ``p0.png`` … (of ``size`` (h, w) when given)."""
    d = tmp_path / "in"
    d.mkdir()
    for i in range(n):
        make_photo(d / f"p{i}.png", *size, seed=i)
    return d


def _bad_inputs(d):
    """Every bad-input case of the brief; returns {name: expected words in the error}."""
    (d / "empty.jpg").write_bytes(b"")
    (d / "notes.jpg").write_text("not an image at all\n" * 20)
    make_photo(d / "full.png")
    data = (d / "full.png").read_bytes()
    (d / "truncated.png").write_bytes(data[: len(data) // 3])
    os.remove(d / "full.png")
    make_photo(d / "tiny.png", 20, 20)
    # A PNG whose header claims 30000 x 30000 pixels (a decompression bomb).
    import struct
    import zlib

    def chunk(t, b):
        return struct.pack(">I", len(b)) + t + b + struct.pack(">I", zlib.crc32(t + b) & 0xFFFFFFFF)
    (d / "bomb.png").write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 30000, 30000, 8, 2, 0, 0, 0))
                                 + chunk(b"IDAT", zlib.compress(b"\0" * 300001)) + chunk(b"IEND", b""))
    (d / "fake.dng").write_bytes(b"II*\0" + os.urandom(4000))  # a RAW LibRaw cannot decode
    return {"empty.jpg": "empty", "notes.jpg": "Could not read", "truncated.png": "truncated", "tiny.png": "too small",
            "bomb.png": "Could not read", "fake.dng": "Could not decode RAW"}


def test_bad_inputs_get_one_line_errors_and_the_batch_goes_on(tmp_path):
    d = tmp_path / "in"
    d.mkdir()
    expected = _bad_inputs(d)
    good = [make_photo(d / "good1.png", seed=1), make_photo(d / "good2.jpg", seed=2)]
    code, out = run("batch", d, "-o", tmp_path / "out")
    assert code == 1
    errors = [line for line in out.splitlines() if line.startswith("error:")]
    for name, words in expected.items():
        line = [e for e in errors if name in e]
        assert len(line) == 1 and words in line[0], (name, errors)
    assert sorted(os.listdir(tmp_path / "out")) == ["good1", "good2", "index.html"]  # nothing half-written, no temp folders
    assert len(good) == 2 and "2 done" in out and f"{len(expected)} failed" in out


def test_accepted_variants_grey_16bit_alpha_cmyk(tmp_path):
    d = tmp_path / "in"
    d.mkdir()
    make_photo(d / "p16.png", bits=16)
    grey = np.linspace(0, 1, 300 * 300, dtype=np.float32).reshape(300, 300, 1)
    write_image(d / "grey.png", grey)
    write_image(d / "alpha.png", np.concatenate([np.full((300, 300, 3), 0.4, np.float32),
                                                 np.full((300, 300, 1), 0.5, np.float32)], -1))
    from PIL import Image

    # a real CMYK TIFF (separated inks; OpenImageIO converts it to RGB)
    Image.fromarray(np.full((300, 300, 3), [230, 60, 50], np.uint8)).convert("CMYK").save(d / "cmyk.tif")
    code, text = run("batch", d, "-o", tmp_path / "out", "--no-preview")
    assert code == 0, text
    assert sorted(os.listdir(tmp_path / "out")) == ["alpha", "cmyk", "grey", "index.html", "p16"]
    rec = json.loads((tmp_path / "out" / "cmyk" / "material.json").read_text())
    assert rec["input"]["bits"] == 8


def test_batch_resumes_after_an_interruption(tmp_path):
    d = _photos(tmp_path, 3)
    out = tmp_path / "out"
    # An interrupted run: p0 finished, p1 killed mid-write (its temporary folder left behind; no
    # process has that pid).
    assert run("capture", d / "p0.png", "-o", out)[0] == 0
    stamp = (out / "p0" / "material.json").read_text()
    left = out / ".svbrdf-999999999-abc12345.partial"
    left.mkdir()
    (left / "normal.png").write_bytes(b"half")
    (left / ownership.TEMP_MARKER).write_text(json.dumps(
        {"tool": "svbrdf", "pid": 999999999, "token": "abc12345", "host": socket.gethostname()}))
    code, text = run("batch", d, "-o", out)
    assert code == 0 and "2 done, 1 already done" in text
    assert (out / "p0" / "material.json").read_text() == stamp  # skipped, untouched
    assert sorted(os.listdir(out)) == ["index.html", "p0", "p1", "p2"]
    code, text = run("batch", d, "-o", out)
    assert code == 0 and "0 done, 3 already done" in text
    code, text = run("batch", d, "-o", out, "--force")
    assert code == 0 and "3 done" in text


def test_batch_interrupted_by_a_kill_leaves_only_complete_sets(tmp_path):
    """SIGKILL a real batch process part-way: every set present is complete; a rerun finishes the rest."""
    import signal
    import time

    d = _photos(tmp_path, 6, 400, 500)
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "svbrdf_cli.cli.main", "batch", str(d), "-o", str(out), "--size", "1024", "-q"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 120
    while time.time() < deadline and not (out.exists() and any(not n.startswith(".") for n in os.listdir(out))):
        assert proc.poll() is None, "the batch ended before it could be interrupted"
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    for name in os.listdir(out):
        if not name.startswith("."):
            assert (out / name / "material.json").exists(), name
    assert subprocess.run(cmd).returncode == 0
    assert sorted(n for n in os.listdir(out)) == ["index.html"] + [f"p{i}" for i in range(6)]



def test_a_batch_logged_to_a_file_is_one_line_per_photo(tmp_path):
    """Not a terminal: no progress bar (no carriage returns); warnings on lines of their own."""
    d = _photos(tmp_path, 3, 300, 400)
    make_photo(d / "wide.png", 300, 900, seed=4)
    cmd = [sys.executable, "-m", "svbrdf_cli.cli.main", "batch", str(d), "-o", str(tmp_path / "out"), "--size", "256"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "\r" not in r.stderr
    lines = r.stderr.splitlines()
    assert sum(" -> " in line for line in lines) == 4 and lines[-1] == "4 done"
    assert all(line.startswith(("WARNING:", "warning:", "INFO:")) or " -> " in line or line == "4 done" for line in lines), lines


def test_batch_writes_a_gallery_of_every_set_and_the_failures(tmp_path):
    d = tmp_path / "in"
    d.mkdir()
    make_photo(d / "oak.png", seed=1)
    make_photo(d / "slate.jpg", seed=2)
    (d / "broken.jpg").write_bytes(b"\xff\xd8\xff not really")
    out = tmp_path / "out"
    code, _ = run("batch", d, "-o", out, "--preset", "unreal", "--size", 256)
    assert code == 1
    page = (out / "index.html").read_text()
    assert "2 texture sets" in page and "broken.jpg" in page and 'class="err"' in page
    for name in ("oak", "slate"):
        assert f'src="{name}/T_{name}_BC.png"' in page and f'src="{name}/preview.png"' in page
    assert 'src="../in/oak.png"' in page  # the photo, by a relative path
    for name in ("oak", "slate"):  # each set's viewer, written beside it (an unreal set: read back)
        assert f'href="{name}/viewer.html"' in page and (out / name / "viewer.html").is_file()
    # plain labels, not the files' roles
    assert "base colour" in page and "packed: AO (R), roughness (G), metallic (B)" in page and "R = " not in page
    # resumed: the broken photo removed, the page lists the same sets and no failure; a viewer is not rewritten
    (d / "broken.jpg").unlink()
    (out / "oak" / "viewer.html").unlink()
    (out / "oak" / "viewer.html").write_text("<html>the user's own</html>")
    assert run("batch", d, "-o", out, "--preset", "unreal", "--size", 256)[0] == 0
    page = (out / "index.html").read_text()
    assert "2 texture sets" in page and "broken.jpg" not in page and 'href="oak/viewer.html"' in page
    assert (out / "oak" / "viewer.html").read_text() == "<html>the user's own</html>"


def test_the_gallery_labels_native_maps_plainly_and_wraps_to_the_window(tmp_path):
    from .test_view import BROWSER, _shot

    d = tmp_path / "in"
    d.mkdir()
    make_photo(d / "oak.png", seed=1)
    out = tmp_path / "out"
    assert run("batch", d, "-o", out, "--size", 256)[0] == 0
    page = (out / "index.html").read_text()
    assert "stored^2.2" not in page and "diffuse colour" in page and "specular (reflectance)" in page
    if BROWSER is None:
        pytest.skip("no Chromium (apt-get install chromium; .ci/run installs it)")
    for width in (800, 1600):
        shot = _shot(f"file://{out / 'index.html'}", tmp_path / f"g{width}.png", width, 700)
        ink = np.abs(shot - shot[5, 5]).max(-1) > 0.08
        # nothing runs into the window's right edge (the old table was cut off there: its preview column)
        assert not ink[:, width - 12:].any(), width
        assert ink[:, width // 2:].any() or width > 1200  # the page is not empty on the right at 800


def test_resume_redoes_sets_made_with_other_options_and_keeps_the_users_files(tmp_path):
    d = _photos(tmp_path, 2, 300, 400)
    out = tmp_path / "out"
    base = ["batch", d, "-o", out, "--size", 256, "--no-preview", "--refine", 0]
    code, text = run(*base)
    assert code == 0 and text.strip().endswith("2 done"), text
    (out / "p0" / "notes.txt").write_text("mine")  # the user's file inside a set
    code, text = run(*base)
    assert code == 0 and "2 already done" in text, text
    before = (out / "p1" / "material.json").read_text()
    # the same batch for Unreal at another size: every set is redone (it was reported "already done")
    code, text = run("batch", d, "-o", out, "--size", 512, "--no-preview", "--refine", 0, "--preset", "unreal")
    assert code == 0 and text.strip().endswith("2 done") and "already done" not in text, text
    assert "made with other options (--preset, --size)" in text, text
    for i in range(2):
        rec = json.loads((out / f"p{i}" / "material.json").read_text())
        assert rec["options"]["preset"] == "unreal" and rec["size"] == 512
        assert (out / f"p{i}" / f"T_p{i}_BC.png").is_file() and not (out / f"p{i}" / "diffuse.png").exists()
    assert (out / "p0" / "notes.txt").read_text() == "mine"
    assert (out / "p1" / "material.json").read_text() != before
    code, text = run("batch", d, "-o", out, "--size", 512, "--no-preview", "--refine", 0, "--preset", "unreal")
    assert code == 0 and "2 already done" in text, text
