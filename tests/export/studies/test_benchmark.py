"""The benchmark command (speed against accuracy, stability, confidence): it runs, and its pieces are sound."""

import numpy as np
import pytest
import torch

from export.studies import stability
from svbrdf_cli import conventions as cv


@pytest.mark.parametrize("name", [k for k, v in stability.PERTURBATIONS.items() if v[1] is not None])
def test_photometric_perturbations_keep_a_valid_linear_photo_and_change_it(name):
    rng = np.random.default_rng(0)
    lin = rng.uniform(0.05, 0.6, (64, 64, 3)).astype(np.float32)
    out = stability.PERTURBATIONS[name][1](lin, rng)
    assert out.shape == lin.shape and out.dtype == np.float32
    assert np.isfinite(out).all() and out.min() >= 0 and out.max() <= 1
    assert np.abs(out - lin).mean() > 1e-3


def test_rendered_variants_differ_where_they_should():
    maps = {"normal": torch.tensor([0.0, 0.0, 1.0]).reshape(3, 1, 1).expand(3, 64, 64).clone(),
            "diffuse": torch.full((3, 64, 64), 0.3), "roughness": torch.full((1, 64, 64), 0.3),
            "specular": torch.full((3, 64, 64), 0.04)}
    centred = stability.rendered_photo(maps, "centred")
    off = stability.rendered_photo(maps, "off_centre")
    soft = stability.rendered_photo(maps, "no_flash")
    for img in (centred, off, soft):
        assert img.shape == (64, 64, 3) and np.isfinite(img).all() and img.min() >= 0
    # The flash's hot spot moves with it: the brightest quarter is the light's (x right, y up).
    def quadrant_means(x):
        return [x[:32, 32:].mean(), x[32:, 32:].mean(), x[32:, :32].mean(), x[:32, :32].mean()]
    assert int(np.argmax(quadrant_means(off))) == 1  # light at (+0.7, -0.5): bottom right
    assert soft.max() / soft.min() < 0.7 * centred.max() / centred.min()  # no hot spot, less falloff


def test_benchmark_runs_on_two_samples(shared_data, tmp_path):
    pytest.importorskip("matplotlib")
    from export.studies import benchmark

    res = benchmark.run(limit=2, repeat=1, figures=str(tmp_path / "fig"), tables=str(tmp_path / "tab"),
                        log=lambda *a: None)
    from export.studies import methods as method_zoo
    from svbrdf_cli.infer.chain import installed_tiers

    rows = {r["name"]: r for r in res["methods"]}
    assert {"floor", "physical", "physical+refine", *installed_tiers(), "auto", "paper"} <= set(rows)
    measured = [r["name"] for r in res["methods"] if r["name"] not in ("paper", "reference")]
    assert measured == [m.name for m in method_zoo.available(refined=True)]  # every runnable method, once
    for name in measured:
        r = rows[name]
        assert all(0 < r[k] < 1 for k in cv.MAP_NAMES + ("des19_relight", "real_relight")), r
        assert 0 < r["s_256"] and 0 < r["s_2048"]
    assert res["samples"] == 2 and set(res["confidence"]["maps"]) == set(cv.MAP_NAMES)
    networks = [n for n in measured if n == "e2e" or n in installed_tiers()]  # --confidence: a network's passes
    assert res["confidence"]["tier"] == (networks[-1] if networks else "physical")
    st = res["stability"]
    assert set(st["rows"]) == set(stability.PERTURBATIONS) and st["failures"] == []
    assert st["photos"] == {"des19": 2, "real": 2}
    for f in ("speed_vs_accuracy.png", "stability_gallery.png"):
        assert (tmp_path / "fig" / f).stat().st_size > 10_000
    ev = res["auto"]["sets"]
    # Auto's maps are one tier's per photo: its Des19 error is the benchmark row of the tiers it took.
    taken = [t for t, n in ev["des19"]["taken"].items() for _ in range(n)]
    if len(set(taken)) == 1:
        assert rows["auto"]["des19_relight"] == pytest.approx(rows[taken[0]]["des19_relight"], rel=1e-5)
    assert ev["des19"]["photos"] == 2 and sum(ev["des19"]["taken"].values()) == 2
    assert ev["real photos (no ground truth)"]["photos"] == 2
    assert all(v > 0 for v in ev["des19"]["seconds"].values())
    again = res["auto"]["recalibrated"]["rule"]
    assert again["ladder"] == res["auto"]["rule"]["ladder"] and "8 photos" in again["calibration"]["data"]
    for f in ("speed_vs_accuracy.md", "stability.md", "confidence.md", "auto.md", "benchmark.json"):
        assert (tmp_path / "tab" / f).is_file()


def test_stability_change_is_relative_to_each_maps_own_contrast():
    flat = {k: np.full((8, 8, 3), 0.5, np.float32) for k in stability.MAPS}
    textured = {k: v.copy() for k, v in flat.items()}
    textured["diffuse"][::2] = 0.7  # contrast (RMS deviation from the mean) 0.2
    textured["diffuse"][1::2] = 0.3
    moved = {k: v.copy() for k, v in textured.items()}
    moved["diffuse"] += 0.01
    rel = stability.relative_change([stability._change(moved, textured)], [stability._contrast(textured)])
    assert rel["diffuse"]["ratio"] == pytest.approx(0.05, rel=1e-3)
    assert rel["normal"] == {"ratio": None, "constant": 1}  # constant: no ratio, counted apart
    assert stability._relative_cell(rel["normal"]) == "constant"
    assert stability._relative_cell(rel["diffuse"]) == "0.05×"
