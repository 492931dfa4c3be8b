"""Speed against accuracy, --model auto, stability, and confidence: the figures of ``docs/benchmarks.md``
and ``docs/stability.md``.

    python -m export.studies.benchmark                 # everything (minutes on 2 cores), into docs/
    python -m export.studies.benchmark --limit 2       # a smoke run on 2 samples of each set

For every runnable method (:mod:`export.studies.methods`: the floor, the end-to-end
baseline, each installed tier, ``--model auto``) it measures, in one run:

* **Des19 accuracy**: the maps of each sample's ``input.png``, scored by the
  paper's reference scorer ``../shared/tools/score_maps.py`` (per-map RMSE),
  and the re-rendering RMSE under 9 lights (``export.studies.evaluate``). The paper's
  published outputs are scored the same way (accuracy only; its 0.107 s is
  a GPU time).
* **Real relighting** on ``../shared/data/real/card_blue_9lights``: maps from
  photo 00 (as ``svbrdf capture --crop none`` would make them), rendered
  under the 8 other photos' known light = camera positions with the one
  light intensity that best reproduces photo 00, against those photos
  (RMSE of encoded images, saturated pixels left out). The reference maps
  shipped with the capture (optimised on all 9 photos by MaterialGAN) are
  scored the same way.
* **Time per image** of the whole chain on this CPU, median of ``--repeat``
  runs: at 256² (network input to maps) and at 2048² (a 2048² linear crop
  -> network input -> maps -> guided upsampling to 2048², as ``svbrdf
  capture`` does it, without file input/output).

It scores colour fidelity on the real photos (:mod:`export.studies.colour`: the diffuse map's hue and
saturation against the photo's, highlight excluded). It then runs the auto evidence
(:func:`export.studies.auto_calibration.evidence`: the shipped
rule against each tier on Des19, ``card_blue_9lights`` and the real photos,
with time per photo measured on those photos; then auto's calibration again,
to show it reproduces the shipped rule), the stability suite
(:mod:`export.studies.stability`) and the confidence evidence (does low confidence
mark high error on Des19?) and writes ``speed_vs_accuracy.png``,
``stability_gallery.png`` and ``benchmark.json`` into ``--figures`` and the
tables into ``--tables``.
"""

from __future__ import annotations

import json
import os
import tempfile

import click
import numpy as np
import torch

from export.studies import methods as method_zoo
from export.studies.auto_calibration import CALIBRATION_SAMPLES, calibrate, calibration_table, generated
from export.studies.auto_calibration import evidence as auto_evidence, evidence_table as auto_table
from export.studies.evaluate import chw, load_des19, relight_rmse, score, score_predictions
from export.files import REAL_PHOTOS, command_errors, shared_root
from export.render.relight import NineLights
from svbrdf_cli import conventions as cv
from export.studies.capture_speed import median_seconds
from svbrdf_cli.errors import SvbrdfError
from svbrdf_cli.write.mapset import read_map_set

MAPS = cv.MAP_NAMES


def des19_accuracy(method, samples, des19, out):
    """({map: rmse (reference scorer), relight: mean 9-light RMSE}, per-sample relighting RMSEs) of ``method``."""
    scores, rel, _, _ = score_predictions(samples, des19, out,
                                          lambda name, photo: chw(method(photo.permute(1, 2, 0).numpy())))
    return scores, rel


def paper_accuracy(samples, des19):
    """The paper's published Des19 outputs, scored like a method."""
    maps, _ = score(des19, prefix="paper_")
    paper = {k: f"paper_{k}" for k in MAPS}
    rel = [relight_rmse(chw(read_map_set(os.path.join(des19, name), paper, linear_albedo=True)), gt)
           for name, _, gt in samples]
    return {**maps, "relight": float(np.mean(rel))}


# --------------------------------------------------------------------------
# Time
# --------------------------------------------------------------------------

