"""Calibrate ``--model auto`` on generated photos, and measure it on Des19 and the real photos.

    python -m export.studies.auto_calibration                  # calibrate: writes svbrdf_cli/models/auto.json
    python -m export.studies.auto_calibration --samples 16 --out /tmp/auto.json    # a smoke run

**Calibration.** Photos from our own data engine (:mod:`export.data.dataset`,
seed :data:`CALIBRATION_SEED`, which no training run uses) go through every
installed tier; each tier's error is the re-rendering RMSE under 9 lights
against the photo's ground truth (:func:`export.studies.evaluate.relight_rmse`),
its cost the median seconds per 256² image on this CPU. For each step up the
ladder (tier i -> tier i + 1) and each signal of :data:`svbrdf_cli.infer.auto.SIGNALS`,
every threshold is tried: photos whose signal is above it (or, the other
candidate, below it) take the next tier.
The rule kept is the *cheapest* whose mean error is within ``--margin``
(relative) of the best single tier's; ties go to the lower error. "Never step
up" is one of the candidates, so when the cheap tier is already as good as
the next on these photos, the rule says so. With the physical estimate the
only installed tier, the ladder is that one rung and has no step; its error
and cost are measured all the same.

**Evidence** (:func:`evidence`, run by ``python -m export.studies.benchmark``): the
shipped rule, frozen, on Des19 (per-photo relighting error of each tier and of
auto, and seconds per photo measured on those photos in the same run), on
``card_blue_9lights`` (relighting of the 8 held-out photos) and on the real
photos of the stability suite (cost and tier chosen; they have no ground truth).
"""

from __future__ import annotations

import json
import os
import time

import click
import numpy as np
import torch

from export.studies.evaluate import chw, relight_rmse
from export.files import command_errors, write_json
from svbrdf_cli.infer import auto as auto_tier
from svbrdf_cli import conventions as cv
from export.studies.capture_speed import median_seconds
from svbrdf_cli.errors import SvbrdfError
from svbrdf_cli.write.mapset import stored_to_linear

#: The data engine's seed for calibration photos (training uses 0 and its per-stage streams, validation 1).
CALIBRATION_SEED = 2468
#: Default tolerance: auto's mean error may exceed the best tier's by this fraction.
MARGIN = 0.02
#: Default number of calibration photos.
CALIBRATION_SAMPLES = 128


def tier_error(stored, gt):
    """Re-rendering RMSE (9 lights) of stored maps against linear (C, H, W) ground truth."""
    return relight_rmse(chw(stored_to_linear({k: stored[k] for k in cv.MAP_NAMES})), gt)


def generated(count, seed=CALIBRATION_SEED, size=256):
    """``count`` (network input (H, W, 3), linear GT maps of (C, H, W)) from the data engine."""
    from export.data import dataset

    g = torch.Generator().manual_seed(seed)
    bank = dataset.SeedBank.find(None)
    out = []
    while len(out) < count:
        batch = dataset.make_batch(g, min(8, count - len(out)), dataset.DataConfig(size=size, targets=()), seeds=bank)
        out += [(batch["photo"][i].permute(1, 2, 0).numpy(), {k: batch[k][i] for k in cv.MAP_NAMES})
                for i in range(batch["photo"].shape[0])]
    return out


def tier_seconds(chains, repeat=5, size=256):
    """Median seconds per ``size``² network input of each tier, and of each signal (on the cheapest tier)."""
    x = np.random.default_rng(0).uniform(0, 1, (size, size, 3)).astype(np.float32)
    tiers = {t: median_seconds(lambda c=c: c(x), repeat) for t, c in chains.items()}
    first = next(iter(chains.values()))
    maps = first(x)
    signals = {n: median_seconds(lambda n=n: auto_tier.signal(n, x, maps, first), repeat) for n in auto_tier.SIGNALS}
    return tiers, signals


def collect(chains, samples, log=None):
    """Per tier (``chains``, cheapest first), the error on each sample; per (tier, signal), its value on
    each sample (for every tier but the dearest, which is never stepped up from)."""
    errors = {t: [] for t in chains}
    values = {t: {n: [] for n in auto_tier.SIGNALS} for t in list(chains)[:-1]}  # signals of every tier but the dearest
    for i, (image, gt) in enumerate(samples):
        for t, chain in chains.items():
            out = chain(image)
            maps = {k: out[k] for k in cv.MAP_NAMES}
            errors[t].append(tier_error(maps, gt))
            for n in auto_tier.SIGNALS if t in values else ():
                values[t][n].append(auto_tier.signal(n, image, maps, chain))
        if log and (i + 1) % 16 == 0:
            log(f"calibration: {i + 1}/{len(samples)} photos")
    return ({t: np.array(v) for t, v in errors.items()},
            {t: {n: np.array(v) for n, v in d.items()} for t, d in values.items()})


