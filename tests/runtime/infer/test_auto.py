"""``--model auto``: the rule's logic, that its maps are exactly one tier's, and the CLI's record.

The ladders here step from the physical estimate to a network exported for the tests
(``swift_model``, ``tests/conftest.py``), named ``net`` in the rule."""

import json
import os

import numpy as np
import pytest
from click.testing import CliRunner

from svbrdf_cli.infer import auto as auto_tier
from svbrdf_cli import conventions as cv
from svbrdf_cli.infer.chain import ModelError, installed_tiers
from svbrdf_cli.infer.registry import load_model

NET = "net"
LADDER = [auto_tier.PHYSICAL, NET]


@pytest.fixture
def load(swift_model):
    """``load_model`` with ``net`` the test network's folder."""
    return lambda tier, threads=0: load_model(str(swift_model) if tier == NET else tier, threads=threads)


def _rule(*steps):
    return {"ladder": ["a", "b", "c"][:len(steps) + 1], "steps": list(steps)}


@pytest.mark.parametrize("steps,values,level", [
    ([{"signal": "contrast", "threshold": None}], [5.0], 0),                       # never step up
    ([{"signal": "contrast", "threshold": 0.2}], [0.3], 1),                         # above (the default side)
    ([{"signal": "contrast", "threshold": 0.2}], [0.2], 0),                         # at the threshold: stay
    ([{"signal": "contrast", "threshold": 0.2, "above": False}], [0.1], 1),         # below
    ([{"signal": "contrast", "threshold": 0.2, "above": False}], [0.3], 0),
    ([{"signal": "contrast", "threshold": 0.2}, {"signal": "saturated", "threshold": 0.5}], [0.3, 0.6], 2),
    ([{"signal": "contrast", "threshold": 0.2}, {"signal": "saturated", "threshold": 0.5}], [0.3, 0.4], 1),
    ([{"signal": "contrast", "threshold": 0.2}, {"signal": "saturated", "threshold": 0.5}], [0.1], 0),
])
def test_decide_climbs_while_each_signal_is_on_its_stepping_side(steps, values, level):
    assert auto_tier.decide(_rule(*steps), values) == level


def _photo(seed=0, size=64):
    rng = np.random.default_rng(seed)
    return np.clip(rng.uniform(0.2, 0.5, (size, size, 3)) + 0.05 * rng.standard_normal((size, size, 3)),
                   0, 1).astype(np.float32)


@pytest.mark.parametrize("threshold,chosen", [(None, 0), (-1.0, 1)])
def test_auto_returns_exactly_the_chosen_tiers_maps(threshold, chosen, load):
    rule = {"ladder": LADDER, "steps": [{"signal": "contrast", "threshold": threshold, "above": True}]}
    auto = auto_tier.AutoModel(load, rule, threads=1)
    img = _photo()
    out = auto(img)
    tier = LADDER[chosen]
    ref = auto.chain(tier)(img)
    assert auto.used is auto.chain(tier) and auto.decision["chosen"] == tier
    for k in cv.MAP_NAMES:
        np.testing.assert_array_equal(out[k], ref[k])
    other = auto.chain(LADDER[1 - chosen])(img)  # the two rungs' maps differ: the test can tell them apart
    assert any(np.abs(out[k] - other[k]).max() > 0.01 for k in cv.MAP_NAMES)
    rec = auto.describe()
    assert rec["tier"] == auto.chain(tier).describe()["tier"] and rec["auto"]["steps"][0]["stepped_up"] == bool(chosen)
    assert any(k.startswith(f"{tier}_") for k in auto.timings)
    if threshold is None:  # a step that never climbs computes no signal
        assert rec["auto"]["steps"][0]["signal"] is None and not any(k.startswith("signal") for k in auto.timings)
    else:
        assert rec["auto"]["steps"][0]["value"] == pytest.approx(float(img.std()), abs=1e-5)
        assert "signal_contrast" in auto.timings


@pytest.mark.parametrize("cheap", [auto_tier.PHYSICAL, NET])
@pytest.mark.parametrize("name", list(auto_tier.SIGNALS))
def test_signals_are_finite_numbers(name, cheap, load):
    rule = {"ladder": [cheap, NET], "steps": [{"signal": name, "threshold": None}]}
    chain = auto_tier.AutoModel(load, rule, threads=1).chain(cheap)
    img = _photo(1)
    maps = chain(img)
    v = auto_tier.signal(name, img, {k: maps[k] for k in cv.MAP_NAMES}, chain)
    assert isinstance(v, float) and np.isfinite(v) and v >= 0


