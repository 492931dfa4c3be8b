"""``docs/figures/learning_curve.png``: a run's ``curve.jsonl`` against samples seen and CPU hours.

Top row: the Des19 scores of the whole chain (normal and relief, diffuse, roughness, specular; the
corrected scorer's numbers, :func:`export.engine.run.score_des19`) against samples seen, run at
256² (the evaluations before ``des19_size`` was recorded) and at the run's size (as the runtime runs
it), with the physical estimate + ``--refine``'s and the paper's levels as lines; bottom: each
stage's generated validation loss against CPU hours, the relighting error on the first 16 generated
captures under known lights (:func:`export.engine.run.score_known_lights`) and the card's
(:func:`export.engine.run.score_card`).

    python -m export.engine curve --run runs/swift --out docs/figures/learning_curve.png
"""

from __future__ import annotations

import json

#: Des19 with the corrected scorer, the card and the first 16 known-light captures: the physical estimate +
#: --refine and the paper.
REFERENCE = {"default": {"normal": 0.0588, "relief": 0.100, "diffuse": 0.0389, "roughness": 0.1937, "specular": 0.0595,
                         "card": 0.1309, "known_lights": 0.0654},
             "paper": {"normal": 0.0387, "relief": 0.603, "diffuse": 0.0174, "roughness": 0.0715, "specular": 0.0214}}


LABELS = {"default": "physical + refine", "paper": "paper"}


def read(path):
    with open(path) as f:
        return [json.loads(line) for line in f if line.strip()]


def plot(entries, out):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 5, figsize=(17, 6.5))
    names = ("normal", "relief", "diffuse", "roughness", "specular")
    scored = [e for e in entries if e.get("des19")]
    for ax, k in zip(axes[0], names):
        for label, pts in (("chain at 256²", [e for e in scored if not e.get("des19_size")]),
                           ("chain at its size", [e for e in scored if e.get("des19_size")])):
            if pts:
                ax.plot([e["samples"] / 1e3 for e in pts], [e["des19"][k] for e in pts], "o-", ms=3, label=label)
        for ref, style in (("default", "--"), ("paper", ":")):
            ax.axhline(REFERENCE[ref][k], ls=style, c="grey", label=f"{LABELS[ref]} {REFERENCE[ref][k]}")
        ax.set_title(f"Des19 {k}")
        ax.set_xlabel("samples seen (thousands)")
        ax.legend(fontsize=7)
    stages = []
    for e in entries:
        if e["stage"] not in stages:
            stages.append(e["stage"])
    for ax in axes[1]:
        ax.axis("off")
    for ax, s in zip(axes[1], stages):
        ax.axis("on")
        pts = [e for e in entries if e["stage"] == s and e.get("val_loss") is not None]
        ax.plot([e["cpu_hours"] for e in pts], [e["val_loss"] for e in pts], "o-", ms=3, label="generated validation")
        tr = [e for e in pts if e.get("train_loss") is not None]
        ax.plot([e["cpu_hours"] for e in tr], [e["train_loss"] for e in tr], "x--", ms=3, label="training (running)")
        ax.set_title(f"stage {s}: loss")
        ax.set_xlabel("CPU hours (one core)")
        ax.legend(fontsize=7)
    for key, title, ax in (("known_lights", "16 generated captures, known lights", axes[1][-2]),
                           ("card", "card_blue_9lights relighting", axes[1][-1])):
        _relighting(ax, [e for e in entries if e.get(key)], key, title)
    last = entries[-1] if entries else {"samples": 0, "cpu_hours": 0}
    fig.suptitle(f"swift chain: {last['samples']} samples, {last['cpu_hours']:.2f} CPU hours")
    fig.tight_layout()
    fig.savefig(out, dpi=80)
    plt.close(fig)


def _relighting(ax, pts, key, title):
    """One relighting panel: ``key`` and ``key_refined`` of the entries ``pts`` against samples seen."""
    if not pts:
        return
    ax.axis("on")
    ax.plot([e["samples"] / 1e3 for e in pts], [e[key] for e in pts], "o-", ms=3, label="chain, as captured")
    refined = [e for e in pts if e.get(f"{key}_refined")]
    if refined:
        ax.plot([e["samples"] / 1e3 for e in refined], [e[f"{key}_refined"] for e in refined], "s-", ms=3,
                label="chain + --refine")
    ref = REFERENCE["default"][key]
    ax.axhline(ref, ls="--", c="grey", label=f"{LABELS['default']} {ref}")
    ax.set_title(title)
    ax.set_xlabel("samples seen (thousands)")
    ax.legend(fontsize=7)
