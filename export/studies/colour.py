"""Colour fidelity: does a method's diffuse keep the photo's colour?

    python -m export.studies.colour            # every runnable method on the 12 real photos of the benchmark

For each real photo (cropped and exposed as ``svbrdf capture`` does) and each method, the photo
and the method's diffuse map are compared in HSV of their encoded values (the photo's network
input; the diffuse in its stored gamma-2.2 encoding, the same curve):

* pixels that are clipped or among the brightest 10 % of the photo are left out of both (the
  flash highlight is not the material's colour);
* **hue**: the direction of the median chroma vector ``s (cos h, sin h)`` (a circular median that
  near-neutral pixels barely move); **saturation**: the median HSV saturation;
* the hue difference is circular, in degrees, reported where the photo's saturation is above
  :data:`SATURATED` (below, hue is noise).

Pass (issue "Honest scoring"): hue within :data:`MAX_HUE_DEGREES` of the photo's for every photo
above :data:`SATURATED`, and a diffuse saturation under :data:`NEUTRAL` for every photo under it.
"""

from __future__ import annotations

import os

import click
import numpy as np

from svbrdf_cli import conventions as cv

#: Photos more saturated than this have a hue to keep.
SATURATED = 0.15
#: Photos less saturated than this count as near-neutral.
NEUTRAL = 0.1
MAX_HUE_DEGREES = 15.0


def hsv(rgb):
    """(..., 3) values in [0, 1] -> hue (radians), saturation."""
    mx, mn = rgb.max(-1), rgb.min(-1)
    c = mx - mn
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    safe = np.where(c > 1e-8, c, 1.0)
    h = np.where(mx == r, ((g - b) / safe) % 6, np.where(mx == g, (b - r) / safe + 2, (r - g) / safe + 4))
    h = np.where(c > 1e-8, h, 0.0) * (np.pi / 3)
    s = np.where(mx > 1e-8, c / np.where(mx > 1e-8, mx, 1.0), 0.0)
    return h, s


def colour_stats(rgb, keep):
    """(hue in degrees, saturation) of the pixels ``keep`` of an encoded (H, W, 3) image."""
    h, s = hsv(rgb[keep])
    vec = np.median(np.stack([s * np.cos(h), s * np.sin(h)], -1), 0)
    return float(np.degrees(np.arctan2(vec[1], vec[0])) % 360), float(np.median(s))


def hue_difference(a, b):
    d = abs(a - b) % 360
    return min(d, 360 - d)


def fidelity(photo, diffuse):
    """{photo_hue, photo_saturation, diffuse_hue, diffuse_saturation, hue_error (None when the photo is
    near-grey), ok} for one photo (encoded network input) and its stored diffuse."""
    lum = photo @ np.asarray(cv.LUMA, np.float32)
    keep = (photo < 0.98).all(-1) & (lum <= np.percentile(lum, 90))
    ph, ps = colour_stats(photo, keep)
    dh, ds = colour_stats(np.asarray(diffuse)[..., :3], keep)
    err = hue_difference(ph, dh) if ps > SATURATED else None
    if ps > SATURATED:
        ok = err <= MAX_HUE_DEGREES
    elif ps < NEUTRAL:
        ok = ds < NEUTRAL
    else:
        ok = None  # between the two: no requirement
    return {"photo_hue": ph, "photo_saturation": ps, "diffuse_hue": dh, "diffuse_saturation": ds,
            "hue_error": err, "ok": ok}


def evaluate(methods, inputs, log=print):
    """{method: [fidelity row per photo]} for ``inputs`` = [(name, network input)] (the real photos
    cropped and exposed as ``svbrdf capture`` does: :func:`svbrdf_cli.infer.exposure.network_input`)."""
    out = {}
    for m in methods:
        rows = []
        for name, x in inputs:
            rows.append({"photo": name, **fidelity(x, m(x)["diffuse"])})
        out[m.name] = rows
        judged = [r for r in rows if r["ok"] is not None]
        log(f"{m.name:9s} colour kept on {sum(r['ok'] for r in judged)}/{len(judged)} judged photos")
    return out


def table(results):
    """Markdown: per photo, the photo's hue/saturation and each method's diffuse hue error/saturation."""
    names = list(results)
    rows = results[names[0]]
    head = ("| photo | photo hue / sat | " + " | ".join(f"{n}: Δhue / sat" for n in names) + " |\n"
            + "|---" * (2 + len(names)) + "|\n")
    lines = []
    for i, r in enumerate(rows):
        cells = []
        for n in names:
            x = results[n][i]
            dh = "–" if x["hue_error"] is None else f"{x['hue_error']:.0f}°"
            mark = "" if x["ok"] is None else (" ✓" if x["ok"] else " ✗")
            cells.append(f"{dh} / {x['diffuse_saturation']:.2f}{mark}")
        lines.append(f"| {r['photo']} | {r['photo_hue']:.0f}° / {r['photo_saturation']:.2f} | " + " | ".join(cells) + " |")
    summary = "| **kept** | | " + " | ".join(
        f"{sum(x['ok'] for x in results[n] if x['ok'] is not None)}/{sum(x['ok'] is not None for x in results[n])}"
        for n in names) + " |"
    return head + "\n".join(lines + [summary]) + "\n"


@click.command()
@click.option("--tables", default="docs/tables", show_default=True, type=click.Path(file_okay=False))
def cli(tables):
    """Colour fidelity of every runnable method on the benchmark's real photos."""
    from export.studies import methods as method_zoo
    from export.studies import stability
    from export.files import REAL_PHOTOS, shared_root

    from svbrdf_cli.infer.exposure import network_input

    real = stability.real_crops(shared_root() / "data" / "real", REAL_PHOTOS)
    res = evaluate(method_zoo.available(refined=True), [(name, network_input(lin)) for name, lin in real], log=click.echo)
    os.makedirs(tables, exist_ok=True)
    text = table(res)
    with open(os.path.join(tables, "colour.md"), "w") as f:
        f.write(text)
    click.echo(text)


if __name__ == "__main__":
    cli()
