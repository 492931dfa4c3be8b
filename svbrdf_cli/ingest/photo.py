"""Photos in: RAW through rawpy, everything else through OpenImageIO.

:func:`load_photo` returns *linear* RGB (sRGB/Rec.709 primaries), oriented
as the camera meant it (EXIF orientation applied), whatever the file:

* camera RAW (DNG, NEF, CR2, ARW, ...): demosaiced by LibRaw with the
  camera's white balance, no auto-brightening, 16 bits, linear;
* JPEG, PNG, TIFF (8 or 16 bit): sRGB-decoded;
* EXR and float TIFF: taken as linear.

Grey images are repeated to three channels, alpha is dropped. The networks
take the photo exposed, clipped and encoded as training images are
(:func:`encode_for_network`, through :func:`svbrdf_cli.infer.exposure.network_input`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import logging
import os
import tempfile

import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli.ingest import decoder_output
from svbrdf_cli.ingest import filecheck
from svbrdf_cli.errors import ImageReadError

log = logging.getLogger("svbrdf")

RAW_EXTENSIONS = frozenset(
    ".dng .nef .nrw .cr2 .cr3 .crw .arw .srf .sr2 .raf .rw2 .orf .pef .srw .gpr .3fr .iiq .erf .kdc .mos "
    ".mrw .x3f .rwl .dcr".split())

#: Largest image read, in pixels (a decompression bomb guard): 200 MP.
MAX_PIXELS = 200_000_000
#: Smallest side read, in pixels (the networks see 256 × 256; a smaller photo is upsampled).
MIN_SIDE = 32


@dataclasses.dataclass
class Photo:
    """A decoded photo: linear (H, W, 3) float32 pixels and what the file said about them."""
    linear: np.ndarray          # (H, W, 3) float32, linear, >= 0
    path: str
    kind: str                   # "raw", "encoded" or "linear"
    bits: int
    scale: float = 1.0          # decoded at this fraction of the file's size (1/2, 1/4 ...)
    sha256: str | None = None   # of the file's bytes (read once, with the checks of its format)
    focal_35mm: float | None = None  # 35 mm-equivalent focal length from the EXIF, when it has one
    opaque: tuple | None = None  # (x0, y0, x1, y1): the opaque region kept of a file with transparent borders


def load_photo(path, white_balance=None, min_side=None):
    """Read a photo as linear RGB (see the module docstring).

    Args:
        path: the file.
        white_balance: optional (r, g, b) multipliers applied to the linear image.
        min_side: the fewest pixels the short side needs (what the output uses): a photo at least twice
            that is decoded at a reduced size (JPEG by DCT scaling, RAW by half-size demosaicing).

    Raises:
        ImageReadError: with a one-line message naming the file and what to do.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise ImageReadError(f"Could not read '{path}': no such file. Check the path.")
    if os.path.getsize(path) == 0:
        raise ImageReadError(f"Could not read '{path}': the file is empty. Copy it from the camera again.")
    ext = os.path.splitext(path)[1].lower()
    with open(path, "rb") as f:  # the one read of the file in Python: its hash and format checks
        data = f.read()
    with _openable(path) as name:  # (``name``: what the decoders open; messages name ``path``)
        if ext in RAW_EXTENSIONS:
            photo = _load_raw(path, name, min_side)
            photo.focal_35mm = _exif_focal_35mm(name)  # (LibRaw does not give it)
        else:
            photo = _load_image(path, name, min_side, data)
    photo.sha256 = hashlib.sha256(data).hexdigest()
    del data
    _check_exposed(path, photo.linear)
    if white_balance is not None:
        photo.linear = photo.linear * np.asarray(white_balance, np.float32).reshape(1, 1, 3)
    return photo


def _check_exposed(path, linear):
    """Refuse a photo that is black (nothing to measure) or white everywhere (all clipped)."""
    if float(linear.max()) <= cv.srgb_to_linear(np.float32(BLACK_LEVEL)):
        raise ImageReadError(f"Could not use '{path}': the photo is black. Take it again with the flash on.")
    if float(linear.min()) >= cv.srgb_to_linear(np.float32(WHITE_LEVEL)):
        raise ImageReadError(f"Could not use '{path}': the photo is white (overexposed everywhere). Take it "
                             "again with less exposure, or from a little further away.")


