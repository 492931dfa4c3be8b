"""Benchmark the intermediate targets: seconds per batch, beside the paper's figures.

    python -m export.render.target_speed                     # batch 16 at 256^2 on the CPU
    python -m export.render.target_speed --device cuda       # on a GPU
    python -m export.render.target_speed --batch 4 --size 128 --repeat 2   # quick

Prints the median time of each target for one batch of random maps (float32)
and its ratio to rendering the plain flash image I, measured in the same run,
so the ratios hold across machines. The paper's numbers (RTX 3090, batch 16,
256^2, section IV-A) are printed beside ours.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time

import torch

from export.render import targets
from svbrdf_cli import conventions as cv

#: Section IV-A of the paper: seconds per batch of 16 at 256^2 on an RTX 3090.
PAPER_SECONDS = {"I_bf": 0.029, "I_hr": 0.164, "I_hr2": 0.164, "M_b": 0.03, "M_h": 0.03}


def random_maps(batch, size, device, seed=0):
    """A batch of random but plausible linear maps (bumpy normals, mixed roughness)."""
    g = torch.Generator().manual_seed(seed)
    n = torch.randn(batch, 3, size, size, generator=g) * 0.2
    n[:, 2] += 1
    maps = {"normal": cv.normalize(n, axis=1), "diffuse": torch.rand(batch, 3, size, size, generator=g) * 0.6,
            "roughness": torch.rand(batch, 1, size, size, generator=g) * 0.9 + 0.05,
            "specular": torch.rand(batch, 3, size, size, generator=g) * 0.5}
    return {k: v.to(device) for k, v in maps.items()}


def _time(fn, repeat, device):
    times = []
    for i in range(repeat + 1):
        if device.startswith("cuda"):
            torch.cuda.synchronize()
        t0 = time.perf_counter()
        fn()
        if device.startswith("cuda"):
            torch.cuda.synchronize()
        if i:  # the first call warms up caches and kernels
            times.append(time.perf_counter() - t0)
    return statistics.median(times)


def run(batch=16, size=256, device="cpu", repeat=3, chunk=5):
    """Returns {target: seconds per batch}."""
    maps = random_maps(batch, size, device)
    jobs = {
        "I": lambda: targets.flash_image(maps),
        "I_bf": lambda: targets.bumpiness_flattened(maps),
        "I_hr": lambda: targets.highlight_removed(maps, chunk=chunk),
        "I_hr2": lambda: targets.highlight_removed(maps, high_roughness=True, chunk=chunk),
        "M_b": lambda: targets.bumpiness_mask(maps),
        "M_h": lambda: targets.highlight_mask(maps),
    }
    with torch.no_grad():
        return {k: _time(fn, repeat, device) for k, fn in jobs.items()}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--chunk", type=int, default=5, help="lights rendered at once for I_hr / I_hr^2")
    a = ap.parse_args(argv)
    where = torch.cuda.get_device_name() if a.device.startswith("cuda") else \
        f"{platform.processor() or platform.machine()}, {torch.get_num_threads()} threads"
    print(f"intermediate targets: batch {a.batch} at {a.size}^2, float32, {a.device} ({where}), "
          f"median of {a.repeat}")
    res = run(a.batch, a.size, a.device, a.repeat, a.chunk)
    base = res["I"]
    print(f"{'target':8s} {'s/batch':>9s} {'x I':>7s} {'paper 3090 s':>13s}")
    for k, s in res.items():
        paper = PAPER_SECONDS.get(k)
        print(f"{k:8s} {s:9.3f} {s / base:7.1f} {paper if paper is not None else '-':>13}")


if __name__ == "__main__":
    main()
