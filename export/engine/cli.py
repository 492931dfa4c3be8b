"""Commands of the training engine.

    python -m export.engine bank --count 8000          # grow the material bank (reused by every run)
    python -m export.engine train --run runs/swift     # train, or resume the run in that folder
    python -m export.engine background --run runs/swift  # the same, detached, on one core
    python -m export.engine stop --run runs/swift      # SIGTERM: save and exit 0
    python -m export.engine compact --run runs/swift   # the run's state as files to commit

A run folder without a state resumes from the committed checkpoint (``--checkpoint``, default
:data:`CHECKPOINT`), so on a fresh machine ``background`` picks up where the last session stopped.
"""

from __future__ import annotations

import click

from export.engine import bank as bank_mod
from export.engine import keep_memory
from export.engine.batches import FLASH_CONTEXTS
from svbrdf_cli.conventions import SPECULAR_LEVELS

#: The committed compact checkpoint of the current run (export.engine.run.write_compact).
CHECKPOINT = "weights/checkpoints/swift-run"


@click.group()
def main():
    """The fast training engine (see docs/training.md)."""


@main.command()
@click.option("--count", default=8000, show_default=True, help="Grow the bank to at least this many materials.")
@click.option("--root", default=None, help="Bank folder (default $SVBRDF_BANK or ~/.cache/svbrdf/bank).")
@click.option("--threads", default=1, show_default=True)
def bank(count, root, threads):
    """Grow the material bank."""
    import torch

    torch.set_num_threads(threads)
    n = bank_mod.grow(root, count)
    click.echo(f"bank: {n} materials in {root or bank_mod.default_root()}")


def _setup(threads):
    import torch

    torch.set_num_threads(threads)
    try:
        torch.set_num_interop_threads(1)
    except RuntimeError:  # set once per process: a second command in the same process keeps it
        pass
    keep_memory()


@main.command()
@click.option("--run", "folder", default="runs/swift", show_default=True, help="Run folder (resumed when it holds a state).")
@click.option("--threads", default=1, show_default=True)
@click.option("--steps", type=int, default=None, help="Stop after this many more steps.")
@click.option("--minutes", type=float, default=None, help="Stop after this many minutes.")
@click.option("--checkpoint-minutes", type=float, default=None, help="Save every this many minutes (default 10).")
@click.option("--eval-minutes", type=float, default=None, help="Evaluate every this many minutes (default 30).")
@click.option("--checkpoint", default=None,
              help=f"Committed compact checkpoint to resume from when FOLDER holds no state (default {CHECKPOINT}; "
                   "one named here must exist).")
@click.option("--schedule", default=None, callback=lambda ctx, p, v: _schedule(v),
              help="Samples per stage, e.g. masks=300000,aux=200000,maps=3000000, then joint=N to fine-tune the "
                   "whole chain (default: the run's own).")
@click.option("--restart-stage", type=click.Choice(["masks", "aux", "maps"]), default=None,
              help="Train this stage (and those after it) again from its start under the current loss "
                   "settings; the earlier stages and the run's counters are kept.")
@click.option("--bank-count", type=int, default=None,
              help="Grow the material bank to this many materials and train on them from now on "
                   "(default: the run's own).")
@click.option("--weight", "weight_pairs", multiple=True, metavar="NAME=VALUE", callback=lambda ctx, p, v: _weights(v),
              help="A maps-loss weight from now on (normal, diffuse, roughness, specular, relief, render, real_f0; 0 drops "
                   "the term), e.g. render=0.5; repeatable. The run keeps it.")
@click.option("--specular-level", type=click.Choice(SPECULAR_LEVELS), default=None,
              help="The maps stage's F0 target from now on: the material's, or at the photo's flash level as "
                   "the diffuse (the run keeps it).")
@click.option("--halve-every", type=click.IntRange(1), default=None,
              help="The learning rate halves every this many samples of a stage from now on (the run keeps it).")
