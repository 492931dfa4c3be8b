"""``docs/figures/learning_curve.png``: a run's ``curve.jsonl`` against samples seen and CPU hours.

Top row: the Des19 scores of the whole chain (normal and relief, diffuse, roughness, specular; the
corrected scorer's numbers, :func:`export.engine.run.score_des19`) against samples seen, with the
physical estimate's and the paper's levels as lines; bottom: each stage's generated validation loss
against CPU hours.

    python -m export.engine curve --run runs/swift --out docs/figures/learning_curve.png
"""

from __future__ import annotations

import json

#: Des19 with the corrected scorer: the default (physical estimate + --refine) and the paper.
REFERENCE = {"default": {"normal": 0.0587, "relief": 0.093, "diffuse": 0.0394, "roughness": 0.1936, "specular": 0.0608},
             "paper": {"normal": 0.0387, "relief": 0.603, "diffuse": 0.0174, "roughness": 0.0715, "specular": 0.0214}}


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
        ax.plot([e["samples"] / 1e3 for e in scored], [e["des19"][k] for e in scored], "o-", ms=3, label="swift chain")
        for ref, style in (("default", "--"), ("paper", ":")):
            ax.axhline(REFERENCE[ref][k], ls=style, c="grey", label=f"{ref} {REFERENCE[ref][k]}")
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
    last = entries[-1] if entries else {"samples": 0, "cpu_hours": 0}
    fig.suptitle(f"swift chain: {last['samples']} samples, {last['cpu_hours']:.2f} CPU hours")
    fig.tight_layout()
    fig.savefig(out, dpi=80)
    plt.close(fig)
