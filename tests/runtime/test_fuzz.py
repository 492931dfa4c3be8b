"""The project's own mutation fuzzer: mutated photos through ``svbrdf capture`` and ``svbrdf batch``.

Seeds are small valid photos of every accepted format (:mod:`mutations`, made here); each mutant is one
seeded mutation of one (bit flips, random bytes, truncation, a cut-out middle, inserted or appended
bytes, a deleted or duplicated PNG chunk or JPEG segment, a header number set to 0, huge or negative
with its CRC fixed, a wrong extension, a splice of two files). Files are run in groups of
:data:`GROUP`: once by ``svbrdf capture`` in reverse order and once by ``svbrdf batch`` (sorted
order), each in a fresh process under ``-q``. Every file must end one of two ways, the same in both
runs:

* ``set``: a complete texture set, from a file whose decoded pixels are mostly its seed's (not
  garbage: :func:`garbage_fraction`), with maps identical in both runs (order never matters);
* ``refused``: exactly one ``error:`` line naming the file, and no folder for it.

(A file without a photo's extension is ignored by ``batch``, as every folder's non-photo files are:
only ``capture`` judges it. A set with other pixels from a JPEG or the uncompressed DNG whose bytes
were changed or inserted in place is counted apart, ``set_unverifiable``: those formats carry no
check that could tell, see :data:`UNCHECKED`.)

Anything else fails the group: a traceback, an "unexpected" error, a line on stderr that is not an
error under ``-q`` (a decoder talking), an exit code other than 0 or 1, a run over its time, a peak
memory over :data:`PEAK_MB`, anything left behind (a hidden folder, a temporary file), a set from a
mostly-garbage file, or a verdict or map that differs between the two runs.

``SVBRDF_FUZZ_COUNT`` mutants are run (default :data:`DEFAULT_COUNT`, what CI runs), from
``SVBRDF_FUZZ_SEED`` (default 35); ``SVBRDF_FUZZ_REPORT``, a file, receives one JSON line of counts per
group. docs/fuzzing.md has the command that runs thousands.
"""

import hashlib
import json
import os
import subprocess
import sys
import time

import numpy as np
import pytest

import mutations
from svbrdf_cli.run.batch import photo_extensions

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DEFAULT_COUNT = 240
COUNT = int(os.environ.get("SVBRDF_FUZZ_COUNT", DEFAULT_COUNT))
BASE_SEED = int(os.environ.get("SVBRDF_FUZZ_SEED", 35))
GROUP = 40
#: Peak memory of one run (issue 35: never above 1 GB).
PEAK_MB = 1024
#: A set may come from a file whose pixels differ from its seed's in at most this fraction.
MOSTLY_GARBAGE = 0.5
MAPS = ("normal.png", "diffuse.png", "roughness.png", "specular.png")
OPTIONS = ["--size", "256", "--no-preview", "--refine", "0", "--threads", "1", "-q"]


@pytest.fixture(scope="module")
def seeds(tmp_path_factory):
    return mutations.make_seeds(str(tmp_path_factory.mktemp("seeds")))


def run_svbrdf(args, cwd, tmpdir, timeout):
    """``svbrdf ARGS`` in a fresh process: (exit code, stderr text, peak MB, seconds)."""
    wrapper = ("import resource, subprocess, sys\n"
               "r = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)\n"
               "sys.stdout.buffer.write(r.stderr)\n"
               "print('\\nPEAK_KB', resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)\n"
               "sys.exit(r.returncode)\n")
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=ROOT, TMPDIR=str(tmpdir))
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-c", wrapper, sys.executable, "-m", "svbrdf_cli.cli.main", *args],
                       cwd=cwd, env=env, capture_output=True, timeout=timeout)
    text = r.stdout.decode("utf-8", "replace")
    peak = [int(line.split()[1]) for line in text.splitlines() if line.startswith("PEAK_KB")]
    text = "\n".join(line for line in text.splitlines() if not line.startswith("PEAK_KB")).strip()
    return r.returncode, text, (peak[0] / 1024 if peak else 0.0), time.perf_counter() - t0