def timings(method, repeat=5, big=2048, seed=0):
    """Seconds per image: the method at 256², and a ``big``² crop through the capture path to ``big``² maps."""
    from svbrdf_cli.infer.exposure import NETWORK_SIZE, auto_exposure_gain, network_input
    from svbrdf_cli.imageops import resize
    from svbrdf_cli.infer.upsample import upsample_maps
    from svbrdf_cli.ingest.photo import encode_for_network

    rng = np.random.default_rng(seed)
    small = rng.random((NETWORK_SIZE, NETWORK_SIZE, 3), dtype=np.float32)
    crop = np.clip(resize(rng.random((64, 64, 3), dtype=np.float32) * 0.3, big)
                   + rng.normal(0, 0.01, (big, big, 3)).astype(np.float32), 0, 1)

    def whole():
        low = resize(crop, NETWORK_SIZE)  # as svbrdf capture: exposure measured at network size, then applied
        gain_ev = auto_exposure_gain(low)
        net_in = network_input(low, gain_ev)
        return upsample_maps(method(net_in), net_in, encode_for_network(crop * np.float32(2.0 ** gain_ev)), "guided")

    return {"s_256": median_seconds(lambda: method(small), repeat), f"s_{big}": median_seconds(whole, repeat)}


# --------------------------------------------------------------------------
# Confidence evidence
# --------------------------------------------------------------------------

def _rank(x):
    r = np.empty(len(x))
    r[np.argsort(x, kind="stable")] = np.arange(len(x))
    return r


def confidence_evidence(chain, samples):
    """Per map: Spearman correlation of (1 - confidence) with the per-pixel error, and the mean error
    of the least and most confident tenth of Des19's pixels (the chain's plain pass)."""
    from svbrdf_cli.infer import tta

    conf, err = {k: [] for k in MAPS}, {k: [] for k in MAPS}
    for _, photo, gt in samples:
        res = tta.passes(chain, photo.permute(1, 2, 0).numpy())
        c = tta.confidence(res)
        g = cv.encode_maps({k: v.permute(1, 2, 0).numpy() for k, v in gt.items()})
        for k in MAPS:
            p = res[0][k]
            err[k].append(np.sqrt(((p - g[k][..., :p.shape[-1]]) ** 2).mean(-1)).ravel())
            conf[k].append(c[k].ravel())
    out = {}
    for k in MAPS:
        c, e = np.concatenate(conf[k]), np.concatenate(err[k])
        lo, hi = np.quantile(c, [0.1, 0.9])
        out[k] = {"spearman_uncertainty_error": float(np.corrcoef(_rank(-c), _rank(e))[0, 1]),
                  "error_least_confident_10pct": float(e[c <= lo].mean()),
                  "error_most_confident_10pct": float(e[c >= hi].mean()),
                  "error_all": float(e.mean()), "mean_confidence": float(c.mean())}
    return out


# --------------------------------------------------------------------------
# Figure and tables
# --------------------------------------------------------------------------

