"""The shipped models: complete, within the size budget, with provenance that matches the files."""

import hashlib
import json
import os

import pytest

from svbrdf_cli.inference import MODELS_DIR, STAGES, Chain, installed_tiers

MB = 1_000_000


def test_a_model_is_shipped():
    assert "fast" in installed_tiers()


def test_size_budget():
    sizes = {os.path.join(d, f): os.path.getsize(os.path.join(d, f))
             for d, _, files in os.walk(MODELS_DIR) for f in files}
    assert all(s < 25 * MB for s in sizes.values()), sizes
    assert sum(sizes.values()) < 60 * MB


@pytest.mark.parametrize("tier", installed_tiers())
def test_provenance_matches_the_files(tier):
    folder = os.path.join(MODELS_DIR, tier)
    with open(os.path.join(folder, "provenance.json")) as f:
        prov = json.load(f)
    for stage in STAGES:
        name = f"{stage}.onnx"
        with open(os.path.join(folder, name), "rb") as f:
            assert hashlib.sha256(f.read()).hexdigest() == prov["export"]["files"][name]["sha256"], name
    assert set(prov["training"]["stages"]) == set(STAGES)
    for stage, rec in prov["training"]["stages"].items():
        assert rec["steps"] > 0 and rec["seconds"] > 0 and rec["validation"], stage
    assert {"normal", "diffuse", "roughness", "specular"} <= set(prov["des19"]["full_chain"])
    chain = Chain(folder)
    assert chain.tier == tier and chain.files["maps.onnx"] == prov["export"]["files"]["maps.onnx"]["sha256"][:16]
