"""How real do simulated flash photos look? Image statistics, real vs simulated, as a table.

    python -m export.data.realism                      # real-photo targets, one column per set
    python -m export.data.realism --sim out/renders     # simulated PNGs vs the real photos
    python -m export.data.realism --sim 'out/**/*.png' --real-sets paper_real,henzler_train

From Python (the simulator hands its renderings over directly)::

    from export.data import realism
    rows = realism.compare(simulated_images, real_images)
    print(realism.format_table(rows))
    # or: realism.main(["--real-sets", "paper_real"], simulated=simulated_images)

Every image is taken as it is stored: sRGB-encoded values in [0, 1], (H, W, 3)
RGB. The statistics are measured on the encoded values (that is what a network
sees), mostly on luma ``Y' = 0.2126 R' + 0.7152 G' + 0.0722 B'``. Lengths that
depend on the resolution (blur radii, block sizes) are scaled by
``min(H, W) / 256``, so compare sets at the same ``--size`` (default 256²).

The real photos are read from ``<shared>/data/real/`` at run time (``<shared>``
is ``$SVBRDF_SHARED`` or ``../shared`` beside the checkout, as in the tests);
they are never copied into the repository. See :func:`load_real_photos`.
"""

from __future__ import annotations

import argparse
import glob
import math
import os
from pathlib import Path

import cv2
import numpy as np

from export.files import shared_root
from svbrdf_cli.imageops import luminance

#: Real-photo sets under ``<shared>/data/real/``, in the default order.
REAL_SETS = ("paper_real", "des18_real", "luo2024", "henzler_train")
#: Sets compared against by default (the CLI's ``--real-sets``).
DEFAULT_REAL_SETS = ("paper_real", "des18_real", "henzler_train")

#: A pixel is clipped when any channel reaches this encoded value.
CLIP_LEVEL = 0.99
#: ``compare`` flags a statistic when |difference of medians| / real inter-decile range exceeds this.
DIFFERS_AT = 0.5
#: Floor on the inter-decile range in ``compare`` (all statistics are O(0.01..1)).
MIN_SPREAD = 1e-3

_IMAGE_EXT = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")

#: Statistic names in table order, with a one-line meaning (the full definitions are in
#: :func:`image_statistics`).
STATISTICS = {
    "mean": "luma mean (brightness)",
    "contrast": "luma standard deviation",
    "p5": "luma 5th percentile",
    "p50": "luma median",
    "p95": "luma 95th percentile",
    "hl_peak": "highlight peak: max - median of blurred luma",
    "hl_size": "highlight blob area / image area",
    "hl_offset": "highlight centroid distance from centre / half-width",
    "hl_dx": "highlight centroid x offset / half-width (+ right)",
    "hl_dy": "highlight centroid y offset / half-height (+ down)",
    "clipped": "fraction of pixels with a channel >= 0.99",
    "colour_sat": "mean HSV saturation of non-black pixels",
    "chroma": "mean max(RGB) - min(RGB)",
    "hf_energy": "luma variance above sigma=2px blur / total variance",
    "falloff": "outer-ring luma mean / centre-disc luma mean",
    "noise": "Immerkaer noise sigma in the flattest unclipped blocks",
}


# ----------------------------------------------------------------------------- statistics

def _luma(img):
    return luminance(np.asarray(img[..., :3], np.float64), np.float64)


def _noise_sigma(luma, valid, block):
    """Immerkaer's noise estimate per ``block``² tile; the 20th percentile over the usable tiles.

    Immerkaer (1996): convolve with the difference of two Laplacians
    ``M = [[1,-2,1],[-2,4,-2],[1,-2,1]]`` (which cancels any locally linear
    image); for white noise of std s, ``mean|I*M| = s * 6 * sqrt(2/pi)``.
    Tiles containing clipped or black-crushed pixels (``valid`` False) are
    skipped (clipping removes noise). Texture and edges only raise a tile's
    estimate, so a low percentile over the tiles picks the flat ones.
    """
    kernel = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float64)
    lap = np.abs(cv2.filter2D(luma, cv2.CV_64F, kernel, borderType=cv2.BORDER_REFLECT))
    lap, valid = lap[1:-1, 1:-1], valid[1:-1, 1:-1]
    h, w = lap.shape
    nby, nbx = h // block, w // block
    if nby == 0 or nbx == 0:
        return float(np.mean(lap) * math.sqrt(math.pi / 2) / 6)
    tiles = lap[:nby * block, :nbx * block].reshape(nby, block, nbx, block).mean(axis=(1, 3))
    ok = valid[:nby * block, :nbx * block].reshape(nby, block, nbx, block).all(axis=(1, 3))
    if not ok.any():
        return float("nan")
    return float(np.percentile(tiles[ok], 20) * math.sqrt(math.pi / 2) / 6)


