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
#: zlib level of the PNGs we write without ISA-L (and OpenImageIO's, for what it writes): 1 writes a
#: 1024² map in 128 ms against 202 ms at OpenImageIO's default (6), for files 3% larger.
PNG_COMPRESSION = 1
#: PNGs are written here, not by a library: every row filtered with Up (its difference from the row
#: above; libpng's adaptive choice among the five filters, what OpenImageIO asks for, costs more than
#: the compression at level 1) and deflated by ISA-L (the ``isal`` package) at its level 1, else by
#: zlib at :data:`PNG_COMPRESSION`. A set of four 2048² maps: 0.07 s of compression against 1.2 s
#: through OpenImageIO, in files 6-12% smaller or 2-5% larger (docs/capture.md, "Writing").
ISAL_LEVEL = 1
#: What OpenImageIO writes before the image data of a colour PNG: sRGB (intent absolute colorimetric),
#: gAMA 1/2.2 and the sRGB cHRM, for readers that ignore the sRGB chunk.
_SRGB_CHUNKS = ((b"sRGB", b"\x03"), (b"gAMA", (45455).to_bytes(4, "big")),
                (b"cHRM", b"".join(v.to_bytes(4, "big") for v in (31270, 32900, 64000, 33000, 30000, 60000,
                                                                   15000, 6000))))


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
    bits, colour), on ``workers`` threads (the encoders hold the GIL little). ``pixels`` may be a
    function of no arguments that makes them (a preview), called on the worker thread, so that it is
    made while other images are encoded: put such jobs first. Every job is finished before the first
    failure, if any, is raised."""
    import concurrent.futures

    if len(jobs) < 2 or workers < 2:
        for job in jobs:
            _write_job(*job)
        return
    with concurrent.futures.ThreadPoolExecutor(max_workers=workers) as pool:
        futures = [pool.submit(_write_job, *job) for job in jobs]
    for f in futures:
        f.result()


def _write_job(path, pixels, *args):
    write_image(path, pixels() if callable(pixels) else pixels, *args)


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
    path = os.fspath(path)
    a = np.asarray(pixels, dtype=np.float32)
    if a.ndim == 2:
        a = a[..., None]
    folder = os.path.dirname(os.path.abspath(path))
    ext = os.path.splitext(path)[1]
    encoded = _encode_png(a, bits, colour) if ext.lower() == ".png" else None
    if encoded is None:
        if bits != 32:
            a = a.clip(0.0, 1.0)
        a = np.ascontiguousarray(a)  # OpenImageIO rejects strided views
    h, w, c = a.shape
    try:
        fd, tmp = tempfile.mkstemp(prefix=".svbrdf-", suffix=ext, dir=folder)
    except OSError as e:
        raise ImageWriteError(f"Could not write '{path}': {e.strerror} ('{folder}'). "
                              "Check that the folder exists and is writable.") from None
    try:
        if encoded is not None:
            try:
                with os.fdopen(fd, "wb") as f:
                    fd = None
                    f.write(encoded)
            except OSError as e:
                raise ImageWriteError(f"Could not write '{path}': {e.strerror}. Check the free space.") from None
            os.chmod(tmp, 0o666 & ~umask())
            os.replace(tmp, path)
            return
        os.close(fd)
        fd = None
        import OpenImageIO as oiio

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
        if fd is not None:
            os.close(fd)
        if os.path.exists(tmp):
            os.unlink(tmp)


def _png_chunk(kind, body):
    import zlib

    return len(body).to_bytes(4, "big") + kind + body + zlib.crc32(body, zlib.crc32(kind)).to_bytes(4, "big")


def _deflate(data):
    """Zlib stream of ``data`` (a buffer): ISA-L's when installed (five times zlib's speed)."""
    try:
        from isal import isal_zlib
    except ImportError:
        import zlib

        return zlib.compress(data, PNG_COMPRESSION)
    return isal_zlib.compress(data, ISAL_LEVEL)


def _encode_png(a, bits, colour):
    """(H, W, C) float32, clipped to [0, 1] here -> PNG file bytes (8 or 16 bits, C = 1 to 4), or None where the
    samples are not finite (OpenImageIO writes those). Samples are rounded as OpenImageIO rounds them
    (to nearest, ties to even), so the pixels are the same whichever writes them; colour images carry
    the sRGB chunks."""
    if bits not in (8, 16) or not 1 <= a.shape[-1] <= 4:
        return None
    h, w, c = a.shape
    top = np.float32(255.0 if bits == 8 else 65535.0)
    q = a * top  # clipped after scaling: the same numbers as scaling the clipped image
    np.clip(q, np.float32(0.0), top, out=q)
    if not np.isfinite(q.sum()):
        return None
    q = np.rint(q, out=q).astype(np.uint8 if bits == 8 else ">u2")
    rows = q.reshape(h, -1).view(np.uint8)  # big-endian samples as PNG stores them
    filtered = np.empty((h, rows.shape[1] + 1), np.uint8)
    filtered[:, 0] = 2  # filter type Up: each byte less the one above (mod 256)
    filtered[0, 1:] = rows[0]
    np.subtract(rows[1:], rows[:-1], out=filtered[1:, 1:])
    colour_type = {1: 0, 2: 4, 3: 2, 4: 6}[c]
    head = _png_chunk(b"IHDR", w.to_bytes(4, "big") + h.to_bytes(4, "big") + bytes([bits, colour_type, 0, 0, 0]))
    tags = b"".join(_png_chunk(k, v) for k, v in _SRGB_CHUNKS) if colour else b""
    return (b"\x89PNG\r\n\x1a\n" + head + tags + _png_chunk(b"IDAT", _deflate(filtered))
            + _png_chunk(b"IEND", b""))