def pareto_figure(rows, path, big=2048):
    """Time at 256² and ``big``² against the Des19 and real relighting errors, one point per method."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [("s_256", "des19_relight", "Des19: re-rendering RMSE (9 lights)"),
              (f"s_{big}", "real_relight", "card_blue_9lights: relighting RMSE (8 held-out photos)")]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, (tkey, akey, title) in zip(axes, panels):
        pts = [(r[tkey], r[akey], r["name"]) for r in rows if r.get(tkey) and r.get(akey) is not None]
        span = max(a for _, a, _ in pts) - min(a for _, a, _ in pts) or 1.0
        for i, (t, a, name) in enumerate(pts):
            ax.scatter([t], [a], s=40, zorder=3, marker="*" if name == "paper" else "o")
            # Auto sits on the tier it picks: stack the labels of points that (nearly) coincide.
            near = sum(abs(np.log(t / t2)) < 0.2 and abs(a - a2) < 0.03 * span for t2, a2, _ in pts[:i])
            ax.annotate(name + (" (GPU, published)" if name == "paper" else ""), (t, a),
                        textcoords="offset points", xytext=(6, 4 - 11 * near), fontsize=8)
        front, best = [], np.inf
        for t, a, _ in sorted(pts):
            if a < best:
                front.append((t, a))
                best = a
        if len(front) > 1:
            ax.step(*zip(*front), where="post", color="0.6", lw=1, zorder=1)
        ax.set_xscale("log")
        lo, hi = ax.get_xlim()
        short = np.log10(hi / lo) < 1.5  # an axis under two decades: its minor ticks labelled at 2 and 5 only
        ax.xaxis.set_minor_formatter(matplotlib.ticker.FuncFormatter(
            lambda v, _, short=short: f"{v:g}" if short and round(v / 10 ** np.floor(np.log10(v))) in (2, 5) else ""))
        what = "network input to maps" if tkey == "s_256" else "crop to upsampled maps"
        ax.set_xlabel(f"seconds per image at {tkey[2:]}² ({what})")
        ax.set_ylabel("RMSE (lower is better)")
        ax.set_title(title, fontsize=10)
        ax.grid(alpha=0.3, which="both")
    fig.suptitle("Speed against accuracy on this CPU (2 cores); grey: the Pareto front", fontsize=10)
    fig.tight_layout()
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _f(x, nd=4):
    return "–" if x is None else f"{x:.{nd}f}"


def speed_table(rows, big=2048):
    head = ("| method | normal | diffuse | roughness | specular | Des19 relight | real relight | "
            f"s @256² | s @{big}² |\n|---|---|---|---|---|---|---|---|---|\n")
    lines = []
    for r in rows:
        t256 = r.get("s_256")
        lines.append(f"| {r['label']} | " + " | ".join(_f(r.get(k)) for k in MAPS) + f" | {_f(r.get('des19_relight'))} | "
                     f"{_f(r.get('real_relight'))} | {_f(t256, 3) if t256 else '–'}"
                     f"{' (GPU)' if r['name'] == 'paper' else ''} | {_f(r.get(f's_{big}'), 3)} |")
    return head + "\n".join(lines) + "\n"


def confidence_table(ev):
    head = ("| map | Spearman (1 − confidence, error) | error, least confident 10 % | error, most confident 10 % "
            "| error, all | mean confidence |\n|---|---|---|---|---|---|\n")
    return head + "\n".join(
        f"| {k} | {v['spearman_uncertainty_error']:.2f} | {v['error_least_confident_10pct']:.4f} | "
        f"{v['error_most_confident_10pct']:.4f} | {v['error_all']:.4f} | {v['mean_confidence']:.2f} |"
        for k, v in ev.items()) + "\n"


def run(limit=None, repeat=5, figures="docs/figures", tables="docs/tables", stability=True, log=print, threads=0):
    """The whole benchmark; returns its results (also written as ``benchmark.json`` beside the figures)."""
    from export.studies import stability as stability_suite
    root = shared_root() / "data"
    des19 = str(root / "validation" / "des19")
    if not os.path.isdir(des19):
        raise SvbrdfError(f"{des19}: Des19 validation samples not found (set SVBRDF_SHARED)")
    samples = load_des19(des19)[:limit] if limit else load_des19(des19)
    if limit:  # the reference scorer reads a whole folder: give it one with just these samples
        sub = tempfile.mkdtemp(prefix="svbrdf-des19-")
        for name, _, _ in samples:
            os.symlink(os.path.join(des19, name), os.path.join(sub, name))
        des19 = sub
    nine = NineLights(str(root / "real" / "card_blue_9lights")) \
        if os.path.isdir(root / "real" / "card_blue_9lights") else None
    work = tempfile.mkdtemp(prefix="svbrdf-bench-")
    rows, per_sample = [], {}
    methods = method_zoo.available(threads, refined=True)  # with the default capture's --refine
    nine_input = nine.network_input() if nine else None
    for method in methods:
        r = {"name": method.name, "label": method.label}
        acc, per_sample[method.name] = des19_accuracy(method, samples, des19, os.path.join(work, method.name))
        r.update({k if k in MAPS else "des19_relight": v for k, v in acc.items()})
        if nine:
            r["real_relight"] = nine.relight_rmse(method(nine_input))
        r.update(timings(method, repeat))
        rows.append(r)
        log(f"{method.name:6s} " + "  ".join(f"{k}={v:.4f}" for k, v in r.items() if isinstance(v, float)))
    paper = {"name": "paper", "label": "paper (Des19 published outputs)", "s_256": method_zoo.PAPER_GPU_SECONDS}
    paper.update({k if k in MAPS else "des19_relight": v for k, v in paper_accuracy(samples, des19).items()})
    rows.append(paper)
    if nine:
        rows.append({"name": "reference", "label": "card_blue reference maps (MaterialGAN, fitted to all 9 photos)",
                     "real_relight": nine.relight_rmse(nine.reference_maps())})
    log("paper  " + "  ".join(f"{k}={v:.4f}" for k, v in paper.items() if isinstance(v, float)))
    results = {"methods": rows, "samples": len(samples), "repeat": repeat, "cores": os.cpu_count()}
    # the chart and its table first: what follows (auto's calibration above all) runs much longer
    os.makedirs(figures, exist_ok=True)
    os.makedirs(tables, exist_ok=True)
    pareto_figure(rows, os.path.join(figures, "speed_vs_accuracy.png"))
    with open(os.path.join(tables, "speed_vs_accuracy.md"), "w") as f:
        f.write(speed_table(rows))

    from svbrdf_cli.infer.exposure import network_input
    from svbrdf_cli.infer.registry import DEFAULT_MODEL

    by_name = {m.name: m for m in methods}  # the sessions loaded above serve every part below
    tier = DEFAULT_MODEL  # what svbrdf capture runs unless told otherwise
    chain = by_name[tier].chain
    # A network's --confidence measures how its maps move under rotation: for the physical estimate (whose
    # roughness and specular are constants) that says nothing, so the evidence is the last network's run
    # here (the dearest installed tier, else the end-to-end baseline).
    networks = [m.name for m in methods if isinstance(m, method_zoo.Network)]
    conf_tier = tier if tier != "physical" or not networks else networks[-1]
    results["confidence"] = {"tier": conf_tier, "maps": confidence_evidence(by_name[conf_tier].chain, samples)}
    real = stability_suite.real_crops(root / "real", limit or REAL_PHOTOS) if os.path.isdir(root / "real") else []
    real_inputs = [(name, network_input(lin)) for name, lin in real]  # once, for colour and auto
    from export.studies import colour

    results["colour"] = colour.evaluate(methods, real_inputs, log=log)
    if "auto" in by_name:
        rule = by_name["auto"].model.rule
        tiers = {t: by_name[t].chain for t in rule["ladder"]}
        results["auto"] = {"rule": rule, "sets": auto_evidence(rule, samples, nine, [x for _, x in real_inputs],
                                                               chains=tiers, log=log)}
        # The shipped rule's calibration, run again (python -m export.studies.auto_calibration, without writing the rule).
        fresh = calibrate(generated(8 if limit else CALIBRATION_SAMPLES), chains=tiers, repeat=repeat, log=log)
        results["auto"]["recalibrated"] = {"rule": fresh, "same_steps_as_shipped": fresh["steps"] == rule["steps"]}
    text = {"speed_vs_accuracy.md": speed_table(rows), "confidence.md": confidence_table(results["confidence"]["maps"]),
            "colour.md": colour.table(results["colour"])}
    if "auto" in results:
        again = results["auto"]["recalibrated"]
        text["auto.md"] = (auto_table(results["auto"]["sets"], rule["ladder"]) + "\n" + calibration_table(again["rule"])
                           + "\nThis calibration, run again by the benchmark, "
                           + ("gives the shipped rule's steps.\n" if again["same_steps_as_shipped"]
                              else "does NOT give the shipped rule's steps: re-run python -m export.studies.auto_calibration.\n"))
    if stability:
        results["stability"] = stability_suite.run(chain, samples, des19, real,
                                     gallery=os.path.join(figures, "stability_gallery.png"), log=log)
        text["stability.md"] = stability_suite.table(results["stability"])
    for name, t in text.items():
        with open(os.path.join(tables, name), "w") as f:
            f.write(t)
        log(f"\n{name}\n{t}")
    with open(os.path.join(tables, "benchmark.json"), "w") as f:
        json.dump(results, f, indent=1)
    return results


@click.command()
@click.option("--limit", type=int, default=None, help="Only the first N samples of each set (a smoke run).")
@click.option("--repeat", default=5, show_default=True, help="Timed runs per method and size (median).")
@click.option("--figures", default="docs/figures", show_default=True, type=click.Path(file_okay=False))
@click.option("--tables", default="docs/tables", show_default=True, type=click.Path(file_okay=False),
              help="Markdown tables and benchmark.json go here.")
@click.option("--no-stability", is_flag=True, help="Skip the stability suite.")
@click.option("--threads", default=0, help="onnxruntime threads (0: one per core).")
def cli(limit, repeat, figures, tables, no_stability, threads):
    """Speed against accuracy, the stability suite and the confidence evidence, in one run."""
    torch.set_num_threads(max(1, os.cpu_count() or 1))
    with command_errors():
        run(limit, repeat, figures, tables, not no_stability, log=click.echo, threads=threads)


if __name__ == "__main__":
    cli()
