"""Photos in: RAW through rawpy, everything else through OpenImageIO.

:func:`load_photo` returns *linear* RGB (sRGB/Rec.709 primaries), oriented
as the camera meant it (EXIF orientation applied), whatever the file:

* camera RAW (DNG, NEF, CR2, ARW, ...): demosaiced by LibRaw with the
  camera's white balance, no auto-brightening, 16 bits, linear;
* JPEG, PNG, TIFF (8 or 16 bit): sRGB-decoded;
* EXR and float TIFF: taken as linear.

Grey images are repeated to three channels, alpha is dropped. The networks
take the photo exposed, clipped and encoded as training images are
(:func:`encode_for_network`, through :func:`svbrdf_cli.pipeline.network_input`).
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli.errors import ImageReadError

RAW_EXTENSIONS = frozenset(
    ".dng .nef .nrw .cr2 .cr3 .crw .arw .srf .sr2 .raf .rw2 .orf .pef .srw .gpr .3fr .iiq .erf .kdc .mos "
    ".mrw .x3f .rwl .dcr".split())

#: Largest image read, in pixels (a decompression bomb guard): 200 MP.
MAX_PIXELS = 200_000_000
#: Smallest side read, in pixels (the networks see 256 × 256; a smaller photo is upsampled).
MIN_SIDE = 32


@dataclasses.dataclass
class Photo:
    linear: np.ndarray          # (H, W, 3) float32, linear, >= 0
    path: str
    kind: str                   # "raw", "encoded" or "linear"
    bits: int


def load_photo(path, white_balance=None):
    """Read a photo as linear RGB (see the module docstring).

    Args:
        path: the file.
        white_balance: optional (r, g, b) multipliers applied to the linear image.

    Raises:
        ImageReadError: with a one-line message naming the file and what to do.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise ImageReadError(f"Could not read '{path}': no such file. Check the path.")
    if os.path.getsize(path) == 0:
        raise ImageReadError(f"Could not read '{path}': the file is empty. Copy it from the camera again.")
    ext = os.path.splitext(path)[1].lower()
    photo = _load_raw(path) if ext in RAW_EXTENSIONS else _load_image(path)
    if white_balance is not None:
        photo.linear = photo.linear * np.asarray(white_balance, np.float32).reshape(1, 1, 3)
    return photo


def encode_for_network(linear):
    """Linear RGB -> the clipped, encoded float32 image the networks take."""
    return cv.image_to_encoded(np.asarray(linear, np.float32)).astype(np.float32)


def _load_raw(path):
    import rawpy

    try:
        with rawpy.imread(path) as raw:
            rgb = raw.postprocess(use_camera_wb=True, no_auto_bright=True, output_bps=16, gamma=(1, 1),
                                  output_color=rawpy.ColorSpace.sRGB)
    except (rawpy.LibRawError, OSError, ValueError) as e:
        why = e.args[0] if e.args else ""
        why = (why.decode(errors="replace") if isinstance(why, bytes) else str(why)).strip() or type(e).__name__
        raise ImageReadError(f"Could not decode RAW '{path}': {why}. "
                             "Convert it to DNG or 16-bit TIFF with the camera's software.") from None
    if rgb.ndim != 3 or rgb.shape[-1] != 3:
        raise ImageReadError(f"Could not decode RAW '{path}': got {rgb.shape} instead of RGB. Convert it to TIFF.")
    return Photo(rgb.astype(np.float32) / 65535.0, path, "raw", 16)


def _load_image(path):
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(path)
    if buf.has_error:
        why = (buf.geterror().strip().splitlines() or ["unknown format"])[0]
        raise ImageReadError(f"Could not read '{path}': {why}. "
                             "Use a JPEG, PNG, TIFF, EXR or camera RAW file.")
    spec = buf.spec()
    if spec.width * spec.height > MAX_PIXELS:
        raise ImageReadError(f"Could not read '{path}': {spec.width}x{spec.height} is over "
                             f"{MAX_PIXELS // 1_000_000} MP. Downscale it first.")
    if spec.width < MIN_SIDE or spec.height < MIN_SIDE:
        raise ImageReadError(f"Could not use '{path}': {spec.width}x{spec.height} is too small; "
                             f"use a photo at least {MIN_SIDE} pixels on each side (256 or more for useful maps).")
    if not buf.read(force=True):
        why = (buf.geterror().strip().splitlines() or ["truncated data"])[0]
        raise ImageReadError(f"Could not decode '{path}': {why}. The file may be damaged; export it again.")
    buf = oiio.ImageBufAlgo.reorient(buf)  # EXIF orientation
    pixels = buf.get_pixels(oiio.FLOAT)
    px = np.asarray(pixels, np.float32)
    px = px[..., None] if px.ndim == 2 else px
    c = px.shape[-1]
    px = np.repeat(px[..., :1], 3, -1) if c < 3 else px[..., :3]
    fmt = str(spec.format)
    floating = fmt in ("half", "float", "double")
    bits = {"uint8": 8, "uint16": 16, "half": 16, "float": 32}.get(fmt, 8)
    linear = np.maximum(px, 0.0) if floating else cv.srgb_to_linear(px)
    return Photo(np.ascontiguousarray(linear, dtype=np.float32), path, "linear" if floating else "encoded", bits)
