"""The shipped models: complete, within the size budget, with provenance that matches the files."""

import hashlib
import json
import os

import numpy as np
import pytest

from svbrdf_cli.infer.chain import MODELS_DIR, STAGES, Chain, installed_tiers

MB = 1_000_000


def test_a_model_is_shipped():
    assert "fast" in installed_tiers()


ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
BASELINES = os.path.join(ROOT, "weights", "baselines")


def test_size_budget():
    """Every model file under 25 MB; the shipped tiers and the committed baselines together under 60 MB."""
    sizes = {os.path.join(d, f): os.path.getsize(os.path.join(d, f))
             for top in (MODELS_DIR, BASELINES) for d, _, files in os.walk(top) for f in files}
    assert all(s < 25 * MB for s in sizes.values()), sizes
    assert sum(sizes.values()) < 60 * MB


@pytest.mark.skipif(not os.path.isdir(os.path.join(BASELINES, "e2e-fast")), reason="no baseline export")
def test_end_to_end_baseline_runs_with_its_one_stage():
    import numpy as np

    folder = os.path.join(BASELINES, "e2e-fast")
    chain = Chain(folder)
    assert chain.stages == ("maps",) and chain.meta["maps"]["variant"] == "e2e"
    out = chain(np.random.default_rng(0).random((64, 96, 3), dtype=np.float32))
    assert set(out) == {"normal", "diffuse", "roughness", "specular"} and out["normal"].shape == (64, 96, 3)
    with open(os.path.join(folder, "provenance.json")) as f:
        prov = json.load(f)
    with open(os.path.join(folder, "maps.onnx"), "rb") as f:
        assert hashlib.sha256(f.read()).hexdigest() == prov["export"]["files"]["maps.onnx"]["sha256"]
    assert prov["training"]["stages"]["maps"]["variant"] == "e2e" and prov["des19"]["full_chain"]["normal"] > 0


@pytest.mark.parametrize("tier", installed_tiers())
def test_provenance_matches_the_files(tier):
    folder = os.path.join(MODELS_DIR, tier)
    with open(os.path.join(folder, "provenance.json")) as f:
        prov = json.load(f)
    chain = Chain(folder)
    assert chain.stages in (STAGES, ("maps",))  # the chain, or one end-to-end network (lite)
    for stage in chain.stages:
        name = f"{stage}.onnx"
        with open(os.path.join(folder, name), "rb") as f:
            assert hashlib.sha256(f.read()).hexdigest() == prov["export"]["files"][name]["sha256"], name
    assert set(prov["training"]["stages"]) == set(chain.stages)
    for stage, rec in prov["training"]["stages"].items():
        assert rec["steps"] > 0 and rec["seconds"] > 0 and rec["validation"], stage
    assert {"normal", "diffuse", "roughness", "specular"} <= set(prov["des19"]["full_chain"])
    assert chain.tier == tier and chain.files["maps.onnx"] == prov["export"]["files"]["maps.onnx"]["sha256"][:16]


def test_the_auto_rule_is_shipped_calibrated_for_the_installed_tiers():
    from svbrdf_cli.infer.auto import SIGNALS, available_tiers, load_rule

    rule = load_rule()  # raises when a tier it steps between is missing
    # the physical estimate first, then the networks, cheapest first
    assert len(rule["ladder"]) >= 2 and rule["ladder"] == [t for t in available_tiers() if t in rule["ladder"]]
    assert rule["ladder"][0] == "physical"
    assert all(s["signal"] in SIGNALS for s in rule["steps"])
    cal = rule["calibration"]
    assert "seed" in cal["data"] and cal["margin"] > 0 and set(cal["tier_error"]) == set(rule["ladder"])
    assert sum(cal["tiers_taken"].values()) > 0 and all(0 < e < 1 for e in cal["tier_error"].values())


@pytest.mark.parametrize("tier", installed_tiers())
def test_no_border_seam_on_a_uniform_material(tier):
    """A flash photo of a uniform material: the maps' 4-pixel border matches the 12 pixels inside it (the
    networks' zero padding used to leave a coloured frame on every diffuse map)."""
    from svbrdf_cli import conventions as cv
    from svbrdf_cli.shading import render_maps

    h = w = 256
    maps = {"normal": np.broadcast_to(np.float32([0, 0, 1]), (h, w, 3)).copy(),
            "diffuse": np.full((h, w, 3), 0.25, np.float32) * np.float32([1.0, 0.8, 0.6]),
            "roughness": np.full((h, w, 1), 0.4, np.float32), "specular": np.full((h, w, 3), 0.04, np.float32)}
    out = Chain(os.path.join(MODELS_DIR, tier), threads=1)(cv.image_to_encoded(render_maps(maps)).astype(np.float32))
    for k in ("diffuse", "roughness"):
        d = out[k]
        c = d.shape[-1]
        border = np.concatenate([d[:4].reshape(-1, c), d[-4:].reshape(-1, c), d[4:-4, :4].reshape(-1, c),
                                 d[4:-4, -4:].reshape(-1, c)]).mean(0)
        inside = np.concatenate([d[4:16, 4:-4].reshape(-1, c), d[-16:-4, 4:-4].reshape(-1, c),
                                 d[16:-16, 4:16].reshape(-1, c), d[16:-16, -16:-4].reshape(-1, c)]).mean(0)
        assert np.abs(border - inside).max() < 0.02, (k, border, inside)
