"""Hostile and unusual inputs and option values, each in a fresh ``svbrdf`` process.

Every case ends one of two ways:

* accepted: exit 0 and a complete texture set (``material.json``), or
* refused: exit 1 (a file the tool cannot use) or 2 (a usage error), exactly one ``error:`` line that
  names the file (or the option), no traceback, and nothing left in the output folder.

Everything is generated here at test time; nothing is downloaded. Decompression bombs also assert a
bounded peak memory, measured on the child process with ``resource.getrusage``.
"""

import os
import struct
import subprocess
import sys
import zlib

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
#: Peak memory allowed to any photo the tool accepts or refuses (issue: at most 1.5 GB).
PEAK_MB = 1536


def svbrdf(*args, cwd=None):
    """Run ``svbrdf ARGS`` in a fresh process: (exit code, stdout + stderr, peak RSS of that process in MB)."""
    wrapper = ("import resource, subprocess, sys\n"
               "r = subprocess.run(sys.argv[1:], stdout=subprocess.PIPE, stderr=subprocess.STDOUT)\n"
               "sys.stdout.buffer.write(r.stdout)\n"
               "print('\\nPEAK_KB', resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)\n"
               "sys.exit(r.returncode)\n")
    argv = [sys.executable, "-c", wrapper, sys.executable, "-m", "svbrdf_cli.cli.main"]
    argv += [a if isinstance(a, bytes) else str(a) for a in args]
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=ROOT)
    r = subprocess.run(argv, capture_output=True, cwd=cwd, env=env, timeout=300)
    text = r.stdout.decode("utf-8", "replace") + r.stderr.decode("utf-8", "replace")
    peak = [int(line.split()[1]) for line in text.splitlines() if line.startswith("PEAK_KB")]
    text = "\n".join(line for line in text.splitlines() if not line.startswith("PEAK_KB"))
    return r.returncode, text, (peak[0] / 1024 if peak else 0.0)


# --------------------------------------------------------------------------
# Making inputs
# --------------------------------------------------------------------------

def flash_photo(h=300, w=400, seed=0, channels=3):
    """A small flash-like linear-ish photo in [0, 1]: texture plus a highlight."""
    y, x = np.mgrid[0:h, 0:w]
    rng = np.random.default_rng(seed)
    base = rng.uniform(0.2, 0.5, 3) * (0.8 + 0.2 * np.sin(x / 7.0)[..., None])
    hl = np.exp(-((x - w / 2) ** 2 + (y - h / 2) ** 2) / (2 * (0.08 * w) ** 2))[..., None]
    img = np.clip(base + 0.6 * hl, 0, 1).astype(np.float32)
    return img if channels == 3 else img.mean(-1, keepdims=True)


def write(path, pixels, fmt="uint8", **attrs):
    """Write ``pixels`` (H, W, C float in [0, 1], or any dtype for float formats) with OpenImageIO."""
    import OpenImageIO as oiio

    a = np.ascontiguousarray(pixels, np.float32)
    spec = oiio.ImageSpec(a.shape[1], a.shape[0], a.shape[2], fmt)
    for k, v in attrs.items():
        spec.attribute(k.replace("__", ":"), v)
    out = oiio.ImageOutput.create(os.fsdecode(path))
    assert out.open(os.fsdecode(path), spec) and out.write_image(a), oiio.geterror()
    out.close()
    return path


def png_chunk(kind, body):
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF)


def streamed_png(path, w, h):
    """A valid 8-bit RGB PNG of ``w`` x ``h`` written row by row (little memory): a flash-like gradient."""
    comp = zlib.compressobj(6)
    x = np.arange(w, dtype=np.float32) / w - 0.5
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + png_chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)))
        data = []
        for row in range(h):
            yy = row / h - 0.5
            v = (60 + 180 * np.exp(-(x * x + yy * yy) / 0.02)).astype(np.uint8)
            data.append(comp.compress(b"\0" + np.repeat(v, 3).tobytes()))
            if row % 512 == 511:
                f.write(png_chunk(b"IDAT", b"".join(data)))
                data = []
        data.append(comp.flush())
        f.write(png_chunk(b"IDAT", b"".join(data)) + png_chunk(b"IEND", b""))
    return path


