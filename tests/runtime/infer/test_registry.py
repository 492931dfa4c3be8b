"""The installed models: the default is the trained chain, every installed tier is complete, within the size
budget, with provenance that matches the files; the auto rule covers exactly what is installed; a
network's maps have no border seam."""

import hashlib
import json
import os

import numpy as np
import pytest

from svbrdf_cli.infer.chain import MODELS_DIR, STAGES, TIERS, Chain, installed_tiers
from svbrdf_cli.infer.registry import AUTO, DEFAULT_MODEL, load_model, model_names
from svbrdf_cli.infer.refine import DEFAULT_ITERATIONS

MB = 1_000_000


def test_the_default_is_the_installed_trained_chain_and_only_complete_tiers_are_installed():
    """models/ holds auto's rule and one complete folder per installed tier (nothing half-installed),
    each with provenance that matches its files; the default is the trained chain ``swift``."""
    from svbrdf_cli.infer.physical import PHYSICAL_VERSION, PhysicalModel
    from svbrdf_cli.infer.swift import SwiftModel, is_swift

    assert DEFAULT_MODEL == "swift" and isinstance(load_model(DEFAULT_MODEL), SwiftModel)
    assert isinstance(load_model("physical"), PhysicalModel) and PHYSICAL_VERSION
    folders = sorted(f for f in os.listdir(MODELS_DIR) if os.path.isdir(os.path.join(MODELS_DIR, f))
                     and f != "__pycache__")
    assert folders == sorted(installed_tiers()) and set(installed_tiers()) <= set(TIERS)
    assert os.path.isfile(os.path.join(MODELS_DIR, "auto.json"))
    assert model_names() == ["physical", *installed_tiers(), AUTO]
    for tier in installed_tiers():
        folder = os.path.join(MODELS_DIR, tier)
        with open(os.path.join(folder, "provenance.json")) as f:
            prov = json.load(f)
        if is_swift(folder):
            with open(os.path.join(folder, "chain.onnx"), "rb") as f:
                assert hashlib.sha256(f.read()).hexdigest() == prov["sha256"], tier
            model = SwiftModel(folder)
            assert model.tier == tier and model.provenance["samples"] == prov["samples_seen"] > 0
            assert model.provenance["step"] == prov["step"] and prov["cpu_hours"] > 0 and prov["data"]
            scores = prov["metrics_through_capture"]["des19_corrected_scorer"]
            default = scores[f"{tier}_refine_{DEFAULT_ITERATIONS}_default"]
            assert {"normal", "relief", "diffuse", "roughness", "specular"} <= set(default)
            continue
        chain = Chain(folder)
        assert chain.stages in (STAGES, ("maps",)), tier  # the chain, or one end-to-end network
        for stage in chain.stages:
            name = f"{stage}.onnx"
            with open(os.path.join(folder, name), "rb") as f:
                assert hashlib.sha256(f.read()).hexdigest() == prov["export"]["files"][name]["sha256"], (tier, name)
        assert set(prov["training"]["stages"]) == set(chain.stages), tier
        for stage, rec in prov["training"]["stages"].items():
            assert rec["steps"] > 0 and rec["seconds"] > 0 and rec["validation"], (tier, stage)
        assert {"normal", "diffuse", "roughness", "specular"} <= set(prov["des19"]["full_chain"]), tier
        assert chain.tier == tier and chain.files["maps.onnx"] == prov["export"]["files"]["maps.onnx"]["sha256"][:16]


ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
BASELINES = os.path.join(ROOT, "weights", "baselines")


def test_size_budget():
    """Every model file under 25 MB; the installed tiers and the committed baselines together under 60 MB."""
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


def test_the_auto_rule_is_shipped_calibrated_for_the_installed_tiers():
    from svbrdf_cli.infer.auto import SIGNALS, available_tiers, load_rule

    rule = load_rule()  # raises when a tier it steps between is missing
    # every installed model, the physical estimate first, then the networks, cheapest first; a step
    # between each rung and the next (none when the estimate is all there is)
    assert rule["ladder"] == available_tiers() and rule["ladder"][0] == "physical"
    assert len(rule["steps"]) == len(rule["ladder"]) - 1 and all(s["signal"] in SIGNALS for s in rule["steps"])
    cal = rule["calibration"]
    assert "seed" in cal["data"] and cal["margin"] > 0 and set(cal["tier_error"]) == set(rule["ladder"])
    assert sum(cal["tiers_taken"].values()) > 0 and all(0 < e < 1 for e in cal["tier_error"].values())
    assert min(cal["tier_error"].values()) <= cal["auto_error"] <= max(cal["tier_error"].values())


@pytest.mark.parametrize("model", ["chain_model", "swift_model", *installed_tiers()])
def test_no_border_seam_on_a_uniform_material(model, request):
    """A flash photo of a uniform material: the maps' 4-pixel border matches the 12 pixels inside it (the
    networks' zero padding used to leave a coloured frame on every diffuse map). On each kind of network
    folder (exported for the test: per-stage networks, a swift chain) and every installed tier."""
    from svbrdf_cli import conventions as cv
    from svbrdf_cli.shading import render_maps

    model = str(request.getfixturevalue(model)) if model.endswith("_model") else model  # a folder, or a tier
    h = w = 256
    maps = {"normal": np.broadcast_to(np.float32([0, 0, 1]), (h, w, 3)).copy(),
            "diffuse": np.full((h, w, 3), 0.25, np.float32) * np.float32([1.0, 0.8, 0.6]),
            "roughness": np.full((h, w, 1), 0.4, np.float32), "specular": np.full((h, w, 3), 0.04, np.float32)}
    out = load_model(model, threads=1)(cv.image_to_encoded(render_maps(maps)).astype(np.float32))
    for k in ("diffuse", "roughness"):
        d = out[k]
        c = d.shape[-1]
        border = np.concatenate([d[:4].reshape(-1, c), d[-4:].reshape(-1, c), d[4:-4, :4].reshape(-1, c),
                                 d[4:-4, -4:].reshape(-1, c)]).mean(0)
        inside = np.concatenate([d[4:16, 4:-4].reshape(-1, c), d[-16:-4, 4:-4].reshape(-1, c),
                                 d[16:-16, 4:16].reshape(-1, c), d[16:-16, -16:-4].reshape(-1, c)]).mean(0)
        assert np.abs(border - inside).max() < 0.02, (k, border, inside)
