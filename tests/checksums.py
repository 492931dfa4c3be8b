"""Checksums of the maps ``svbrdf capture`` writes, to show a change leaves the output bit for bit.

Runs ``svbrdf capture`` with default options (one process per photo, as a user would) on the bundled
sample ``examples/glazed_tiles.jpg`` and on every Des19 validation photo in
``../shared/data/validation/des19/*/input.png``, and takes the sha256 of every image file written
(``material.json`` and ``texture_set.json`` hold a date and paths, so they are left out).

    python tests/checksums.py record   # write tests/data/checksums.json
    python tests/checksums.py check    # compare against it; exit 1 on any difference

Takes about two minutes on one core. ``svbrdf`` is the one next to the running Python.
"""

import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SHARED = Path(os.environ.get("SVBRDF_SHARED", ROOT.parent / "shared"))
RECORD = ROOT / "tests" / "data" / "checksums.json"
IMAGES = (".png", ".exr", ".tif", ".tiff", ".jpg")


def photos():
    """{name: photo path}: the bundled sample, then each Des19 photo present."""
    found = {"glazed_tiles": ROOT / "examples" / "glazed_tiles.jpg"}
    des19 = SHARED / "data" / "validation" / "des19"
    for d in sorted(des19.glob("*/input.png")) if des19.is_dir() else []:
        found[f"des19/{d.parent.name}"] = d
    return found


def capture(photo, out):
    """sha256 of every image file ``svbrdf capture photo -o out`` writes, by relative path."""
    exe = Path(sys.executable).with_name("svbrdf")
    subprocess.run([str(exe), "capture", str(photo), "-o", str(out)], check=True, capture_output=True)
    sums = {}
    for f in sorted(Path(out).rglob("*")):
        if f.is_file() and f.suffix.lower() in IMAGES:
            sums[f.relative_to(out).as_posix()] = hashlib.sha256(f.read_bytes()).hexdigest()
    return sums


def measure():
    """{photo name: {file: sha256}} for every photo present."""
    result = {}
    with tempfile.TemporaryDirectory() as tmp:
        for i, (name, photo) in enumerate(photos().items()):
            result[name] = capture(photo, Path(tmp) / str(i))
    return result


def main(argv):
    if len(argv) != 2 or argv[1] not in ("record", "check"):
        sys.exit(__doc__)
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