def image_statistics(img: np.ndarray) -> dict[str, float]:
    """Statistics of one gamma-encoded flash photo.

    Args:
        img: (H, W, 3) float in [0, 1], sRGB-encoded RGB (extra channels are ignored).

    Returns:
        ``{name: value}`` with these entries (``s = min(H, W) / 256``; luma is
        ``0.2126 R' + 0.7152 G' + 0.0722 B'`` of the encoded values):

        * ``mean``, ``contrast``: mean and standard deviation of luma.
        * ``p5``, ``p50``, ``p95``: luma percentiles.
        * ``hl_peak``: strength of the flash highlight, ``max(B) - median(B)``
          with ``B`` the luma blurred by a Gaussian of sigma ``4 s`` px (the blur
          keeps single bright pixels and fine texture from posing as the highlight).
        * ``hl_size``: area fraction of the highlight blob: the connected region
          (8-neighbour) containing the maximum of ``B`` where
          ``B > median(B) + 0.5 (max(B) - median(B))`` (half maximum above the
          median). 0 when ``hl_peak < 0.01`` (no discernible highlight).
        * ``hl_dx``, ``hl_dy``, ``hl_offset``: centroid of that blob, weighted
          by ``B - threshold``, relative to the image centre, in units of half the
          image width (``hl_dx``, + right) and height (``hl_dy``, + down), and its
          length ``hypot(hl_dx, hl_dy)`` (0 = centred, 1 = at an edge midpoint).
          NaN when there is no highlight.
        * ``clipped``: fraction of pixels with any channel ``>= 0.99``.
        * ``colour_sat``: mean HSV saturation ``(max - min) / max`` over pixels
          with ``max(RGB) >= 0.05`` (near-black pixels have meaningless hue);
          0 if there are none.
        * ``chroma``: mean of ``max(RGB) - min(RGB)`` over all pixels.
        * ``hf_energy``: ``var(Y - G_2s * Y) / var(Y)``: the share of luma
          variance at spatial frequencies above a Gaussian blur of sigma ``2 s``
          px (fine texture, noise, sharp edges). 0 for a constant image.
        * ``falloff``: mean luma in the outer ring ``0.75 <= r <= 1`` over mean
          luma in the centre disc ``r < 0.25``, with ``r`` the distance from the
          image centre over half the shorter side (corners excluded). Below 1 when
          the flash lights the centre more than the border.
        * ``noise``: Immerkaer's (1996) noise std estimate on luma: the
          3x3 difference-of-Laplacians response ``|Y * M|``, averaged in
          ``16 s``-px tiles, times ``sqrt(pi/2)/6``; the 20th percentile over the
          tiles with no clipped (``>= 0.99``) or crushed (``<= 0.01``) pixel,
          i.e. over the flattest usable regions. NaN if no tile is usable. On
          pure white noise it reads about 7 % low (the low percentile); on real
          photos fine texture that survives in every tile reads as noise too.
    """
    img = np.asarray(img, dtype=np.float64)
    if img.ndim != 3 or img.shape[2] < 3:
        raise ValueError(f"expected an (H, W, 3) image, got shape {img.shape}")
    rgb = img[..., :3]
    h, w = rgb.shape[:2]
    s = min(h, w) / 256.0
    y = _luma(rgb)
    out = {"mean": float(y.mean()), "contrast": float(y.std())}
    out["p5"], out["p50"], out["p95"] = (float(v) for v in np.percentile(y, [5, 50, 95]))

    # Flash highlight: half-maximum-above-median blob around the blurred maximum.
    b = cv2.GaussianBlur(y, (0, 0), sigmaX=4 * s, borderType=cv2.BORDER_REFLECT)
    med, top = float(np.median(b)), float(b.max())
    out["hl_peak"] = top - med
    if top - med < 0.01:
        out.update(hl_size=0.0, hl_offset=float("nan"), hl_dx=float("nan"), hl_dy=float("nan"))
    else:
        thr = med + 0.5 * (top - med)
        mask = (b > thr).astype(np.uint8)
        _, labels = cv2.connectedComponents(mask, connectivity=8)
        iy, ix = np.unravel_index(int(np.argmax(b)), b.shape)
        blob = labels == labels[iy, ix]
        wts = (b - thr)[blob]
        yy, xx = np.nonzero(blob)
        cy = float((yy * wts).sum() / wts.sum()) if wts.sum() > 0 else float(iy)
        cx = float((xx * wts).sum() / wts.sum()) if wts.sum() > 0 else float(ix)
        dx, dy = (cx - (w - 1) / 2) / (w / 2), (cy - (h - 1) / 2) / (h / 2)
        out.update(hl_size=float(blob.mean()), hl_dx=dx, hl_dy=dy, hl_offset=math.hypot(dx, dy))

    out["clipped"] = float((rgb >= CLIP_LEVEL).any(axis=-1).mean())
    mx, mn = rgb.max(axis=-1), rgb.min(axis=-1)
    lit = mx >= 0.05
    out["colour_sat"] = float(((mx - mn)[lit] / mx[lit]).mean()) if lit.any() else 0.0
    out["chroma"] = float((mx - mn).mean())

    var = float(y.var())
    if var < 1e-12:
        out["hf_energy"] = 0.0
    else:
        hp = y - cv2.GaussianBlur(y, (0, 0), sigmaX=2 * s, borderType=cv2.BORDER_REFLECT)
        out["hf_energy"] = float(min(hp.var() / var, 1.0))

    yy, xx = np.mgrid[0:h, 0:w]
    r = np.hypot(yy - (h - 1) / 2, xx - (w - 1) / 2) / (min(h, w) / 2)
    centre, ring = y[r < 0.25], y[(r >= 0.75) & (r <= 1.0)]
    out["falloff"] = float(ring.mean() / max(centre.mean(), 1e-6))

    valid = (rgb < CLIP_LEVEL).all(axis=-1) & (rgb > 0.01).any(axis=-1)
    out["noise"] = _noise_sigma(y, valid, block=max(4, int(round(16 * s))))
    return {k: out[k] for k in STATISTICS}