@click.option("--flash-context", type=click.Choice(FLASH_CONTEXTS), default=None,
              help="Where the networks' flash context comes from, from now on: the true flash jittered, or the "
                   "runtime's fit on the photo (the run keeps it).")
@click.option("--prefetch/--no-prefetch", default=False, show_default=True,
              help="Make the batches ahead in a child process that runs only on CPU time no other process wants "
                   "(the same run, faster where a core idles; export/engine/prefetch.py).")
def train(folder, threads, steps, minutes, checkpoint_minutes, eval_minutes, checkpoint, schedule, restart_stage,
          bank_count, weight_pairs, specular_level, halve_every, flash_context, prefetch):
    """Train the swift chain in FOLDER, or resume it; SIGTERM/SIGINT save and exit 0."""
    import dataclasses
    import os

    from export.engine.run import Run, RunConfig

    _setup(threads)
    if checkpoint is None:
        checkpoint = CHECKPOINT
    elif not os.path.isfile(os.path.join(folder, "state.pt")) and not os.path.isfile(os.path.join(checkpoint, "manifest.json")):
        raise click.ClickException(f"{checkpoint}: no compact checkpoint there (manifest.json) to start {folder} from")
    config = dataclasses.replace(RunConfig(), schedule=schedule) if schedule else None
    run = Run(folder, config=config, log=lambda m: click.echo(m, err=True), checkpoint=checkpoint)
    changes = {k: v for k, v in (("checkpoint_minutes", checkpoint_minutes), ("eval_minutes", eval_minutes),
                                 ("bank_count", bank_count), ("halve_every", halve_every)) if v is not None}
    if weight_pairs:
        changes["weights"] = tuple({**dict(run.config.weights), **weight_pairs}.items())
    if specular_level and specular_level != run.config.specular_level:
        changes["specular_level"] = specular_level
        click.echo(f"the maps stage's F0 target from step {run.step}: {specular_level}", err=True)
    if flash_context and flash_context != run.config.flash_context:
        changes["flash_context"] = flash_context
        click.echo(f"the networks' flash context from step {run.step}: {flash_context}", err=True)
    if halve_every and halve_every != run.config.halve_every:
        click.echo(f"the learning rate halves every {halve_every} samples of a stage from step {run.step}", err=True)
    if changes:
        run.config = dataclasses.replace(run.config, **changes)
        run.net.loss_weights = dict(run.config.weights)
        if weight_pairs:
            click.echo(f"maps loss weights from step {run.step}: {dict(run.config.weights)}", err=True)
    if restart_stage:
        run.restart_stage(restart_stage)
        run.save()
    click.echo(f"run {folder}: step {run.step}, stage {run.stage}, {run.samples} samples, "
               f"{run.cpu / 3600:.2f} CPU h", err=True)
    run.train(steps=steps, minutes=minutes, prefetch=prefetch)
    click.echo(f"run {folder}: saved at step {run.step} ({run.samples} samples)", err=True)


def _weights(pairs):
    """``("render=0.5", ...)`` -> {name: weight} (names of :data:`export.engine.run.RunConfig.weights`' kinds)."""
    from export.engine.run import EXTRA_TERMS
    from svbrdf_cli.conventions import MAP_NAMES

    out = {}
    for pair in pairs:
        name, _, value = pair.partition("=")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise click.BadParameter(f"{pair!r}: write NAME=VALUE, e.g. render=0.5")
        if name.strip() not in MAP_NAMES + EXTRA_TERMS or out[name.strip()] < 0:
            raise click.BadParameter(f"{pair!r}: NAME is one of {', '.join(MAP_NAMES + EXTRA_TERMS)}, VALUE at least 0")
    return out


