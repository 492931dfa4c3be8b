"""Can the flash photo alone tell a metal from a dielectric? A study, not a shipped rule.

    python -m export.studies.metal_study            # about 4 minutes on one core
    python -m export.studies.metal_study --model-dir EXPORT   # and a trained network's F0 on the same photos

The physical estimate (:mod:`svbrdf_cli.infer.physical`) gives every photo the dielectric F0 = 0.04
(from the photo alone). This study asks whether a calibrated decision over the fit's physical
evidence would do better. Per photo it measures the evidence the flash fit yields (:func:`features`):
the photo's dynamic range and brightness percentiles, its clipped share and colour, and three fits of
the ring profile round the flash foot (the estimate's bounded dielectric fit, an unbounded diffuse +
lobe fit whose lobe height is a metal's F0 at the conventions' flash power, and a lobe-only fit). A
logistic regression over those features is trained on one set of generated photos (the training
simulator: about 11 % metals, F0 0.2-0.98) and tested on a second set, on Des19 (metal = mean GT
specular above 0.08) and on every real photo in ``../shared/data/real`` as ``svbrdf capture`` crops
and exposes it. A photo called metal gets F0 = the unbounded fit's lobe height (the same
convention the diffuse level is read at), clipped to [0.04, 1].

The score is the mean over photos of |mean GT F0 - predicted F0| (one value per photo; the metric's
per-pixel RMSE behaves the same for constant maps).

It also tests the cue issue 14 names, "a coloured highlight over a dark diffuse", as a rule with no
fitted weights (:func:`colour_rule`): a metal reflects in its own colour, so its highlight is as
coloured as the rest of the photo and of the same hue, and it outshines the rest (no diffuse under
it); a dielectric's highlight is the light's colour, whiter than a coloured material round it.
"""

from __future__ import annotations

import glob
import os

import click
import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli.imageops import luminance
from svbrdf_cli.infer import physical as ph

#: Features the regression uses (:func:`features` names).
NAMES = ("lp10", "lm0", "lc0", "p99", "clip", "sat", "dsat", "rl", "rd", "lres", "lm1", "lp50", "contrast")
#: Generated sets: (seed, photos) for training and for testing.
TRAIN, TEST = (777, 256), (31337, 256)
#: Mean GT specular above which a Des19 sample counts as a metal (its dielectrics store 0.043).
DES19_METAL = 0.08
#: :func:`colour_rule`: the highlight's least saturation, the share of the darker half's saturation it
#: must keep, its least brightness over the photo's median, and the most hue difference (degrees).
COLOUR_RULE = {"saturation": 0.15, "keeps": 0.85, "outshines": 5.0, "hue": 30.0}


def _saturation(c):
    return float((c.max() - c.min()) / max(float(c.max()), 1e-6))


def _hue(c):
    import colorsys

    return 360.0 * colorsys.rgb_to_hsv(*(float(v) for v in c / max(float(c.max()), 1e-9)))[0]


def highlight_colour(lin, lum, clipped):
    """The highlight's colour against the rest of one photo (its linear colours (H, W, 3), their luminance
    and the clipped pixels, as :func:`features` has them): the mean linear colour of the brightest 1 % of
    the unclipped pixels against that of the darker half. Returns a dict: ``hl_sat`` and ``lo_sat`` (their
    saturations), ``dhue`` (their hue difference, degrees) and ``outshines`` (the highlight's luminance
    over the median's)."""
    ok = ~clipped
    if ok.sum() < 100:
        return {"hl_sat": 0.0, "lo_sat": 0.0, "dhue": 180.0, "outshines": 1.0}
    hi = ok & (lum >= np.quantile(lum[ok], 0.99))
    ch, cl = lin[hi].mean(0), lin[lum <= np.quantile(lum, 0.5)].mean(0)
    dh = abs(_hue(ch) - _hue(cl))
    return {"hl_sat": _saturation(ch), "lo_sat": _saturation(cl), "dhue": min(dh, 360.0 - dh),
            "outshines": float(lum[hi].mean() / max(float(np.median(lum)), 1e-9))}


def colour_rule(f, rule=None):
    """Issue 14's cue as a rule (:data:`COLOUR_RULE`) over :func:`highlight_colour`'s measures: a
    coloured highlight, as coloured as the rest of the photo and of its hue, that outshines it."""
    r = rule or COLOUR_RULE
    return bool(f["hl_sat"] >= r["saturation"] and f["hl_sat"] >= r["keeps"] * f["lo_sat"]
                and f["outshines"] >= r["outshines"] and f["dhue"] <= r["hue"])