def summarize(stats: list[dict]) -> dict[str, tuple[float, float, float]]:
    """Per statistic, ``(p10, median, p90)`` over images; NaN values are ignored.

    Args:
        stats: a list of :func:`image_statistics` dicts.

    Returns:
        ``{name: (p10, median, p90)}``; all NaN for a statistic with no finite value.
    """
    names = [k for k in STATISTICS if any(k in d for d in stats)]
    names += sorted({k for d in stats for k in d} - set(names))
    out = {}
    for k in names:
        v = np.array([d.get(k, np.nan) for d in stats], dtype=np.float64)
        v = v[np.isfinite(v)]
        out[k] = tuple(float(x) for x in np.percentile(v, [10, 50, 90])) if v.size else (math.nan,) * 3
    return out


def compare(simulated: list[np.ndarray], real: list[np.ndarray]) -> list[dict]:
    """Compare the statistics of simulated and real photos.

    Args:
        simulated: (H, W, 3) gamma-encoded images in [0, 1].
        real: the same, real photos (ideally at the same resolution).

    Returns:
        One dict per statistic: ``stat``, ``sim`` and ``real`` (each
        ``(p10, median, p90)``), ``norm_diff`` = (sim median - real median) /
        max(real p90 - real p10, 1e-3), and ``differs`` = ``|norm_diff| > 0.5``.
        With no real (or no simulated) images the real (sim) triple and
        ``norm_diff`` are NaN and nothing is flagged.
    """
    sim_s = summarize([image_statistics(im) for im in simulated])
    real_s = summarize([image_statistics(im) for im in real])
    nan3 = (math.nan,) * 3
    rows = []
    for k in STATISTICS:
        sv, rv = sim_s.get(k, nan3), real_s.get(k, nan3)
        nd = (sv[1] - rv[1]) / max(rv[2] - rv[0], MIN_SPREAD)
        rows.append({"stat": k, "sim": sv, "real": rv, "norm_diff": float(nd),
                     "differs": bool(np.isfinite(nd) and abs(nd) > DIFFERS_AT)})
    return rows


