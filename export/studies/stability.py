"""The stability suite: what perturbed photos do to the maps (run by ``python -m export.studies.benchmark``).

Single-image methods fail on over-smooth inputs, large strong highlights and
ambiguous relief (the paper's Fig. 13). Each perturbation below is applied to
the linear photo before the tool's own exposure and encoding (the path of
``svbrdf capture``), on the Des19 inputs and on real photos:

* geometry: quarter turns and mirrors, undone on the maps afterwards (normal
  vectors turned back, :mod:`svbrdf_cli.infer.tta`);
* exposure +-1 EV (clipped at white), under-exposure (-4 EV then 8-bit
  quantised, as a dark JPEG) and over-exposure (+2 EV, clipped);
* white balance shifted warm and cool; sensor noise (shot and read, a dim
  phone shot); JPEG quality 60;
* an oversized saturated highlight painted over the centre;
* Des19 only (they need the ground-truth maps): the flash moved off centre,
  and no flash at all (soft light from a ring of distant lamps); both are
  compared with the same renderer's centred-flash photo.

For each it reports the change of every map against the unperturbed photo's
maps (RMSE in the stored encoding), the Des19 error by the reference scorer
(against ground truth) beside the clean error, and failures: exceptions and
non-finite values (the tool must have none).
"""

from __future__ import annotations

import os
import tempfile

import numpy as np

from export.files import real_photos
from export.studies.evaluate import score
from export.render.brdf import render_maps
from svbrdf_cli import conventions as cv
from svbrdf_cli.infer import tta
from svbrdf_cli.infer.exposure import network_input
from svbrdf_cli.write.mapset import stored_to_linear, write_map_set

MAPS = cv.MAP_NAMES


def _clip(x):
    return np.clip(x, 0.0, 1.0).astype(np.float32)


def _jpeg(lin, quality=60):
    import cv2

    enc = (cv.image_to_encoded(lin)[..., ::-1] * 255 + 0.5).astype(np.uint8)
    ok, buf = cv2.imencode(".jpg", enc, [cv2.IMWRITE_JPEG_QUALITY, quality])
    dec = cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1].astype(np.float32) / 255
    return cv.image_to_linear(dec).astype(np.float32)


def _noise(lin, rng, shot=0.01, read=0.004):
    return _clip(lin + rng.normal(0, 1, lin.shape).astype(np.float32) * np.sqrt(shot * lin + read ** 2))


def _under(lin, rng):
    dark = cv.image_to_encoded(_noise(lin / 16, rng, shot=0.002, read=0.002))
    return cv.image_to_linear(np.round(dark * 255) / 255).astype(np.float32)


def _highlight(lin, radius=0.35, gain=6.0):
    h, w = lin.shape[:2]
    y, x = np.mgrid[0:h, 0:w]
    r2 = ((x + 0.5) / w - 0.5) ** 2 + ((y + 0.5) / h - 0.5) ** 2
    return _clip(lin + gain * np.exp(-r2 / (2 * radius ** 2))[..., None] * lin.mean())


#: name -> (geometry (k, mirror) or None, photometric f(linear, rng) or None, rendered variant or None)
PERTURBATIONS = {
    "rotate 90": ((1, False), None, None),
    "rotate 180": ((2, False), None, None),
    "rotate 270": ((3, False), None, None),
    "mirror left-right": ((0, True), None, None),
    "mirror top-bottom": ((2, True), None, None),
    "+1 EV": (None, lambda x, g: _clip(x * 2), None),
    "-1 EV": (None, lambda x, g: x * 0.5, None),
    "white balance warm": (None, lambda x, g: _clip(x * np.float32([1.3, 1.0, 0.75])), None),
    "white balance cool": (None, lambda x, g: _clip(x * np.float32([0.75, 1.0, 1.3])), None),
    "sensor noise": (None, lambda x, g: _noise(x, g), None),
    "JPEG quality 60": (None, lambda x, g: _jpeg(x), None),
    "oversized saturated highlight": (None, lambda x, g: _highlight(x), None),
    "under-exposed (-4 EV, 8-bit)": (None, _under, None),
    "over-exposed (+2 EV, clipped)": (None, lambda x, g: _clip(x * 4), None),
    "flash off centre": (None, None, "off_centre"),
    "no flash": (None, None, "no_flash"),
}


def rendered_photo(gt, variant):
    """A linear photo of ground-truth maps: centred flash, flash off centre, or no flash."""
    m = {k: v[None] for k, v in gt.items()}
    h = cv.CAMERA_HEIGHT
    if variant == "centred":
        img = render_maps(m, intensity=1.0)
    elif variant == "off_centre":
        img = render_maps(m, light=(0.7, -0.5, h), camera=cv.FLASH_POSITION, intensity=1.0)
    elif variant == "no_flash":  # a ring of 12 distant lamps, 40-65 degrees up: soft light, no hot spot
        img = 0
        for i, a in enumerate(np.linspace(0, 2 * np.pi, 12, endpoint=False)):
            elev = np.radians(40 + 25 * (i % 2))
            d = 50.0
            pos = (d * np.cos(elev) * np.cos(a), d * np.cos(elev) * np.sin(a), d * np.sin(elev))
            img = img + render_maps(m, light=pos, camera=cv.FLASH_POSITION, intensity=d * d / 12)
    else:
        raise ValueError(variant)
    return img[0].permute(1, 2, 0).numpy()


