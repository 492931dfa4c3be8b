"""``svbrdf capture`` / ``batch`` end to end with the shipped model: outputs, presets, bad input, resume."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner

from svbrdf_cli import conventions as cv
from svbrdf_cli.cli.main import cli
from svbrdf_cli.imageio import read_image, write_image
from svbrdf_cli.inference import DEFAULT_MODEL, installed_tiers

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SAMPLE = os.path.join(ROOT, "examples", "glazed_tiles.jpg")

pytestmark = pytest.mark.skipif("fast" not in installed_tiers(), reason="the fast model is not installed")


def run(*args):
    r = CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)
    return r.exit_code, r.output


def _photo(path, h=300, w=400, seed=0, **kw):
    """A small flash-like photo (sRGB file)."""
    y, x = np.mgrid[0:h, 0:w]
    rng = np.random.default_rng(seed)
    base = rng.uniform(0.2, 0.5, 3) * (0.8 + 0.2 * np.sin(x / 7.0)[..., None])
    hl = np.exp(-((x - w / 2) ** 2 + (y - h / 2) ** 2) / (2 * 30.0 ** 2))[..., None]
    write_image(path, np.clip(base + 0.6 * hl, 0, 1).astype(np.float32), **kw)
    return path


def test_capture_writes_the_native_set_with_record_and_preview(tmp_path):
    code, out = run("capture", SAMPLE, "-o", tmp_path / "out", "--size", 512)
    assert code == 0, out
    folder = tmp_path / "out" / "glazed_tiles"
    assert sorted(os.listdir(folder)) == sorted(["normal.png", "diffuse.png", "roughness.png", "specular.png",
                                                  "preview.png", "material.json"])
    rec = json.loads((folder / "material.json").read_text())
    assert rec["crop"]["mode"] == "auto" and rec["crop"]["anchor"] == "highlight"
    assert rec["size"] == 512 and rec["model"]["tier"] == DEFAULT_MODEL and rec["input"]["width"] == 1024
    assert set(rec["timings_s"]) >= {"read", "crop", "network", "upsample", "write"}
    n = read_image(folder / "normal.png")
    assert n.shape == (512, 512, 3) and np.isfinite(n).all()
    dec = cv.decode_normals(n)
    assert (dec[..., 2] > 0).all() and np.allclose(np.linalg.norm(dec, axis=-1), 1, atol=0.03)
    assert read_image(folder / "preview.png").shape == (512, 1024, 3)


def test_debug_and_presets(tmp_path):
    photo = _photo(tmp_path / "wood.png")
    code, out = run("capture", photo, "-o", tmp_path / "ue", "--preset", "unreal", "--debug", "--model", "fast")
    assert code == 0, out
    files = set(os.listdir(tmp_path / "ue" / "wood"))
    assert {"BaseColor.png", "Normal.png", "ORM.png", "Height.png", "texture_set.json", "material.json",
            "preview.png", "debug"} <= files
    assert sorted(os.listdir(tmp_path / "ue" / "wood" / "debug")) == sorted(
        f"{k}.png" for k in ("input", "M_b", "M_h", "I_bf", "I_hr", "I_hr2"))
    code, out = run("capture", photo, "-o", tmp_path / "ph", "--debug", "--model", "physical")
    assert code == 0, out
    assert sorted(os.listdir(tmp_path / "ph" / "wood" / "debug")) == ["flash_fit.png", "input.png"]
    code, out = run("capture", photo, "-o", tmp_path / "gl", "--preset", "gltf", "--no-preview")
    assert code == 0 and "material.gltf" in os.listdir(tmp_path / "gl" / "wood")
    assert "preview.png" not in os.listdir(tmp_path / "gl" / "wood")


def test_confidence_maps(tmp_path):
    code, out = run("capture", SAMPLE, "-o", tmp_path, "--size", 256, "--confidence", "--no-preview", "--model", "fast")
    assert code == 0, out
    folder = tmp_path / "glazed_tiles"
    assert sorted(os.listdir(folder / "confidence")) == sorted(f"{k}.png" for k in cv.MAP_NAMES)
    rec = json.loads((folder / "material.json").read_text())
    assert rec["confidence"]["passes"] == 5 and "confidence" in rec["timings_s"]
    for k in cv.MAP_NAMES:
        c = read_image(folder / "confidence" / f"{k}.png")
        assert c.shape[:2] == (256, 256) and 0 <= c.min() < c.max() <= 1
        assert abs(float(c.mean()) - rec["confidence"]["mean"][k]) < 0.01


def test_existing_output_is_never_overwritten_without_force(tmp_path):
    photo = _photo(tmp_path / "a.png")
    assert run("capture", photo, "-o", tmp_path / "o")[0] == 0
    before = (tmp_path / "o" / "a" / "material.json").read_text()
    code, out = run("capture", photo, "-o", tmp_path / "o")
    assert code == 1 and "--force" in out
    assert (tmp_path / "o" / "a" / "material.json").read_text() == before
    code, out = run("capture", photo, "-o", tmp_path / "o", "--force")
    assert code == 0


def _bad_inputs(d):
    """Every bad-input case of the brief; returns {name: expected words in the error}."""
    (d / "empty.jpg").write_bytes(b"")
    (d / "notes.jpg").write_text("not an image at all\n" * 20)
    _photo(d / "full.png")
    data = (d / "full.png").read_bytes()
    (d / "truncated.png").write_bytes(data[: len(data) // 3])
    os.remove(d / "full.png")
    _photo(d / "tiny.png", 20, 20)
    # A PNG whose header claims 30000 x 30000 pixels (a decompression bomb).
    import struct
    import zlib

    def chunk(t, b):
        return struct.pack(">I", len(b)) + t + b + struct.pack(">I", zlib.crc32(t + b) & 0xFFFFFFFF)
    (d / "bomb.png").write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 30000, 30000, 8, 2, 0, 0, 0))
                                 + chunk(b"IDAT", zlib.compress(b"\0" * 300001)) + chunk(b"IEND", b""))
    (d / "fake.dng").write_bytes(b"II*\0" + os.urandom(4000))  # a RAW LibRaw cannot decode
    return {"empty.jpg": "empty", "notes.jpg": "Could not read", "truncated.png": "damaged", "tiny.png": "too small",
            "bomb.png": "Could not read", "fake.dng": "Could not decode RAW"}


def test_bad_inputs_get_one_line_errors_and_the_batch_goes_on(tmp_path):
    d = tmp_path / "in"
    d.mkdir()
    expected = _bad_inputs(d)
    good = [_photo(d / "good1.png", seed=1), _photo(d / "good2.jpg", seed=2)]
    code, out = run("batch", d, "-o", tmp_path / "out")
    assert code == 1
    errors = [line for line in out.splitlines() if line.startswith("error:")]
    for name, words in expected.items():
        line = [e for e in errors if name in e]
        assert len(line) == 1 and words in line[0], (name, errors)
    assert sorted(os.listdir(tmp_path / "out")) == ["good1", "good2"]  # nothing half-written, no temp folders
    assert len(good) == 2 and "2 done" in out and f"{len(expected)} failed" in out


def test_accepted_variants_grey_16bit_alpha_cmyk(tmp_path):
    import OpenImageIO as oiio

    d = tmp_path / "in"
    d.mkdir()
    _photo(d / "p16.png", bits=16)
    grey = np.linspace(0, 1, 300 * 300, dtype=np.float32).reshape(300, 300, 1)
    write_image(d / "grey.png", grey)
    write_image(d / "alpha.png", np.concatenate([np.full((300, 300, 3), 0.4, np.float32),
                                                 np.full((300, 300, 1), 0.5, np.float32)], -1))
    spec = oiio.ImageSpec(300, 300, 4, "uint8")
    spec.channelnames = ("C", "M", "Y", "K")
    spec.attribute("tiff:PhotometricInterpretation", 5)
    out = oiio.ImageOutput.create(str(d / "cmyk.tif"))
    assert out.open(str(d / "cmyk.tif"), spec) and out.write_image(np.full((300, 300, 4), [0, 200, 200, 0], np.uint8))
    out.close()
    code, text = run("batch", d, "-o", tmp_path / "out", "--no-preview")
    assert code == 0, text
    assert sorted(os.listdir(tmp_path / "out")) == ["alpha", "cmyk", "grey", "p16"]
    rec = json.loads((tmp_path / "out" / "cmyk" / "material.json").read_text())
    assert rec["input"]["bits"] == 8


def test_batch_resumes_after_an_interruption(tmp_path):
    d = tmp_path / "in"
    d.mkdir()
    for i in range(3):
        _photo(d / f"p{i}.png", seed=i)
    out = tmp_path / "out"
    # An interrupted run: p0 finished, p1 killed mid-write (its temporary folder left behind).
    assert run("capture", d / "p0.png", "-o", out)[0] == 0
    stamp = (out / "p0" / "material.json").read_text()
    (out / ".p1.abc123.partial").mkdir()
    (out / ".p1.abc123.partial" / "normal.png").write_bytes(b"half")
    code, text = run("batch", d, "-o", out)
    assert code == 0 and "2 done, 1 already done" in text
    assert (out / "p0" / "material.json").read_text() == stamp  # skipped, untouched
    assert sorted(os.listdir(out)) == ["p0", "p1", "p2"]
    code, text = run("batch", d, "-o", out)
    assert code == 0 and "0 done, 3 already done" in text
    code, text = run("batch", d, "-o", out, "--force")
    assert code == 0 and "3 done" in text


def test_batch_interrupted_by_a_kill_leaves_only_complete_sets(tmp_path):
    """SIGKILL a real batch process part-way: every set present is complete; a rerun finishes the rest."""
    import signal
    import time

    d = tmp_path / "in"
    d.mkdir()
    for i in range(6):
        _photo(d / f"p{i}.png", 400, 500, seed=i)
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
    assert sorted(n for n in os.listdir(out)) == [f"p{i}" for i in range(6)]


def test_usage_errors_exit_2(tmp_path):
    assert run("capture", "-o", tmp_path)[0] == 2                              # no input
    assert run("capture", SAMPLE, "-o", tmp_path, "--size", 100)[0] == 2       # size out of range
    assert run("capture", SAMPLE, "-o", tmp_path, "--corners", "1,2,3")[0] == 2
    assert run("capture", SAMPLE, "-o", tmp_path, "--preset", "svbrdf", "--format", "exr")[0] == 2
    code, out = run("capture", SAMPLE, "-o", tmp_path, "--model", "best")
    assert code == 1 and "not installed" in out


def test_missing_file_is_one_failure_not_a_crash(tmp_path):
    code, out = run("capture", tmp_path / "nope.jpg", SAMPLE, "-o", tmp_path / "o", "--size", 256)
    assert code == 1 and "no such file" in out and (tmp_path / "o" / "glazed_tiles" / "material.json").exists()


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


def test_real_raw_files_through_capture(shared_data, tmp_path):
    """The Bayer DNG becomes a set; the GoPro GPR (VC-5, LibRaw refuses it) is one clean error."""
    raw = shared_data / "raw"
    dng = raw / "imageio_test_images" / "Blackmagic_PocketCinema4K_12bit.dng"
    gpr = raw / "gopro_gpr" / "GOPR0024_HERO6.GPR"
    code, out = run("capture", dng, gpr, "-o", tmp_path / "o", "--size", 256, "--no-preview")
    assert code == 1
    rec = json.loads((tmp_path / "o" / dng.stem / "material.json").read_text())
    assert rec["input"]["kind"] == "raw" and rec["input"]["bits"] == 16 and rec["exposure"]["mode"] == "auto"
    errors = [line for line in out.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "GOPR0024_HERO6.GPR" in errors[0] and "DNG" in errors[0]
    assert not (tmp_path / "o" / gpr.stem).exists()


def test_manual_corners_exposure_and_white_balance_are_recorded(tmp_path):
    photo = _photo(tmp_path / "shot.png", 300, 400)
    code, out = run("capture", photo, "-o", tmp_path / "o", "--corners", "50,40,350,45,340,290,60,280",
                    "--exposure", "0.5", "--white-balance", "1.2,1,0.8", "--no-preview")
    assert code == 0, out
    rec = json.loads((tmp_path / "o" / "shot" / "material.json").read_text())
    assert rec["crop"]["mode"] == "corners" and rec["crop"]["quad"][0] == [50.0, 40.0]
    assert rec["exposure"] == {"mode": "manual", "stops": 0.5}
    assert rec["white_balance"] == [1.2, 1.0, 0.8]
    code, out = run("capture", photo, "-o", tmp_path / "o2", "--corners", "0,0,900,0,900,900,0,900")
    assert code == 1 and "outside" in out
