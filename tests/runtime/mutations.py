"""Small valid photos of every accepted format, and seeded mutations of them (for test_fuzz.py and
test_corrupt_inputs.py). Everything is made here; nothing is downloaded.

Seeds are 64-128 px flash-like photos: JPEG (baseline, progressive, grey), PNG (8 and 16 bit, RGBA
opaque, grey), TIFF (8, 16 bit, float), EXR (half), WebP, and a minimal DNG (16-bit Bayer, uncompressed)
that LibRaw decodes. :func:`mutate` applies one named mutation with a seeded random generator and
returns the new bytes and the file name (extension) to write them under.
"""

import os
import struct
import zlib

import numpy as np


def flash(h, w, seed=0):
    """A flash-like photo in [0, 1]: a textured base and a highlight near the centre."""
    y, x = np.mgrid[0:h, 0:w]
    rng = np.random.default_rng(seed)
    base = rng.uniform(0.2, 0.5, 3) * (0.8 + 0.2 * np.sin(x / 5.0 + rng.uniform(0, 6))[..., None])
    base = base * (0.9 + 0.1 * np.cos(y / 7.0)[..., None])
    hl = np.exp(-((x - w / 2) ** 2 + (y - h / 2) ** 2) / (2 * (0.15 * w) ** 2))[..., None]
    return np.clip(base + 0.6 * hl, 0, 1).astype(np.float32)


def _oiio(path, pixels, fmt="uint8", **attrs):
    import OpenImageIO as oiio

    a = np.ascontiguousarray(pixels, np.float32)
    spec = oiio.ImageSpec(a.shape[1], a.shape[0], a.shape[2], fmt)
    for k, v in attrs.items():
        spec.attribute(k.replace("__", ":"), v)
    out = oiio.ImageOutput.create(path)
    assert out is not None and out.open(path, spec) and out.write_image(a), oiio.geterror()
    out.close()


def _cv_jpeg(pixels, progressive=False, quality=90):
    import cv2

    u8 = (np.clip(pixels, 0, 1) * 255 + 0.5).astype(np.uint8)
    u8 = u8[..., ::-1] if u8.ndim == 3 else u8
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(u8),
                           [cv2.IMWRITE_JPEG_QUALITY, quality, cv2.IMWRITE_JPEG_PROGRESSIVE, int(progressive)])
    assert ok
    return buf.tobytes()


def tiny_dng(h=96, w=128, seed=0):
    """A minimal DNG: uncompressed 16-bit RGGB Bayer data, one IFD, identity colour matrix."""
    rgb = flash(h, w, seed)
    cfa = np.empty((h, w), np.float32)
    cfa[0::2, 0::2], cfa[0::2, 1::2] = rgb[0::2, 0::2, 0], rgb[0::2, 1::2, 1]
    cfa[1::2, 0::2], cfa[1::2, 1::2] = rgb[1::2, 0::2, 1], rgb[1::2, 1::2, 2]
    data = (cfa * 40000 + 1000).astype("<u2").tobytes()
    fmt = {1: "B", 3: "H", 4: "I", 5: "I", 10: "i"}
    entries = [(254, 4, [0]), (256, 4, [w]), (257, 4, [h]), (258, 3, [16]), (259, 3, [1]), (262, 3, [32803]),
               (271, 2, b"svbrdf\0"), (272, 2, b"fuzz seed\0"), (273, 4, [0]), (277, 3, [1]), (278, 4, [h]),
               (279, 4, [len(data)]), (284, 3, [1]), (33421, 3, [2, 2]), (33422, 1, [0, 1, 1, 2]),
               (50706, 1, [1, 4, 0, 0]), (50708, 2, b"svbrdf fuzz seed\0"), (50714, 4, [1000]),
               (50717, 4, [61000]), (50721, 10, [1, 1, 0, 1, 0, 1, 0, 1, 1, 1, 0, 1, 0, 1, 0, 1, 1, 1]),
               (50728, 5, [1, 1, 1, 1, 1, 1]), (50778, 3, [21])]
    ifd = bytearray(struct.pack("<H", len(entries)))
    extra_at = 8 + 2 + 12 * len(entries) + 4
    extra = bytearray()
    for tag, typ, vals in entries:
        if typ == 2:
            count, raw = len(vals), bytes(vals)
        elif typ in (5, 10):
            count, raw = len(vals) // 2, struct.pack(f"<{len(vals)}{fmt[typ]}", *vals)
        else:
            count, raw = len(vals), struct.pack(f"<{len(vals)}{fmt[typ]}", *vals)
        if len(raw) <= 4:
            value = raw.ljust(4, b"\0")
        else:
            value = struct.pack("<I", extra_at + len(extra))
            extra += raw + (b"\0" if len(raw) % 2 else b"")
        ifd += struct.pack("<HHI", tag, typ, count) + value
    ifd += struct.pack("<I", 0)
    out = bytearray(b"II*\0" + struct.pack("<I", 8)) + ifd + extra
    i = out.find(struct.pack("<HHI", 273, 4, 1))
    out[i + 8:i + 12] = struct.pack("<I", len(out))
    return bytes(out + data)


