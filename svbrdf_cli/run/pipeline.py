"""One photo in, one texture set out: ingest -> crop -> expose -> infer -> upsample -> write.

:func:`capture` is the whole job for one photo; :mod:`svbrdf_cli.run.batch` loops
over it for the CLI's ``capture`` and ``batch`` commands. Every output set is written atomically (see
:mod:`svbrdf_cli.write.presets`): the preset's files plus ``material.json`` (what
was done, with which model, how long it took), ``preview.png`` (the maps and
three relit renders) and, with ``debug``, ``debug/`` (network input, masks and
auxiliary renderings).

**Resolution.** The networks run at :data:`NETWORK_SIZE` (their export and
validation resolution; they were trained on 128 px crops, see each model's
``provenance.json``); a model that runs at any size (``any_size``: the physical
estimate) runs again at the output size, and ``--refine``'s change, found at
:data:`NETWORK_SIZE`, is carried over to it (:func:`svbrdf_cli.infer.refine.transfer`).
A network's larger outputs are made by *guided upsampling*
(:mod:`svbrdf_cli.infer.upsample`).

The stages: :mod:`svbrdf_cli.ingest` (the photo read once), :mod:`svbrdf_cli.rectify` (the crop),
:mod:`svbrdf_cli.infer` (exposure, the model, ``--refine``, upsampling), :mod:`svbrdf_cli.write`
(the preview and the preset's files). Progress is reported through the ``progress`` callback; this
module draws nothing.
"""

from __future__ import annotations

import dataclasses
import datetime
import functools
import json
import logging
import os
import time

import numpy as np

from svbrdf_cli.version import __version__
from svbrdf_cli import conventions as cv
from svbrdf_cli.ingest import photo as ingest
from svbrdf_cli.rectify import crops as rectify
from svbrdf_cli.write import ownership
from svbrdf_cli.ingest import plausible
from svbrdf_cli.errors import SvbrdfError
from svbrdf_cli.imageops import resize
from svbrdf_cli.infer.exposure import (NETWORK_SIZE, WHITE_UNDER_FLASH, auto_exposure_gain, network_input, photo_level,
                                       to_photo_level)
from svbrdf_cli.infer.tta import confidence_maps
from svbrdf_cli.infer.upsample import upsample_maps
from svbrdf_cli.write.preview import preview_image
from svbrdf_cli.infer.refine import DEFAULT_ITERATIONS as DEFAULT_REFINE

log = logging.getLogger("svbrdf")

#: Output sizes accepted by ``--size``.
MIN_SIZE, MAX_SIZE = 256, 4096
#: Default output size cap: the largest power of two within the crop's own resolution, at most this.
DEFAULT_SIZE = 1024
#: ``--size`` above the crop's side by more than this factor is upsampling the photo never had: warned.
UPSAMPLE_SLACK = 1.02
#: Marker that a set is complete (the batch command skips such folders).
RECORD = "material.json"


@dataclasses.dataclass
class Options:
    """What ``svbrdf capture`` was asked to do (the CLI's options)."""

    preset: str = "svbrdf"
    crop: str = "auto"
    corners: tuple | None = None
    size: int | None = None                    # None: a power of two within the crop's side (output_size)
    exposure: float | None = None              # stops; None: auto exposure
    white_balance: tuple | None = None         # (r, g, b) multipliers
    upsample: str = "guided"                   # or "bicubic"
    bits: int = 8
    fmt: str = "png"
    debug: bool = False
    confidence: bool = False                   # also write confidence/<map>.png (svbrdf_cli.infer.tta)
    preview: bool = True
    force: bool = False
    name: str | None = None                    # the material's name in engine file names (default: the photo's)
    tileable: bool = False                     # seamless maps (svbrdf_cli.write.tiling)
    ao: bool = True                            # ambient occlusion from the height (engine presets)
    refine: int = DEFAULT_REFINE               # test-time refinement steps (svbrdf_cli.infer.refine); 0: off


# --------------------------------------------------------------------------
# Pieces
# --------------------------------------------------------------------------

def output_size(opts, crop_side):
    """The output maps' side: ``--size``, else the largest power of two within the crop's side, in
    [MIN_SIZE, DEFAULT_SIZE] (engines and the glTF validator expect powers of two; a smaller one
    than the crop rather than pixels the photo does not have)."""
    if opts.size is not None:
        return int(opts.size)
    side = min(DEFAULT_SIZE, max(MIN_SIZE, int(crop_side)))
    return 1 << (side.bit_length() - 1)


#: Options that do not change a set's files (how the run goes, not what it makes).
_NOT_OUTPUT = ("force",)


