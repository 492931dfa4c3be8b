"""One photo in, one texture set out: ingest -> crop -> expose -> infer -> upsample -> write.

:func:`capture` is the whole job for one photo; :mod:`svbrdf_cli.batch` loops
over it for the CLI's ``capture`` and ``batch`` commands. Every output set is written atomically (see
:mod:`svbrdf_cli.presets`): the preset's files plus ``material.json`` (what
was done, with which model, how long it took), ``preview.png`` (the maps and
three relit renders) and, with ``debug``, ``debug/`` (network input, masks and
auxiliary renderings).

**Resolution.** The networks run at :data:`NETWORK_SIZE` (their export and
validation resolution; they were trained on 128 px crops, see each model's
``provenance.json``); a model that runs at any size (``any_size``: the physical
estimate) runs again at the output size, and ``--refine``'s change, found at
:data:`NETWORK_SIZE`, is carried over to it (:func:`svbrdf_cli.refine.transfer`).
A network's larger outputs are made by *guided upsampling*
(:func:`guided_upsample`): the normal and diffuse maps are regressed locally
on the photo's brightness at network resolution, and the full-resolution
photo's fine detail (grain, scratches, pores) is added to their bicubic
upsampling in that proportion. ``docs/capture.md`` has the measured cost and
quality against plain bicubic upsampling.
"""

from __future__ import annotations

import dataclasses
import datetime
import functools
import hashlib
import json
import logging
import os
import time

import numpy as np

from svbrdf_cli import __version__
from svbrdf_cli import conventions as cv
from svbrdf_cli import ingest, ownership, plausible, rectify
from svbrdf_cli.errors import SvbrdfError
from svbrdf_cli.refine import DEFAULT_ITERATIONS as DEFAULT_REFINE

log = logging.getLogger("svbrdf")

#: The networks' working resolution (exported and validated at it; trained on 128 px crops).
NETWORK_SIZE = 256
#: Output sizes accepted by ``--size``.
MIN_SIZE, MAX_SIZE = 256, 4096
#: The most ``--exposure`` may change a photo, in stops either way (2^20: beyond any real photo's need).
MAX_EXPOSURE_STOPS = 20.0
#: Default output size cap: the crop's own resolution, at most this.
DEFAULT_SIZE = 1024
#: Guided upsampling: window radius (network pixels) and regularisation.
GUIDE_RADIUS = 1
GUIDE_EPS = 1e-3
#: Marker that a set is complete (the batch command skips such folders).
RECORD = "material.json"


@dataclasses.dataclass
class Options:
    """What ``svbrdf capture`` was asked to do (the CLI's options)."""

    preset: str = "svbrdf"
    crop: str = "auto"
    corners: tuple | None = None
    size: int | None = None                    # None: the crop's resolution, capped at DEFAULT_SIZE
    exposure: float | None = None              # stops; None: auto exposure
    white_balance: tuple | None = None         # (r, g, b) multipliers
    upsample: str = "guided"                   # or "bicubic"
    bits: int = 8
    fmt: str = "png"
    debug: bool = False
    confidence: bool = False                   # also write confidence/<map>.png (svbrdf_cli.tta)
    preview: bool = True
    force: bool = False
    name: str | None = None                    # the material's name in engine file names (default: the photo's)
    tileable: bool = False                     # seamless maps (svbrdf_cli.tiling)
    ao: bool = True                            # ambient occlusion from the height (engine presets)
    refine: int = DEFAULT_REFINE               # test-time refinement steps (svbrdf_cli.refine); 0: off


# --------------------------------------------------------------------------
# Pieces
# --------------------------------------------------------------------------

def resize(image, side):
    """Square image -> ``side`` x ``side`` (area filter down, bicubic up)."""
    import cv2

    if image.shape[0] == side and image.shape[1] == side:
        return image
    interp = cv2.INTER_AREA if side < image.shape[0] else cv2.INTER_CUBIC
    out = cv2.resize(np.ascontiguousarray(image), (side, side), interpolation=interp)
    return out[..., None] if out.ndim == 2 else out


