"""``--model auto``: per photo, the cheapest installed tier that is good enough for the scene.

The ladder starts with the physical estimate (``physical``, :mod:`svbrdf_cli.infer.physical`: computed
rather than learnt, and the cheapest), then the installed networks (the default, ``swift``). With no network
installed the ladder is the physical estimate alone, with no step: ``auto`` is then ``physical``.

The rule lives in ``models/auto.json`` (written by ``python -m export.studies.auto_calibration``,
with the numbers it was chosen on). It is a *ladder* of tiers, cheapest first,
and for each step up a *signal*, a *threshold* and a side (``above``: true or
false): the photo goes through the cheapest tier; the signal is computed on
the photo and that tier's maps; if it is on the stepping side of the
threshold, the photo goes through the next tier and its maps are kept, and so
on. A threshold of ``null`` means "never step up": the
calibration found no signal value above which the next tier pays for itself.

Signals (:data:`SIGNALS`) cost little: statistics of the photo, of the cheap
tier's maps, or the disagreement of the cheap tier with itself on the photo
turned by 90° (one more pass of the cheap tier). Thresholds are calibrated on
photos of our own data engine with a held-out seed, never on a validation
set: ``docs/benchmarks.md`` has the evidence on Des19 and the real photos.
"""

from __future__ import annotations

import json
import os
import time

import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli.infer.chain import MODELS_DIR, ModelError, installed_tiers
from svbrdf_cli.infer.physical import NAME as PHYSICAL

#: Where the calibrated rule is shipped.
RULE_FILE = os.path.join(MODELS_DIR, "auto.json")


def available_tiers():
    """What a ladder may step through, cheapest first: the physical estimate, then the installed networks."""
    return [PHYSICAL] + installed_tiers()


def _contrast(image, maps, chain):
    return float(np.asarray(image).std())


def _saturated(image, maps, chain):
    return float((np.asarray(image) > 0.98).all(-1).mean())


def _specular(image, maps, chain):
    return float(maps["specular"].mean())


def _disagreement(image, maps, chain):
    from svbrdf_cli.infer import tta

    spread = tta.disagreement([maps] + tta.passes(chain, image, [(1, False)]))
    return float(np.mean([d.mean() for d in spread.values()]))


#: name -> (function(network input, cheap tier's stored maps, cheap tier's chain), extra passes of the cheap tier, what it is).
SIGNALS = {
    "contrast": (_contrast, 0, "standard deviation of the network input"),
    "saturated": (_saturated, 0, "fraction of saturated pixels in the network input"),
    "specular": (_specular, 0, "mean specular albedo (stored) the cheap tier predicts"),
    "disagreement": (_disagreement, 1, "mean per-pixel spread (svbrdf_cli.infer.tta.disagreement) of the cheap "
                                        "tier's maps of the photo and of the photo turned by 90°"),
}


def signal(name, image, maps, chain):
    """The value of signal ``name`` for one network input."""
    return SIGNALS[name][0](image, maps, chain)


def load_rule(path=RULE_FILE):
    """The calibrated rule (a dict; see the module docstring), checked against the installed tiers."""
    if not os.path.isfile(path):
        raise ModelError(f"--model auto needs its rule '{path}', which is missing; reinstall svbrdf or leave "
                         "--model out for the default.")
    with open(path) as f:
        rule = json.load(f)
    missing = [t for t in rule["ladder"] if t not in available_tiers()]
    if missing:
        raise ModelError(f"--model auto steps between {', '.join(rule['ladder'])}, but {', '.join(missing)} "
                         "is not installed; leave --model out for the default.")
    if len(rule["steps"]) != len(rule["ladder"]) - 1 or any(s["signal"] not in SIGNALS for s in rule["steps"]):
        raise ModelError(f"'{path}' is not a rule this version understands; re-run python -m export.studies.auto_calibration.")
    return rule


def steps_up(step, value):
    """Whether a photo with signal ``value`` takes the next tier at this ``step`` of a rule."""
    if step["threshold"] is None:
        return False
    return value > step["threshold"] if step.get("above", True) else value < step["threshold"]


def decide(rule, values):
    """Index into ``rule['ladder']`` of the tier to use, given each step's signal value (a list,
    which may stop early: a value is needed only while the ladder is climbed)."""
    level = 0
    for step, value in zip(rule["steps"], values):
        if not steps_up(step, value):
            break
        level += 1
    return level


class AutoModel:
    """A :class:`svbrdf_cli.infer.model.Model`; after each call ``used`` is the tier's model whose maps
    it returned and ``decision`` says why.

    Args:
        load: ``load(tier, threads=...)`` -> the tier's model (:func:`svbrdf_cli.infer.registry.load_model`).
        rule: the ladder (default: the shipped :data:`RULE_FILE`).
        threads: onnxruntime threads of each network.
        chains: {tier: model} already loaded.
    """

    tier = "auto"

    def __init__(self, load, rule=None, threads=0, chains=None):
        self.load = load
        self.rule = rule if rule is not None else load_rule()
        self.threads = threads
        self.folder = MODELS_DIR
        self._chains = dict(chains or {})  # tier -> Chain; the installed tiers are loaded when first needed
        self.timings, self.decision, self._used = {}, None, None

    def chain(self, tier):
        """The model of ``tier``, loaded when first needed."""
        if tier not in self._chains:
            self._chains[tier] = self.load(tier, threads=self.threads)
        return self._chains[tier]

    @property
    def used(self):
        """The tier whose maps the last call returned."""
        return self._used

    @property
    def found(self):
        """The chosen tier's physical-estimate findings (:attr:`svbrdf_cli.infer.model.Model.found`)."""
        return self._used.found if self._used is not None else None

    @property
    def any_size(self):
        """Whether the chosen tier runs at any size."""
        return self._used is not None and self._used.any_size

    def __call__(self, image):
        """Maps of the encoded (H, W, 3) photo ``image`` from the cheapest tier good enough for it."""
        ladder, steps = self.rule["ladder"], self.rule["steps"]
        timings, trace = {}, []
        level, chain = 0, self.chain(ladder[0])
        out = chain(image)
        timings.update({f"{ladder[0]}_{k}": v for k, v in chain.timings.items()})
        while level < len(steps):
            step = steps[level]
            if step["threshold"] is None:  # never steps up: no signal to compute
                trace.append({"from": ladder[level], "signal": None, "stepped_up": False})
                break
            t0 = time.perf_counter()
            value = signal(step["signal"], image, {k: out[k] for k in cv.MAP_NAMES}, chain)
            timings[f"signal_{step['signal']}"] = time.perf_counter() - t0
            up = steps_up(step, value)
            trace.append({"from": ladder[level], "signal": step["signal"], "value": round(value, 5),
                          "threshold": step["threshold"], "above": step.get("above", True), "stepped_up": up})
            if not up:
                break
            level += 1
            chain = self.chain(ladder[level])
            out = chain(image)
            timings.update({f"{ladder[level]}_{k}": v for k, v in chain.timings.items()})
        self.timings, self._used = timings, chain
        self.decision = {"ladder": list(ladder), "chosen": ladder[level], "steps": trace}
        return out

    def describe(self):
        """What ``material.json`` records: the chosen tier's files and the decision."""
        return {**self._used.describe(), "auto": self.decision}