def _encoded(path):
    from svbrdf_cli.ingest import photo as ingest

    try:
        lin = ingest.load_photo(path).linear
    except Exception:  # noqa: BLE001 - the oracle never fails on what it cannot decode
        return None
    lin = lin / np.maximum(lin.reshape(-1, 3).mean(0), 1e-6)  # exposure and white balance do not count
    return np.clip(lin, 0, 8) ** (1 / 2.2)


def garbage_fraction(mutant, seed):
    """Fraction of the mutant's pixels (as the tool decodes them) that are not its seed's, over the
    eight orientations at the seed's size (1.0 when the sizes cannot match)."""
    a, b = _encoded(mutant), _encoded(seed)
    if a is None or b is None:
        return 1.0
    best = 1.0
    for k in range(4):
        for flip in (False, True):
            x = np.rot90(a[::-1] if flip else a, k)
            if x.shape != b.shape:
                continue
            bad = np.abs(x - b).max(-1) > 0.25 * (1 + b.max(-1))
            best = min(best, float(bad.mean()))
    return best


#: Seeds whose format carries no integrity check at all: JPEG (its tables and entropy-coded data
#: decode whatever their bits are) and the uncompressed DNG (no checksum, no code); and the mutations
#: that change or insert bytes in place (the file keeps its structure). A set from such a mutant with
#: other pixels is counted apart, ``set_unverifiable``: nothing in the file can tell.
UNCHECKED = ("base.jpg", "prog.jpg", "grey.jpg", "raw.dng")
IN_PLACE = ("bitflip", "bytes", "header_field", "insert", "duplicate_segment")


def _files_below(folder):
    return sorted(os.path.relpath(os.path.join(d, n), folder) for d, _, ns in os.walk(folder) for n in ns)


def _map_hashes(folder):
    return {m: hashlib.sha256(open(os.path.join(folder, m), "rb").read()).hexdigest() for m in MAPS}


def judge(run_name, files, code, text, peak, seconds, out, tmpdir, timeout, problems):
    """Verdicts of one run: {file: ("set", hashes) or ("refused", line)}; problems appended."""
    if "Traceback" in text:
        problems.append(f"{run_name}: traceback\n{text[-3000:]}")
    if code not in (0, 1):
        problems.append(f"{run_name}: exit code {code}\n{text[-2000:]}")
    if peak > PEAK_MB:
        problems.append(f"{run_name}: peak memory {peak:.0f} MB")
    lines = [line for line in text.splitlines() if line.strip()]
    noise = [line for line in lines if not line.startswith("error: ")]
    if noise:
        problems.append(f"{run_name}: lines other than errors under -q: {noise[:5]}")
    left = [n for n in os.listdir(tmpdir)]
    if left:
        problems.append(f"{run_name}: left in TMPDIR: {left}")
    entries = os.listdir(out) if os.path.isdir(out) else []
    hidden = [n for n in entries if n.startswith(".")]
    if hidden:
        problems.append(f"{run_name}: left in the output folder: {hidden}")
    verdicts = {}
    for f in files:
        stem = os.path.splitext(f)[0]
        if run_name == "batch" and os.path.splitext(f)[1].lower() not in photo_extensions():
            verdicts[f] = ("ignored", "")  # a folder contributes its photos only
            continue
        errs = [line for line in lines if f"in/{f}'" in line or f"'{f}'" in line]
        folder = os.path.join(out, stem)
        has_set = os.path.isdir(folder)
        if has_set and errs:
            problems.append(f"{run_name}: {f} has a set and an error: {errs}")
        elif has_set:
            names = _files_below(folder)
            if not all(m in names for m in MAPS + ("material.json", "texture_set.json")):
                problems.append(f"{run_name}: {f}: incomplete set {names}")
                continue
            verdicts[f] = ("set", _map_hashes(folder))
        elif len(errs) == 1:
            if "please report it" in errs[0] or "unexpected" in errs[0]:
                problems.append(f"{run_name}: {f}: {errs[0]}")
            verdicts[f] = ("refused", errs[0])
        else:
            problems.append(f"{run_name}: {f}: {len(errs)} error lines and no set: {errs}")
    stray = [n for n in entries if not n.startswith(".") and n != "index.html"
             and n not in {os.path.splitext(f)[0] for f in files}]
    if stray:
        problems.append(f"{run_name}: unexpected entries in the output folder: {stray}")
    return verdicts