def output_options(opts, model):
    """What a set's files depend on besides its photo and the tool: ``material.json`` records it under
    ``options``, and a batch that resumes redoes a set recorded with other ones (:func:`options_differ`)."""
    out = {k: v for k, v in dataclasses.asdict(opts).items() if k not in _NOT_OUTPUT}
    return _jsonable({**out, "model": model})


def options_differ(record, opts, model):
    """The names of the output options in which the set's ``record`` (its ``material.json``) differs
    from ``opts`` and ``model``. A record from before ``options`` was recorded is compared on what it
    has (preset, bits, format, tileable, model)."""
    want = output_options(opts, model)
    record = record if isinstance(record, dict) else {}
    had = record.get("options")
    if not isinstance(had, dict):
        legacy = {"preset": record.get("preset"), "bits": record.get("bits"), "fmt": record.get("format"),
                  "tileable": record.get("tileable"), "model": (record.get("model") or {}).get("name")}
        return sorted(k for k, v in legacy.items() if v is not None and v != want[k])
    return sorted(k for k in want if had.get(k) != want[k])


def output_folder(out_root, photo_path):
    """``OUT/<photo stem>``: the contract benchmarks rely on."""
    return os.path.join(os.fspath(out_root), os.path.splitext(os.path.basename(os.fspath(photo_path)))[0])


def is_complete(folder):
    """A finished set: the folder exists and holds its ``material.json`` (written last, in the same rename)."""
    return os.path.isfile(os.path.join(folder, RECORD))


# --------------------------------------------------------------------------
# The job
# --------------------------------------------------------------------------

@dataclasses.dataclass
class Prepared:
    """A photo read, cropped and exposed: ready for the networks."""

    path: str
    photo: ingest.Photo
    crop: rectify.Crop
    small: np.ndarray   # the crop at NETWORK_SIZE², linear (what the exposure was measured on)
    gain_ev: float
    timings: dict


def prepare(path, opts):
    """Read, crop and expose one photo (the part that needs no model)."""
    t0 = time.perf_counter()
    # the auto and whole-photo crops keep the photo's short side: decode no more than the output needs
    need = (opts.size or DEFAULT_SIZE) if opts.crop in ("auto", "none") and opts.corners is None else None
    photo = ingest.load_photo(path, white_balance=opts.white_balance, min_side=need)
    t1 = time.perf_counter()
    try:
        c = rectify.crop(photo.linear, opts.crop, opts.corners)
    except rectify.CropError as e:
        raise rectify.CropError(f"Could not crop '{path}': {e}.") from None
    if c.image.shape[0] < 64:
        raise rectify.CropError(f"Could not crop '{path}': the crop is only {c.image.shape[0]} px wide; "
                                "use a larger region or a sharper photo.")
    small = resize(c.image, NETWORK_SIZE)
    plausible.check_crop(path, photo.linear, c.image)
    side, have = output_size(opts, c.image.shape[0]), c.image.shape[0]
    if side > UPSAMPLE_SLACK * have:
        log.warning("'%s': --size %d upsamples the crop's %d px %.1fx, detail the photo does not have; use "
                    "--size %d or less (%d: a power of two), or photograph closer", path, side, have, side / have,
                    have, output_size(Options(), have))
    try:
        gain = opts.exposure if opts.exposure is not None else auto_exposure_gain(small)
    except SvbrdfError as e:
        raise SvbrdfError(f"Could not expose '{path}': {e}; crop a part the flash lights (--corners).") from None
    if opts.exposure is None:
        plausible.check_exposure(path, gain)
    t2 = time.perf_counter()
    return Prepared(os.fspath(path), photo, c, small, float(gain), {"read": t1 - t0, "crop": t2 - t1})


def refine_maps(prepared, chain, net_in, stored, iterations, progress=None):
    """``--refine``: the capture's geometry from the photo, then :func:`svbrdf_cli.infer.refine.refine` at the
    network's size; ``progress(done, iterations)`` after each step. Returns (maps, record entries)."""
    from svbrdf_cli.infer import geometry
    from svbrdf_cli.infer import refine

    p = prepared
    geo = geometry.for_capture(net_in, p.photo.focal_35mm, p.photo.linear.shape, p.crop.report, chain.used.found)
    step = (lambda n: progress(n, iterations)) if progress else None
    res = refine.refine(net_in, stored, geo, iterations, progress=step)
    log.info("refine: photo loss %.5f -> %.5f in %.2f s", res.report["photo_loss_before"],
             res.report["photo_loss_after"], res.report["seconds"])
    return res.stored, {"geometry": geo.report(), "refine": res.report}