def choose_step(err_lo, err_hi, cost_lo, cost_hi, values, signal_cost, margin=MARGIN):
    """The rule for one step up (tier lo -> tier hi) and every candidate's figures.

    ``values``: {signal: per-photo values}; ``signal_cost``: {signal: seconds}.
    A candidate steps up the photos whose signal is on one side of its threshold; its
    error is the mean of the errors of the tiers taken, its cost the mean
    seconds (the cheap tier always, the signal, the next tier where taken).
    Returns (chosen candidate, the candidates within the tolerance), as dicts with
    ``signal``, ``threshold`` (None: never step up), ``above`` (step up above
    the threshold, or below), ``error``, ``seconds``, ``stepped_up`` (fraction).
    """
    err_lo, err_hi = np.asarray(err_lo, float), np.asarray(err_hi, float)
    best = min(err_lo.mean(), err_hi.mean())
    cands = [{"signal": next(iter(values)), "threshold": None, "above": True, "error": float(err_lo.mean()),
              "seconds": float(cost_lo), "stepped_up": 0.0}]
    for name, v in values.items():
        v = np.asarray(v, float)
        cuts = np.unique(v)
        # Thresholds between consecutive values, and one below them all (every photo steps up);
        # stepping up above or below each.
        for tau in np.concatenate([[cuts[0] - 1.0], (cuts[:-1] + cuts[1:]) / 2]):
            for above in (True, False):
                up = v > tau if above else v < tau
                if not above and not up.any():
                    continue
                cands.append({"signal": name, "threshold": float(tau), "above": above,
                              "error": float(np.where(up, err_hi, err_lo).mean()),
                              "seconds": float(cost_lo + signal_cost[name] + up.mean() * cost_hi),
                              "stepped_up": float(up.mean())})
    ok = [c for c in cands if c["error"] <= best * (1 + margin) + 1e-12]
    return min(ok, key=_cheapest), ok