def _fmt(v):
    if not np.isfinite(v):
        return "nan"
    return f"{v:.4f}" if abs(v) < 10 else f"{v:.1f}"


def format_table(rows) -> str:
    """Plain-text table of :func:`compare` rows (``differs`` marked ``<<``)."""
    head = ["statistic", "sim p10", "sim med", "sim p90", "real p10", "real med", "real p90", "norm diff", ""]
    body = [[r["stat"], *map(_fmt, r["sim"]), *map(_fmt, r["real"]), _fmt(r["norm_diff"]),
             "<< differs" if r["differs"] else ""] for r in rows]
    return _grid(head, body)


def format_summary(summaries: dict[str, dict]) -> str:
    """Plain-text table of medians (p10..p90 beneath) for several named :func:`summarize` results."""
    names = list(summaries)
    head = ["statistic"] + [f"{n} med [p10, p90]" for n in names]
    body = []
    for k in STATISTICS:
        row = [k]
        for n in names:
            p10, p50, p90 = summaries[n].get(k, (math.nan,) * 3)
            row.append(f"{_fmt(p50)} [{_fmt(p10)}, {_fmt(p90)}]")
        body.append(row)
    return _grid(head, body)


def _grid(head, body):
    widths = [max(len(str(x)) for x in col) for col in zip(head, *body)]
    line = lambda cells: "  ".join(str(c).ljust(wd) if i == 0 else str(c).rjust(wd)  # noqa: E731
                                   for i, (c, wd) in enumerate(zip(cells, widths))).rstrip()
    return "\n".join([line(head), line(["-" * wd for wd in widths])] + [line(r) for r in body])


# ----------------------------------------------------------------------------- loading

def read_photo(path, size=256) -> np.ndarray | None:
    """Read an 8/16-bit image as (size, size, 3) float RGB in [0, 1]: centred square crop, then resize.

    Grey images become three equal channels, alpha is dropped, EXIF orientation applied.

    Downsizing uses ``cv2.INTER_AREA``, upsizing ``cv2.INTER_LINEAR``. Returns None
    when the file cannot be decoded.
    """
    im = cv2.imread(os.fspath(path), cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH)  # applies EXIF orientation
    if im is None:
        return None
    scale = float(np.iinfo(im.dtype).max) if np.issubdtype(im.dtype, np.integer) else 1.0
    im = im.astype(np.float32) / scale
    if im.ndim == 2:
        im = np.repeat(im[..., None], 3, axis=2)
    elif im.shape[2] == 1:
        im = np.repeat(im, 3, axis=2)
    im = cv2.cvtColor(np.ascontiguousarray(im[..., :3]), cv2.COLOR_BGR2RGB)
    return _square(im, size)


def _square(im, size):
    h, w = im.shape[:2]
    side = min(h, w)
    y0, x0 = (h - side) // 2, (w - side) // 2
    im = im[y0:y0 + side, x0:x0 + side]
    if size and side != size:
        im = cv2.resize(im, (size, size), interpolation=cv2.INTER_AREA if side > size else cv2.INTER_LINEAR)
    return np.clip(im, 0.0, 1.0).astype(np.float32)


def _set_files(base, name):
    """The photo files of one real set, sorted (see :func:`load_real_photos`)."""
    d = base / name
    if name == "paper_real":
        return sorted(d.glob("*/input.png"))
    if name == "des18_real":
        return sorted(d.glob("*.png"))
    if name == "luo2024":
        return sorted(p for p in d.glob("*.png") if "gt" not in p.name.lower() and "license" not in p.name.lower())
    if name == "henzler_train":
        return sorted(p for p in d.glob("*/*") if p.suffix.lower() in (".jpg", ".jpeg"))
    raise ValueError(f"unknown real set {name!r}; known: {', '.join(REAL_SETS)}")