def make_seeds(folder):
    """Write the seeds into ``folder``; returns {file name: bytes}."""
    os.makedirs(folder, exist_ok=True)
    seeds = {}
    seeds["base.jpg"] = _cv_jpeg(flash(96, 128, 1))
    seeds["prog.jpg"] = _cv_jpeg(flash(112, 96, 2), progressive=True)
    seeds["grey.jpg"] = _cv_jpeg(flash(80, 120, 3).mean(-1))
    for name, pixels, fmt in (("rgb8.png", flash(96, 128, 4), "uint8"), ("rgb16.png", flash(72, 96, 5), "uint16"),
                              ("rgba.png", np.concatenate([flash(96, 96, 6), np.ones((96, 96, 1), np.float32)], -1),
                               "uint8"),
                              ("greyp.png", flash(96, 112, 7).mean(-1, keepdims=True), "uint8"),
                              ("t8.tif", flash(80, 96, 8), "uint8"), ("t16.tif", flash(96, 80, 9), "uint16"),
                              ("tf.tif", flash(64, 96, 10) ** 2.2, "float"), ("h.exr", flash(96, 96, 11) ** 2.2, "half"),
                              ("w.webp", flash(96, 128, 12), "uint8")):
        path = os.path.join(folder, name)
        _oiio(path, pixels, fmt)
        with open(path, "rb") as f:
            seeds[name] = f.read()
    seeds["raw.dng"] = tiny_dng(96, 128, 13)
    for name, data in seeds.items():
        with open(os.path.join(folder, name), "wb") as f:
            f.write(data)
    return seeds


# --------------------------------------------------------------------------
# Structure: PNG chunks, JPEG segments, TIFF entries
# --------------------------------------------------------------------------

def png_chunks(data):
    """[(start, end, type)] of a PNG's chunks (as far as they parse)."""
    out, pos = [], 8
    while pos + 12 <= len(data):
        n = struct.unpack(">I", data[pos:pos + 4])[0]
        end = pos + 12 + n
        if end > len(data):
            break
        out.append((pos, end, data[pos + 4:pos + 8]))
        pos = end
    return out


def png_fix_crc(data, start):
    """``data`` (bytearray) with the CRC of the chunk at ``start`` recomputed."""
    n = struct.unpack(">I", data[start:start + 4])[0]
    body = bytes(data[start + 4:start + 8 + n])
    data[start + 8 + n:start + 12 + n] = struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)
    return data


def jpeg_segments(data):
    """[(start, end, marker)] of a JPEG's marker segments; a scan runs to the next marker (not RSTn)."""
    out, pos = [], 2
    while pos + 4 <= len(data) and data[pos] == 0xFF:
        marker = data[pos + 1]
        if marker == 0xD9:
            out.append((pos, pos + 2, marker))
            break
        n = struct.unpack(">H", data[pos + 2:pos + 4])[0]
        end = pos + 2 + n
        if marker == 0xDA:  # entropy-coded data follows, up to the next non-RST marker
            i = end
            while i + 1 < len(data) and not (data[i] == 0xFF and data[i + 1] not in (0, *range(0xD0, 0xD8))):
                i += 1
            end = i
        out.append((pos, end, marker))
        pos = end
    return out


def tiff_entries(data):
    """[(entry offset, tag, type, count)] of a TIFF's first IFD (little or big endian)."""
    if data[:4] not in (b"II*\0", b"MM\0*"):
        return [], "<"
    e = "<" if data[:2] == b"II" else ">"
    off = struct.unpack(e + "I", data[4:8])[0]
    if off + 2 > len(data):
        return [], e
    n = struct.unpack(e + "H", data[off:off + 2])[0]
    out = []
    for i in range(n):
        p = off + 2 + 12 * i
        if p + 12 > len(data):
            break
        tag, typ, count = struct.unpack(e + "HHI", data[p:p + 8])
        out.append((p, tag, typ, count))
    return out, e


# --------------------------------------------------------------------------
# Mutations: (rng, data, name, seeds) -> (bytes, name)
# --------------------------------------------------------------------------

def _bitflip(rng, data, name, seeds):
    d = bytearray(data)
    for _ in range(int(rng.integers(1, 9))):
        i = int(rng.integers(0, len(d)))
        d[i] ^= 1 << int(rng.integers(0, 8))
    return bytes(d), name


def _bytes_random(rng, data, name, seeds):
    d = bytearray(data)
    i = int(rng.integers(0, len(d)))
    n = int(rng.integers(1, 64))
    d[i:i + n] = rng.integers(0, 256, len(d[i:i + n]), dtype=np.uint8).tobytes()
    return bytes(d), name


def _truncate(rng, data, name, seeds):
    return data[: int(len(data) * rng.uniform(0.02, 0.995))], name


def _cut_middle(rng, data, name, seeds):
    a = int(len(data) * rng.uniform(0.05, 0.5))
    b = int(a + (len(data) - a) * rng.uniform(0.1, 0.9))
    return data[:a] + data[b:], name