def auto_exposure_gain(linear, target=cv.AUTO_EXPOSURE_MEAN):
    """Gain making the encoded image's mean ``target`` (what the networks were trained on)."""
    lo, hi = -plausible.EXPOSURE_LIMIT, plausible.EXPOSURE_LIMIT
    flat = linear.reshape(-1, 3)[:: max(1, linear.size // 3 // 65536)]
    if float(flat.max()) <= 0:
        raise SvbrdfError("the crop is black")
    for _ in range(30):
        mid = (lo + hi) / 2
        if cv.image_to_encoded(flat * np.float32(2.0 ** mid)).mean() < target:
            lo = mid
        else:
            hi = mid
    return (lo + hi) / 2


def _box(x, r):
    """Mean over (2r+1)^2 windows, reflecting at the borders; keeps the (h, w, C) shape."""
    import cv2

    return cv2.boxFilter(x, -1, (2 * r + 1, 2 * r + 1), borderType=cv2.BORDER_REFLECT).reshape(x.shape)


def _resize_to(x, shape):
    import cv2

    return cv2.resize(x, (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR).reshape(*shape, x.shape[-1])


def guided_upsample(low, guide_low, guide_high, radius=GUIDE_RADIUS, eps=GUIDE_EPS, detail=None):
    """Bicubic upsampling plus the photo's own fine detail, scaled by a local regression.

    In each (2r+1)^2 window at network resolution the map is regressed on
    the guide (slope ``a = cov(guide, map) / (var(guide) + eps)``, as in He
    et al.'s guided filter); the upsampled map then gains ``a`` times the
    guide's detail that the low resolution could not hold
    (``guide_high - upsample(guide_low)``). Where the map does not follow
    the photo's brightness, ``a`` is ~0 and this is plain bicubic.

    Args:
        low: (h, w, C) map at network resolution.
        guide_low: (h, w) guide (the photo's encoded brightness) at that resolution.
        guide_high: (H, W) the same guide at the output resolution (square).
        detail: ``guide_high`` less the guide's bicubic upsampling, if the caller has it already.

    Returns:
        (H, W, C) float32.
    """
    low = np.ascontiguousarray(low, np.float32)
    g = np.ascontiguousarray(guide_low, np.float32)[..., None]
    mean_g = _box(g, radius)
    var_g = _box(g * g, radius) - mean_g ** 2
    cov = _box(np.ascontiguousarray(g * low), radius) - mean_g * _box(low, radius)
    a = _box(np.ascontiguousarray(cov / (var_g + eps)), radius)
    side = guide_high.shape[0]
    if detail is None:
        detail = guide_detail(guide_low, guide_high)
    out = resize(low, side).reshape(side, side, -1)
    a = _resize_to(a, guide_high.shape)
    a *= detail[..., None]
    out += a
    return out


def guide_detail(guide_low, guide_high):
    """What the output-size guide holds beyond the bicubic upsampling of the network-size one."""
    g = np.ascontiguousarray(guide_low, np.float32)[..., None]
    return guide_high - resize(g, guide_high.shape[0])[..., 0]


#: Maps that take the photo's detail in guided upsampling; the others are
#: bicubic (measured: ``python -m export.upsample_eval``, docs/capture.md).
GUIDED_MAPS = ("normal", "diffuse")
#: How maps reach the output size: guided by the photo (:data:`GUIDED_MAPS`), or plain bicubic.
UPSAMPLE_METHODS = ("guided", "bicubic")


def upsample_maps(stored, photo_low, photo_high, method="guided"):
    """Stored-encoding maps at network resolution -> the output resolution.

    ``photo_low`` / ``photo_high``: the encoded network input and the encoded
    crop at the output size. ``method``: "guided" (:func:`guided_upsample`
    for :data:`GUIDED_MAPS`, bicubic for the rest) or "bicubic".
    """
    side = photo_high.shape[0]
    if stored["normal"].shape[0] == side:
        return dict(stored)
    if method not in UPSAMPLE_METHODS:
        raise ValueError(f"unknown upsampling method {method!r}")
    lum = np.asarray(cv.LUMA, np.float32)
    gl, gh = photo_low @ lum, photo_high @ lum
    detail = guide_detail(gl, gh) if method == "guided" else None  # once for every guided map
    out = {}
    for k, v in stored.items():
        if method == "guided" and k in GUIDED_MAPS:
            out[k] = guided_upsample(v, gl, gh, detail=detail)
        else:
            out[k] = resize(v, side).reshape(side, side, -1)
    n = out["normal"]
    n *= np.float32(2.0)
    n -= np.float32(1.0)
    np.maximum(n[..., 2], np.float32(1e-3), out=n[..., 2])  # stay in the upper hemisphere
    # cv.normalize then cv.encode_normals, in place (the same sums, without numpy's slow reduction
    # over a 3-long axis)
    norm = n[..., 0] * n[..., 0]
    norm += n[..., 1] * n[..., 1]
    norm += n[..., 2] * n[..., 2]
    norm += np.float32(1e-20)
    np.sqrt(norm, out=norm)
    n /= norm[..., None]
    n *= np.float32(0.5)
    n += np.float32(0.5)
    for k, v in out.items():
        np.clip(v, 0.0, 1.0, out=v)
        out[k] = v if v.dtype == np.float32 else v.astype(np.float32)
    return out


def network_input(linear, gain_ev=None):
    """A linear square crop -> what the networks take: :data:`NETWORK_SIZE`², exposed by ``gain_ev``
    stops (None: :func:`auto_exposure_gain`), encoded."""
    low = resize(linear, NETWORK_SIZE)
    if gain_ev is None:
        gain_ev = auto_exposure_gain(low)
    return ingest.encode_for_network(low, 2.0 ** gain_ev)


def confidence_maps(chain, net_in, stored, side):
    """{map: (side, side) confidence} from :data:`svbrdf_cli.tta.CONFIDENCE_PASSES` (``stored``: the plain pass)."""
    from svbrdf_cli import tta

    conf = tta.confidence([stored] + tta.passes(chain, net_in, tta.CONFIDENCE_PASSES[1:]))
    return {k: v if v.shape[0] == side else np.clip(_resize_to(v[..., None], (side, side))[..., 0], 0, 1)
            for k, v in conf.items()}


def output_size(opts, crop_side):
    if opts.size is not None:
        return int(opts.size)
    return int(min(DEFAULT_SIZE, max(MIN_SIZE, crop_side)))


#: Lights of the preview's relit renders (surface units; the surface spans -1..1).
PREVIEW_LIGHTS = {"flash": cv.FLASH_POSITION, "left": (-2.0, 0.5, 1.2), "top right": (1.5, 1.5, 1.5)}


def preview_image(network_input, stored, tile=256):
    """4 x 2 grid: photo, normal, diffuse, roughness / specular and three relit renders."""
    import cv2

    from svbrdf_cli.mapset import stored_to_linear
    from svbrdf_cli.shading import render_maps

    small = {k: resize(v, tile) for k, v in stored.items()}
    lin = stored_to_linear(small)
    tiles = [("photo", resize(network_input, tile)), ("normal", small["normal"]), ("diffuse", small["diffuse"]),
             ("roughness", np.repeat(small["roughness"][..., :1], 3, -1)), ("specular", small["specular"])]
    for name, light in PREVIEW_LIGHTS.items():
        img = render_maps(lin, light=light)  # float32: the preview within 1/255 of float64, in 60% of its time
        tiles.append((f"relit: {name}", cv.image_to_encoded(img).astype(np.float32)))
    grid = np.zeros((2 * tile, 4 * tile, 3), np.float32)
    for i, (name, img) in enumerate(tiles):
        r, c = divmod(i, 4)
        t = np.ascontiguousarray((img.clip(0, 1) * 255 + 0.5).astype(np.uint8))
        t[-20:] = t[-20:] // 3  # a dark band under the label
        cv2.putText(t, name, (5, tile - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
        grid[r * tile:(r + 1) * tile, c * tile:(c + 1) * tile] = t / np.float32(255)
    return grid


def file_sha256(path):
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


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
    try:
        gain = opts.exposure if opts.exposure is not None else auto_exposure_gain(small)
    except SvbrdfError as e:
        raise SvbrdfError(f"Could not expose '{path}': {e}; crop a part the flash lights (--corners).") from None
    if opts.exposure is None:
        plausible.check_exposure(path, gain)
    t2 = time.perf_counter()
    return Prepared(os.fspath(path), photo, c, small, float(gain), {"read": t1 - t0, "crop": t2 - t1})


def refine_maps(prepared, chain, net_in, stored, iterations):
    """``--refine``: the capture's geometry from the photo, then :func:`svbrdf_cli.refine.refine` at the
    network's size, with a progress bar on a terminal (not with --quiet). Returns (maps, record entries)."""
    import sys

    from tqdm import tqdm

    from svbrdf_cli import geometry, refine

    p = prepared
    found = getattr(getattr(chain, "used", chain), "found", None)
    geo = geometry.for_capture(net_in, p.path, p.photo.linear.shape, p.crop.report, found)
    bar = tqdm(total=iterations, unit="step", desc="refine", leave=False, file=sys.stderr, dynamic_ncols=True,
               disable=not (sys.stderr.isatty() and log.isEnabledFor(logging.WARNING)))
    try:
        res = refine.refine(net_in, stored, geo, iterations, progress=lambda n: bar.update(1))
    finally:
        bar.close()
    log.info("refine: photo loss %.5f -> %.5f in %.2f s", res.report["photo_loss_before"],
             res.report["photo_loss_after"], res.report["seconds"])
    return res.stored, {"geometry": geo.report(), "refine": res.report}


def capture(prepared, chain, out_root, opts, model_name="fast"):
    """Infer and write the texture set of a :class:`Prepared` photo; returns (folder, record)."""
    return infer_set(prepared, chain, out_root, opts, model_name)()


def infer_set(prepared, chain, out_root, opts, model_name="fast"):
    """The model's part of :func:`capture` (infer, refine, upsample): returns a function of no
    arguments that writes the set (preview, PNG encoding, the atomic rename) and returns (folder,
    record). A batch runs it on a thread while the next photo is in the model."""
    from svbrdf_cli.mapset import stored_to_linear

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
        low_refined, refined = refine_maps(p, chain, net_in, stored, opts.refine)
        timings["refine"] = refined["refine"]["seconds"]
    t_up = time.perf_counter()
    high = ingest.encode_for_network(resize(p.crop.image, side), gain, fast=True) if side != NETWORK_SIZE else net_in
    upsampling = opts.upsample if side != NETWORK_SIZE else None
    if side != NETWORK_SIZE and getattr(chain.used, "any_size", False):
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
        from svbrdf_cli.refine import transfer

        start = transfer(stored, low_refined, start)
    stored = start
    for k, v in stored.items():
        if not np.isfinite(v).all():
            raise SvbrdfError(f"The model produced non-finite values for '{p.path}' ({k}); please report this photo.")
    plausible.check_maps(p.path, net_in, stored, chain.describe().get("found"))
    maps = None  # linear maps, made only where needed (the native preset writes the stored ones)
    if opts.tileable:
        from svbrdf_cli.mapset import linear_to_stored
        from svbrdf_cli.tiling import make_tileable

        maps = make_tileable(stored_to_linear(stored))
        stored = linear_to_stored(maps)
    t2 = time.perf_counter()
    timings["upsample"] = t2 - t_up
    timings["network"] = t1 - t0
    conf = None
    if opts.confidence:
        conf = confidence_maps(chain.used, net_in, {k: out[k] for k in cv.MAP_NAMES}, side)
        timings["confidence"] = time.perf_counter() - t2

    record = {
        "tool": f"svbrdf {__version__}",
        "conventions_version": cv.CONVENTIONS_VERSION,
        "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "input": {"file": os.path.abspath(p.path), "sha256": None, "kind": p.photo.kind,
                  "bits": p.photo.bits, "width": int(p.photo.linear.shape[1]), "height": int(p.photo.linear.shape[0]),
                  "decoded_at": p.photo.scale, **({"opaque_region": list(p.photo.opaque)} if p.photo.opaque else {})},
        "model": {"name": model_name, **chain.describe()},
        "crop": _jsonable(p.crop.report),
        "exposure": {"mode": "auto" if opts.exposure is None else "manual", "stops": round(p.gain_ev, 3)},
        "white_balance": list(opts.white_balance) if opts.white_balance else None,
        "network_size": NETWORK_SIZE, "size": side,
        "upsampling": upsampling,
        "preset": opts.preset, "bits": opts.bits, "format": opts.fmt, "tileable": opts.tileable,
    }
    if refined is not None:
        record.update(refined)
    if conf is not None:
        from svbrdf_cli import tta

        record["confidence"] = {"passes": len(tta.CONFIDENCE_PASSES), "half_at_disagreement": tta.CONFIDENCE_HALF,
                                "mean": {k: round(float(v.mean()), 4) for k, v in conf.items()}}

    # (the photo's path, not the Prepared: its decoded photo is not kept while the set is written)
    return functools.partial(_write_set, p.path, folder, opts, record, timings, stored, maps, net_in, out, conf)


def _write_set(path, folder, opts, record, timings, stored, maps, net_in, out, conf):
    """The writing part of :func:`capture` (see :func:`infer_set`): returns (folder, record)."""
    from svbrdf_cli.imageio import write_image
    from svbrdf_cli.presets import write_preset

    t2 = time.perf_counter()
    record["input"]["sha256"] = file_sha256(path)
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
