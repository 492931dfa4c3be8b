"""Capture benchmark: seconds per photo by stage, and peak memory, at several output sizes.

    python -m export.studies.capture_speed                       # 256, 1024, 2048 from a 12 MP JPEG
    python -m export.studies.capture_speed --sizes 256,4096 --repeat 5 --photo my.dng
    python -m export.studies.capture_speed --throughput 24      # svbrdf batch: local engine vs Ray, photos/s

Each configuration runs in its own process (so peak memory is its own):
the photo is read, cropped, exposed, run through the model chain,
upsampled and written as a native texture set with its preview, ``--repeat``
times; the median of each stage is printed. In the same run, as baselines,
the networks alone at 256 px and the same job with bicubic instead of guided
upsampling, so ratios hold on any machine.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time


STAGE_ORDER = ("read", "crop", "network_masks", "network_aux", "network_maps", "upsample", "write")


def _synthetic_photo(path, width=4000, height=3000):
    """A 12 MP flash-like JPEG (textured, with a highlight), written once."""
    import numpy as np

    from svbrdf_cli import conventions as cv
    from svbrdf_cli.imageio import write_image

    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    tex = 0.25 + 0.1 * np.sin(x / 23.0) * np.cos(y / 17.0) + 0.05 * rng.standard_normal((height, width)).astype(np.float32)
    hl = np.exp(-((x - width / 2) ** 2 + (y - height / 2) ** 2) / (2 * (0.05 * width) ** 2))
    lin = np.clip(tex[..., None] * np.array([0.9, 0.7, 0.5], np.float32) + 0.8 * hl[..., None], 0, 1)
    write_image(path, cv.linear_to_srgb(lin).astype(np.float32))


def _one(photo, size, repeat, upsample, model, threads):
    """In this process: run the job ``repeat`` times; returns timings and peak memory."""
    from svbrdf_cli.run import pipeline
    from svbrdf_cli.infer.registry import load_model

    chain = load_model(model, threads=threads)
    # refine=0: every variant here does the same work (decode, infer, upsample, write); --refine's own
    # time is measured by export.studies.refine_eval
    opts = pipeline.Options(size=size, upsample=upsample, force=True, refine=0)
    runs = []
    with tempfile.TemporaryDirectory() as out:
        for _ in range(repeat + 1):  # the first run warms up onnxruntime
            t0 = time.perf_counter()
            prepared = pipeline.prepare(photo, opts)
            _, rec = pipeline.capture(prepared, chain, out, opts, model_name=model)
            t = dict(rec["timings_s"], total=time.perf_counter() - t0)
            runs.append(t)
    runs = runs[1:]
    med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
    return {"timings": med, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def median_seconds(fn, repeat):
    """Median wall time of ``repeat`` calls of ``fn`` after one warm-up call (onnxruntime sizes its arenas then)."""
    fn()
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def _networks_only(model, threads, repeat):
    import numpy as np

    from svbrdf_cli.infer.registry import load_model

    chain = load_model(model, threads=threads)
    x = np.random.default_rng(0).uniform(0, 1, (256, 256, 3)).astype(np.float32)
    return {"timings": {"total": median_seconds(lambda: chain(x), repeat)},
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def _spawn(args):
    r = subprocess.run([sys.executable, "-m", "export.studies.capture_speed", "--child", json.dumps(args)],
                       capture_output=True, text=True)
    if r.returncode:
        raise SystemExit(f"error: benchmark child failed: {r.stderr.strip().splitlines()[-1:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def _copies(folder, count):
    """``folder/p000.jpg`` copied to p001 ... so that the folder holds ``count`` photos (a batch)."""
    import shutil

    for i in range(1, count):
        shutil.copy(os.path.join(folder, "p000.jpg"), os.path.join(folder, f"p{i:03d}.jpg"))


def _throughput(count, model):
    """Wall-clock photos/s of ``svbrdf batch`` (a fresh process each), local engine then Ray."""
    with tempfile.TemporaryDirectory() as tmp:
        src = os.path.join(tmp, "in")
        os.makedirs(src)
        _synthetic_photo(os.path.join(src, "p000.jpg"), 1600, 1200)
        _copies(src, count)
        print(f"{count} photos 1600x1200 JPEG -> 1024 px native sets with previews; model {model}; "
                   f"{os.cpu_count()} cores; wall clock of the whole command (start-up included)")
        rows = []
        for engine in ("local", "ray"):
            out = os.path.join(tmp, f"out_{engine}")
            cmd = [sys.executable, "-m", "svbrdf_cli.cli.main", "batch", src, "-o", out, "--model", model, "-q",
                   "--engine", engine]
            t0 = time.perf_counter()
            r = subprocess.run(cmd, capture_output=True, text=True)
            dt = time.perf_counter() - t0
            if r.returncode:
                raise SystemExit(f"error: {engine} engine failed: {r.stderr.strip()[-300:]}")
            rows.append((engine, dt))
    print("| engine | seconds | photos/s | vs local |")
    print("|---|---|---|---|")
    for engine, dt in rows:
        print(f"| {engine} | {dt:.1f} | {count / dt:.2f} | {rows[0][1] / dt:.2f} |")


def _ratio_row(label, whole, networks, peak):
    print(f"| {label} | {whole:.3f} | {networks:.3f} | {whole / max(networks, 1e-9):.2f} | {peak:.0f} |")


def _ratios(model, threads, repeat, dng=None):
    """Issue 19's cases, each in its own process: the whole capture's seconds over its model's (the
    ``network`` stage of ``material.json``), measured in the same run, and the peak memory."""
    print(f"model {model}; {os.cpu_count()} cores; median of {repeat} after a warm-up; each case in its own process")
    print("| case | whole s | model s | whole / model | peak MB |")
    print("|---|---|---|---|---|")
    def make(path, w, h):  # in a process of its own: Linux keeps a parent's peak memory across fork and exec
        subprocess.run([sys.executable, "-c", "import sys; from export.studies.capture_speed import _synthetic_photo; "
                        f"_synthetic_photo(sys.argv[1], {w}, {h})", path], check=True)

    with tempfile.TemporaryDirectory() as tmp:
        for key, (w, h) in {"12mp": (4000, 3000), "48mp": (8000, 6000)}.items():
            make(os.path.join(tmp, f"{key}.jpg"), w, h)
        cases = [("12 MP JPEG, default size", "12mp.jpg", None), ("12 MP JPEG, --size 2048", "12mp.jpg", 2048),
                 ("48 MP JPEG, default size", "48mp.jpg", None)]
        if dng:
            cases.append((f"RAW {os.path.basename(dng)}, default size", dng, None))
        for label, photo, size in cases:
            r = _spawn({"photo": os.path.join(tmp, photo), "size": size, "upsample": "guided", "model": model,
                        "threads": threads, "repeat": repeat})
            _ratio_row(label, r["timings"]["total"], r["timings"]["network"], r["peak_rss_mb"])
        for side in (256, 1024):
            src = os.path.join(tmp, f"batch{side}")
            os.makedirs(src)
            make(os.path.join(src, "p000.jpg"), side, side)
            _copies(src, 40)
            one = _spawn({"photo": os.path.join(src, "p000.jpg"), "size": side, "upsample": "guided", "model": model,
                          "threads": threads, "repeat": repeat})
            cmd = [sys.executable, "-m", "svbrdf_cli.cli.main", "batch", src, "-o", os.path.join(tmp, f"out{side}"),
                   "--model", model, "--size", str(side), "--threads", str(threads), "--refine", "0", "-q"]  # as _one
            peak = ("import resource, subprocess, sys; r = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL); "
                    "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss); sys.exit(r.returncode)")
            t0 = time.perf_counter()
            r = subprocess.run([sys.executable, "-c", peak, *cmd], capture_output=True, text=True)
            wall = (time.perf_counter() - t0) / 40
            if r.returncode:
                raise SystemExit(f"error: batch failed: {r.stderr.strip()[-300:]}")
            _ratio_row(f"batch of 40 at {side}², per photo (start-up included)", wall, one["timings"]["network"],
                       int(r.stdout.split()[-1]) / 1024)


def _arguments(argv=None):
    p = argparse.ArgumentParser(prog="python -m export.studies.capture_speed",
                                description="Time the capture job by stage at several output sizes, with peak memory.")
    p.add_argument("--photo", default=None, help="Photo to run on (default: a synthetic 4000x3000 JPEG).")
    p.add_argument("--sizes", default="256,1024,2048", help="Output sizes (comma-separated; default %(default)s).")
    p.add_argument("--repeat", type=int, default=3, help="Timed runs per configuration (median; default %(default)s).")
    p.add_argument("--model", default="physical",
                   help="A --model value: physical, auto or a folder of exported models (default %(default)s).")
    p.add_argument("--threads", type=int, default=0, help="onnxruntime threads (0: one per core).")
    p.add_argument("--json", dest="json_out", default=None, help="Also write the figures here.")
    p.add_argument("--throughput", type=int, default=0,
                   help="Instead: time 'svbrdf batch' on this many 1600x1200 JPEGs, local engine vs Ray.")
    p.add_argument("--ratios", action="store_true",
                   help="Instead: issue 19's cases (12 MP at the default size and 2048, 48 MP, --dng, batches of 40 "
                        "at 256 and 1024), the whole capture over its model's time, and peak memory.")
    p.add_argument("--dng", default=None, help="With --ratios: a RAW file to add as a case.")
    p.add_argument("--child", default=None, help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.photo is not None and not os.path.isfile(a.photo):
        p.error(f"--photo '{a.photo}' is not a file.")
    return a


def main(argv=None):
    """Time the capture job by stage at several output sizes, with peak memory."""
    a = _arguments(argv)
    photo, sizes, repeat, model, threads = a.photo, a.sizes, a.repeat, a.model, a.threads
    json_out, child, throughput = a.json_out, a.child, a.throughput
    if a.ratios:
        return _ratios(model, threads, repeat, a.dng)
    if throughput:
        return _throughput(throughput, model)
    if child:
        a = json.loads(child)
        res = _networks_only(a["model"], a["threads"], a["repeat"]) if a["photo"] is None else \
            _one(a["photo"], a["size"], a["repeat"], a["upsample"], a["model"], a["threads"])
        print(json.dumps(res))
        return
    sizes = [int(s) for s in sizes.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        if photo is None:
            photo = os.path.join(tmp, "photo_12mp.jpg")
            _synthetic_photo(photo)
        from svbrdf_cli.ingest.photo import load_photo

        h, w = load_photo(photo).linear.shape[:2]
        print(f"photo: {os.path.basename(photo)} {w}x{h}; model {model}; {os.cpu_count()} cores; "
                   f"median of {repeat} runs after one warm-up; each row in its own process")
        base = _spawn({"photo": None, "model": model, "threads": threads, "repeat": max(repeat, 5)})
        rows = []
        for size in sizes:
            for up in (("guided", "bicubic") if size > 256 else ("guided",)):
                r = _spawn({"photo": photo, "size": size, "upsample": up, "model": model, "threads": threads,
                            "repeat": repeat})
                rows.append((size, up, r))
    t_net = base["timings"]["total"]
    head = ["size", "upsampling"] + list(STAGE_ORDER) + ["total s", "x networks", "peak MB"]
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    print("| 256 | networks alone | " + " | ".join("" for _ in STAGE_ORDER)
               + f" | {t_net:.3f} | 1.0 | {base['peak_rss_mb']:.0f} |")
    for size, up, r in rows:
        t = r["timings"]
        cells = [f"{t.get(k, 0):.3f}" for k in STAGE_ORDER]
        print(f"| {size} | {up} | " + " | ".join(cells) + f" | {t['total']:.3f} | {t['total'] / t_net:.1f} | "
                   f"{r['peak_rss_mb']:.0f} |")
    if json_out:
        with open(json_out, "w") as f:
            json.dump({"photo": [w, h], "networks_alone": base,
                       "rows": [{"size": s, "upsample": u, **r} for s, u, r in rows]}, f, indent=2)


if __name__ == "__main__":
    main()
