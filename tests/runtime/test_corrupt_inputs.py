"""Damaged files never become confident texture sets, never pass pixels from one photo to another, and
fail with one readable line (issue 35, items 7-13). Each run is a fresh ``svbrdf`` process."""

import hashlib
import json
import os
import shutil
import struct
import subprocess
import sys

import numpy as np
import pytest

import mutations
from svbrdf_cli.ingest import plausible
from svbrdf_cli.errors import SvbrdfError

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SHARED_DNG = os.path.join(os.environ.get("SVBRDF_SHARED", os.path.join(os.path.dirname(ROOT), "shared")),
                          "data", "raw", "imageio_test_images", "Blackmagic_PocketCinema4K_12bit.dng")
OPTIONS = ["--size", "256", "--no-preview", "--refine", "0", "--threads", "1"]


def svbrdf(*args, cwd):
    """(exit code, stdout, stderr) of ``svbrdf ARGS``."""
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=ROOT)
    r = subprocess.run([sys.executable, "-m", "svbrdf_cli.cli.main", *map(str, args)], cwd=cwd, env=env,
                       capture_output=True, timeout=600)
    return r.returncode, r.stdout.decode("utf-8", "replace"), r.stderr.decode("utf-8", "replace")


def errors(text):
    return [line for line in text.splitlines() if line.startswith("error:")]


def maps_hash(folder):
    return {m: hashlib.sha256((folder / f"{m}.png").read_bytes()).hexdigest()
            for m in ("normal", "diffuse", "roughness", "specular")}


@pytest.fixture
def dng(tmp_path):
    if not os.path.isfile(SHARED_DNG):
        pytest.skip("../shared is not present (the reference DNG)")
    shutil.copy(SHARED_DNG, tmp_path / "valid.dng")
    return (tmp_path / "valid.dng").read_bytes()


def _ifd0_set(data, tag, value):
    """``data`` with IFD0's ``tag`` (a SHORT or LONG of count 1) set to ``value``."""
    d = bytearray(data)
    entries, e = mutations.tiff_entries(data)
    for p, t, typ, count in entries:
        if t == tag:
            d[p + 8:p + 12] = struct.pack(e + ("H" if typ == 3 else "I"), value).ljust(4, b"\0")
            return bytes(d)
    raise KeyError(tag)


# --------------------------------------------------------------------------
# 7. no pixel crosses files; results never depend on the order
# --------------------------------------------------------------------------

def test_a_dng_without_its_data_is_refused_whatever_came_before(dng, tmp_path):
    (tmp_path / "head500.dng").write_bytes(dng[:500])
    # tile offsets pointing past the end
    entries, e = mutations.tiff_entries(dng)
    tiles = [(p, typ, count) for p, t, typ, count in entries if t == 324][0]
    d = bytearray(dng)
    at = struct.unpack(e + "I", d[tiles[0] + 8:tiles[0] + 12])[0]
    d[at + 8:at + 12] = struct.pack(e + "I", len(dng) + 1000)  # the third tile
    (tmp_path / "pastend.dng").write_bytes(bytes(d))
    for order in (["valid.dng", "head500.dng", "pastend.dng"], ["head500.dng", "pastend.dng", "valid.dng"],
                  ["head500.dng"], ["pastend.dng"]):
        shutil.rmtree(tmp_path / "o", ignore_errors=True)
        code, _, err = svbrdf("capture", *order, "-o", "o", *OPTIONS, cwd=tmp_path)
        assert code == 1 and "Traceback" not in err
        lines = errors(err)
        assert len(lines) == sum(n != "valid.dng" for n in order), err
        assert all("past the end of the file" in line for line in lines), lines
        made = sorted(os.listdir(tmp_path / "o")) if os.path.isdir(tmp_path / "o") else []
        assert made == (["valid"] if "valid.dng" in order else []), order


def test_raw_buffers_come_fresh_for_every_decode(dng, tmp_path):
    """What LibRaw leaves unfilled is zero, never the previous photo (the data check bypassed)."""
    (tmp_path / "head500.dng").write_bytes(dng[:500])
    code = ("import sys, numpy as np, rawpy\n"
            "from svbrdf_cli.ingest import photo as ingest\n"
            "ingest._fresh_large_buffers()\n"
            "def decode(p):\n"
            "    with rawpy.imread(p) as r:\n"
            "        return r.postprocess(use_camera_wb=True, no_auto_bright=True, output_bps=16, gamma=(1, 1),\n"
            "                             half_size=True)\n"
            "alone = int(decode(sys.argv[2]).max())\n"
            "decode(sys.argv[1])\n"
            "after = int(decode(sys.argv[2]).max())\n"
            "print(alone, after)\n")
    r = subprocess.run([sys.executable, "-c", code, "valid.dng", "head500.dng"], cwd=tmp_path, capture_output=True,
                       env=dict(os.environ, PYTHONPATH=ROOT), timeout=300)
    assert r.returncode == 0, r.stderr.decode()
    assert r.stdout.decode().split() == ["0", "0"]