def jpeg_header_bomb(path, w=14000, h=14000):
    """A 2 KB 'JPEG' that declares ``w`` x ``h``: a real small JPEG whose SOF0 size is rewritten."""
    import cv2

    ok, buf = cv2.imencode(".jpg", (flash_photo(64, 64) * 255).astype(np.uint8))
    data = bytearray(buf.tobytes())
    i = data.find(b"\xff\xc0")
    data[i + 5:i + 9] = struct.pack(">HH", h, w)
    with open(path, "wb") as f:
        f.write(bytes(data))
    return path


def jpeg(path, pixels, quality=92):
    import cv2

    u8 = (np.clip(pixels, 0, 1) * 255 + 0.5).astype(np.uint8)
    u8 = u8[..., ::-1] if u8.ndim == 3 else u8
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(u8), [cv2.IMWRITE_JPEG_QUALITY, quality])
    assert ok
    with open(path, "wb") as f:  # (cv2.imwrite crashes on a file name that is not UTF-8)
        f.write(buf.tobytes())
    return path


def truncated(path, source, fraction):
    data = open(source, "rb").read()
    with open(path, "wb") as f:
        f.write(data[: int(len(data) * fraction)])
    return path


# --------------------------------------------------------------------------
# The cases: name -> builder(tmp) returning (args, expected exit code, words the error line holds)
# --------------------------------------------------------------------------

def _capture(photo, *more):
    return ["capture", photo, "-o", "out", "--size", "256", "--threads", "1", *more]


CASES = {}


def case(name, code, words=None, peak=False):
    def deco(fn):
        CASES[name] = (fn, code, words, peak)
        return fn
    return deco


@case("zero_byte", 1, "empty")
def _(t):
    (t / "z.jpg").write_bytes(b"")
    return _capture("z.jpg")


@case("text_named_jpg", 1, "t.jpg")
def _(t):
    (t / "t.jpg").write_text("hello\n" * 50)
    return _capture("t.jpg")


# JPEGs under odd names: another format's extension, none, spaces, non-Latin letters
for _name, _file in {"jpeg_named_png": "j.png", "no_extension": "photo", "name_with_spaces": "my photo 1.jpg",
                     "name_unicode": "ткань_木目_é.jpg"}.items():
    @case(_name, 0)
    def _(t, _file=_file):
        jpeg(t / _file, flash_photo())
        return _capture(_file)


@case("png_named_jpg", 0)
def _(t):
    write(t / "p.png", flash_photo())
    os.rename(t / "p.png", t / "p.jpg")
    return _capture("p.jpg")


for _frac in (0.1, 0.5, 0.99):
    for _ext, _writer in (("jpg", jpeg), ("png", write)):
        @case(f"truncated_{'jpeg' if _ext == 'jpg' else _ext}_{int(_frac * 100)}", 1, "truncated")
        def _(t, _frac=_frac, _ext=_ext, _writer=_writer):
            _writer(t / f"full.{_ext}", flash_photo(600, 800))
            truncated(t / f"cut.{_ext}", t / f"full.{_ext}", _frac)
            os.remove(t / f"full.{_ext}")
            return _capture(f"cut.{_ext}")


@case("jpeg_header_bomb_14000", 1, "bomb.jpg", peak=True)
def _(t):
    jpeg_header_bomb(t / "bomb.jpg")
    return _capture("bomb.jpg")


@case("png_header_bomb_30000", 1, "bomb.png", peak=True)
def _(t):
    (t / "bomb.png").write_bytes(b"\x89PNG\r\n\x1a\n" + png_chunk(b"IHDR", struct.pack(">IIBBBBB", 30000, 30000, 8, 2, 0, 0, 0))
                                 + png_chunk(b"IDAT", zlib.compress(b"\0" * 300001)) + png_chunk(b"IEND", b""))
    return _capture("bomb.png")


