"""Learning curves of a training lineage: validation error against steps, per map, next to the physical estimate.

    python -m export.studies.learning_curves weights/checkpoints/lite-normal/provenance.json -o docs/figures/learning_curve.png
    python -m export.studies.learning_curves RUN_A/maps.pt RUN_B/maps.pt --json curve.json   # join runs' histories

Inputs are checkpoints (``maps.pt``: their ``history`` holds a validation entry every
``--val-every`` steps) or a ``provenance.json`` whose ``learning_curve`` holds such entries already
joined. Runs are joined in the order given, each one's steps following the previous one's.
"""

from __future__ import annotations

import json
import os

import click

from export.files import command_errors
from svbrdf_cli.errors import SvbrdfError
from svbrdf_cli import conventions as cv


def curve_of_checkpoint(path, offset=0, label=None):
    """Validation entries of one checkpoint's history, steps shifted by ``offset``."""
    import torch

    ck = torch.load(path, map_location="cpu", weights_only=False)
    label = label or os.path.basename(os.path.dirname(os.path.abspath(path)))
    out = []
    for h in ck.get("history") or []:
        v = h.get("val")
        if v:
            out.append({"step": offset + int(h["step"]), "run": label, "physical_version": ck.get("physical_version"),
                        **{k: round(float(x), 5) for k, x in v.items() if k != "step"}})
    return out, offset + int(ck.get("step", 0))


def load_curve(paths):
    """Joined validation entries of ``paths`` (checkpoints or provenance files), in order."""
    curve, offset = [], 0
    for p in paths:
        if p.endswith(".json"):
            with open(p) as f:
                part = json.load(f).get("learning_curve")
            if not part:
                raise SvbrdfError(f"{p}: no learning_curve entries; give the runs' maps.pt files instead.")
            curve += part
            offset = max([offset] + [e["step"] for e in part])
        else:
            part, offset = curve_of_checkpoint(p, offset)
            curve += part
    return curve


def plot(curve, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 4, figsize=(16, 3.6))
    steps = [e["step"] for e in curve]
    for ax, name in zip(axes, cv.MAP_NAMES):
        ax.plot(steps, [e[f"rmse_{name}"] for e in curve], "o-", label="network")
        ax.plot(steps, [e[f"physical_{name}"] for e in curve], "--", color="grey", label="physical estimate")
        ax.set_title(name)
        ax.set_xlabel("training step (joined runs)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("RMSE, generated validation")
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


@click.command()
@click.argument("inputs", nargs=-1, required=True, type=click.Path(exists=True, dir_okay=False))
@click.option("-o", "--output", type=click.Path(dir_okay=False), default=None, help="PNG figure.")
@click.option("--json", "json_out", type=click.Path(dir_okay=False), default=None, help="The joined entries.")
def cli(inputs, output, json_out):
    with command_errors():
        curve = load_curve(list(inputs))
        for e in curve:
            click.echo(f"{e['step']:6d} {e['run']:14s} " + " ".join(f"{k}={e[f'rmse_{k}']:.4f}" for k in cv.MAP_NAMES))
        if output:
            plot(curve, output)
        if json_out:
            with open(json_out, "w") as f:
                json.dump(curve, f, indent=1)


if __name__ == "__main__":
    cli()
