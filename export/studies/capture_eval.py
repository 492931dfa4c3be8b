"""What ``svbrdf capture`` itself scores: the real command (crop, exposure, albedo convention,
upsampling, ``--refine``) on Des19's 29 inputs and on ``card_blue_9lights``.

    python -m export.studies.capture_eval                            # the default capture
    python -m export.studies.capture_eval -- --model physical        # options passed to svbrdf capture
    python -m export.studies.capture_eval --crop auto -- --refine 0  # the default crop instead of none

The harnesses of :mod:`export.studies.refine_eval` call the estimate directly at the Des19 inputs' own
flash power; a user's maps come from the command. Here each Des19 input goes through
``svbrdf capture --size 256`` and the written maps are scored by ``score_maps.py``; the card's photo
00 goes through the command and its maps relight photos 01-08
(:meth:`export.render.relight.NineLights.relight_rmse`), and ``--all-card`` also captures each of
the 9 photos in turn and relights the 8 others from it.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile

import click
import numpy as np

from export.files import command_errors, shared_root
from export.render.relight import NineLights
from export.studies.evaluate import score
from svbrdf_cli.errors import SvbrdfError
from svbrdf_cli.write.mapset import read_stored_maps

#: The maps the scorer reads, written by the native preset.
NATIVE = ("normal", "diffuse", "roughness", "specular")


def capture(photos, out, options=(), crop="none"):
    """``svbrdf capture`` on ``photos`` (one process) at 256 px into ``out``; raises on failure."""
    cmd = [os.path.join(os.path.dirname(sys.executable), "svbrdf"), "capture", *map(str, photos), "-o", str(out), "--size", "256",
           "--no-preview", "--crop", crop, *options]
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        raise SvbrdfError(f"svbrdf capture failed ({' '.join(cmd[1:])}): {res.stderr.strip()[-400:]}")


def des19(root, options=(), crop="none"):
    """Des19's inputs through the command, scored: ({map: rmse}, the scorer's line)."""
    samples = sorted(d for d in os.listdir(root) if os.path.isfile(os.path.join(root, d, "input.png")))
    with tempfile.TemporaryDirectory() as tmp:
        inputs = os.path.join(tmp, "in")
        os.makedirs(inputs)
        for s in samples:  # the set is named after the photo: one file per sample, named as its folder
            shutil.copyfile(os.path.join(root, s, "input.png"), os.path.join(inputs, f"{s}.png"))
        capture([inputs], os.path.join(tmp, "out"), options, crop)
        return score(root, os.path.join(tmp, "out"))


def card(folder, options=(), all_photos=False):
    """The card's relighting from photo 00's capture, and (``all_photos``) the mean over the 9 photos
    each captured in turn and relit under the other 8."""
    nine = NineLights(folder)
    order = list(range(len(nine.photos))) if all_photos else [0]
    with tempfile.TemporaryDirectory() as tmp:
        capture([os.path.join(folder, f"{i:02d}.jpg") for i in order], tmp, options, "none")
        errs = [nine.relight_rmse(read_stored_maps(os.path.join(tmp, f"{i:02d}")), source=i) for i in order]
    return {"card": errs[0], **({"card_all": float(np.mean(errs))} if all_photos else {})}


@click.command(context_settings={"show_default": True})
@click.option("--crop", type=click.Choice(["none", "auto"]), default="none",
              help="The crop for Des19 (its inputs are the material already: none keeps them aligned).")
@click.option("--all-card", is_flag=True, help="Also capture each of the card's 9 photos and relight the others.")
@click.option("--json", "json_out", type=click.Path(dir_okay=False), help="Write the numbers here too.")
@click.argument("options", nargs=-1, type=click.UNPROCESSED)
def cli(crop, all_card, json_out, options):
    """Des19 and the card through ``svbrdf capture OPTIONS``."""
    with command_errors():
        data = shared_root() / "data"
        des, line = des19(data / "validation" / "des19", options, crop)
        res = {**des, **card(str(data / "real" / "card_blue_9lights"), options, all_card)}
        click.echo(line)
        click.echo("  ".join(f"{k} {v:.4f}" for k, v in res.items()))
        if json_out:
            with open(json_out, "w") as f:
                json.dump({"options": list(options), "crop": crop, **res}, f, indent=1)


if __name__ == "__main__":
    cli()