def test_a_damaged_small_dng_gets_the_same_verdict_in_any_order(tmp_path):
    seed = mutations.tiny_dng(96, 128, 3)
    (tmp_path / "good.dng").write_bytes(seed)
    (tmp_path / "cut.dng").write_bytes(seed[: len(seed) * 2 // 3])
    runs = []
    for order in (["good.dng", "cut.dng"], ["cut.dng", "good.dng"]):
        shutil.rmtree(tmp_path / "o", ignore_errors=True)
        code, _, err = svbrdf("capture", *order, "-o", "o", *OPTIONS, cwd=tmp_path)
        assert code == 1 and len(errors(err)) == 1 and "cut.dng" in errors(err)[0], err
        runs.append(maps_hash(tmp_path / "o" / "good"))
    assert runs[0] == runs[1]


# --------------------------------------------------------------------------
# 8. JPEGs whose data is missing
# --------------------------------------------------------------------------

def _jpeg(tmp_path):
    from mutations import _cv_jpeg, flash

    y, x = np.mgrid[0:600, 0:800]
    img = flash(600, 800, 1) * (0.8 + 0.2 * np.sin(x / 3.0 + y / 5.0))[..., None]
    return _cv_jpeg(img, quality=95)


def test_a_jpeg_with_its_middle_cut_out_is_refused(tmp_path):
    data = _jpeg(tmp_path)
    (tmp_path / "cut.jpg").write_bytes(data[: len(data) // 10] + data[-len(data) // 100:])
    code, _, err = svbrdf("capture", "cut.jpg", "-o", "o", *OPTIONS, "-q", cwd=tmp_path)
    assert code == 1 and err.strip().splitlines() == errors(err) and len(errors(err)) == 1, err
    assert "cut.jpg" in err and "Corrupt JPEG data" in err and not os.path.exists(tmp_path / "o" / "cut")


def test_a_jpeg_claiming_more_rows_than_it_holds_is_refused(tmp_path):
    data = bytearray(_jpeg(tmp_path))
    sof = [s for s in mutations.jpeg_segments(bytes(data)) if s[2] == 0xC0][0][0]
    data[sof + 5:sof + 7] = struct.pack(">H", 1800)  # 600 rows of data, 1800 declared
    (tmp_path / "tall.jpg").write_bytes(bytes(data))
    code, _, err = svbrdf("capture", "tall.jpg", "-o", "o", *OPTIONS, cwd=tmp_path)
    assert code == 1 and len(errors(err)) == 1 and "tall.jpg" in errors(err)[0], err
    assert not os.path.exists(tmp_path / "o" / "tall")


def test_a_jpeg_with_a_duplicated_scan_is_refused_or_sound(tmp_path):
    data = _jpeg(tmp_path)
    a, b, _ = [s for s in mutations.jpeg_segments(data) if s[2] == 0xDA][0]
    (tmp_path / "twice.jpg").write_bytes(data[:b] + data[a:b] + data[b:])
    code, _, err = svbrdf("capture", "twice.jpg", "-o", "o", *OPTIONS, cwd=tmp_path)
    assert "Traceback" not in err
    if code == 0:  # the first scan is the whole image: the set must be the sound file's
        (tmp_path / "once.jpg").write_bytes(data)
        assert svbrdf("capture", "once.jpg", "-o", "o", *OPTIONS, cwd=tmp_path)[0] == 0
        assert maps_hash(tmp_path / "o" / "twice") == maps_hash(tmp_path / "o" / "once")
    else:
        assert len(errors(err)) == 1 and "twice.jpg" in errors(err)[0]


# --------------------------------------------------------------------------
# 9. DNGs that decode to near-black
# --------------------------------------------------------------------------

def test_damaged_dngs_are_refused(dng, tmp_path):
    from svbrdf_cli.ingest import filecheck

    mid = len(dng) // 2
    cases = {"black.dng": _ifd0_set(dng, 50714, 32768), "tilewidth.dng": _ifd0_set(dng, 322, 1000),
             "inserted.dng": dng[:mid] + bytes(4096) + dng[mid:]}
    for name, data in cases.items():
        (tmp_path / name).write_bytes(data)
    code, _, err = svbrdf("capture", *cases, "-o", "o", *OPTIONS, cwd=tmp_path)
    assert code == 1 and len(errors(err)) == 3, err
    for name in cases:
        assert len([line for line in errors(err) if name in line]) == 1, (name, err)
    assert not os.path.exists(tmp_path / "o") or os.listdir(tmp_path / "o") == []
    assert filecheck.raw_data_problem(str(tmp_path / "valid.dng")) is None


def test_a_small_dng_with_an_absurd_black_level_is_refused(tmp_path):
    (tmp_path / "black.dng").write_bytes(_ifd0_set(mutations.tiny_dng(), 50714, 60990))
    code, _, err = svbrdf("capture", "black.dng", "-o", "o", *OPTIONS, cwd=tmp_path)
    assert code == 1 and len(errors(err)) == 1 and "black.dng" in errors(err)[0], err


# --------------------------------------------------------------------------
# 10. half-transparent PNGs
# --------------------------------------------------------------------------

def _rgba(path, h, w, opaque):
    from mutations import _oiio, flash

    img = np.zeros((h, w, 4), np.float32)
    img[..., :3] = flash(h, w, 4)
    y0, y1, x0, x1 = opaque
    img[y0:y1, x0:x1, 3] = 1.0
    _oiio(str(path), img)


def test_a_half_transparent_png_is_refused_even_under_q(tmp_path):
    _rgba(tmp_path / "half.png", 300, 400, (0, 300, 0, 200))
    code, _, err = svbrdf("capture", "half.png", "-o", "o", *OPTIONS, "-q", cwd=tmp_path)
    assert code == 1 and errors(err) == err.strip().splitlines() and len(errors(err)) == 1, err
    assert "half.png" in err and "200x300 region of 400x300 is opaque" in err


def test_a_thin_transparent_border_is_cropped_and_recorded(tmp_path):
    _rgba(tmp_path / "border.png", 300, 400, (20, 290, 30, 380))
    code, _, err = svbrdf("capture", "border.png", "-o", "o", *OPTIONS, cwd=tmp_path)
    assert code == 0, err
    assert "opaque 350x270 region of 400x300" in err
    rec = json.loads((tmp_path / "o" / "border" / "material.json").read_text())
    assert rec["input"]["opaque_region"] == [30, 20, 380, 290]


# --------------------------------------------------------------------------
# 11. results that cannot be right
# --------------------------------------------------------------------------

def _maps(value=None, seed=0):
    rng = np.random.default_rng(seed)
    if value is not None:
        return {k: np.full((64, 64, 3), value, np.float32) for k in ("normal", "diffuse", "roughness", "specular")}
    return {k: rng.uniform(0.2, 0.8, (64, 64, 3)).astype(np.float32)
            for k in ("normal", "diffuse", "roughness", "specular")}


def test_constant_or_black_maps_from_a_real_photo_are_refused():
    photo = np.random.default_rng(1).uniform(0.1, 0.9, (64, 64, 3)).astype(np.float32)
    plausible.check_maps("p.jpg", photo, _maps())  # fine
    with pytest.raises(SvbrdfError, match="'p.jpg'.*constant"):
        plausible.check_maps("p.jpg", photo, _maps(0.5))
    black = _maps()
    black["diffuse"][:] = 0
    with pytest.raises(SvbrdfError, match="'p.jpg'.*diffuse map came out black"):
        plausible.check_maps("p.jpg", photo, black)
    plausible.check_maps("flat.jpg", np.full((64, 64, 3), 0.4, np.float32), _maps(0.5))  # a flat photo may


@pytest.mark.parametrize("gain", [-1e21, 1e30, 1.5, float("nan"), float("inf")])
def test_an_impossible_fit_is_refused(gain):
    photo = np.random.default_rng(1).uniform(0.1, 0.9, (64, 64, 3)).astype(np.float32)
    with pytest.raises(SvbrdfError, match="'p.jpg'"):
        plausible.check_maps("p.jpg", photo, _maps(), {"fit_gain": gain})
    plausible.check_maps("p.jpg", photo, _maps(), {"fit_gain": 0.93})
    plausible.check_maps("p.jpg", photo, _maps(), {"fit_gain": -99.5})  # an evenly lit sheet's
    plausible.check_maps("flat.png", np.full((64, 64, 3), 0.4, np.float32), _maps(), {"fit_gain": -1e21})


def test_exposure_at_its_limit_and_a_uniform_crop_are_refused():
    with pytest.raises(SvbrdfError, match="'d.dng'.*almost black"):
        plausible.check_exposure("d.dng", 11.99)
    plausible.check_exposure("d.dng", 3.0)
    photo = np.random.default_rng(1).uniform(0.1, 0.9, (300, 400, 3)).astype(np.float32)
    photo[100:] = 0.5
    with pytest.raises(SvbrdfError, match="'g.jpg'.*perfectly uniform"):
        plausible.check_crop("g.jpg", photo, photo[120:280, 100:260])
    plausible.check_crop("g.jpg", photo, photo[0:100, 0:100])


# --------------------------------------------------------------------------
# 12, 13. messages
# --------------------------------------------------------------------------

def test_a_corrupt_exr_with_a_non_utf8_message_gets_a_clear_error(tmp_path):
    from mutations import _oiio, flash

    _oiio(str(tmp_path / "good.exr"), flash(64, 64) ** 2.2, "half")
    data = (tmp_path / "good.exr").read_bytes().replace(b"chlist\x00", b"chl\xffst\x00", 1)
    (tmp_path / "bad.exr").write_bytes(data)
    code, _, err = svbrdf("capture", "bad.exr", "-o", "o", *OPTIONS, cwd=tmp_path)
    assert code == 1 and len(errors(err)) == 1, err
    assert "bad.exr" in err and "UnicodeDecodeError" not in err and "please report" not in err


def test_decoders_say_nothing_under_q(tmp_path):
    """libjpeg, libpng and LibRaw print to stderr themselves; under -q only our error lines remain."""
    data = _jpeg(tmp_path)
    (tmp_path / "a_cut.jpg").write_bytes(data[: len(data) // 3] + data[-200:])
    png = (tmp_path / "seed.png")
    from mutations import _oiio, flash

    _oiio(str(png), flash(96, 128))
    raw = bytearray(png.read_bytes())
    chunks = mutations.png_chunks(bytes(raw))
    idat = [c for c in chunks if c[2] == b"IDAT"][0]
    raw[idat[0] + 20] ^= 0xFF
    (tmp_path / "b_crc.png").write_bytes(bytes(raw))
    (tmp_path / "c_tail.png").write_bytes(png.read_bytes() + b"\0junk appended" * 50)
    png.unlink()
    code, out, err = svbrdf("capture", "a_cut.jpg", "b_crc.png", "c_tail.png", "-o", "o", *OPTIONS, "-q",
                            cwd=tmp_path)
    assert code == 1 and out == ""
    assert err.strip().splitlines() == errors(err) and len(errors(err)) == 2, err
    assert "a_cut.jpg" in errors(err)[0] and "b_crc.png" in errors(err)[1]
    assert "truncated" not in errors(err)[1]
    assert os.listdir(tmp_path / "o") == ["c_tail"]  # bytes after a complete PNG do not spoil it
    code, _, err = svbrdf("capture", "c_tail.png", "-o", "o2", *OPTIONS, cwd=tmp_path)
    assert code == 0 and "bytes after the end of the PNG image were ignored" in err


def test_a_png_with_a_damaged_chunk_names_the_damage(tmp_path):
    from mutations import _oiio, flash

    _oiio(str(tmp_path / "p.png"), flash(96, 128))
    raw = bytearray((tmp_path / "p.png").read_bytes())
    idat = [c for c in mutations.png_chunks(bytes(raw)) if c[2] == b"IDAT"][0]
    raw[idat[0] + 40:idat[0] + 60] = bytes(20)
    mutations.png_fix_crc(raw, idat[0])  # the CRC is right: the deflate stream is not
    (tmp_path / "p.png").write_bytes(bytes(raw))
    code, _, err = svbrdf("capture", "p.png", "-o", "o", *OPTIONS, cwd=tmp_path)
    assert code == 1 and len(errors(err)) == 1 and "p.png" in errors(err)[0], err
    assert "truncated data" not in err


def test_a_tiff_whose_predictor_libtiff_would_ignore_is_refused(tmp_path):
    """Found by the fuzzer: a Predictor tag with a wrong count is ignored by libtiff, which then decodes
    every row as differences (a set from garbage)."""
    from mutations import _oiio, flash

    _oiio(str(tmp_path / "t.tif"), flash(80, 96))
    data = bytearray((tmp_path / "t.tif").read_bytes())
    entries, e = mutations.tiff_entries(bytes(data))
    p = [p for p, tag, *_ in entries if tag == 317][0]
    data[p + 4:p + 8] = struct.pack(e + "I", 65535)
    (tmp_path / "t.tif").write_bytes(bytes(data))
    code, _, err = svbrdf("capture", "t.tif", "-o", "o", *OPTIONS, cwd=tmp_path)
    assert code == 1 and len(errors(err)) == 1 and "Predictor" in errors(err)[0], err