def test_a_missing_or_unusable_rule_is_a_clear_error(tmp_path):
    with pytest.raises(ModelError, match="auto.json.*missing"):
        auto_tier.load_rule(str(tmp_path / "auto.json"))
    p = tmp_path / "rule.json"
    p.write_text(json.dumps({"ladder": ["best"], "steps": []}))
    if "best" not in installed_tiers():
        with pytest.raises(ModelError, match="best is not installed"):
            auto_tier.load_rule(str(p))
    p.write_text(json.dumps({"ladder": [auto_tier.PHYSICAL] * 2, "steps": [{"signal": "moon", "threshold": 1}]}))
    with pytest.raises(ModelError, match="re-run python -m export.studies.auto_calibration"):
        auto_tier.load_rule(str(p))


def test_capture_with_model_auto_records_the_tier_and_why(tmp_path):
    from svbrdf_cli.cli.main import cli
    from svbrdf_cli.imageio import write_image

    photo = tmp_path / "stone.png"
    write_image(photo, _photo(2, 300))
    r = CliRunner().invoke(cli, ["capture", str(photo), "-o", str(tmp_path / "out"), "--model", "auto",
                                 "--confidence"], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    rec = json.loads((tmp_path / "out" / "stone" / "material.json").read_text())
    m = rec["model"]
    assert m["name"] == "auto" and m["tier"] == m["auto"]["chosen"] and m["tier"] in auto_tier.load_rule()["ladder"]
    if m["tier"] == auto_tier.PHYSICAL:  # the estimate: no model file, what it found instead
        assert m["method"].startswith("physical estimate") and "flash_foot" in m["found"]
    else:
        assert m["sha256_16"]["maps.onnx"] and os.path.isdir(m["folder"])
    assert any(k.startswith("network_") for k in rec["timings_s"])
    # the chosen model's confidence: a network's for every map, the physical estimate's for what it measures
    maps = ("diffuse", "roughness") if m["tier"] == auto_tier.PHYSICAL else ("normal", "diffuse", "roughness", "specular")
    assert sorted(os.listdir(tmp_path / "out" / "stone" / "confidence")) == sorted(f"{k}.png" for k in maps)


@pytest.mark.parametrize("threshold,chosen", [(None, 0), (-1.0, 1)])
def test_the_ladder_starts_with_the_physical_estimate(threshold, chosen, tmp_path, load):
    from svbrdf_cli.infer.physical import PhysicalModel

    p = tmp_path / "auto.json"
    p.write_text(json.dumps({"ladder": [auto_tier.PHYSICAL], "steps": []}))
    assert auto_tier.load_rule(str(p))["ladder"] == ["physical"]  # needs no model file
    rule = {"ladder": LADDER, "steps": [{"signal": "contrast", "threshold": threshold, "above": True}]}
    auto = auto_tier.AutoModel(load, rule, threads=1)
    img = _photo(3)
    out = auto(img)
    ref = (PhysicalModel() if chosen == 0 else auto.chain(rule["ladder"][1]))(img)
    assert auto.decision["chosen"] == rule["ladder"][chosen]
    for k in cv.MAP_NAMES:
        np.testing.assert_array_equal(out[k], ref[k])
    assert isinstance(auto.used, PhysicalModel) == (chosen == 0)
    assert auto.describe()["tier"] == ("physical" if chosen == 0 else "swift")


def test_with_the_physical_estimate_alone_auto_is_the_physical_estimate():
    """The ladder of the estimate alone has no step: auto returns its maps and computes no signal."""
    from svbrdf_cli.infer.physical import PhysicalModel

    auto = auto_tier.AutoModel(load_model, {"ladder": [auto_tier.PHYSICAL], "steps": []}, threads=1)
    img = _photo(4)
    out, ref = auto(img), PhysicalModel()(img)
    for k in cv.MAP_NAMES:
        np.testing.assert_array_equal(out[k], ref[k])
    assert auto.decision == {"ladder": ["physical"], "chosen": "physical", "steps": []}
    assert not any(k.startswith("signal") for k in auto.timings) and auto.describe()["tier"] == "physical"