def capture(prepared, chain, out_root, opts, model_name="physical", progress=None):
    """Infer and write the texture set of a :class:`Prepared` photo; returns (folder, record)."""
    return infer_set(prepared, chain, out_root, opts, model_name, progress)()


def infer_set(prepared, chain, out_root, opts, model_name="physical", progress=None):
    """The model's part of :func:`capture` (infer, refine, upsample): returns a function of no
    arguments that writes the set (preview, PNG encoding, the atomic rename) and returns (folder,
    record). A batch runs it on a thread while the next photo is in the model. ``progress(done,
    total)``: called after each step of ``--refine``."""
    from svbrdf_cli.write.mapset import stored_to_linear

    p = prepared
    folder = output_folder(out_root, p.path)
    timings = dict(p.timings)
    gain = np.float32(2.0 ** p.gain_ev)
    t0 = time.perf_counter()
    net_in = network_input(p.small, p.gain_ev)  # already at network size: no second resize
    out = chain(net_in)
    timings.update({f"network_{k}": v for k, v in chain.timings.items()})
    t1 = time.perf_counter()
    side = output_size(opts, p.crop.image.shape[0])
    stored = {k: out[k] for k in cv.MAP_NAMES}
    refined = None
    if opts.refine:
        low_refined, refined = refine_maps(p, chain, net_in, stored, opts.refine, progress)
        timings["refine"] = refined["refine"]["seconds"]
    t_up = time.perf_counter()
    high = ingest.encode_for_network(resize(p.crop.image, side), gain, fast=True) if side != NETWORK_SIZE else net_in
    upsampling = opts.upsample if side != NETWORK_SIZE else None
    if side != NETWORK_SIZE and chain.used.any_size:
        # a model that runs at any size (the physical estimate) runs again at the output size: the
        # photo's own detail, not an upsampled map (docs/capture.md, "Resolution")
        full = chain.used(high)
        timings["network_full_size"] = time.perf_counter() - t_up
        start = {k: full[k] for k in cv.MAP_NAMES}
        upsampling = "model at output size"
    else:
        start = upsample_maps(stored, net_in, high, opts.upsample)
    if refined is not None and side == NETWORK_SIZE:
        start = low_refined
    elif refined is not None:
        from svbrdf_cli.infer.refine import transfer

        start = transfer(stored, low_refined, start)
    stored = start
    if out.get("hidden") is not None:  # the photo's own detail where the highlight hid the diffuse
        from svbrdf_cli.infer.physical import photo_detail_under_highlight

        stored["diffuse"] = photo_detail_under_highlight(stored["diffuse"], high, out["hidden"])
    if out.get("clipped") is not None:  # where the photo clipped, the texture just beside
        from svbrdf_cli.infer.physical import texture_beside_clipped

        stored["diffuse"] = texture_beside_clipped(stored["diffuse"], out["clipped"])
    if out.get("spot") is not None:  # the photo's detail the diffuse lacks in the flash's spot
        from svbrdf_cli.infer.physical import photo_detail_in_spot

        stored["diffuse"] = photo_detail_in_spot(stored["diffuse"], high, out["spot"])
    for k, v in stored.items():
        if not np.isfinite(v).all():
            raise SvbrdfError(f"The model produced non-finite values for '{p.path}' ({k}); please report this photo.")
    plausible.check_maps(p.path, net_in, stored, chain.describe().get("found"))
    # the albedo of the photo as shot (docs/conventions.md, "The albedo level")
    level = photo_level(p.gain_ev, manual=opts.exposure is not None)
    specular_scaled = getattr(chain.used, "specular_level", "absolute") == "photo"
    stored = to_photo_level(stored, level, specular=specular_scaled)
    maps = None  # linear maps, made only where needed (the native preset writes the stored ones)
    tiling = None
    if opts.tileable:
        from svbrdf_cli.write.mapset import linear_to_stored
        from svbrdf_cli.write.tiling import make_tileable

        tiling = {}
        maps = make_tileable(stored_to_linear(stored), report=tiling)
        stored = linear_to_stored(maps)
    t2 = time.perf_counter()
    timings["upsample"] = t2 - t_up
    timings["network"] = t1 - t0
    conf = conf_record = None
    if opts.confidence:
        conf, conf_record = _confidence(chain.used, net_in, {k: out[k] for k in cv.MAP_NAMES}, side)
        timings["confidence"] = time.perf_counter() - t2

    record = {
        "tool": f"svbrdf {__version__}",
        "conventions_version": cv.CONVENTIONS_VERSION,
        "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "input": {"file": os.path.abspath(p.path), "sha256": p.photo.sha256, "kind": p.photo.kind,
                  "bits": p.photo.bits, "width": int(p.photo.linear.shape[1]), "height": int(p.photo.linear.shape[0]),
                  "decoded_at": p.photo.scale, **({"opaque_region": list(p.photo.opaque)} if p.photo.opaque else {})},
        "model": {"name": model_name, **chain.describe()},
        "crop": _jsonable(p.crop.report),
        "exposure": {"mode": "auto" if opts.exposure is None else "manual", "stops": round(p.gain_ev, 3)},
        "albedo_level": {"scale": round(level, 6),
                         "convention": "the photo " + ("as shot" if opts.exposure is None else "at --exposure") +
                                       ", the highlight and the flash's fall-off taken off, read at the Des19 "
                                       f"flash power: a white surface under the flash photographs at "
                                       f"{WHITE_UNDER_FLASH:.3f} (docs/conventions.md)",
                         "specular_scaled": specular_scaled},
        "white_balance": list(opts.white_balance) if opts.white_balance else None,
        "network_size": NETWORK_SIZE, "size": side,
        "upsampling": upsampling,
        "preset": opts.preset, "bits": opts.bits, "format": opts.fmt, "tileable": opts.tileable,
        "options": output_options(opts, model_name),
    }
    if tiling is not None:
        record["tiling"] = tiling
    if refined is not None:
        record.update(refined)
    if conf is not None:
        record["confidence"] = {**conf_record, "mean": {k: round(float(v.mean()), 4) for k, v in conf.items()}}

    # (the photo's path, not the Prepared: its decoded photo is not kept while the set is written)
    return functools.partial(_write_set, p.path, folder, opts, record, timings, stored, maps, net_in, out, conf)