def load_real_photos(root=None, size=256, sets=None) -> dict[str, list[np.ndarray]]:
    """Load the real flash photos, set name -> list of (size, size, 3) float RGB images.

    Args:
        root: the shared root (holding ``data/real/``) or the ``real/`` folder
            itself; default :func:`shared_root`.
        size: output side in pixels (every image is centre-cropped to a square
            and resized; None or 0 keeps the cropped size).
        sets: names from :data:`REAL_SETS` (default: all of them).

    Sets: ``paper_real/<name>/input.png`` (22, 256²), ``des18_real/*.png`` (13,
    256²), ``luo2024/*.png`` without "gt"/"LICENSE" in the name and skipping
    strips with width >= 2 x height, ``henzler_train/<id>/*.jpg|JPG`` (every
    photo of the 77 folders, uncropped phone shots up to 1024 px).

    Returns:
        ``{}`` when the shared data is absent; a set whose folder is missing is left out.
    """
    base = Path(root) if root is not None else shared_root()
    if (base / "data" / "real").is_dir():
        base = base / "data" / "real"
    if not base.is_dir():
        return {}
    out = {}
    for name in (sets or REAL_SETS):
        files = _set_files(base, name)  # raises on an unknown name, present or not
        if not (base / name).is_dir():
            continue
        imgs = []
        for f in files:
            if name == "luo2024":
                hw = cv2.imread(os.fspath(f), cv2.IMREAD_UNCHANGED)
                if hw is None or hw.shape[1] >= 2 * hw.shape[0]:
                    continue
            im = read_photo(f, size)
            if im is not None:
                imgs.append(im)
        out[name] = imgs
    return out


def read_simulated(spec, size=256) -> list[np.ndarray]:
    """Images from a folder (its ``*.png``/``*.jpg``/...) or a glob pattern (``**`` allowed)."""
    if os.path.isdir(spec):
        files = sorted(p for p in glob.glob(os.path.join(spec, "*")) if p.lower().endswith(_IMAGE_EXT))
    else:
        files = sorted(p for p in glob.glob(spec, recursive=True) if p.lower().endswith(_IMAGE_EXT))
    return [im for im in (read_photo(f, size) for f in files) if im is not None]


# ----------------------------------------------------------------------------- CLI

def build_parser():
    ap = argparse.ArgumentParser(prog="python -m export.data.realism", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sim", help="folder of simulated PNGs, or a glob pattern; without it (and "
                                  "without simulated images from Python) print the real sets' statistics")
    ap.add_argument("--real-sets", default=",".join(DEFAULT_REAL_SETS),
                    help=f"comma-separated real sets, pooled for the comparison (known: {', '.join(REAL_SETS)})")
    ap.add_argument("--size", type=int, default=256, help="square side every image is brought to (default 256)")
    ap.add_argument("--per-set", action="store_true", help="also compare against each real set separately")
    return ap


def _simulated_images(a) -> list[np.ndarray] | None:
    """The simulated images the options ask for (None: no simulated input).

    Place for further sources (e.g. a ``--generate N`` option that renders N
    images with the simulator): add the option in :func:`build_parser` and
    return its images here.
    """
    if a.sim:
        return read_simulated(a.sim, a.size)
    return None


def main(argv=None, simulated: list[np.ndarray] | None = None) -> int:
    """CLI entry. ``simulated``: images handed over from Python (they replace ``--sim``)."""
    a = build_parser().parse_args(argv)
    sets = [s.strip() for s in a.real_sets.split(",") if s.strip()]
    for s in sets:
        if s not in REAL_SETS:
            build_parser().error(f"unknown real set {s!r}; known: {', '.join(REAL_SETS)}")
    if simulated is None:
        simulated = _simulated_images(a)
    else:
        simulated = [_square(np.asarray(im, np.float32), a.size) for im in simulated]
    real = load_real_photos(size=a.size, sets=sets)
    if not real:
        print(f"(no real photos: {shared_root() / 'data' / 'real'} is absent)")
    counts = ", ".join(f"{k} {len(v)}" for k, v in real.items())

    if simulated is None:
        if real:
            print(f"Real photos at {a.size}²: {counts}")
            print(format_summary({k: summarize([image_statistics(im) for im in v]) for k, v in real.items()}))
        return 0
    if not simulated:
        print(f"no simulated images found ({a.sim!r})")
        return 0
    pooled = [im for v in real.values() for im in v]
    print(f"Simulated {len(simulated)} vs real {len(pooled)} ({counts or 'none'}) at {a.size}²")
    rows = compare(simulated, pooled)
    print(format_table(rows))
    n = sum(r["differs"] for r in rows)
    print(f"{n} statistic(s) differ (|median difference| > {DIFFERS_AT} x real p10-p90 range)")
    if a.per_set:
        for k, v in real.items():
            print(f"\nvs {k} ({len(v)})")
            print(format_table(compare(simulated, v)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
