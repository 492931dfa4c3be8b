"""How far can one capture's maps of ``card_blue_9lights`` go by changing a few numbers per material?

    python -m export.studies.card_ceiling                       # the default capture
    python -m export.studies.card_ceiling --classes 6 -- --model physical
    python -m export.studies.card_ceiling --swaps                # the reference's maps swapped in

The card is relit from photo 00's maps under its 8 other lights (:class:`export.render.relight.NineLights`).
Here photo 00 goes through ``svbrdf capture`` (the options after ``--``), and its maps are refitted with
their normals and the diffuse's pattern kept: the diffuse's colours are split into ``--classes`` soft classes
(k-means of the log colour, as :func:`svbrdf_cli.infer.swift.roughness_from_observed` splits them) and each
class gets its own F0 (RGB), roughness and diffuse factor (RGB), constant over the class. The refit is
fitted by Adam through the differentiable renderer (:func:`export.render.brdf.render_maps`), the light's
intensity the one fitted to the capture's maps on photo 00 and held:

* **from photo 00**: what one photo can tell of those numbers, a method's reach;
* **from all 9 photos**: fitted on the photos it is scored on, so not a method but a bound: how well
  these normals and this diffuse pattern can relight the card with per-material constants at best.

Printed: the card's relighting RMSE of the capture, of each refit, and each class's fitted values.

With ``--swaps``, instead: the capture relit with one or two of its maps replaced by the card's reference
maps (:meth:`export.render.relight.NineLights.reference_maps`, fitted by MaterialGAN on all 9 photos),
and the reference relit with one of the capture's in place of its own (:func:`swaps`): which map holds the
error, and which maps only work together.
"""

from __future__ import annotations

import os
import tempfile

import click
import numpy as np

from export.files import command_errors, shared_root

#: Adam steps and step size of a refit.
STEPS = 300
LEARNING_RATE = 0.05


def soft_classes(diffuse_lin, k):
    """(H*W, k) soft classes of the diffuse's colour (float32): the runtime's
    (:func:`svbrdf_cli.imageops.soft_classes`), on every pixel with 3 restarts."""
    from svbrdf_cli.imageops import soft_classes as classes

    return classes(diffuse_lin, k, every=1, attempts=3).astype(np.float32)


def refit(nine, lin, classes, photos):
    """``lin`` (linear maps) with per-class F0, roughness and diffuse factor fitted to ``photos`` (indices of
    ``nine``'s photos); returns (the refitted linear maps, {name: (k, C) fitted values})."""
    import torch

    from export.render.brdf import render_maps
    from export.render.relight import fit_intensity
    from svbrdf_cli import conventions as cv

    def nchw(a):
        return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32)).permute(2, 0, 1)[None]

    h, w = lin["diffuse"].shape[:2]
    k = classes.shape[1]
    p = torch.from_numpy(classes.T.reshape(k, 1, h, w))  # (k, 1, H, W)
    normal, diffuse = nchw(lin["normal"]), nchw(lin["diffuse"])
    start_f0 = float(np.clip(lin["specular"].mean(), 0.01, 0.5))
    f0 = torch.full((k, 3), float(np.log(start_f0 / (1 - start_f0))), requires_grad=True)
    rough = torch.zeros(k, requires_grad=True)
    gain = torch.zeros(k, 3, requires_grad=True)

    def maps():
        return {"normal": normal,
                "diffuse": (diffuse * (torch.exp(gain)[:, :, None, None] * p).sum(0)[None]).clamp(0, 1),
                "roughness": (torch.sigmoid(rough)[:, None, None, None] * p).sum(0)[None],
                "specular": (torch.sigmoid(f0)[:, :, None, None] * p).sum(0)[None]}

    intensity = fit_intensity(nine._render(lin, 0), nine.photos[0])
    targets = [(i, nchw(cv.image_to_linear(nine.photos[i])), nchw((nine.photos[i] < 0.98).all(-1, keepdims=True)))
               for i in photos]
    opt = torch.optim.Adam([f0, rough, gain], lr=LEARNING_RATE)
    for _ in range(STEPS):
        m = maps()
        loss = 0.0
        for i, photo, ok in targets:
            r = render_maps(m, light=nine.lights[i], camera=nine.lights[i], intensity=intensity)
            enc = (r.clamp_min(0) + 1e-3) ** (1 / cv.IMAGE_GAMMA)
            loss = loss + (((enc - (photo + 1e-3) ** (1 / cv.IMAGE_GAMMA)) ** 2) * ok).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        out = {n: v[0].permute(1, 2, 0).numpy() for n, v in maps().items()}
        values = {"F0": torch.sigmoid(f0).numpy(), "roughness": torch.sigmoid(rough).numpy()[:, None],
                  "diffuse factor": torch.exp(gain).numpy()}
    return out, values


def swaps(score, ours, reference):
    """{label: ``score(maps)``} of ``ours`` (stored maps), of ``ours`` with each one map and each pair of maps
    of ``reference``, and of ``reference`` with each one of ``ours``."""
    import itertools

    from svbrdf_cli.conventions import MAP_NAMES

    out = {"capture": score(ours), "reference": score(reference)}
    for k in (1, 2):
        for names in itertools.combinations(MAP_NAMES, k):
            out["capture with the reference's " + " and ".join(names)] = score({**ours, **{n: reference[n] for n in names}})
    for name in MAP_NAMES:
        out[f"reference with the capture's {name}"] = score({**reference, name: ours[name]})
    return out


@click.command(context_settings={"show_default": True})
@click.option("--classes", default=4, help="Soft classes of the diffuse's colour, each refitted with its own numbers.")
@click.option("--threads", default=1, help="torch threads.")
@click.option("--swaps", "swap", is_flag=True, help="Instead: the capture relit with the reference's maps swapped in, one "
                                            "or two at a time, and the reference with each of the capture's.")
@click.argument("options", nargs=-1, type=click.UNPROCESSED)
def cli(classes, threads, swap, options):
    """The card relit from photo 00's capture (``svbrdf capture OPTIONS``) and from its per-class refits."""
    import torch

    from export.render.relight import NineLights
    from export.studies.capture_eval import capture
    from svbrdf_cli.write.mapset import linear_to_stored, read_stored_maps, stored_to_linear

    torch.set_num_threads(threads)
    with command_errors():
        folder = os.path.join(shared_root(), "data", "real", "card_blue_9lights")
        nine = NineLights(folder)
        with tempfile.TemporaryDirectory() as tmp:
            capture([os.path.join(folder, "00.jpg")], tmp, options, "none")
            stored = read_stored_maps(os.path.join(tmp, "00"))
        if swap:
            import cv2

            side = stored["diffuse"].shape[1]
            reference = {n: cv2.resize(v, (side, side), interpolation=cv2.INTER_AREA).reshape(side, side, -1)
                         for n, v in nine.reference_maps().items()}
            for label, value in swaps(nine.relight_rmse, stored, reference).items():
                click.echo(f"{label}: {value:.4f}")
            return
        lin = stored_to_linear(stored)
        p = soft_classes(lin["diffuse"], classes)
        click.echo(f"the capture: {nine.relight_rmse(stored):.4f}")
        for label, photos in (("refit on photo 00", [0]), ("refit on all 9 photos (a bound)", range(len(nine.photos)))):
            maps, values = refit(nine, lin, p, list(photos))
            click.echo(f"{label}: {nine.relight_rmse(linear_to_stored(maps)):.4f}")
            for name, v in values.items():
                click.echo(f"  {name}: " + "  ".join(np.array2string(row, precision=3) for row in v))


if __name__ == "__main__":
    cli()