def _confidence(model, net_in, stored, side):
    """``--confidence``: ({map: (side, side) confidence}, what ``material.json`` says of them). A network:
    its rotated and mirrored passes' agreement (:mod:`svbrdf_cli.infer.tta`); the physical estimate:
    what it read off the photo where (:mod:`svbrdf_cli.infer.physical_confidence`), for the maps it
    measures only."""
    from svbrdf_cli.infer import physical_confidence as pc, tta
    from svbrdf_cli.infer.physical import NAME as PHYSICAL

    if getattr(model, "tier", None) != PHYSICAL:
        return (confidence_maps(model, net_in, stored, side),
                {"method": "agreement of rotated and mirrored passes", "passes": len(tta.CONFIDENCE_PASSES),
                 "half_at_disagreement": tta.CONFIDENCE_HALF})
    conf = {k: np.clip(resize(v[..., None], side)[..., 0], 0, 1) for k, v in pc.confidence(net_in).items()}
    return conf, {"method": "physical estimate: where the photo shows each map (svbrdf_cli.infer.physical_confidence)",
                  "not_measured": pc.NOT_MEASURED}


def _write_set(path, folder, opts, record, timings, stored, maps, net_in, out, conf):
    """The writing part of :func:`capture` (see :func:`infer_set`): returns (folder, record)."""
    from svbrdf_cli.imageio import write_image
    from svbrdf_cli.write.presets import write_preset

    t2 = time.perf_counter()
    # the preview is made and encoded on the same threads as the maps (write_preset's images)
    images = [("preview.png", functools.partial(preview_image, net_in, stored), 8, True)] if opts.preview else []

    def extra(tmp):
        names = []
        if conf is not None:
            os.makedirs(os.path.join(tmp, "confidence"))
            for k, v in conf.items():
                write_image(os.path.join(tmp, "confidence", f"{k}.png"), v[..., None], colour=False)
                names.append(f"confidence/{k}.png")
        if opts.debug:
            os.makedirs(os.path.join(tmp, "debug"))
            debug = {"input": net_in, **{k: out[k] for k in ("M_b", "M_h", "I_bf", "I_hr", "I_hr2", "flash_fit")
                                         if k in out}}
            for k, v in debug.items():
                write_image(os.path.join(tmp, "debug", f"{k}.png"), v)
                names.append(f"debug/{k}.png")
        timings["write"] = time.perf_counter() - t2
        files = ownership.files_in(tmp)  # (not the temporary folder's own marker)
        rec = dict(record, files=files + [RECORD],
                   timings_s={k: round(v, 4) for k, v in timings.items()})
        with open(os.path.join(tmp, RECORD), "w") as f:
            json.dump(rec, f, indent=2)
            f.write("\n")
        record.update(rec)
        return names + [RECORD]

    write_preset(opts.preset, folder, maps, stored=stored, bits=opts.bits, fmt=opts.fmt, force=opts.force,
                 extra=extra, protect=(path,), name=opts.name, tileable=opts.tileable, ao=opts.ao, images=images)
    return folder, record


def _jsonable(x):
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    return x
