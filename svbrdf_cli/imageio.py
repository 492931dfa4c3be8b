"""Reading and writing images through OpenImageIO.

Arrays are HWC float32 in [0, 1] in whatever encoding the file holds; callers
decide the colour space with :mod:`svbrdf_cli.conventions`. Writes go to a
temporary file in the target folder and are renamed into place, so a failed
write never leaves a half-written image behind.
"""

from __future__ import annotations

import os
import tempfile

import numpy as np

from svbrdf_cli.errors import ImageReadError, ImageWriteError

_FORMATS = {8: "uint8", 16: "uint16", 32: "float"}
#: zlib level of the PNGs we write: 1 writes a 1024² map in 128 ms against 202 ms at OpenImageIO's
#: default (6), for files 3% larger (measured on a textured 8-bit map; docs/capture.md).
PNG_COMPRESSION = 1


def umask() -> int:
    """The process umask (read without changing it), for files made by mkstemp/mkdtemp."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def read_image(path):
    """Read an image file.

    Args:
        path: file path (anything OpenImageIO reads: PNG, JPEG, TIFF, EXR, ...).

    Returns:
        (H, W, C) float32 array; integer formats scaled to [0, 1]. Grey images
        have C = 1.

    Raises:
        ImageReadError: the file is missing or cannot be decoded.
    """
    import OpenImageIO as oiio

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise ImageReadError(f"Could not read '{path}': no such file. Check the path.")
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)  # a 4th channel is data, never premultiplied
    inp = oiio.ImageInput.open(path, config)
    if inp is None:
        raise ImageReadError(f"Could not read '{path}': {oiio.geterror().strip() or 'unknown format'}. "
                             "Convert it to PNG, TIFF or EXR.")
    try:
        spec = inp.spec()
        pixels = inp.read_image(0, 0, 0, spec.nchannels, "float")
    finally:
        inp.close()
    if pixels is None:
        raise ImageReadError(f"Could not decode '{path}': {oiio.geterror().strip()}. The file may be damaged.")
    pixels = np.asarray(pixels, dtype=np.float32)
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    return pixels


def write_images(jobs, workers=2):
    """Write several images at once, ``jobs`` a list of ``write_image`` argument tuples (path, pixels,
    bits, colour), on ``workers`` threads (OpenImageIO encodes without holding the GIL). Every job is
    finished before the first failure, if any, is raised."""
    import concurrent.futures

    if len(jobs) < 2 or workers < 2:
        for job in jobs:
            write_image(*job)
        return
    with concurrent.futures.ThreadPoolExecutor(max_workers=workers) as pool:
        futures = [pool.submit(write_image, *job) for job in jobs]
    for f in futures:
        f.result()


def write_image(path, pixels, bits=8, colour=True):
    """Write an image atomically.

    Args:
        path: target file; the extension chooses the format.
        pixels: (H, W) or (H, W, C) float array in [0, 1] (clipped for
            integer formats).
        bits: 8 or 16 for integer formats, 32 for float (EXR/TIFF).
        colour: an sRGB-encoded colour image (PNG: sRGB chunk); False for
            data (normals, roughness, masks, height), written untagged so
            that no viewer or engine applies a colour transform to it.

    Raises:
        ImageWriteError: the image could not be written.
    """
    import OpenImageIO as oiio

    path = os.fspath(path)
    a = np.asarray(pixels, dtype=np.float32)
    if a.ndim == 2:
        a = a[..., None]
    if bits != 32:
        a = a.clip(0.0, 1.0)
    a = np.ascontiguousarray(a)  # OpenImageIO rejects strided views
    h, w, c = a.shape
    folder = os.path.dirname(os.path.abspath(path))
    ext = os.path.splitext(path)[1]
    try:
        fd, tmp = tempfile.mkstemp(prefix=".svbrdf-", suffix=ext, dir=folder)
    except OSError as e:
        raise ImageWriteError(f"Could not write '{path}': {e.strerror} ('{folder}'). "
                              "Check that the folder exists and is writable.") from None
    os.close(fd)
    try:
        out = oiio.ImageOutput.create(tmp)
        if out is None:
            raise ImageWriteError(f"Could not write '{path}': no writer for '{ext}'. Use .png, .tif or .exr.")
        spec = oiio.ImageSpec(w, h, c, _FORMATS[bits])
        # RGBA in memory is written as given: OpenImageIO would otherwise
        # treat it as premultiplied and divide by alpha (a mask map's A is data).
        spec.attribute("oiio:UnassociatedAlpha", 1)
        if not colour:
            spec.attribute("oiio:ColorSpace", "Raw")  # PNG: no sRGB, gAMA or cHRM chunk
        spec.attribute("png:compressionLevel", PNG_COMPRESSION)
        ok = out.open(tmp, spec) and out.write_image(a)
        out.close()
        if not ok:
            raise ImageWriteError(f"Could not write '{path}': {oiio.geterror().strip()}.")
        # mkstemp creates 0600 files; give the result the mode a plain open() would.
        os.chmod(tmp, 0o666 & ~umask())
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
