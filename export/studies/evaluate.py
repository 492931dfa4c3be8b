"""Evaluate a trained run on the Des19 validation samples (paper Tables I and IV).

    python -m export.studies.evaluate --run runs/fast

For every sample of ``../shared/data/validation/des19`` it predicts the maps
from ``input.png``, writes them as native map sets under ``--out`` and scores
them with the paper's metric, the reference scorer
``../shared/tools/score_maps.py`` (run as it is, not restated). It also
reports the re-rendering RMSE under 9 fixed lights (encoded images,
ground-truth vs predicted maps) and the step-by-step analysis of Table IV:

* ``full``: input -> masks -> aux -> maps;
* ``gt_masks``: ground-truth masks -> aux -> maps;
* ``gt_aux``: ground-truth aux renderings -> maps (the upper bound of the
  maps stage).

Ground-truth masks and aux renderings are rendered from the ground-truth
maps at the paper's geometry (flash at the default position) with the flash
intensity that gives the input's mean brightness: the light positions of the
Des19 inputs are not given (they vary within +-0.35 around the centre), so
these targets are close to, not exactly, what the input shows.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tempfile

import click
import numpy as np
import torch

from export.files import command_errors, shared_root
from export.render import targets
from export.render.brdf import render, render_maps
from export.render.relight import fit_intensity
from svbrdf_cli import conventions as cv
from svbrdf_cli.errors import SvbrdfError
from svbrdf_cli.imageio import read_image
from svbrdf_cli.write.mapset import read_map_set, write_map_set

MODES = ("full", "gt_masks", "gt_aux")
#: Fixed relighting positions for the re-rendering RMSE (8 around + 1 centre, as in 9-light captures).
RELIGHT = [(0.0, 0.0, cv.CAMERA_HEIGHT)] + [
    (1.2 * np.cos(a), 1.2 * np.sin(a), cv.CAMERA_HEIGHT) for a in np.linspace(0, 2 * np.pi, 9)[:-1]]


def chw(maps):
    """{name: (H, W, C) numpy map} -> {name: (C, H, W) float32 torch tensor}."""
    return {k: torch.from_numpy(np.ascontiguousarray(v)).permute(2, 0, 1).float() for k, v in maps.items()}


def load_des19(folder):
    """[(name, input (3, H, W) tensor, linear GT maps dict of (C, H, W))].

    The ground truth's diffuse and specular PNGs hold linear albedo (``../shared/data/README.md``),
    so they are read as they are, not decoded from our gamma-2.2 encoding.
    """
    out = []
    for name in sorted(os.listdir(folder)):
        d = os.path.join(folder, name)
        if not os.path.isfile(os.path.join(d, "input.png")):
            continue
        img = torch.from_numpy(read_image(os.path.join(d, "input.png"))[..., :3]).permute(2, 0, 1).float()
        maps = {k: torch.from_numpy(np.ascontiguousarray(v)).permute(2, 0, 1).float()
                for k, v in read_map_set(d, linear_albedo=True).items()}
        maps["roughness"] = maps["roughness"][:1]
        out.append((name, img, maps))
    return out


def ground_truth_intermediates(photo, maps):
    """Masks and aux renderings from GT maps, exposed like the input (see module doc)."""
    m = {k: v[None] for k, v in maps.items()}
    intensity = targets.auto_exposure(m, target=float(photo.mean()))
    return {k: v[0] for k, v in targets.intermediate_targets(m, intensity=intensity,
                                                        names=("I_bf", "I_hr", "I_hr2", "M_b", "M_h")).items()}


@torch.no_grad()
def predict(net, photo, mode="full", gt=None):
    x = photo[None]
    if mode == "gt_aux":
        aux = {k: gt[k][None] for k in ("I_bf", "I_hr", "I_hr2")}
    else:
        masks = net.run_masks(x) if mode == "full" else {k: gt[k][None] for k in ("M_b", "M_h")}
        aux = net.run_aux(x, masks)
    out = net.run_maps(x, aux)
    return {k: v[0] for k, v in out.items()}


def relight_rmse(pred_linear, gt_linear, lights=RELIGHT):
    """Mean RMSE of encoded renderings under ``lights`` (default :data:`RELIGHT`)."""
    errs = []
    for light in lights:
        a = cv.image_to_encoded(render(*(pred_linear[k][None] for k in cv.MAP_NAMES), light=light))
        b = cv.image_to_encoded(render(*(gt_linear[k][None] for k in cv.MAP_NAMES), light=light))
        errs.append(float(((a - b) ** 2).mean().sqrt()))
    return float(np.mean(errs))


def score(gt_root, pred_root=None, prefix=""):
    """Run the reference scorer; returns {map: rmse} and its output line."""
    scorer = shared_root() / "tools" / "score_maps.py"
    cmd = [sys.executable, str(scorer), str(gt_root)] + (["--pred", str(pred_root)] if pred_root else []) \
        + (["--prefix", prefix] if prefix else [])
    res = subprocess.run(cmd, capture_output=True, text=True)
    line = res.stdout.strip().splitlines()[-1] if res.stdout.strip() else res.stderr.strip()
    vals = dict(re.findall(r"(normal|relief|diffuse|roughness|specular)=(-?[0-9.]+)", line))
    return {k: float(v) for k, v in vals.items()}, line


def oracle_scale(pred_linear, gt_linear):
    """Pred maps with diffuse and specular times the one scalar that best fits the ground truth.

    A diagnostic, not a method: from one auto-exposed photo the albedo scale
    is ambiguous (a darker material under a stronger light looks the same).
    Least squares over both maps, in linear space, per sample.
    """
    p = torch.cat([pred_linear["diffuse"].flatten(), pred_linear["specular"].flatten()])
    g = torch.cat([gt_linear["diffuse"].flatten(), gt_linear["specular"].flatten()])
    k = float((p * g).sum() / (p * p).sum().clamp_min(1e-12))
    return dict(pred_linear, diffuse=pred_linear["diffuse"] * k, specular=pred_linear["specular"] * k), k


def known_flash_scale(pred_linear, photo, intensity=cv.FLASH_INTENSITY):
    """Pred maps with diffuse and specular rescaled so that, rendered under a
    flash of the known ``intensity``, they reproduce the photo's brightness.

    Uses the input alone, never the ground truth: the photo's linear values
    are fitted (least squares over unsaturated pixels) by the predicted maps'
    flash rendering at unit intensity; the fitted intensity over the known one
    is the albedo scale. This is what a capture with a calibrated flash and
    fixed exposure allows. Des19's inputs are not such captures: its ground
    truth needs a median intensity of 42 (0.3 to 856 across samples) to
    reproduce its inputs under our renderer, against the conventions' 2.91.
    """
    img = render_maps({k: v[None] for k, v in pred_linear.items()}, intensity=1.0)[0]  # linear, unit flash
    k = fit_intensity(img.permute(1, 2, 0).numpy(), photo.permute(1, 2, 0).numpy()) / intensity
    return dict(pred_linear, diffuse=(pred_linear["diffuse"] * k).clamp(0, 1),
                specular=(pred_linear["specular"] * k).clamp(0, 1)), k


#: Post-hoc albedo rescalings of the ``full`` row: name -> (row suffix, f(linear maps, photo, gt) -> (maps, scale)).
RESCALINGS = {"oracle": ("_oracle_scale", lambda lin, photo, gt: oracle_scale(lin, gt)),
              "known_flash": ("_known_flash", lambda lin, photo, gt: known_flash_scale(lin, photo))}


def score_predictions(samples, des19, out, predict, rescale=None):
    """Write predicted map sets under ``out`` and score them (reference scorer, 9-light relighting).

    ``predict(name, photo) -> {map: stored (C, H, W) tensor}`` for each Des19
    sample; ``rescale(linear maps, photo, gt) -> (maps, scale)`` is applied
    after decoding when given. Returns ({map: rmse, "relight": mean}, per-sample
    relighting RMSEs, scales, the scorer's line).
    """
    rel, scales = [], []
    for name, photo, gt in samples:
        lin = cv.decode_maps(predict(name, photo), axis=0)
        if rescale:
            lin, k = rescale(lin, photo, gt)
            scales.append(k)
        write_map_set(os.path.join(out, name), {k: v.permute(1, 2, 0).numpy() for k, v in lin.items()})
        rel.append(relight_rmse(lin, gt))
    maps, line = score(des19, out)
    return {**maps, "relight": float(np.mean(rel))}, rel, scales, line


def evaluate(run=None, des19=None, out=None, modes=MODES, log=print, onnx=None, oracle=False, known_flash=False):
    """Score a torch run, or (``onnx``: a folder of exported stages) the
    runtime's onnxruntime chain; the latter has only the ``full`` mode.
    ``oracle`` adds the ``full`` row with :func:`oracle_scale` applied,
    ``known_flash`` the one with :func:`known_flash_scale`."""
    des19 = des19 or str(shared_root() / "data" / "validation" / "des19")
    if not os.path.isdir(des19):
        raise SvbrdfError(f"{des19}: Des19 validation samples not found (set SVBRDF_SHARED)")
    if onnx:
        from svbrdf_cli.infer.chain import Chain

        chain, modes = Chain(onnx), ("full",)
    else:
        from export.train import load_trained

        net = load_trained(run)
    samples = load_des19(des19)
    # Rendered once per sample, shared by the modes that need them (I_hr is the costly part).
    inter = {name: ground_truth_intermediates(photo, gt) for name, photo, gt in samples} \
        if any(m != "full" for m in modes) else {}
    out = out or tempfile.mkdtemp(prefix="svbrdf-eval-")
    results = {}
    full = {}  # the full chain's maps per sample, shared by the rescaled rows

    def predictor(mode):
        def f(name, photo):
            if mode == "full" and name in full:
                return full[name]
            if onnx:
                res = chain(photo.permute(1, 2, 0).numpy())
                pred = {k: torch.from_numpy(res[k]).permute(2, 0, 1) for k in cv.MAP_NAMES}
            else:
                pred = predict(net, photo, mode, inter.get(name))
            pred = {k: pred[k] for k in cv.MAP_NAMES}
            if mode == "full":
                full[name] = pred
            return pred
        return f

    extra = [RESCALINGS[r] for r, on in (("oracle", oracle), ("known_flash", known_flash)) if on and "full" in modes]
    for mode, rescale in [(m, None) for m in modes] + [("full" + suffix, f) for suffix, f in extra]:
        scores, _, scales, line = score_predictions(samples, des19, os.path.join(out, mode),
                                                    predictor("full" if rescale else mode), rescale)
        results[mode] = {**scores, "samples": len(samples)}
        if scales:
            results[mode]["scale_median"] = float(np.median(scales))
        log(f"{mode:9s} {line}  relight={scores['relight']:.4f}"
            + (f"  median scale={np.median(scales):.3f}" if scales else ""))
    paper, line = score(des19, prefix="paper_")
    results["paper"] = paper
    log(f"{'paper':9s} {line}")
    return results


@click.command()
@click.option("--run", "run", type=click.Path(exists=True, file_okay=False), default=None,
              help="Run folder holding masks.pt, aux.pt, maps.pt.")
@click.option("--onnx", type=click.Path(exists=True, file_okay=False), default=None,
              help="Score exported ONNX stages through the runtime chain instead (full chain only).")
@click.option("--des19", type=click.Path(file_okay=False), default=None)
@click.option("--out", type=click.Path(file_okay=False), default=None, help="Where predicted maps go.")
@click.option("--json", "json_out", type=click.Path(dir_okay=False), default=None, help="Write the numbers here too.")
@click.option("--threads", default=0)
@click.option("--modes", default=",".join(MODES), show_default=True,
              help="Which Table IV rows (comma-separated); ablation runs (--variant nomask/e2e) use 'full'.")
@click.option("--record", is_flag=True, help="With --onnx: add the scores to the folder's provenance.json.")
@click.option("--oracle-scale", "oracle", is_flag=True,
              help="Also score 'full' with diffuse and specular rescaled per sample by the best-fitting "
                   "scalar (a diagnostic of the albedo-scale ambiguity, not a result).")
@click.option("--known-flash", "known_flash", is_flag=True,
              help="Also score 'full' with diffuse and specular rescaled so that the maps reproduce the input "
                   "under the conventions' flash intensity (a calibrated capture; uses the input only).")
def cli(run, onnx, des19, out, json_out, threads, modes, record, oracle, known_flash):
    """Score a trained run (or its ONNX export) on Des19 with the paper's metric."""
    if not (run or onnx):
        raise click.UsageError("give --run or --onnx")
    if threads:
        torch.set_num_threads(threads)
    modes = tuple(m for m in modes.split(",") if m)
    unknown = set(modes) - set(MODES)
    if unknown:
        raise click.BadParameter(f"unknown mode(s) {', '.join(sorted(unknown))}; choose from {', '.join(MODES)}",
                                 param_hint="--modes")
    with command_errors():
        results = evaluate(run, des19, out, modes=modes, log=click.echo, onnx=onnx, oracle=oracle,
                           known_flash=known_flash)
    if json_out:
        with open(json_out, "w") as f:
            json.dump(results, f, indent=1)
    if record:
        if not onnx:
            raise click.UsageError("--record needs --onnx")
        from export.files import read_json, write_json

        path = os.path.join(onnx, "provenance.json")
        prov = read_json(path)
        prov["des19"] = {"full_chain": results["full"], "paper": results["paper"],
                         **({"full_chain_known_flash": results["full_known_flash"]}
                            if "full_known_flash" in results else {}),
                         "metric": "../shared/tools/score_maps.py (per-map RMSE; roughness as 0.9 r + 0.1); "
                                   "relight: mean RMSE of encoded renders under 9 lights",
                         "command": f"python -m export.studies.evaluate --onnx {onnx} --record"
                                    + (" --known-flash" if known_flash else "")}
        write_json(path, prov)


if __name__ == "__main__":
    cli()