def features(image, geo=None):
    """The flash fit's evidence about metal for one encoded photo (H, W, 3): a dict of :data:`NAMES`
    plus ``m1``, the unbounded fit's lobe height over the flash power (a metal's F0 reading), and
    :func:`highlight_colour`'s measures."""
    geo = geo or ph.Geometry()
    im = np.asarray(image, np.float32)
    lin = cv.image_to_linear(im).astype(np.float32)
    lum = luminance(lin)
    h, w = lum.shape
    x, y = ph.surface_grid(h, w)
    foot = ph.flash_foot(lum, x, y)
    rho = np.sqrt((x - foot[0]) ** 2 + (y - foot[1]) ** 2)
    clipped = (im >= ph.CLIPPED).any(-1)
    fd = ph.fit_lobe(lum, clipped, rho, geo)
    p = geo.intensity
    r, prof, wts = ph.ring_profile(lum, clipped, rho)
    unb = {"m0": 0.0, "m1": 0.0, "res_u": 1.0, "res_l": 1.0, "r_l": ph.DEFAULT_ROUGHNESS}
    if len(r) >= 6:
        t = ph.lobe_terms(r, prof, wts, geo)
        s, g, wt, m0, m1 = t.s, t.g, t.w, t.m0, t.m1
        flat = max(float((wts * (prof - (wts * prof).sum() / wts.sum()) ** 2).sum()), 1e-20)
        c1 = np.maximum((wt * g * prof).sum(-1) / np.maximum((wt * g * g).sum(-1), 1e-30), 0.0)
        res_l = (wt * (prof - c1[..., None] * g) ** 2).sum(-1)
        j = np.unravel_index(int(np.argmin(res_l)), res_l.shape)
        res_u = np.where((m0 >= 0) & (m1 > 0), (wt * (prof - m0[..., None] * s - m1[..., None] * g) ** 2).sum(-1), np.inf)
        k = np.unravel_index(int(np.argmin(res_u)), res_u.shape)
        unb["res_l"], unb["r_l"] = float(res_l[j]) / flat, float(ph.ROUGHNESS_GRID[j[1]])
        if np.isfinite(res_u[k]):
            unb.update(m0=float(m0[k]) / p, m1=float(m1[k]) / p, res_u=float(res_u[k]) / flat)
    inner, outer = rho < np.percentile(rho, 5), rho > np.percentile(rho, 60)
    ci = lin[inner & ~clipped].mean(0) if (inner & ~clipped).sum() > 4 else lin[inner].mean(0)
    p10, p50, p99 = (float(np.percentile(lum, q)) for q in (10, 50, 99))
    f = {"lp10": np.log(p10 + 1e-3), "lm0": np.log(unb["m0"] + 1e-3), "lc0": np.log(fd.diffuse / p + 1e-3),
         "p99": p99, "clip": float(clipped.mean()), "sat": _saturation(lin.reshape(-1, 3).mean(0)),
         "dsat": _saturation(ci) - _saturation(lin[outer].mean(0)), "rl": unb["r_l"], "rd": fd.roughness,
         "lres": np.log((unb["res_l"] + 1e-3) / (1.0 - fd.gain + 1e-3)), "lm1": np.log(unb["m1"] + 1e-3),
         "lp50": np.log(p50 + 1e-3), "contrast": np.log((p99 + 1e-3) / (p10 + 1e-3)), "m1": unb["m1"]}
    f.update(highlight_colour(lin, lum, clipped))
    return {k: float(np.nan_to_num(v)) for k, v in f.items()}


def fit_logistic(x, y, l2=1e-2, steps=3000, rate=0.5):
    """A standardised logistic regression by gradient descent: returns ``predict(x) -> P(metal)``."""
    mu, sd = x.mean(0), x.std(0) + 1e-9
    z = np.c_[(x - mu) / sd, np.ones(len(x))]
    w = np.zeros(z.shape[1])
    for _ in range(steps):
        q = 1.0 / (1.0 + np.exp(-z @ w))
        w -= rate * (z.T @ (q - y) / len(y) + l2 * np.r_[w[:-1], 0.0])
    return lambda xn: 1.0 / (1.0 + np.exp(-np.c_[(xn - mu) / sd, np.ones(len(xn))] @ w))


def _matrix(rows):
    return np.array([[r[n] for n in NAMES] for r in rows], np.float64)


def _generated(seed, count):
    from export.studies.physical_eval import generated_photos

    photos, maps = generated_photos(count, size=256, seed=seed)
    rows = [features(p) for p in photos]
    gt = maps["specular"].reshape(count, -1).mean(1)
    return rows, gt, gt > 0.2


def _report(tag, call, rows, gt, metal, log):
    f0 = np.where(call, np.clip([r["m1"] for r in rows], cv.DIELECTRIC_F0, 1.0), cv.DIELECTRIC_F0)
    log(f"{tag:<22} metals {int(metal.sum()):>3}/{len(rows):<4} called {int(call.sum()):>3}: {int((call & metal).sum())} metals, "
        f"{int((call & ~metal).sum())} dielectrics | |F0 error| {np.abs(gt - f0).mean():.4f} (F0 = 0.04 everywhere: "
        f"{np.abs(gt - cv.DIELECTRIC_F0).mean():.4f})")


#: A network's mean F0 above which :func:`study` lists a real photo (about 4x a dielectric's).
NETWORK_CALL = 0.15


