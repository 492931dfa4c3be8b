"""Training speed of each stage, measured as training runs it (``python -m export.train --benchmark``).

For every stage of a tier, and the whole chain fine-tuned (:data:`export.engine.run.JOINT`): **data** samples/s (:func:`export.engine.batches.make` alone), **step**
samples/s (the frozen earlier stages' forward passes, the stage's forward, backward and Adam on a
ready batch) and **loop** samples/s (both, one after the other, as :meth:`export.engine.run.Run.train_step`
does; for the maps and joint stages, with their share of self-supervised steps on real photos when
``../shared/data/real`` is there). All in one process on ``--threads`` threads; the last line is
``samples/s=<the slowest stage's loop rate> size=<training size>``.

``--tier fast`` (or ``lite``) measures the same for a tier of the first training loop
(:func:`export.train.benchmark_rows`): the baseline.

Without a material bank it grows a small one in a temporary folder (two shards; a few seconds).
"""

from __future__ import annotations

import os
import tempfile
import time

import torch

from export.engine import bank as bank_mod
from export.engine import keep_memory
from export.engine import batches, nets
from export.engine import real as real_mod
from export.engine.run import JOINT, REAL_STAGES, RunConfig, real_loss, stage_loss


def _bank(log):
    root = bank_mod.default_root()
    if bank_mod.count(root) >= 2 * bank_mod.SHARD:
        return bank_mod.Bank(root)
    tmp = tempfile.mkdtemp(prefix="svbrdf-bank-")
    log(f"no material bank at {root}: a small one in {tmp}")
    bank_mod.grow(tmp, 2 * bank_mod.SHARD, progress=None)
    return bank_mod.Bank(tmp)


def rate(fn, batch, repeats):
    """Samples per second of this process's CPU time (on one thread, its wall time when nothing else
    runs; on a shared machine, what one core of its own would give)."""
    fn()  # warm-up
    t = time.process_time()
    for _ in range(repeats):
        fn()
    return batch * repeats / (time.process_time() - t)


def _real_photos(log):
    """A few real training photos (:mod:`export.engine.real`), or None without the shared data."""
    from export.files import shared_data

    root = os.path.join(shared_data(), "real")
    if not os.path.isdir(root):
        log("no ../shared/data/real: the maps stage's loop is measured on synthetic batches only")
        return None
    return real_mod.RealPhotos(real_mod.split(root)[0][:16])


def measure(tier="swift", size=None, batch=None, repeats=4, log=print):
    """[(stage, parameters, data/s, step/s, loop/s)] for every stage of ``tier``."""
    cfg = RunConfig(tier=tier)
    size, batch = size or cfg.size, batch or cfg.batch
    bank = _bank(log)
    net = nets.build(tier)
    net.loss_weights = dict(cfg.weights)
    g = torch.Generator().manual_seed(0)
    rows = []
    for stage in nets.STAGES + (JOINT,):
        module = net if stage == JOINT else getattr(net, stage)
        opt = torch.optim.Adam(module.parameters(), lr=cfg.lr, betas=(0.5, 0.9), fused=True)
        ready = batches.make(bank, g, batch, size, stage)

        def step(b=None):
            net.train()
            loss = stage_loss(net, stage, b if b is not None else ready)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()

        data = rate(lambda: batches.make(bank, g, batch, size, stage), batch, repeats)
        stepped = rate(step, batch, repeats)
        loop = rate(lambda: step(batches.make(bank, g, batch, size, stage)), batch, repeats)
        real = _real_photos(log) if stage in REAL_STAGES and cfg.real_fraction > 0 else None
        if real:  # as training runs it: a share of the steps are real photos (no rendering of the data)
            def real_step():
                net.train()
                loss = real_loss(net, real.batch(g, batch, size), stage)
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()

            real_rate = rate(real_step, batch, repeats)
            log(f"{stage}: real-photo steps {real_rate:.1f}/s, synthetic {loop:.1f}/s")
            loop = 1.0 / ((1 - cfg.real_fraction) / loop + cfg.real_fraction / real_rate)
        params = sum(p.numel() for p in module.parameters())
        rows.append((stage, params, data, stepped, loop))
        log(f"{stage}: {params / 1e6:.2f} M parameters, data {data:.1f}/s, step {stepped:.1f}/s, loop {loop:.1f}/s")
    return rows, size


def table(rows, size, threads):
    lines = [f"| stage ({size}², {threads} thread{'s' if threads != 1 else ''}) | parameters | data samples/s "
             "| step samples/s | loop samples/s |", "|---|---|---|---|---|"]
    lines += [f"| {s} | {p / 1e6:.2f} M | {d:.1f} | {st:.1f} | {lo:.1f} |" for s, p, d, st, lo in rows]
    return "\n".join(lines)


def main(tier="swift", threads=1, log=print, rows=None):
    """Print the table and the last line; ``rows`` measured elsewhere (the first loop's) or by :func:`measure`."""
    torch.set_num_threads(threads)
    keep_memory()
    if rows is not None:
        log(table(rows[0], rows[1], threads))
        log(f"samples/s={min(r[4] for r in rows[0]):.1f} size={rows[1]}")
        return rows[0]
    rows, size = measure(tier, log=lambda m: None)
    log(table(rows, size, threads))
    log(f"samples/s={min(r[4] for r in rows):.1f} size={size}")
    return rows