def _schedule(text):
    """``masks=300000,aux=200000,maps=3000000[,joint=1000000]`` -> the schedule tuple (stages in the chain's
    order, then the whole chain fine-tuned if named: :data:`export.engine.run.JOINT`)."""
    if not text:
        return None
    from export.engine.nets import STAGES
    from export.engine.run import JOINT

    try:
        pairs = [(k.strip(), int(v)) for k, v in (item.split("=") for item in text.split(","))]
    except ValueError:
        raise click.BadParameter(f"{text!r}: write stage=samples pairs, e.g. masks=300000,aux=200000,maps=3000000")
    names = [k for k, _ in pairs]
    if names not in (list(STAGES), list(STAGES) + [JOINT]) or any(v <= 0 for _, v in pairs):
        raise click.BadParameter(f"{text!r}: give every stage ({', '.join(STAGES)}) in that order, each a positive "
                                 f"count, and {JOINT}=N after them to fine-tune the whole chain")
    return tuple(pairs)


@main.command()
@click.option("--run", "folder", default="runs/swift", show_default=True)
@click.option("--schedule", default=None, callback=lambda ctx, p, v: (_schedule(v), v)[1],
              help="Passed to train: samples per stage (default: the run's own).")
@click.option("--restart-stage", type=click.Choice(["masks", "aux", "maps"]), default=None,
              help="Passed to train (once: a later resume goes on from the restarted stage).")
@click.option("--bank-count", type=int, default=None, help="Passed to train: the bank's size from now on.")
@click.option("--weight", "weight_pairs", multiple=True, metavar="NAME=VALUE", callback=lambda ctx, p, v: (_weights(v), v)[1],
              help="Passed to train: a maps-loss weight from now on, e.g. render=0.5; repeatable.")
@click.option("--specular-level", type=click.Choice(SPECULAR_LEVELS), default=None,
              help="Passed to train: the maps stage's F0 target from now on.")
@click.option("--checkpoint", default=None,
              help=f"Passed to train: the compact checkpoint a run folder without a state starts from (default {CHECKPOINT}).")
@click.option("--halve-every", type=click.IntRange(1), default=None,
              help="Passed to train: the learning rate halves every this many samples of a stage from now on.")
@click.option("--flash-context", type=click.Choice(FLASH_CONTEXTS), default=None,
              help="Passed to train: where the networks' flash context comes from, from now on.")
@click.option("--prefetch/--no-prefetch", default=True, show_default=True,
              help="Passed to train: make the batches ahead on the machine's idle CPU time.")
def background(folder, schedule, restart_stage, bank_count, weight_pairs, specular_level, checkpoint, halve_every,
               flash_context, prefetch):
    """Resume (or start) the run in FOLDER detached, on one core (and the other's idle time, making its batches
    ahead: --prefetch); its log is FOLDER/log.txt."""
    import os
    import subprocess
    import sys

    os.makedirs(folder, exist_ok=True)
    pid_file = os.path.join(folder, "pid")
    if os.path.isfile(pid_file):
        try:
            pid = int(open(pid_file).read())
            os.kill(pid, 0)
            raise click.ClickException(f"{folder}: already running as pid {pid}")
        except (ValueError, ProcessLookupError):
            pass
    env = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    with open(os.path.join(folder, "log.txt"), "a") as log:
        args = [sys.executable, "-m", "export.engine", "train", "--run", folder, "--threads", "1"]
        args += (["--schedule", schedule] if schedule else []) + (["--restart-stage", restart_stage] if restart_stage else [])
        args += ["--bank-count", str(bank_count)] if bank_count else []
        args += [a for pair in weight_pairs for a in ("--weight", pair)]
        args += ["--specular-level", specular_level] if specular_level else []
        args += ["--checkpoint", checkpoint] if checkpoint else []
        args += ["--halve-every", str(halve_every)] if halve_every else []
        args += ["--flash-context", flash_context] if flash_context else []
        args += ["--prefetch"] if prefetch else []
        p = subprocess.Popen(args,
                             stdout=log, stderr=log, stdin=subprocess.DEVNULL, start_new_session=True, env=env)
    with open(pid_file, "w") as f:
        f.write(str(p.pid))
    click.echo(f"training {folder} in the background as pid {p.pid}; log: {folder}/log.txt")


