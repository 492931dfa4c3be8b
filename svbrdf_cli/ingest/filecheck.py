"""Checks of a file's structure before it is decoded: does the data the header promises exist?

Decoders given a file whose data is missing do not always fail: libjpeg and libpng fill the rest with
grey, and LibRaw leaves its raw buffer as it found it (whatever the last decode left in that memory).
These checks read only the file's own structure (TIFF directories, PNG chunks, JPEG markers) and
return a phrase saying what is wrong, or None.
"""

from __future__ import annotations

import mmap
import os
import struct

#: Bytes per value of each TIFF field type (BigTIFF's 8-byte types are not read).
_TIFF_SIZES = {1: 1, 2: 1, 3: 2, 4: 4, 5: 8, 6: 1, 7: 1, 8: 2, 9: 4, 10: 8, 11: 4, 12: 8, 13: 4}
_WIDTH, _HEIGHT, _STRIPS, _STRIP_BYTES, _TILES, _TILE_BYTES, _SUBIFDS, _EXIF = 256, 257, 273, 279, 324, 325, 330, 34665
_COMPRESSION, _ROWS_PER_STRIP, _TILE_WIDTH, _TILE_LENGTH, _SAMPLES = 259, 278, 322, 323, 277
_READ = (_WIDTH, _HEIGHT, _STRIPS, _STRIP_BYTES, _TILES, _TILE_BYTES, _SUBIFDS, _EXIF, _COMPRESSION, _ROWS_PER_STRIP,
         _TILE_WIDTH, _TILE_LENGTH, _SAMPLES)
#: Compressions whose every strip or tile is a JPEG stream (SOI ... EOI): old JPEG, JPEG, lossy DNG.
_JPEG_COMPRESSIONS = (6, 7, 34892)
#: Most directories and values read (a loop or a hostile count ends the walk there).
_MAX_IFDS, _MAX_VALUES = 256, 1 << 22


def _open(path):
    """(file or None, its bytes) of ``path``, mapped; bytes given (the file already read) are used as they are."""
    if isinstance(path, (bytes, bytearray, memoryview)):
        return None, path
    f = open(path, "rb")
    try:
        if os.fstat(f.fileno()).st_size == 0:
            return f, b""
        return f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
    except (OSError, ValueError):
        f.close()
        raise


def tiff_images(path):
    """[(width, height, [(offset, bytes)...], {tag: first value})] of every image directory of a
    TIFF-structured file (DNG, NEF, CR2, ARW ... and TIFF), or None when the file is not TIFF-structured.
    A directory that lies outside the file is an image of size (0, 0) with a chunk (its offset, -1)."""
    f, m = _open(path)
    try:
        return _walk(m)
    finally:
        if isinstance(m, mmap.mmap):
            m.close()
        if f is not None:
            f.close()


def _walk(m):
    if len(m) < 8 or m[:4] not in (b"II*\0", b"MM\0*"):
        return None
    e = "<" if m[:2] == b"II" else ">"
    size = len(m)
    queue, seen, images = [struct.unpack(e + "I", m[4:8])[0]], set(), []
    while queue and len(seen) < _MAX_IFDS:
        off = queue.pop(0)
        if off == 0 or off in seen:
            continue
        seen.add(off)
        if off + 2 > size:
            images.append((0, 0, [(off, -1)], {}))
            continue
        n = struct.unpack(e + "H", m[off:off + 2])[0]
        if off + 2 + 12 * n + 4 > size:
            images.append((0, 0, [(off, -1)], {}))
            continue
        tags = {}
        for i in range(n):
            p = off + 2 + 12 * i
            tag, typ, count = struct.unpack(e + "HHI", m[p:p + 8])
            if tag not in _READ:
                continue
            width = _TIFF_SIZES.get(typ)
            if width is None or count > _MAX_VALUES:
                tags[tag] = None  # unreadable: the decoder judges
                continue
            where = p + 8 if width * count <= 4 else struct.unpack(e + "I", m[p + 8:p + 12])[0]
            if where + width * count > size:
                tags[tag] = "outside"
                continue
            fmt = {1: "B", 3: "H", 4: "I", 13: "I", 6: "b", 8: "h", 9: "i"}.get(typ)
            tags[tag] = list(struct.unpack(f"{e}{count}{fmt}", m[where:where + width * count])) if fmt else None
        queue.extend(v for t in (_SUBIFDS,) if isinstance(tags.get(t), list) for v in tags[t])
        queue.append(struct.unpack(e + "I", m[off + 2 + 12 * n:off + 6 + 12 * n])[0])
        offsets = tags.get(_TILES) if _TILES in tags else tags.get(_STRIPS)
        counts = tags.get(_TILE_BYTES) if _TILES in tags else tags.get(_STRIP_BYTES)
        first = {t: v[0] for t, v in tags.items() if isinstance(v, list) and v}
        w, h = first.get(_WIDTH, 0), first.get(_HEIGHT, 0)
        if offsets == "outside" or counts == "outside":
            images.append((w, h, [(size, -1)], first))
        elif isinstance(offsets, list) and isinstance(counts, list):
            images.append((w, h, list(zip(offsets, counts))
                           + ([(size, -1)] if len(offsets) != len(counts) else []), first))
    return images