@case("png_valid_14000", 0, peak=True)
def _(t):
    streamed_png(t / "big.png", 14000, 14000)
    return _capture("big.png", "--no-preview")


@case("jpeg_large_48mp", 0, peak=True)
def _(t):
    import cv2

    small = (flash_photo(750, 1000) * 255).astype(np.uint8)
    jpeg(t / "large.jpg", cv2.resize(small, (8000, 6000), interpolation=cv2.INTER_LINEAR) / 255.0)
    return _capture("large.jpg", "--no-preview")


@case("tiny_8px", 1, "too small")
def _(t):
    write(t / "tiny.png", flash_photo(8, 8))
    return _capture("tiny.png")


@case("one_pixel", 1, "too small")
def _(t):
    write(t / "px.png", flash_photo(1, 1))
    return _capture("px.png")


@case("png_16bit", 0)
def _(t):
    write(t / "p16.png", flash_photo(), "uint16")
    return _capture("p16.png")


@case("tiff_16bit", 0)
def _(t):
    write(t / "t16.tif", flash_photo(), "uint16")
    return _capture("t16.tif")


@case("tiff_float", 0)
def _(t):
    write(t / "tf.tif", flash_photo() ** 2.2, "float")
    return _capture("tf.tif")


@case("exr_half", 0)
def _(t):
    write(t / "e.exr", flash_photo() ** 2.2, "half")
    return _capture("e.exr")


@case("exr_nan_inf_repaired", 0)
def _(t):
    img = flash_photo() ** 2.2
    img[10:20, 10:20] = np.nan
    img[30:32, 30:32] = np.inf
    img[40, 40] = -np.inf
    write(t / "nan.exr", img, "float")
    return _capture("nan.exr")


@case("grey_jpeg", 0)
def _(t):
    jpeg(t / "g.jpg", flash_photo(channels=1)[..., 0])
    return _capture("g.jpg")


@case("grey_png", 0)
def _(t):
    write(t / "g.png", flash_photo(channels=1))
    return _capture("g.png")


@case("grey_alpha_png_opaque", 0)
def _(t):
    g = flash_photo(channels=1)
    write(t / "ga.png", np.concatenate([g, np.ones_like(g)], -1))
    return _capture("ga.png")


@case("rgba_opaque", 0)
def _(t):
    img = flash_photo()
    write(t / "a.png", np.concatenate([img, np.ones_like(img[..., :1])], -1))
    return _capture("a.png")


@case("rgba_transparent_border_cropped", 0)
def _(t):
    img = np.zeros((400, 500, 4), np.float32)
    img[50:350, 60:440, :3] = flash_photo(300, 380)
    img[50:350, 60:440, 3] = 1.0
    write(t / "border.png", img)
    return _capture("border.png")


@case("rgba_transparent_holes", 1, "transparent")
def _(t):
    img = np.concatenate([flash_photo(), np.ones((300, 400, 1), np.float32)], -1)
    img[100:200, 150:250, 3] = 0.0
    write(t / "holes.png", img)
    return _capture("holes.png")


@case("cmyk_jpeg", 0)
def _(t):
    from PIL import Image

    Image.fromarray((flash_photo() * 255).astype(np.uint8)).convert("CMYK").save(t / "cmyk.jpg")
    return _capture("cmyk.jpg")


@case("animated_gif", 0)
def _(t):
    from PIL import Image

    frames = [Image.fromarray((flash_photo(seed=s) * 255).astype(np.uint8)) for s in range(3)]
    frames[0].save(t / "anim.gif", save_all=True, append_images=frames[1:], duration=100, loop=0)
    return _capture("anim.gif")


@case("tiff_5_channels", 0)
def _(t):
    img = flash_photo()
    write(t / "five.tif", np.concatenate([img, np.full((300, 400, 2), 0.3, np.float32)], -1))
    return _capture("five.tif")


for _o in range(1, 9):
    @case(f"exif_orientation_{_o}", 0)
    def _(t, _o=_o):
        write(t / f"o{_o}.jpg", flash_photo(), Orientation=_o)
        return _capture(f"o{_o}.jpg")