def encode_for_network(linear, gain=None, fast=False):
    """Linear RGB (times ``gain``, a number, if given) -> the clipped, encoded float32 image the
    networks take (:func:`svbrdf_cli.conventions.image_to_encoded`, in one new array).

    ``fast``: the power by OpenCV, three times numpy's speed and within 2e-7 of it (for the photo
    at the output size; the network's input keeps numpy's, which ``--refine``'s descent would
    carry to a few pixels changing by 2/255)."""
    x = np.multiply(linear, np.float32(gain), dtype=np.float32) if gain is not None else \
        np.array(linear, np.float32)
    np.clip(x, np.float32(1e-10), np.float32(1.0), out=x)
    if not fast:
        return np.power(x, np.float32(1.0 / cv.IMAGE_GAMMA), out=x)
    import cv2

    return cv2.pow(x.reshape(x.shape[0], -1), 1.0 / cv.IMAGE_GAMMA).reshape(x.shape)


def _load_raw(path, name, min_side=None):
    """A camera RAW through LibRaw, each in a fresh decoder state: its image data checked to exist first
    (:func:`svbrdf_cli.ingest.filecheck.raw_data_problem`), its large buffers fresh from the system
    (:func:`_fresh_large_buffers`: what LibRaw leaves unfilled is zero, never an earlier photo's pixels),
    and what it prints caught (a "data corrupted" refuses the file)."""
    import rawpy

    problem = filecheck.tiff_problem(name)
    if problem:
        raise ImageReadError(f"Could not decode RAW '{path}': {problem}; the file is damaged or cut short. "
                             "Copy it from the camera again.")
    _fresh_large_buffers()
    said = []
    try:
        with decoder_output.captured() as said, rawpy.imread(name) as raw:
            factor = _reduction(raw.sizes.width, raw.sizes.height, min_side)
            # half-size demosaicing (each 2x2 Bayer block one pixel) when half the size is enough
            rgb = raw.postprocess(use_camera_wb=True, no_auto_bright=True, output_bps=16, gamma=(1, 1),
                                  output_color=rawpy.ColorSpace.sRGB, half_size=factor > 1)
    except (rawpy.LibRawError, OSError, ValueError) as e:
        why = e.args[0] if e.args else ""
        why = (why.decode(errors="replace") if isinstance(why, bytes) else str(why)).strip() or type(e).__name__
        raise ImageReadError(f"Could not decode RAW '{path}': {why}. "
                             "Convert it to DNG or 16-bit TIFF with the camera's software.") from None
    _judge_decoder_output(path, said, "LibRaw")
    if rgb.ndim != 3 or rgb.shape[-1] != 3:
        raise ImageReadError(f"Could not decode RAW '{path}': got {rgb.shape} instead of RGB. Convert it to TIFF.")
    if factor > 2:
        import cv2

        h, w = rgb.shape[:2]
        rgb = cv2.resize(rgb, (w * 2 // factor, h * 2 // factor), interpolation=cv2.INTER_AREA)
    return Photo(rgb.astype(np.float32) / 65535.0, path, "raw", 16, 1.0 / factor)


#: Photos over this many pixels are decoded at a reduced size (halved until under it: JPEG by its
#: DCT scaling, other formats strip by strip with an area filter), so that memory stays bounded
#: whatever the file declares. 16 MP keeps a 4096 px map's crop (a 4:3 photo's short side is 3464 px
#: at 16 MP) within 20% of its full resolution.
DECODE_MAX_PIXELS = 16_000_000
#: Rows decoded at once by the strip reader, as a budget in bytes of float32 samples.
STRIP_BYTES = 64 << 20
#: A JPEG that holds fewer bytes than its declared pixels / this is a header bomb or damaged: even a
#: flat grey JPEG needs about a bit per 8x8 block (0.002 bytes a pixel).
JPEG_MIN_PIXELS_PER_BYTE = 2000
#: Brightness (encoded, 0-1) under which a whole photo counts as black, over which as white.
BLACK_LEVEL, WHITE_LEVEL = 2.0 / 255.0, 253.0 / 255.0
#: Alpha under which a pixel counts as transparent.
TRANSPARENT = 0.5

_MAGIC = {b"\xff\xd8\xff": "jpeg", b"\x89PNG\r\n\x1a\n": "png"}
_HEIF_BRANDS = (b"heic", b"heix", b"hevc", b"hevx", b"heim", b"heis", b"mif1", b"msf1", b"avif")


def _sniff(data):
    """The file's format from its first bytes: "jpeg", "png", "heif" or None (let OpenImageIO decide)."""
    head = bytes(data[:16])
    for magic, kind in _MAGIC.items():
        if head.startswith(magic):
            return kind
    return "heif" if head[4:8] == b"ftyp" and head[8:12] in _HEIF_BRANDS else None


def _truncated(data, kind):
    """Whether a JPEG or PNG (its bytes ``data``) ends before its image does: no EOI marker after the
    last scan (JPEG), no IEND chunk at the end (PNG). Decoders fill a cut image with grey and carry on;
    we refuse it."""
    if kind == "png":
        return data.rfind(b"IEND", max(0, len(data) - 64)) < 0
    if kind == "jpeg":
        sos = data.rfind(b"\xff\xda")
        return sos < 0 or data.find(b"\xff\xd9", sos) < 0
    return False


def _focal_of(spec):
    """The 35 mm-equivalent focal length in an OpenImageIO spec's EXIF (None when absent or implausible)."""
    f = spec.getattribute("Exif:FocalLengthIn35mmFilm")
    try:
        return float(f) if f and 0 < float(f) < 2000 else None
    except (TypeError, ValueError):
        return None


def _exif_focal_35mm(name):
    """The focal length of a file LibRaw decodes, from OpenImageIO's read of its header (None when absent
    or unreadable)."""
    try:
        import OpenImageIO as oiio

        inp = oiio.ImageInput.open(name)
        if not inp:
            oiio.geterror()
            return None
        try:
            return _focal_of(inp.spec())
        finally:
            inp.close()
    except Exception:  # a name the library cannot open, a broken EXIF block: no focal length, no error
        return None


@contextlib.contextmanager
def _openable(path):
    """A name the decoders (OpenImageIO, OpenCV, LibRaw) can open for ``path``: itself, or for a name
    that is not valid UTF-8 (which they mangle) a link to it with a plain name in a temporary folder."""
    try:
        path.encode("utf-8")
        yield path
        return
    except UnicodeEncodeError:
        pass
    with tempfile.TemporaryDirectory(prefix="svbrdf-") as tmp:
        link = os.path.join(tmp, "photo" + os.path.splitext(path)[1].encode("utf-8", "replace").decode("ascii", "replace"))
        os.symlink(os.path.abspath(path), link)
        yield link


def _orient(a, orientation):
    """Apply an EXIF orientation (1-8) to an (H, W, ...) array: what the camera meant to show."""
    if orientation in (5, 6, 7, 8):
        a = a.swapaxes(0, 1)
    flip = {2: (False, True), 3: (True, True), 4: (True, False), 6: (False, True), 7: (True, True),
            8: (True, False)}.get(orientation, (False, False))
    if flip[0]:
        a = a[::-1]
    if flip[1]:
        a = a[:, ::-1]
    return a


def _reduction(w, h, min_side=None):
    """The power of two the photo is decoded at a fraction of: enough for it to fit
    :data:`DECODE_MAX_PIXELS`, and with ``min_side``, as much more as keeps its short side at least
    that (the most the output needs; up to 1/8, libjpeg's smallest DCT scale)."""
    f = 1
    while (w // f) * (h // f) > DECODE_MAX_PIXELS:
        f *= 2
    while min_side and f < 8 and min(w, h) // (2 * f) >= min_side:
        f *= 2
    return f


def _decode_jpeg_reduced(path, factor):
    """A large JPEG decoded at 1/``factor`` by libjpeg's DCT scaling (OpenCV; EXIF orientation applied):
    (H, W, 3) uint8 RGB."""
    import cv2

    flags = {1: cv2.IMREAD_COLOR, 2: cv2.IMREAD_REDUCED_COLOR_2,
             4: cv2.IMREAD_REDUCED_COLOR_4}.get(factor, cv2.IMREAD_REDUCED_COLOR_8)
    bgr = cv2.imread(path, flags)
    if bgr is None:
        return None
    if factor > 8:
        h, w = bgr.shape[:2]
        bgr = cv2.resize(bgr, (max(1, w * 8 // factor), max(1, h * 8 // factor)), interpolation=cv2.INTER_AREA)
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def _decode_strips(inp, spec, factor):
    """Decode ``inp`` a few rows at a time, each strip averaged over ``factor`` x ``factor`` blocks:
    (H // factor, W // factor, C) float32 as stored (integers scaled to 0-1), never the whole image at
    full size."""
    w, h, c = spec.width, spec.height, spec.nchannels
    oh, ow = h // factor, w // factor
    out = np.empty((oh, ow, c), np.float32)
    rows = max(factor, STRIP_BYTES // max(1, w * c * 4) // factor * factor)
    for y0 in range(0, oh * factor, rows):
        y1 = min(y0 + rows, oh * factor)
        px = inp.read_scanlines(0, 0, spec.y + y0, spec.y + y1, 0, 0, c, "float")
        if px is None:
            return None
        px = np.asarray(px, np.float32).reshape(y1 - y0, w, c)
        if factor > 1:
            px = px[:, :ow * factor].reshape((y1 - y0) // factor, factor, ow, factor, c).mean((1, 3))
        out[y0 // factor:y1 // factor] = px
    return out


def _load_image(path, name, min_side=None, data=b""):
    kind = _sniff(data)
    if kind == "heif":
        raise ImageReadError(f"Could not read '{path}': HEIC/HEIF photos are not supported. Export it as JPEG "
                             "(iPhone: Settings > Camera > Formats > Most Compatible).")
    if kind == "png":
        _check_png(path, data)
    problem = filecheck.tiff_problem(data)  # (None unless the file is TIFF-structured)
    if problem:
        raise ImageReadError(f"Could not read '{path}': {problem}; the file is damaged. Export it again.")
    if kind == "jpeg" and _truncated(data, kind):
        raise ImageReadError(f"Could not read '{path}': the file is truncated (its end is missing). "
                             "Copy it from the camera again.")
    with decoder_output.captured() as said:
        decoded = _decode_image(path, name, kind, min_side)
    _judge_decoder_output(path, said, "the JPEG decoder" if kind == "jpeg" else "the decoder")
    rgb, alpha, orientation, bits, floating, factor, (w, h), focal = decoded
    if factor > 1:
        log.info("'%s' is %dx%d: decoded at 1/%d (%dx%d), all the output needs", path, w, h, factor,
                 w // factor, h // factor)
    opaque = None
    if alpha is not None:
        rgb, opaque = _opaque_region(path, rgb, alpha)
    rgb = np.ascontiguousarray(_orient(rgb, orientation))
    if floating:
        _check_light_values(path, rgb)
        _repair_non_finite(path, rgb)
        np.maximum(rgb, 0.0, out=rgb)
    elif floating is not None:  # (None: decoded to linear already)
        _srgb_to_linear_inplace(rgb)
    return Photo(rgb, path, "linear" if floating else "encoded", bits, 1.0 / factor, opaque=opaque, focal_35mm=focal)


def _decode_image(path, name, kind, min_side):
    """The decoding part of :func:`_load_image` (fd 2 is caught meanwhile: nothing here may log):
    (rgb, alpha or None, orientation, bits, floating, factor, (width, height))."""
    import OpenImageIO as oiio

    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)  # colour as stored, alpha apart (never premultiplied)
    inp = oiio.ImageInput.open(name, config)
    if inp is None:
        why = oiio_message(None, "unknown format")
        raise ImageReadError(f"Could not read '{path}': {why}. Use a JPEG, PNG, TIFF, EXR or camera RAW file.")
    try:
        spec = inp.spec()
        focal = _focal_of(spec)
        w, h = spec.width, spec.height
        _check_size(path, kind, w, h)
        factor = _reduction(w, h, min_side)
        orientation = spec.get_int_attribute("Orientation", 1)
        fmt = str(spec.format)
        floating = fmt in ("half", "float", "double")
        bits = {"uint8": 8, "uint16": 16, "half": 16, "float": 32}.get(fmt, 8)
        if kind == "jpeg" and (factor > 1 or (fmt == "uint8" and spec.nchannels in (1, 3))):
            # libjpeg-turbo through OpenCV: the same pixels as OpenImageIO's decoder (checked on the
            # bundled sample and the benchmark's photos), in a third less time, and at a reduced size
            # by DCT scaling; sRGB to linear by a table on OpenCV's LUT (a quarter of numpy's time)
            inp.close()
            inp = None
            rgb = _decode_jpeg_reduced(name, factor)  # oriented by OpenCV
            if rgb is None:
                raise ImageReadError(f"Could not decode '{path}'. The file may be damaged; export it again.")
            rgb, alpha, orientation, bits, floating = _srgb8_to_linear(rgb), None, 1, 8, None
        else:
            px = _decode_strips(inp, spec, factor)
            if px is None:
                why = oiio_message(inp, "the decoder gave no pixels")
                raise ImageReadError(f"Could not decode '{path}': {why}. The file may be damaged; export it again.")
            if inp.has_error:  # the pixels came with a complaint (libjpeg's "Corrupt JPEG data" ...)
                why = oiio_message(inp, "the decoder reported an error")
                raise ImageReadError(f"Could not decode '{path}': {why}. The file is damaged; export it again.")
            rgb, alpha = _channels(px, spec)
            del px
    finally:
        if inp is not None:
            inp.close()
    return rgb, alpha, orientation, bits, floating, factor, (w, h), focal


def oiio_message(source=None, default="unknown error"):
    """The first line of OpenImageIO's error (``source``'s, else the global one), whatever bytes it
    holds (a damaged file's message may not be UTF-8)."""
    import OpenImageIO as oiio

    try:
        text = source.geterror() if source is not None else oiio.geterror()
    except UnicodeDecodeError:
        return "the decoder's message is not readable text (the file is damaged)"
    return (str(text).strip().splitlines() or [default])[0]


def _judge_decoder_output(path, said, who):
    """What a decoder printed while decoding ``path``: a line saying pixels were made up refuses the
    file; anything else is logged (at info level: never under -q)."""
    text = said[0] if said else ""
    bad = decoder_output.corruption(text)
    if bad:
        raise ImageReadError(f"Could not decode '{path}': {who} says \"{bad}\"; the file is damaged. "
                             "Copy or export it again.")
    for line in decoder_output.lines(text)[:5]:
        log.info("'%s': %s says: %s", path, who, line)


def _check_png(path, data):
    problem, trailing = filecheck.png_problem(data)
    if problem:
        raise ImageReadError(f"Could not read '{path}': {problem}. Copy or export it again.")
    if trailing:
        log.warning("'%s': %d bytes after the end of the PNG image were ignored", path, trailing)


#: glibc's threshold above which every allocation gets fresh (zeroed) pages from the system, set
#: before the first RAW decode (glibc's own threshold moves up to 32 MB as large buffers are freed,
#: after which a new raw buffer may reuse the memory of the last photo).
FRESH_BUFFER_BYTES = 1 << 20


def _fresh_large_buffers():
    """Fix glibc's mmap threshold at :data:`FRESH_BUFFER_BYTES` (once; elsewhere nothing to do)."""
    global _FRESH_SET
    if _FRESH_SET:
        return
    _FRESH_SET = True
    try:
        import ctypes
        import ctypes.util

        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        libc.mallopt(-3, FRESH_BUFFER_BYTES)  # M_MMAP_THRESHOLD
    except (OSError, AttributeError):  # not glibc: the data check above still runs
        pass


_FRESH_SET = False


def _channels(px, spec):
    """(H, W, C) decoded samples -> (RGB, alpha or None): grey repeated, extra channels dropped (CMYK
    files arrive as RGB: OpenImageIO converts them)."""
    c = px.shape[-1]
    rgb = np.repeat(px[..., :1], 3, -1) if c < 3 else np.ascontiguousarray(px[..., :3])
    named = spec.channelnames[c - 1] in ("A", "Alpha", "alpha") if c in (2, 4) else False
    return rgb, (px[..., c - 1] if named and spec.alpha_channel == c - 1 else None)


def _check_size(path, kind, w, h):
    """Refuse what no decode should be tried on: too many pixels, too few, or a JPEG far too small for
    the size it declares (a header bomb)."""
    if w * h > MAX_PIXELS:
        raise ImageReadError(f"Could not read '{path}': {w}x{h} is over {MAX_PIXELS // 1_000_000} MP. "
                             "Downscale it first.")
    if w < MIN_SIDE or h < MIN_SIDE:
        raise ImageReadError(f"Could not use '{path}': {w}x{h} is too small; "
                             f"use a photo at least {MIN_SIDE} pixels on each side (256 or more for useful maps).")
    size = os.path.getsize(path)
    if kind == "jpeg" and size * JPEG_MIN_PIXELS_PER_BYTE < w * h:
        raise ImageReadError(f"Could not read '{path}': it declares {w}x{h} pixels but holds only {size // 1024} KB; "
                             "the file is damaged. Export it again.")


#: The most of each side a transparent border may take for the photo to be used (cropped to its
#: opaque part): more, and the flash's centre may be in what is cut away.
MAX_TRANSPARENT_BORDER = 0.15


def _opaque_region(path, rgb, alpha):
    """(the photo cropped to its opaque part, (x0, y0, x1, y1) or None) when transparency only
    surrounds it in a border of at most :data:`MAX_TRANSPARENT_BORDER` of each side; refused when the
    border is wider or the picture itself has transparent holes (they hold no colour: they would be
    baked into every map)."""
    clear = alpha < TRANSPARENT
    if not clear.any():
        return rgb, None
    if clear.all():
        raise ImageReadError(f"Could not use '{path}': it is fully transparent.")
    h, w = clear.shape
    ys, xs = np.flatnonzero(~clear.all(1)), np.flatnonzero(~clear.all(0))
    y0, y1, x0, x1 = int(ys[0]), int(ys[-1]) + 1, int(xs[0]), int(xs[-1]) + 1
    holes = float(clear[y0:y1, x0:x1].mean())
    if holes > 0.001:
        raise ImageReadError(f"Could not use '{path}': {holes:.1%} of the picture is transparent, and transparent "
                             "pixels hold no colour. Flatten it onto its background or crop the transparent part out.")
    cut = max(y0 / h, (h - y1) / h, x0 / w, (w - x1) / w)
    if cut > MAX_TRANSPARENT_BORDER:
        raise ImageReadError(f"Could not use '{path}': only its {x1 - x0}x{y1 - y0} region of {w}x{h} is opaque "
                             f"(a transparent border takes {cut:.0%} of a side; the flash's centre may be in it). "
                             "Crop the file to the photographed surface or flatten it onto its background.")
    log.warning("'%s': using its opaque %dx%d region of %dx%d (the rest is transparent)", path, x1 - x0, y1 - y0,
                w, h)
    return rgb[y0:y1, x0:x1], (x0, y0, x1, y1)


#: Linear samples beyond this are no light a photo records (a float file's damaged data is mostly
#: such numbers: random bits make exponents of every size).
MAX_LIGHT = 1e6
#: The most of a float photo's pixels that may hold samples that are not light values (NaN, infinite,
#: under -1e-3 or over :data:`MAX_LIGHT`) for the rest to be used (they are set to black).
MAX_BROKEN_PIXELS = 0.005


def _check_light_values(path, rgb):
    """Refuse a float photo whose samples are too often not light values (the file is damaged)."""
    with np.errstate(invalid="ignore", over="ignore"):
        bad = (~np.isfinite(rgb) | (rgb < -1e-3) | (rgb > MAX_LIGHT)).any(-1)
    share = float(bad.mean())
    if share > MAX_BROKEN_PIXELS:
        raise ImageReadError(f"Could not use '{path}': {share:.1%} of its pixels hold numbers that are no light values "
                             "(NaN, infinite, negative or huge); the file is damaged. Export it again.")


def _repair_non_finite(path, rgb):
    """NaN and infinite samples (a float file's broken pixels) set to 0, with a warning."""
    bad = ~np.isfinite(rgb)
    if bad.any():
        n = int(bad.any(-1).sum())
        rgb[bad] = 0.0
        log.warning("'%s': %d pixel%s not numbers (NaN or infinite); set to black", path, n,
                    " was" if n == 1 else "s were")


def _srgb_to_linear_inplace(rgb, rows=256):
    """SRGB decoding a few rows at a time (no full-size temporaries)."""
    for y in range(0, rgb.shape[0], rows):
        rgb[y:y + rows] = cv.srgb_to_linear(rgb[y:y + rows])


#: 8-bit sRGB -> linear, each code scaled to [0, 1] as OpenImageIO scales it (times the float 1/255),
#: so a table lookup gives exactly the values of decoding to float and then to linear.
_SRGB8_TO_LINEAR = cv.srgb_to_linear(np.arange(256, dtype=np.float32) * np.float32(1 / 255)).astype(np.float32)


def _srgb8_to_linear(rgb):
    """(H, W, 3) uint8 sRGB -> linear float32, by :data:`_SRGB8_TO_LINEAR` (OpenCV's LUT)."""
    import cv2

    return cv2.LUT(rgb, _SRGB8_TO_LINEAR)
