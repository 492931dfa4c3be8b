"""``python -m export.data``: throughput, validation shards, gallery, realism check."""

from __future__ import annotations

import time

import click


def _setup(threads):
    import torch

    if threads:
        torch.set_num_threads(threads)
    return torch


def _bank(shared, device="cpu"):
    from export.data.dataset import SeedBank
    from export.files import shared_data

    bank = SeedBank.find(shared, device=device)
    if bank is None:
        click.echo(f"(no CC0 seeds: {shared_data(shared)}/materials is absent; procedural materials only)", err=True)
    return bank


shared_opt = click.option("--shared", type=click.Path(file_okay=False), default=None,
                          help="Shared data folder holding materials/ and real/ (default: ../shared/data).")


@click.group()
def cli():
    """Training-data engine: procedural materials, CC0 seeds, flash-photo simulation."""


@cli.command()
@click.option("--batch", default=16, show_default=True)
@click.option("--size", default=256, show_default=True)
@click.option("--batches", default=8, show_default=True, help="Batches timed per stage (after one warm-up).")
@click.option("--device", default="cpu", show_default=True)
@click.option("--threads", default=0, help="torch threads (0: torch's default).")
@shared_opt
def throughput(batch, size, batches, device, threads, shared):
    """Samples per second for each stage of sample generation."""
    from tqdm import tqdm

    torch = _setup(threads)
    from export.data import dataset
    from export.data import simulate

    bank = _bank(shared, device)
    cfg = dataset.DataConfig(size=size)
    stages = {
        "materials (procedural + seeds + mixing + augmentation)": lambda g: dataset.materials(g, batch, cfg, bank, device),
        "+ simulated photo and I": lambda g: simulate.photograph(dataset.materials(g, batch, cfg, bank, device),
                                                          simulate.sample_capture(g, batch, cfg.capture), g),
        "+ I_bf, M_b, M_h": lambda g: dataset.make_batch(g, batch, dataset.DataConfig(size=size, targets=("I_bf", "M_b", "M_h")),
                                                    bank, device),
        "full sample (+ I_hr, I_hr2)": lambda g: dataset.make_batch(g, batch, cfg, bank, device),
    }
    click.echo(f"device {device}, torch threads {torch.get_num_threads()}, batch {batch}, {size}²")
    rows = []
    for name, fn in stages.items():
        g = dataset.worker_generator(0, 0, device)
        fn(g)  # warm-up
        if device.startswith("cuda"):
            torch.cuda.synchronize()
        t = time.perf_counter()
        for _ in tqdm(range(batches), desc=name[:40], unit="batch", leave=False):
            fn(g)
        if device.startswith("cuda"):
            torch.cuda.synchronize()
        dt = time.perf_counter() - t
        rows.append((name, batches * batch / dt))
    for name, rate in rows:
        click.echo(f"{name:58s} {rate:8.1f} samples/s")


@cli.command()
@click.argument("out_dir", type=click.Path(file_okay=False))
@click.option("--count", default=512, show_default=True)
@click.option("--seed", default=1, show_default=True, help="Validation seed (training streams use others).")
@click.option("--shard-size", default=64, show_default=True)
@click.option("--size", default=256, show_default=True)
@click.option("--threads", default=0)
@shared_opt
def shards(out_dir, count, seed, shard_size, size, threads, shared):
    """Write a fixed, reproducible sample set (validation shards)."""
    _setup(threads)
    from export.data import dataset
    from export.files import shared_data

    n = dataset.write_shards(out_dir, count, seed=seed, shard_size=shard_size, config=dataset.DataConfig(size=size),
                       seeds_root=shared_data(shared))
    click.echo(f"{out_dir}: {n} shard(s), {count} samples")


@cli.command()
@click.option("-o", "--output", default="docs/figures/materials.png", show_default=True)
@click.option("--seed", default=0, show_default=True)
@shared_opt
def gallery(output, seed, shared):
    """Grid of generated materials (maps + simulated photo) and, beside it
    when the shared data is present, real flash photos at the same scale."""
    from export.data.gallery import make_gallery

    for path in make_gallery(output, seed=seed, shared=shared):
        click.echo(path)


@cli.command(context_settings={"ignore_unknown_options": True})
@click.option("--count", default=256, show_default=True, help="Simulated photos to generate.")
@click.option("--seed", default=2, show_default=True)
@click.option("--paper", is_flag=True, help="Paper setting: no camera model (flash at the lens, 45 degrees).")
@shared_opt
@click.argument("realism_args", nargs=-1, type=click.UNPROCESSED)
def realism(count, seed, paper, shared, realism_args):
    """Compare statistics of simulated photos with real ones (extra
    arguments go to ``python -m export.data.realism``)."""
    import dataclasses

    from tqdm import tqdm

    _setup(0)
    from export.data import dataset
    from export.data import realism as realism_check
    from export.data import simulate

    bank = _bank(shared)
    cfg = dataset.DataConfig(targets=())
    if paper:
        cfg = dataclasses.replace(cfg, capture=simulate.PAPER)
    g = dataset.worker_generator(seed, 0)
    images = []
    for _ in tqdm(range(0, count, 16), desc="simulating", unit="batch"):
        b = dataset.make_batch(g, min(16, count - len(images)), cfg, bank)
        images += list(b["photo"].permute(0, 2, 3, 1).numpy())
    raise SystemExit(realism_check.main(list(realism_args), simulated=images))


if __name__ == "__main__":
    cli()