@pytest.mark.parametrize("start", list(range(0, COUNT, GROUP)))
def test_fuzz(start, seeds, tmp_path):
    seed_dir = tmp_path / "seeds"
    seed_dir.mkdir()
    for name, data in seeds.items():
        (seed_dir / name).write_bytes(data)
    src = tmp_path / "in"
    src.mkdir()
    made = {}
    for i in range(start, min(start + GROUP, COUNT)):
        fname, data, seed, kind = mutations.mutate(seeds, i, BASE_SEED)
        (src / fname).write_bytes(data)
        made[fname] = (seed, kind)
    files = sorted(made)
    timeout = 60 + 6 * len(files)
    problems, runs = [], {}
    for run_name, args in (("capture", ["capture", *[f"in/{f}" for f in reversed(files)], "-o", "out_c", *OPTIONS]),
                           ("batch", ["batch", "in", "-o", "out_b", *OPTIONS])):
        tmpdir = tmp_path / f"tmp_{run_name}"
        tmpdir.mkdir()
        try:
            code, text, peak, seconds = run_svbrdf(args, tmp_path, tmpdir, timeout)
        except subprocess.TimeoutExpired:
            pytest.fail(f"{run_name}: no answer within {timeout} s (a hang) on {files}")
        out = tmp_path / ("out_c" if run_name == "capture" else "out_b")
        runs[run_name] = judge(run_name, files, code, text, peak, seconds, out, tmpdir, timeout, problems)
    counts = {"set": 0, "refused": 0, "ignored_by_batch": 0, "set_unverifiable": 0, "garbage_set": 0, "order": 0,
              "files": len(files)}
    for f in files:
        a, b = runs["capture"].get(f), runs["batch"].get(f)
        if a is None or b is None:
            continue
        if b[0] == "ignored":
            counts["ignored_by_batch"] += 1
            continue
        if a[0] != b[0] or (a[0] == "set" and a[1] != b[1]):
            counts["order"] += 1
            problems.append(f"{f}: capture (reverse order) gave {a[0]}, batch {b[0]}"
                            + (" with other maps" if a[0] == b[0] else ""))
            continue
        counts[a[0]] += 1
        if a[0] == "set":
            seed, kind = made[f]
            g = garbage_fraction(str(src / f), str(seed_dir / seed))
            if g > MOSTLY_GARBAGE and seed in UNCHECKED and kind in IN_PLACE:
                counts["set_unverifiable"] += 1  # (counted apart: see UNCHECKED)
            elif g > MOSTLY_GARBAGE:
                counts["garbage_set"] += 1
                problems.append(f"{f}: a set from a file whose pixels are {g:.0%} not its seed's ({kind} of {seed})")
    report = os.environ.get("SVBRDF_FUZZ_REPORT")
    if report:
        with open(report, "a") as fh:
            fh.write(json.dumps({"start": start, **counts, "problems": len(problems)}) + "\n")
    assert not problems, "\n".join(problems)


def test_every_seed_makes_a_set(seeds, tmp_path):
    """The seeds themselves are sound: each becomes a set (else the fuzzer would prove nothing)."""
    (tmp_path / "in").mkdir()
    for name, data in seeds.items():
        (tmp_path / "in" / name).write_bytes(data)
    (tmp_path / "tmp").mkdir()
    code, text, peak, _ = run_svbrdf(["batch", "in", "-o", "out", *OPTIONS], tmp_path, tmp_path / "tmp", 300)
    assert code == 0 and text == "", text
    assert sorted(n for n in os.listdir(tmp_path / "out") if n != "index.html") == \
        sorted(os.path.splitext(n)[0] for n in seeds)


def test_the_mutations_are_seeded_and_cover_every_kind(seeds):
    first = [mutations.mutate(seeds, i, 1) for i in range(200)]
    assert first == [mutations.mutate(seeds, i, 1) for i in range(200)]
    assert {kind for *_, kind in first} == set(mutations.MUTATIONS)
    assert {seed for _, _, seed, _ in first} == set(seeds)
    assert sum(data != seeds[seed] for _, data, seed, _ in first) > 150