def _network_f0(network, image):
    """Mean linear F0 of ``network``'s (an :class:`export.studies.methods.Network`) maps for one encoded photo."""
    return float(cv.decode_maps(network(image))["specular"].mean())


def study(log=print, model_dir=None):
    from export.files import shared_root

    train, gt_a, metal_a = _generated(*TRAIN)
    test, gt_b, metal_b = _generated(*TEST)
    predict = fit_logistic(_matrix(train), metal_a.astype(np.float64))
    colour = lambda rows: np.array([colour_rule(r) for r in rows])  # noqa: E731
    for tag, rows, gt, metal in ((f"generated (train {TRAIN[0]})", train, gt_a, metal_a),
                                 (f"generated (test {TEST[0]})", test, gt_b, metal_b)):
        _report(tag, predict(_matrix(rows)) > 0.5, rows, gt, metal, log)
        _report("  colour rule", colour(rows), rows, gt, metal, log)
    root = shared_root()
    if not (root / "data" / "validation" / "des19").is_dir():
        log("../shared not found: Des19 and the real photos are left out")
        return
    from export.studies.evaluate import load_des19

    des = load_des19(str(root / "data" / "validation" / "des19"))
    rows = [features(img.permute(1, 2, 0).numpy()) for _, img, _ in des]
    gt = np.array([float(m["specular"].mean()) for _, _, m in des])
    _report("Des19", predict(_matrix(rows)) > 0.5, rows, gt, gt > DES19_METAL, log)
    _report("  colour rule", colour(rows), rows, gt, gt > DES19_METAL, log)
    network = None
    if model_dir:
        from export.studies.methods import Network

        network = Network(os.path.basename(os.path.normpath(model_dir)), model_dir, threads=1)
        f0 = np.array([_network_f0(network, img.permute(1, 2, 0).numpy()) for _, img, _ in des])
        metal = gt > DES19_METAL
        log(f"network {network.name} on Des19: mean F0 {f0[~metal].min():.3f}-{f0[~metal].max():.3f} on the "
            f"{int((~metal).sum())} dielectrics, {f0[metal].min():.3f}-{f0[metal].max():.3f} on the {int(metal.sum())} "
            f"metals | |F0 error| {np.abs(gt - f0).mean():.4f} "
            f"(F0 = 0.04 everywhere: {np.abs(gt - cv.DIELECTRIC_F0).mean():.4f})")
    from svbrdf_cli.ingest import photo as ingest
    from svbrdf_cli.infer import exposure
    from svbrdf_cli.rectify import crops as rectify

    names, rows, images = [], [], []
    for path in sorted(glob.glob(str(root / "data" / "real" / "**" / "*"), recursive=True)):
        if not path.lower().endswith((".jpg", ".jpeg", ".png")) or "reference_maps" in path:
            continue
        try:
            lin = rectify.crop(ingest.load_photo(path, min_side=512).linear, "auto").image
        except Exception:  # noqa: BLE001 (a photo the crop refuses is left out of the count)
            continue
        names.append(os.path.relpath(path, root / "data" / "real"))
        image = exposure.network_input(lin)
        rows.append(features(image))
        if network is not None:  # (only then: 267 photos at 256 px are 200 MB)
            images.append(image)
    p = predict(_matrix(rows))
    called = [(float(q), n, r["m1"]) for q, n, r in zip(p, names, rows) if q > 0.5]
    log(f"real photos: {len(called)} of {len(rows)} called metal (their F0 reading m1 in brackets):")
    for q, n, m1 in sorted(called, reverse=True):
        log(f"  P {q:.2f}  F0 {min(max(m1, cv.DIELECTRIC_F0), 1.0):.3f}  {n}")
    called = [(n, r["m1"]) for n, r in zip(names, rows) if colour_rule(r)]
    log(f"real photos: {len(called)} of {len(rows)} called metal by the colour rule:")
    for n, m1 in called:
        log(f"  F0 {min(max(m1, cv.DIELECTRIC_F0), 1.0):.3f}  {n}")
    if network is not None:
        f0 = [(_network_f0(network, im), n) for im, n in zip(images, names)]
        called = sorted((v, n) for v, n in f0 if v > NETWORK_CALL)
        log(f"real photos: {len(called)} of {len(f0)} given a mean F0 above {NETWORK_CALL} by network {network.name}:")
        for v, n in reversed(called):
            log(f"  F0 {v:.3f}  {n}")


@click.command()
@click.option("--model-dir", type=click.Path(exists=True, file_okay=False), default=None,
              help="Also an exported network's F0 on Des19 and the real photos (e.g. a training run's export).")
def cli(model_dir):
    """Train the metal decision on generated photos; report it there, on Des19 and on the real photos."""
    import logging
    import warnings

    warnings.filterwarnings("ignore", category=RuntimeWarning)
    logging.getLogger("svbrdf").setLevel(logging.ERROR)  # the crop's per-photo advice
    study(log=click.echo, model_dir=model_dir)


if __name__ == "__main__":
    cli()