@case("name_not_utf8", 0)
def _(t):
    name = b"caf\xe9.jpg"
    jpeg(os.path.join(os.fsencode(t), name), flash_photo())
    return ["capture", name, "-o", "out", "--size", "256", "--threads", "1"]


@case("name_leading_dash", 0)
def _(t):
    jpeg(t / "-photo.jpg", flash_photo())
    return ["capture", "-o", "out", "--size", "256", "--threads", "1", "--", "-photo.jpg"]


@case("folder_without_photos", 2, "no photos")
def _(t):
    (t / "empty").mkdir()
    (t / "empty" / "notes.txt").write_text("x")
    return _capture("empty")


@case("symlink_loop", 1, "loop.jpg")
def _(t):
    os.symlink("loop.jpg", t / "loop.jpg")
    return _capture("loop.jpg")


@case("output_is_a_file", 2, "out")
def _(t):
    jpeg(t / "p.jpg", flash_photo())
    (t / "out").write_text("a file, not a folder")
    return _capture("p.jpg")


@case("output_unwritable", 1, "out")
def _(t):
    jpeg(t / "p.jpg", flash_photo())
    if os.geteuid() == 0:  # root writes anywhere but in /proc
        return ["capture", "p.jpg", "-o", "/proc/svbrdf-out", "--size", "256"]
    (t / "out").mkdir()
    os.chmod(t / "out", 0o555)
    return _capture("p.jpg")


@case("all_white", 1, "white.png")
def _(t):
    write(t / "white.png", np.ones((300, 400, 3), np.float32))
    return _capture("white.png")


@case("all_black", 1, "black.png")
def _(t):
    write(t / "black.png", np.zeros((300, 400, 3), np.float32))
    return _capture("black.png")


@case("heic_refused", 1, "HEIC")
def _(t):
    (t / "p.heic").write_bytes(b"\0\0\0\x18ftypheic" + b"\0" * 200)
    return _capture("p.heic")


@case("model_folder_of_corrupt_onnx", 1, "bad_model")
def _(t):
    jpeg(t / "p.jpg", flash_photo())
    (t / "bad_model").mkdir()
    for s in ("masks", "aux", "maps"):
        (t / "bad_model" / f"{s}.onnx").write_bytes(b"not a model" * 10)
    return _capture("p.jpg", "--model", "bad_model")


@case("model_unknown", 2, "nonesuch")  # a usage error
def _(t):
    jpeg(t / "p.jpg", flash_photo())
    return _capture("p.jpg", "--model", "nonesuch")


@case("corners_outside_the_photo", 1, "p.jpg")
def _(t):
    jpeg(t / "p.jpg", flash_photo())
    return _capture("p.jpg", "--corners", "0,0,9000,0,9000,9000,0,9000")


_BAD_CAPTURE_OPTIONS = {
    "size_too_small": ("--size", "100"), "size_not_a_number": ("--size", "abc"),
    "white_balance_nan": ("--white-balance", "nan,1,1"), "white_balance_zero": ("--white-balance", "0,1,1"),
    "white_balance_two_values": ("--white-balance", "1,1"), "exposure_huge": ("--exposure", "10000"),
    "exposure_nan": ("--exposure", "nan"), "exposure_word": ("--exposure", "bright"),
    "corners_three_numbers": ("--corners", "1,2,3"), "crop_unknown": ("--crop", "bogus"),
    "preset_unknown": ("--preset", "bogus"), "bits_12": ("--bits", "12"), "threads_negative": ("--threads", "-1"),
    "exr_with_png_only_preset": ("--format", "exr"),
}
for _name, _opt in _BAD_CAPTURE_OPTIONS.items():
    @case(f"capture_{_name}", 2, _opt[0] if _name != "exr_with_png_only_preset" else "PNG only")
    def _(t, _opt=_opt):
        jpeg(t / "p.jpg", flash_photo())
        return _capture("p.jpg", *_opt)