def raw_data_problem(path):
    """What is wrong with a TIFF-structured RAW's image data, or None: the largest image's strips or
    tiles must lie inside the file and hold some bytes. (Other RAW formats are not read: None.)"""
    images = tiff_images(path)
    if not images:
        return None
    size = len(path) if isinstance(path, (bytes, bytearray, memoryview)) else os.path.getsize(path)
    w, h, chunks, tags = max(images, key=lambda i: i[0] * i[1])
    if w * h == 0:
        return "its image directory lies past the end of the file" if any(c < 0 for _, c in chunks) else None
    past = sum(1 for o, c in chunks if c < 0 or o + c > size)
    if past:
        return ("its image data lies past the end of the file" if past == len(chunks) else
                f"{past} of its {len(chunks)} blocks of image data lie past the end of the file")
    if not chunks or sum(chunks_bytes for _, chunks_bytes in chunks) == 0:
        return "it holds no image data"
    expected = _chunk_count(w, h, tags)
    if expected and len(chunks) not in (expected, expected * tags.get(_SAMPLES, 1)):
        return (f"its directory's layout ({expected} blocks for {w}x{h}) does not match its "
                f"{len(chunks)} blocks of image data")
    if tags.get(_COMPRESSION) in _JPEG_COMPRESSIONS:
        with open(path, "rb") as f:
            for i, (o, c) in enumerate(chunks):
                f.seek(o)
                head = f.read(2)
                f.seek(max(o, o + c - 16))
                tail = f.read(16)
                if head != b"\xff\xd8" or b"\xff\xd9" not in tail:
                    return f"block {i + 1} of its {len(chunks)} blocks of image data is not where its directory says"
    return None


def _chunk_count(w, h, tags):
    """How many strips or tiles a ``w`` x ``h`` image's directory implies (0: it does not say)."""
    if tags.get(_TILE_WIDTH) and tags.get(_TILE_LENGTH):
        tw, tl = tags[_TILE_WIDTH], tags[_TILE_LENGTH]
        return -(-w // tw) * -(-h // tl)
    rows = tags.get(_ROWS_PER_STRIP)
    return -(-h // rows) if rows and h else 0


#: TIFF tags that hold exactly one value (libtiff ignores such a tag with another count, and decodes
#: wrongly without it: a Predictor ignored leaves every row as differences).
_SINGLE_VALUED = {256: "ImageWidth", 257: "ImageLength", 259: "Compression", 262: "PhotometricInterpretation",
                  266: "FillOrder", 274: "Orientation", 277: "SamplesPerPixel", 278: "RowsPerStrip",
                  284: "PlanarConfiguration", 317: "Predictor", 322: "TileWidth", 323: "TileLength"}


def tiff_problem(path):
    """What is wrong with a TIFF-structured file's first directory or image data, or None: a tag that
    holds one value with another count, a Predictor other than 1-3, then :func:`raw_data_problem`."""
    f, m = _open(path)
    try:
        if len(m) < 8 or m[:4] not in (b"II*\0", b"MM\0*"):
            return None
        e = "<" if m[:2] == b"II" else ">"
        off = struct.unpack(e + "I", m[4:8])[0]
        if off + 2 > len(m):
            return "its image directory lies past the end of the file"
        n = struct.unpack(e + "H", m[off:off + 2])[0]
        if off + 2 + 12 * n > len(m):
            return "its image directory lies past the end of the file"
        for i in range(n):
            p = off + 2 + 12 * i
            tag, typ, count = struct.unpack(e + "HHI", m[p:p + 8])
            if tag in _SINGLE_VALUED and count != 1:
                return f"its {_SINGLE_VALUED[tag]} tag holds {count} values instead of 1"
            if tag == 317 and typ == 3:
                predictor = struct.unpack(e + "H", m[p + 8:p + 10])[0]
                if predictor not in (1, 2, 3):
                    return f"its Predictor is {predictor} (1, 2 or 3 exist)"
    finally:
        if isinstance(m, mmap.mmap):
            m.close()
        if f is not None:
            f.close()
    return raw_data_problem(path)


def png_problem(path):
    """What is wrong with a PNG's chunk structure, or None; and how many bytes follow its IEND chunk."""
    f, m = _open(path)
    try:
        size, pos, seen_idat = len(m), 8, False
        if m[:8] != b"\x89PNG\r\n\x1a\n":
            return None, 0
        while True:
            if pos + 8 > size:
                return "the file is truncated (its end is missing)", 0
            length = struct.unpack(">I", m[pos:pos + 4])[0]
            kind = bytes(m[pos + 4:pos + 8])
            if length > 0x7FFFFFFF or not kind.isalpha():
                return f"its chunk at byte {pos} is damaged", 0
            end = pos + 12 + length
            if end > size:
                return "the file is truncated (its end is missing)", 0
            seen_idat = seen_idat or kind == b"IDAT"
            if kind == b"IEND":
                return (None if seen_idat else "it holds no image data"), size - end
            pos = end
    finally:
        if isinstance(m, mmap.mmap):
            m.close()
        if f is not None:
            f.close()


def jpeg_truncated(path):
    """Whether a JPEG ends before its image does: no EOI marker after the last scan."""
    f, m = _open(path)
    try:
        sos = m.rfind(b"\xff\xda") if m else -1
        return sos < 0 or m.find(b"\xff\xd9", sos) < 0
    finally:
        if isinstance(m, mmap.mmap):
            m.close()
        if f is not None:
            f.close()