def _correlation(a, b):
    """Pearson correlation of two per-photo series; None where one is constant (the physical estimate's
    F0 is the same 0.04 on every photo: its specular signal says nothing)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if a.std() == 0 or b.std() == 0:
        return None
    return float(np.corrcoef(a, b)[0, 1])


def _r2(value):
    return "–" if value is None else f"{value:.2f}"


def _cheapest(candidate):
    """Order of preference among rules within the tolerance: cost, then error."""
    return round(candidate["seconds"], 6), candidate["error"]


def calibrate(samples, chains=None, margin=MARGIN, repeat=5, log=print):
    """The rule for the installed tiers (cheapest first), from ``samples`` (see :func:`generated`)."""
    if chains is None:
        from svbrdf_cli.infer.registry import load_model

        chains = {t: load_model(t) for t in auto_tier.available_tiers()}
    ladder = list(chains)
    if not ladder:
        raise SvbrdfError("--model auto needs an installed tier; found none")
    cost, sig_cost = tier_seconds(chains, repeat)
    errors, values = collect(chains, samples, log)
    steps, report = [], []
    for lo, hi in zip(ladder, ladder[1:]):
        chosen, within = choose_step(errors[lo], errors[hi], cost[lo], cost[hi], values[lo], sig_cost, margin)
        per_signal = {n: min(cs, key=_cheapest) for n in auto_tier.SIGNALS
                      if (cs := [c for c in within if c["signal"] == n and c["threshold"] is not None])}
        steps.append({k: chosen[k] for k in ("signal", "threshold", "above")})
        report.append({"from": lo, "to": hi, "chosen": chosen, "cheapest_per_signal": per_signal,
                       "correlation": {n: _correlation(values[lo][n], errors[hi] - errors[lo])
                                       for n in auto_tier.SIGNALS}})
    rule = {"ladder": ladder, "steps": steps}
    levels = [auto_tier.decide(rule, [values[ladder[i]][s["signal"]][j] for i, s in enumerate(steps)])
              for j in range(len(samples))]
    auto_err = float(np.mean([errors[ladder[lv]][j] for j, lv in enumerate(levels)]))
    rule["calibration"] = {
        "data": f"export.data.dataset.make_batch, {len(samples)} photos at 256², seed {CALIBRATION_SEED}",
        "metric": "re-rendering RMSE under 9 lights (export.studies.evaluate.relight_rmse)",
        "margin": margin, "tier_error": {t: float(e.mean()) for t, e in errors.items()},
        "tier_seconds_256": cost, "signal_seconds_256": sig_cost,
        "auto_error": auto_err, "tiers_taken": {t: levels.count(i) for i, t in enumerate(ladder)},
        "steps": report, "cores": os.cpu_count(), "made": time.strftime("%Y-%m-%dT%H:%M:%S"),
        "command": f"python -m export.studies.auto_calibration --samples {len(samples)} --margin {margin}",
    }
    return rule


# --------------------------------------------------------------------------
# Evidence on Des19 and the real photos
# --------------------------------------------------------------------------

def _timed(fn, x, repeat=3):
    """(fn(x), median seconds of ``repeat`` calls)."""
    out = fn(x)
    return out, median_seconds(lambda: fn(x), repeat)


def evidence(rule, des19, nine=None, real=(), chains=None, log=print):
    """The frozen rule against each tier, per set: mean error, mean seconds per photo (network input to
    maps, median of 3 runs on each of that set's photos, in this run), and the tiers auto took.

    ``des19``: [(name, (3, H, W) input, linear GT)]; ``nine``: a
    :class:`export.studies.benchmark.NineLights` or None; ``real``: network inputs
    without ground truth (cost and tiers only).
    """
    from svbrdf_cli.infer.registry import load_model

    auto = auto_tier.AutoModel(load_model, rule, chains=chains)
    models = {t: auto.chain(t) for t in rule["ladder"]}
    models["auto"] = auto
    for m in models.values():  # warm up every session once, outside the timings
        m(np.zeros((256, 256, 3), np.float32))
    sets = {"des19": [(p.permute(1, 2, 0).numpy(), gt) for _, p, gt in des19]}
    if nine is not None:
        sets["card_blue_9lights"] = [(nine.network_input(), None)]
    if len(real):
        sets["real photos (no ground truth)"] = [(x, None) for x in real]
    out = {}
    cheap = rule["ladder"][0]
    for name, items in sets.items():
        row = {"photos": len(items), "error": {}, "seconds": {}, "taken": {t: 0 for t in rule["ladder"]}}
        per_photo, signals = {}, {n: [] for n in auto_tier.SIGNALS}
        for key, model in models.items():
            errs, secs = [], []
            for image, gt in items:
                maps, s = _timed(model, image)
                secs.append(s)
                maps = {k: maps[k] for k in cv.MAP_NAMES}
                if gt is not None:
                    errs.append(tier_error(maps, gt))
                elif nine is not None and name == "card_blue_9lights":
                    errs.append(nine.relight_rmse(maps))
                if key == "auto":
                    row["taken"][auto.decision["chosen"]] += 1
                if key == cheap:
                    for n in auto_tier.SIGNALS:
                        signals[n].append(auto_tier.signal(n, image, maps, models[cheap]))
            per_photo[key] = np.array(errs)
            row["error"][key] = float(np.mean(errs)) if errs else None
            row["seconds"][key] = float(np.mean(secs))
        tiers = [t for t in rule["ladder"] if row["error"][t] is not None]
        if tiers:
            best = min(tiers, key=lambda t: row["error"][t])
            row["best_tier"] = best
            row["error_vs_best"] = row["error"]["auto"] / row["error"][best] - 1
            row["cost_vs_best"] = row["seconds"]["auto"] / row["seconds"][best]
            # What a perfect per-photo choice would reach, and whether the signals would have told it
            # (a diagnostic on this set, never used to set the rule).
            row["better_of_tiers"] = float(np.min([per_photo[t] for t in tiers], axis=0).mean())
            if len(rule["ladder"]) > 1 and len(items) > 2:
                nxt = rule["ladder"][1]
                d = per_photo[nxt] - per_photo[cheap]
                row["correlation"] = {n: _correlation(v, d) for n, v in signals.items()}
                row["next_better_on"] = float((d < 0).mean())
        row["cost_vs_dearest"] = row["seconds"]["auto"] / row["seconds"][rule["ladder"][-1]]
        out[name] = row
        log(f"auto on {name}: " + json.dumps(row))
    return out


def evidence_table(ev, ladder):
    head = ("| set | photos | " + " | ".join(f"{t}: error" for t in ladder) + " | auto: error | auto vs best tier | "
            + " | ".join(f"{t}: s/photo" for t in ladder) + " | auto: s/photo | auto cost / best tier's | "
            f"auto cost / {ladder[-1]}'s | tiers auto took |\n|" + "---|" * (8 + 2 * len(ladder)) + "\n")
    lines = []
    for name, r in ev.items():
        e = r["error"]
        lines.append(
            f"| {name} | {r['photos']} | " + " | ".join("–" if e[t] is None else f"{e[t]:.4f}" for t in ladder)
            + f" | {'–' if e['auto'] is None else format(e['auto'], '.4f')} | "
            + (f"{100 * r['error_vs_best']:+.1f} % ({r['best_tier']})" if "best_tier" in r else "–") + " | "
            + " | ".join(f"{r['seconds'][t]:.3f}" for t in ladder) + f" | {r['seconds']['auto']:.3f} | "
            + (f"{r['cost_vs_best']:.2f}" if "cost_vs_best" in r else "–") + f" | {r['cost_vs_dearest']:.2f} | "
            + ", ".join(f"{t} {n}" for t, n in r["taken"].items()) + " |")
    diag = [(n, r) for n, r in ev.items() if "correlation" in r]
    if diag:
        names = list(diag[0][1]["correlation"])
        lines += ["", f"Diagnostics (not used to set the rule): the error of the better tier per photo, how often "
                  f"{ladder[1]} beats {ladder[0]}, and how each signal correlates with ({ladder[1]} − {ladder[0]})'s "
                  "error.", "",
                  "| set | better tier per photo | " + f"{ladder[1]} better on | "
                  + " | ".join(f"corr({n})" for n in names) + " |", "|---|---|---|" + "---|" * len(names)]
        lines += [f"| {n} | {r['better_of_tiers']:.4f} | {100 * r['next_better_on']:.0f} % | "
                  + " | ".join(_r2(r["correlation"][k]) for k in names) + " |" for n, r in diag]
    return head + "\n".join(lines) + "\n"


def calibration_table(rule):
    cal = rule["calibration"]
    lines = [f"Calibration: {cal['data']}; tolerance {100 * cal['margin']:.0f} % over the best single tier.", ""]
    if not cal["steps"]:
        lines.append(f"The ladder is one tier ({rule['ladder'][0]}): there is no step to calibrate.")
    else:
        lines += ["| step | signal | cost of the signal (s) | corr(signal, next − this tier's error) | cheapest "
                  "threshold within tolerance | error | s/photo | stepped up |", "|---|---|---|---|---|---|---|---|"]
    for st in cal["steps"]:
        for n in auto_tier.SIGNALS:
            c = st["cheapest_per_signal"].get(n)
            lines.append(f"| {st['from']} → {st['to']} | {n} | {cal['signal_seconds_256'][n]:.4f} | "
                         f"{_r2(st['correlation'][n])} | " + ("none within tolerance | – | – | –" if c is None else
                         f"{'>' if c['above'] else '<'} {c['threshold']:.4f} | {c['error']:.4f} | {c['seconds']:.3f} | "
                         f"{100 * c['stepped_up']:.0f} %")
                         + " |")
        ch = st["chosen"]
        lines.append(f"| {st['from']} → {st['to']} | **chosen**: "
                     + ("never step up" if ch["threshold"] is None
                        else f"{ch['signal']} {'>' if ch['above'] else '<'} {ch['threshold']:.4f}")
                     + f" | | | | {ch['error']:.4f} | {ch['seconds']:.3f} | {100 * ch['stepped_up']:.0f} % |")
    lines.append("")
    lines.append("| tier | error on the calibration photos | s/photo (256²) |\n|---|---|---|")
    lines += [f"| {t} | {cal['tier_error'][t]:.4f} | {cal['tier_seconds_256'][t]:.3f} |" for t in rule["ladder"]]
    lines.append(f"| auto | {cal['auto_error']:.4f} | |")
    return "\n".join(lines) + "\n"


@click.command()
@click.option("--samples", default=CALIBRATION_SAMPLES, show_default=True, help="Generated calibration photos.")
@click.option("--margin", default=MARGIN, show_default=True, help="Tolerated relative error over the best tier.")
@click.option("--repeat", default=5, show_default=True, help="Timed runs per tier (median).")
@click.option("--out", type=click.Path(dir_okay=False), default=auto_tier.RULE_FILE, show_default=True)
@click.option("--threads", default=0, show_default=True,
              help="Threads for torch's data generation (0: every core; 1 beside a training run, which it "
                   "would otherwise stall).")
def cli(samples, margin, repeat, out, threads):
    """Calibrate --model auto's rule on generated photos and write it."""
    torch.set_num_threads(threads or max(1, os.cpu_count() or 1))
    with command_errors():
        rule = calibrate(generated(samples), margin=margin, repeat=repeat, log=click.echo)
    write_json(out, rule)
    click.echo(calibration_table(rule))
    click.echo(f"wrote {out}")


if __name__ == "__main__":
    cli()