@case("batch_on_a_file", 2, "p.jpg")
def _(t):
    jpeg(t / "p.jpg", flash_photo())
    return ["batch", "p.jpg", "-o", "out"]


@case("batch_workers_zero", 2, "--workers")
def _(t):
    (t / "in").mkdir()
    jpeg(t / "in" / "p.jpg", flash_photo())
    return ["batch", "in", "-o", "out", "--workers", "0"]


@case("batch_engine_unknown", 2, "--engine")
def _(t):
    (t / "in").mkdir()
    return ["batch", "in", "-o", "out", "--engine", "bogus"]


def _mapset(t):
    from svbrdf_cli.write.mapset import write_map_set

    h = w = 32
    maps = {"normal": np.broadcast_to(np.float32([0, 0, 1]), (h, w, 3)), "diffuse": np.full((h, w, 3), 0.3, np.float32),
            "roughness": np.full((h, w, 1), 0.5, np.float32), "specular": np.full((h, w, 3), 0.04, np.float32)}
    write_map_set(t / "set", maps)
    return "set"


@case("export_missing_set", 1, "normal.png")
def _(t):
    (t / "nothing").mkdir()
    return ["export", "nothing", "-o", "out", "--preset", "gltf"]


@case("export_preset_missing", 2, "--preset")
def _(t):
    return ["export", _mapset(t), "-o", "out"]


@case("export_over_a_folder_of_other_files", 1, "out")
def _(t):
    (t / "out").mkdir()
    (t / "out" / "keep.txt").write_text("mine")
    return ["export", _mapset(t), "-o", "out", "--preset", "gltf", "--force"]


_BAD_RENDER = {"light_nan": ("--light", "nan,nan,nan"), "light_at_the_surface": ("--light", "0,0,0"),
               "light_below": ("--light", "0,0,-1"), "intensity_nan": ("--intensity", "nan"),
               "intensity_zero": ("--intensity", "0"), "exposure_huge": ("--exposure", "10000")}
for _name, _opt in _BAD_RENDER.items():
    @case(f"render_{_name}", 2, _opt[0])
    def _(t, _opt=_opt):
        return ["render", _mapset(t), "-o", "r.png", *_opt]


@case("render_into_missing_folder", 1, "no/such/dir")
def _(t):
    return ["render", _mapset(t), "-o", "no/such/dir/r.png"]


@case("markers_cell_too_small", 2, "--cell")
def _(t):
    return ["markers", "m.png", "--cell", "5"]


@case("markers_into_missing_folder", 1, "no/such")
def _(t):
    return ["markers", "no/such/m.png"]


def _leftovers(t):
    """What a refused run may not leave: anything in out/ (a set, a hidden temporary), or r.png/m.png."""
    out = t / "out"
    found = [f"out/{n}" for n in os.listdir(out)] if out.is_dir() else []
    return found + [n for n in ("r.png", "m.png") if (t / n).exists()]


@pytest.mark.parametrize("name", sorted(CASES))
def test_hostile_input(name, tmp_path):
    build, expected, words, check_peak = CASES[name]
    args = build(tmp_path)
    before = _leftovers(tmp_path)
    code, text, peak = svbrdf(*args, cwd=tmp_path)
    assert "Traceback" not in text, text
    assert code == expected, text
    if check_peak:
        assert peak < PEAK_MB, f"peak memory {peak:.0f} MB"
    if expected == 0:
        sets = [n for n in os.listdir(tmp_path / "out") if not n.startswith(".")]
        assert len(sets) == 1 and (tmp_path / "out" / sets[0] / "material.json").is_file(), text
        assert not [n for n in os.listdir(tmp_path / "out") if n.startswith(".")], "temporaries left"
        return
    errors = [line for line in text.splitlines() if "error:" in line.lower()]
    assert len(errors) == 1, text
    assert words is None or words in errors[0], (words, errors[0])
    assert _leftovers(tmp_path) == before, "a refused run left files behind"


def test_the_suite_covers_at_least_60_cases():
    assert len(CASES) >= 60, len(CASES)