def _change(a, b):
    return {k: float(np.sqrt(((a[k] - b[k]) ** 2).mean())) for k in MAPS}


#: A map whose spatial contrast (:func:`_contrast`) is under this is constant: perfectly stable and
#: carrying nothing, so its change is not divided by it.
CONSTANT = 1e-3


def _contrast(maps):
    """Each map's own spatial contrast: the RMS of its deviation from its mean over the image (per channel)."""
    return {k: float(np.sqrt(((maps[k] - maps[k].reshape(-1, maps[k].shape[-1]).mean(0)) ** 2).mean())) for k in MAPS}


def relative_change(changes, contrasts):
    """Per map: the mean over samples of change / the clean map's contrast, over the samples whose clean map
    is not constant, and how many were (None where every one was: a constant map moves by nothing)."""
    out = {}
    for k in MAPS:
        ratios = [c[k] / r[k] for c, r in zip(changes, contrasts) if r[k] >= CONSTANT]
        out[k] = {"ratio": float(np.mean(ratios)) if ratios else None,
                  "constant": sum(r[k] < CONSTANT for r in contrasts)}
    return out


def _finite(maps):
    return all(np.isfinite(v).all() for v in maps.values())


def real_crops(real_root, count):
    """[(name, linear crop at network size)] of :func:`real_photos`, cropped as ``svbrdf capture`` does."""
    from svbrdf_cli.ingest import photo as ingest
    from svbrdf_cli.rectify import crops as rectify
    from svbrdf_cli.infer.exposure import NETWORK_SIZE
    from svbrdf_cli.imageops import resize

    out = []
    for path in real_photos(real_root, count):
        photo = ingest.load_photo(path)
        out.append((os.path.relpath(path, real_root), resize(rectify.crop(photo.linear, "auto").image, NETWORK_SIZE)))
    return out


def run(chain, des19_samples, des19_dir, real, gallery=None, log=print, seed=0):
    """Run every perturbation on ``des19_samples`` (from ``export.studies.evaluate.load_des19(des19_dir)``) and
    ``real`` photos (:func:`real_crops`); returns {"rows": {name: stats}, "clean": Des19 scores,
    "failures": [...], "photos": counts}."""
    rng = np.random.default_rng(seed)
    des19 = [(n, cv.image_to_linear(p.permute(1, 2, 0).numpy()).astype(np.float32), gt) for n, p, gt in des19_samples]
    work = tempfile.mkdtemp(prefix="svbrdf-stability-")
    failures, examples = [], []

    def infer(name, label, image, geom=None):
        x = image if geom is None else tta.transform_image(image, *geom)
        try:
            out = chain(network_input(x))  # svbrdf capture's own path: auto exposure, encoding
            maps = {k: out[k] for k in MAPS}
        except Exception as e:  # noqa: BLE001 -- the suite records every failure instead of stopping
            failures.append({"perturbation": label, "sample": name, "error": f"{type(e).__name__}: {e}"})
            return None
        if not _finite(maps):
            failures.append({"perturbation": label, "sample": name, "error": "non-finite values"})
            return None
        return maps if geom is None else tta.untransform_maps(maps, *geom)

    # Clean references.
    clean = {n: infer(n, "clean", lin) for n, lin, _ in des19}
    clean.update({n: infer(n, "clean", lin) for n, lin in real})
    rendered = {n: infer(n, "clean (rendered)", rendered_photo(gt, "centred")) for n, _, gt in des19}
    for n, _, _ in des19:
        for sub, maps in (("clean", clean[n]), ("clean_rendered", rendered[n])):
            if maps is not None:
                write_map_set(os.path.join(work, sub, n), stored_to_linear(maps))
    scores = {"clean": score(des19_dir, os.path.join(work, "clean"))[0],
              "clean_rendered": score(des19_dir, os.path.join(work, "clean_rendered"))[0]}

    rows = {}
    for label, (geom, photometric, variant) in PERTURBATIONS.items():
        changes = {"des19": [], "real": []}
        contrasts = []
        folder = os.path.join(work, label.replace(" ", "_").replace("/", "_"))
        sets = [("des19", n, lin, gt) for n, lin, gt in des19] \
            + ([] if variant else [("real", n, lin, None) for n, lin in real])
        for kind, n, lin, gt in sets:
            if variant:
                src, ref = rendered_photo(gt, variant), rendered[n]
            else:
                src, ref = (lin if photometric is None else photometric(lin, rng)), clean[n]
            maps = infer(n, label, src, geom)
            if maps is None or ref is None:
                continue
            ch = _change(maps, ref)
            changes[kind].append(ch)
            contrasts.append(_contrast(ref))
            examples.append((float(np.mean(list(ch.values()))), label, n, src, ref, maps))
            if kind == "des19":
                write_map_set(os.path.join(folder, n), stored_to_linear(maps))
        row = {"samples": {k: len(v) for k, v in changes.items()},
               "change": {k: float(np.mean([c[k] for c in changes["des19"] + changes["real"]])) for k in MAPS}
               if changes["des19"] or changes["real"] else None,
               "relative": relative_change(changes["des19"] + changes["real"], contrasts) if contrasts else None,
               "reference": "clean_rendered" if variant else "clean"}
        if changes["des19"]:
            row["des19"] = score(des19_dir, folder)[0]
        rows[label] = row
        log(f"{label:32s} change " + " ".join(f"{k}={v:.4f}" for k, v in (row["change"] or {}).items())
            + ("  des19 " + " ".join(f"{k}={v:.4f}" for k, v in row.get("des19", {}).items())))
    if gallery and examples:
        worst = {}
        for e in sorted(examples, key=lambda e: -e[0]):
            worst.setdefault(e[1], e)  # the worst sample of each perturbation
        gallery_figure(sorted(worst.values(), key=lambda e: -e[0])[:4], gallery)
    return {"rows": rows, "clean": scores, "failures": failures,
            "photos": {"des19": len(des19), "real": len(real)}}