@main.command()
@click.option("--run", "folder", default="runs/swift", show_default=True)
@click.option("--out", default=CHECKPOINT, show_default=True)
def compact(folder, out):
    """Write FOLDER's last saved state to OUT as files under 25 MB (commit them)."""
    import os

    from export.engine.run import Run

    if not os.path.isfile(os.path.join(folder, "state.pt")):
        raise click.ClickException(f"{folder}: no saved state")
    run = Run(folder, log=lambda m: None)
    run.save_compact(out)
    size = sum(os.path.getsize(os.path.join(out, f)) for f in os.listdir(out))
    click.echo(f"{out}: step {run.step}, stage {run.stage}, {run.samples} samples, {size / 1e6:.1f} MB")


@main.command()
@click.option("--run", "folder", default="runs/swift", show_default=True)
def stop(folder):
    """Ask the background run in FOLDER to save and stop (SIGTERM), and wait for it."""
    import os
    import signal
    import time

    pid_file = os.path.join(folder, "pid")
    try:
        pid = int(open(pid_file).read())
        os.kill(pid, signal.SIGTERM)
    except (OSError, ValueError):
        raise click.ClickException(f"{folder}: no background run")
    while True:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            break
        time.sleep(1)
    os.remove(pid_file)
    click.echo(f"{folder}: stopped and saved")


@main.command()
@click.option("--out", default="docs/figures/bank.png", show_default=True)
@click.option("--seed", default=0, show_default=True)
def figure(out, seed):
    """Draw 64 random bank materials (photo and maps) to OUT."""
    import cv2

    from export.engine.figure import bank_figure

    _setup(1)
    sheet = bank_figure(bank_mod.Bank(), seed=seed)
    cv2.imwrite(out, sheet[..., ::-1])
    click.echo(f"{out}: {sheet.shape[1]}x{sheet.shape[0]}")


@main.command()
@click.option("--run", "folder", default="runs/swift", show_default=True)
@click.option("--out", default="docs/figures/learning_curve.png", show_default=True)
def curve(folder, out):
    """Plot FOLDER/curve.jsonl to OUT."""
    import os

    from export.engine import curve as curve_mod

    path = os.path.join(folder, "curve.jsonl")
    if not os.path.isfile(path):
        raise click.ClickException(f"{path}: no evaluations yet")
    curve_mod.plot(curve_mod.read(path), out)
    click.echo(out)


@main.command()
@click.option("--run", "folder", default="runs/swift", show_default=True)
@click.option("--out", default="weights/swift", show_default=True, help="Folder for chain.onnx.")
def onnx(folder, out):
    """Export the run's chain (its last saved state) as OUT/chain.onnx with its provenance."""
    import json
    import os

    from export.engine import onnx as engine_onnx
    from export.engine.run import Run

    run = Run(folder, log=lambda m: None, checkpoint=CHECKPOINT)
    curve = os.path.join(folder, "curve.jsonl")
    last = json.loads(open(curve).read().splitlines()[-1]) if os.path.isfile(curve) else {}
    provenance = {"run": folder, "step": run.step, "samples": run.samples, "cpu_hours": round(run.cpu / 3600, 3),
                  "stage": run.stage, "schedule": run.config.schedule, "bank": "export.engine.bank (procedural, CC0, mixes)",
                  "des19": last.get("des19"), "specular_level": run.config.specular_level}
    provenance["weights"] = "moving average" if run.ema is not None else "as trained"
    with run.averaged():
        path = engine_onnx.export(run.net, os.path.join(out, "chain.onnx"), provenance, run_size=run.config.size,
                                 specular_level=run.config.specular_level)
    click.echo(f"{path}: {os.path.getsize(path) / 1e6:.1f} MB, {run.samples} samples")