def _insert(rng, data, name, seeds):
    i = int(rng.integers(0, len(data)))
    n = int(rng.integers(1, 4096))
    blob = bytes(n) if rng.random() < 0.5 else rng.integers(0, 256, n, dtype=np.uint8).tobytes()
    return data[:i] + blob + data[i:], name


def _append(rng, data, name, seeds):
    return data + rng.integers(0, 256, int(rng.integers(1, 5000)), dtype=np.uint8).tobytes(), name


def _segments(data):
    if data[:8] == b"\x89PNG\r\n\x1a\n":
        return png_chunks(data)
    if data[:2] == b"\xff\xd8":
        return jpeg_segments(data)
    return []


def _delete_segment(rng, data, name, seeds):
    segs = _segments(data)
    if not segs:
        return _cut_middle(rng, data, name, seeds)
    a, b, _ = segs[int(rng.integers(0, len(segs)))]
    return data[:a] + data[b:], name


def _duplicate_segment(rng, data, name, seeds):
    segs = _segments(data)
    if not segs:
        i, n = int(rng.integers(0, len(data))), int(rng.integers(16, 2048))
        return data[:i + n] + data[i:i + n] + data[i + n:], name
    a, b, _ = segs[int(rng.integers(0, len(segs)))]
    return data[:b] + data[a:b] + data[b:], name


_HUGE = (0, 1, 0x7FFF, 0xFFFF, 0x7FFFFFFF, 0xFFFFFFFF, 0x80000000)


def _header_field(rng, data, name, seeds):
    """A header number set to 0, huge or negative (PNG IHDR with its CRC fixed, JPEG SOF, TIFF entries)."""
    d = bytearray(data)
    value = int(_HUGE[int(rng.integers(0, len(_HUGE)))]) if rng.random() < 0.7 else int(rng.integers(0, 1 << 16))
    if d[:8] == b"\x89PNG\r\n\x1a\n":
        field = int(rng.integers(0, 7))  # width, height, bit depth, colour type, compression, filter, interlace
        if field < 2:
            d[16 + 4 * field:20 + 4 * field] = struct.pack(">I", value & 0xFFFFFFFF)
        else:
            d[24 + field - 2] = value & 0xFF
        return bytes(png_fix_crc(d, 8)), name
    if d[:2] == b"\xff\xd8":
        sofs = [s for s in jpeg_segments(data) if s[2] in (0xC0, 0xC1, 0xC2)]
        targets = [(s[0] + 5, 2) for s in sofs] + [(s[0] + 7, 2) for s in sofs] + [(s[0] + 4, 1) for s in sofs] \
            + [(s[0] + 9, 1) for s in sofs]
        if targets:
            at, n = targets[int(rng.integers(0, len(targets)))]
            d[at:at + n] = (value & (0xFFFF if n == 2 else 0xFF)).to_bytes(n, "big")
            return bytes(d), name
    entries, e = tiff_entries(data)
    if entries:
        p, tag, typ, count = entries[int(rng.integers(0, len(entries)))]
        if rng.random() < 0.3:
            d[p + 4:p + 8] = struct.pack(e + "I", value & 0xFFFFFFFF)  # the count
        elif typ == 3 and count == 1:
            d[p + 8:p + 10] = struct.pack(e + "H", value & 0xFFFF)
        else:
            d[p + 8:p + 12] = struct.pack(e + "I", value & 0xFFFFFFFF)
        return bytes(d), name
    return _bytes_random(rng, data, name, seeds)


_EXTENSIONS = (".jpg", ".png", ".tif", ".exr", ".webp", ".dng", ".nef", ".jpeg", "")


def _wrong_extension(rng, data, name, seeds):
    stem, ext = os.path.splitext(name)
    others = [x for x in _EXTENSIONS if x != ext]
    return data, stem + others[int(rng.integers(0, len(others)))]


def _splice(rng, data, name, seeds):
    other = seeds[sorted(seeds)[int(rng.integers(0, len(seeds)))]]
    a = int(len(data) * rng.uniform(0.05, 0.95))
    b = int(len(other) * rng.uniform(0.05, 0.95))
    return data[:a] + other[b:], name


MUTATIONS = {"bitflip": _bitflip, "bytes": _bytes_random, "truncate": _truncate, "cut_middle": _cut_middle,
             "insert": _insert, "append": _append, "delete_segment": _delete_segment,
             "duplicate_segment": _duplicate_segment, "header_field": _header_field,
             "wrong_extension": _wrong_extension, "splice": _splice}


def mutate(seeds, index, base_seed=0):
    """The ``index``-th mutant: (file name, bytes, seed name, mutation name), the same for the same arguments."""
    rng = np.random.default_rng([base_seed, index])
    names = sorted(seeds)
    seed = names[index % len(names)]
    kind = sorted(MUTATIONS)[int(rng.integers(0, len(MUTATIONS)))]
    data, fname = MUTATIONS[kind](rng, seeds[seed], seed, seeds)
    if rng.random() < 0.15 and kind != "wrong_extension":  # some mutants also carry a wrong extension
        data, fname = _wrong_extension(rng, data, fname, seeds)
    stem, ext = os.path.splitext(fname)
    return f"m{index:05d}_{kind}_{stem}{ext}", data, seed, kind