def gallery_figure(examples, path, tile=160):
    """Worst cases: input, perturbed input, and the diffuse, normal and roughness maps clean vs perturbed."""
    import cv2

    from export.render.figure import captioned_tile
    from svbrdf_cli.imageio import write_image

    rows = []
    for change, label, name, src, ref, maps in examples:
        cells = [("perturbed input", cv.image_to_encoded(np.clip(src, 0, None)))]
        for k in ("diffuse", "normal", "roughness"):
            cells += [(f"{k}, clean", ref[k]), (f"{k}, perturbed", maps[k])]
        row = [captioned_tile(img, title, tile) for title, img in cells]
        head = np.full((22, tile * len(cells), 3), 255, np.uint8)
        cv2.putText(head, f"{label} on {name}: mean map change {change:.3f}", (4, 16), cv2.FONT_HERSHEY_SIMPLEX,
                    0.45, (0, 0, 0), 1, cv2.LINE_AA)
        rows += [head, np.concatenate(row, 1)]
    write_image(path, np.concatenate(rows, 0).astype(np.float32) / 255)


def _relative_cell(rel):
    """``0.12×`` (change over the map's own contrast), ``constant`` where every clean map was."""
    if rel is None:
        return "–"
    if rel["ratio"] is None:
        return "constant"
    return f"{rel['ratio']:.2f}×" + (f" ({rel['constant']} const.)" if rel["constant"] else "")


def table(res):
    head = ("| perturbation | photos (Des19 + real) | change: normal | diffuse | roughness | specular | "
            "change / contrast: normal | diffuse | roughness | specular | "
            "Des19 error: normal | diffuse | roughness | specular |\n|" + "---|" * 14 + "\n")
    lines = []
    for ref in ("clean", "clean_rendered"):
        s = res["clean"][ref]
        lines.append(f"| *{'clean' if ref == 'clean' else 'clean, our centred-flash render'}* | | | | | | | | | | "
                     + " | ".join(f"{s.get(k, float('nan')):.4f}" for k in MAPS) + " |")
    for label, r in res["rows"].items():
        ch = r["change"] or {}
        rel = r.get("relative") or {}
        d = r.get("des19", {})
        n = r["samples"]
        lines.append(f"| {label} | {n['des19']} + {n['real']} | " + " | ".join(f"{ch[k]:.4f}" if k in ch else "–" for k in MAPS)
                     + " | " + " | ".join(_relative_cell(rel.get(k)) for k in MAPS)
                     + " | " + " | ".join(f"{d[k]:.4f}" if k in d else "–" for k in MAPS) + " |")
    fails = res["failures"]
    tail = ("\n*change / contrast*: each map's RMS change divided by that map's own spatial contrast in the clean run "
            "(RMS deviation from its mean), averaged over the photos; a constant map (contrast under "
            f"{CONSTANT:g}) moves by nothing and carries nothing, so it is counted apart (`constant`).\n")
    tail += f"\nFailures (exceptions or non-finite maps): {len(fails)}" + (
        ":\n" + "\n".join(f"- {f['perturbation']} on {f['sample']}: {f['error']}" for f in fails) if fails else ".")
    return head + "\n".join(lines) + "\n" + tail + "\n"
