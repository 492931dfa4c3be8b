"""Records of the maps ``svbrdf capture`` writes: checksums, to show a change leaves the output bit for
bit, and the bundled sample's maps, to show it stays the same within rounding whatever kernels the CPU gets.

``record`` and ``check`` run ``svbrdf capture`` with default options (one process per photo, as a user
would) on the bundled sample ``examples/glazed_tiles.jpg`` and on every Des19 validation photo in
``../shared/data/validation/des19/*/input.png``, and take the sha256 of every image file written
(``material.json`` and ``texture_set.json`` hold a date and paths, so they are left out). The sums hold
on the machine that recorded them: onnxruntime and OpenBLAS choose their kernels by the CPU's
instruction set (AVX-512, AVX2, ...), and another choice moves the last bits of the maps.

``record-sample`` runs the same default capture of the bundled sample and keeps each of its four maps
(:data:`MAPS`) as the sums of its integer levels over 4x4 blocks (:func:`block_sums`) in
``tests/data/sample_maps.npz``; ``tests/runtime/run/test_sample_maps.py`` requires every capture to
stay within :data:`MEAN_LEVELS` and :data:`MAX_LEVELS` of it (:func:`sample_differences`,
:func:`beyond_rounding`).

    python tests/checksums.py record          # write tests/data/checksums.json
    python tests/checksums.py check           # compare against it; exit 1 on any difference
    python tests/checksums.py record-sample   # write tests/data/sample_maps.npz

``record`` and ``check`` take about two minutes on one core, ``record-sample`` a few seconds.
``svbrdf`` is the one next to the running Python.
"""

import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

from svbrdf_cli.conventions import MAP_NAMES

ROOT = Path(__file__).resolve().parent.parent
SHARED = Path(os.environ.get("SVBRDF_SHARED", ROOT.parent / "shared"))
RECORD = ROOT / "tests" / "data" / "checksums.json"
IMAGES = (".png", ".exr", ".tif", ".tiff", ".jpg")
SAMPLE = ROOT / "examples" / "glazed_tiles.jpg"
SAMPLE_RECORD = ROOT / "tests" / "data" / "sample_maps.npz"
#: The maps of the bundled sample's set that ``record-sample`` keeps (``<map>.png``, 8 bits).
MAPS = MAP_NAMES
#: The side of the square blocks whose level sums are kept.
BLOCK = 4
#: Within rounding: per map, the mean absolute difference of the block sums in levels per pixel (the
#: sums' difference over BLOCK**2) at most MEAN_LEVELS, a block's at most MAX_LEVELS. Other kernels
#: (OpenBLAS's SSE ones, onnxruntime without its graph optimisations) move the sample's maps by at most
#: 0.0035 and 1.75; one refinement step fewer (``--refine 29``) by 0.03-0.38 on average (at most 1.81 in a
#: block: the mean is what tells a change from rounding, the block's limit only catches a local one).
MEAN_LEVELS = 0.015
MAX_LEVELS = 4.0


def photos():
    """{name: photo path}: the bundled sample, then each Des19 photo present."""
    found = {"glazed_tiles": SAMPLE}
    des19 = SHARED / "data" / "validation" / "des19"
    for d in sorted(des19.glob("*/input.png")) if des19.is_dir() else []:
        found[f"des19/{d.parent.name}"] = d
    return found


def capture(photo, out):
    """sha256 of every image file ``svbrdf capture photo -o out`` writes, by relative path."""
    _capture(photo, out)
    sums = {}
    for f in sorted(Path(out).rglob("*")):
        if f.is_file() and f.suffix.lower() in IMAGES:
            sums[f.relative_to(out).as_posix()] = hashlib.sha256(f.read_bytes()).hexdigest()
    return sums


def _capture(photo, out):
    """Run ``svbrdf capture photo -o out`` with default options."""
    exe = Path(sys.executable).with_name("svbrdf")
    subprocess.run([str(exe), "capture", str(photo), "-o", str(out)], check=True, capture_output=True)


def block_sums(path):
    """The 8-bit map file ``path`` as the sums of its integer levels over BLOCK x BLOCK blocks:
    (h / BLOCK, w / BLOCK, channels) uint16, channels in RGB(A) order."""
    a = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if a is None or a.dtype != np.uint8 or a.shape[0] % BLOCK or a.shape[1] % BLOCK:
        raise ValueError(f"{path}: not an 8-bit image whose sides are multiples of {BLOCK}")
    if a.ndim == 2:
        a = a[..., None]
    elif a.shape[2] >= 3:  # OpenCV's BGR(A)
        a = np.concatenate([a[..., 2::-1], a[..., 3:]], axis=2)
    h, w, c = a.shape
    return a.reshape(h // BLOCK, BLOCK, w // BLOCK, BLOCK, c).sum((1, 3), dtype=np.uint32).astype(np.uint16)


def sample_differences(folder, record=SAMPLE_RECORD):
    """{map: (mean, max)}: the absolute differences between the block sums of ``folder/<map>.png``
    and the recorded ones, in levels per pixel (the sums' difference over BLOCK**2); (inf, inf) for a
    map whose blocks are not the recorded ones' shape."""
    then = np.load(record)
    out = {}
    for m in MAPS:
        now, was = block_sums(Path(folder) / f"{m}.png"), then[m]
        if now.shape != was.shape:
            out[m] = (float("inf"), float("inf"))
            continue
        d = np.abs(now.astype(np.int32) - was.astype(np.int32)) / BLOCK ** 2
        out[m] = (float(d.mean()), float(d.max()))
    return out


def beyond_rounding(differences):
    """The maps of :func:`sample_differences`' answer beyond MEAN_LEVELS or MAX_LEVELS."""
    return [m for m, (mean, top) in differences.items() if mean > MEAN_LEVELS or top > MAX_LEVELS]


def record_sample():
    """Capture the bundled sample with default options and write its block sums to SAMPLE_RECORD."""
    with tempfile.TemporaryDirectory() as tmp:
        _capture(SAMPLE, tmp)
        sums = {m: block_sums(Path(tmp) / SAMPLE.stem / f"{m}.png") for m in MAPS}
    np.savez_compressed(SAMPLE_RECORD, **sums)
    return sums


def measure():
    """{photo name: {file: sha256}} for every photo present."""
    result = {}
    with tempfile.TemporaryDirectory() as tmp:
        for i, (name, photo) in enumerate(photos().items()):
            result[name] = capture(photo, Path(tmp) / str(i))
    return result


def main(argv):
    if len(argv) != 2 or argv[1] not in ("record", "check", "record-sample"):
        sys.exit(__doc__)
    if argv[1] == "record-sample":
        sums = record_sample()
        print(f"{len(sums)} maps of {SAMPLE.name} recorded in {SAMPLE_RECORD} ({SAMPLE_RECORD.stat().st_size} bytes)")
        return 0
    now = measure()
    if argv[1] == "record":
        RECORD.write_text(json.dumps(now, indent=1, sort_keys=True) + "\n")
        print(f"{sum(map(len, now.values()))} files of {len(now)} photos recorded in {RECORD}")
        return 0
    then = json.loads(RECORD.read_text())
    bad = [f"{n}: {f}" for n in now for f in sorted(set(now[n]) | set(then.get(n, {})))
           if now[n].get(f) != then.get(n, {}).get(f)]
    missing = sorted(set(then) - set(now))
    print(f"{sum(map(len, now.values())) - len(bad)} of {sum(map(len, now.values()))} files identical"
          f" ({len(now)} photos; {len(missing)} recorded photos absent here)")
    for line in bad:
        print("differs:", line)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
