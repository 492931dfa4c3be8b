"""Calibrating --model auto: the cheapest rule within the tolerance, never a worse one."""

import numpy as np
import pytest

from export.studies.auto_calibration import choose_step

N = 200


def _case(seed=0):
    rng = np.random.default_rng(seed)
    hard = rng.random(N) < 0.3                       # 30 % of photos need the dear tier
    err_lo = np.where(hard, 0.30, 0.10) + 0.005 * rng.standard_normal(N)
    err_hi = np.full(N, 0.11) + 0.005 * rng.standard_normal(N)
    good = np.where(hard, 0.8, 0.2) + 0.05 * rng.standard_normal(N)   # separates hard photos
    noise = rng.random(N)                                             # says nothing
    return hard, err_lo, err_hi, good, noise


def test_a_separating_signal_is_found_with_its_side_and_threshold():
    hard, err_lo, err_hi, good, noise = _case()
    for values, above in (({"good": good, "noise": noise}, True), ({"good": -good, "noise": noise}, False)):
        chosen, cands = choose_step(err_lo, err_hi, 0.02, 0.25, values, {"good": 0.0, "noise": 0.0}, margin=0.02)
        assert chosen["signal"] == "good" and chosen["above"] is above
        up = values["good"] > chosen["threshold"] if above else values["good"] < chosen["threshold"]
        assert (up == hard).mean() >= 0.9 and up[~hard].mean() < 0.05  # cheapest: may leave a few hard ones
        best = min(err_lo.mean(), err_hi.mean())
        assert chosen["error"] <= best * 1.02 and chosen["seconds"] < 0.02 + 0.25
        # Nothing cheaper stays within the tolerance.
        assert not [c for c in cands if c["error"] <= best * 1.02 and c["seconds"] < chosen["seconds"] - 1e-9]


def test_never_step_up_when_the_cheap_tier_is_as_good():
    _, _, err_hi, good, noise = _case(1)
    chosen, _ = choose_step(err_hi - 0.01, err_hi, 0.02, 0.25, {"good": good, "noise": noise},
                            {"good": 0.0, "noise": 0.0})
    assert chosen["threshold"] is None and chosen["stepped_up"] == 0 and chosen["seconds"] == pytest.approx(0.02)


def test_the_signals_own_cost_counts():
    hard, err_lo, err_hi, good, _ = _case(2)
    # The same separating signal twice, one dear to compute: the cheap one wins.
    chosen, _ = choose_step(err_lo, err_hi, 0.02, 0.25, {"dear": good, "cheap": good.copy()},
                            {"dear": 0.5, "cheap": 0.001})
    assert chosen["signal"] == "cheap"
    # Never stepping up is out of tolerance here: a rule that is within it wins, whatever its cost.
    chosen, _ = choose_step(err_lo, err_hi, 0.02, 0.25, {"dear": good}, {"dear": 5.0})
    assert chosen["threshold"] is not None and chosen["error"] <= min(err_lo.mean(), err_hi.mean()) * 1.02


def test_calibration_needs_a_tier_and_says_so():
    from export.studies.auto_calibration import calibrate
    from svbrdf_cli.errors import SvbrdfError

    with pytest.raises(SvbrdfError, match="needs an installed tier; found none"):
        calibrate([], chains={})


def test_a_ladder_of_the_physical_estimate_alone_has_no_step(tmp_path):
    """With no network installed the rule is the estimate for every photo, its error and cost measured."""
    import json

    from export.studies.auto_calibration import calibrate, calibration_table, generated
    from svbrdf_cli.infer import auto as auto_tier
    from svbrdf_cli.infer.physical import PhysicalModel

    rule = calibrate(generated(3, size=64), chains={"physical": PhysicalModel()}, repeat=1, log=None)
    assert rule["ladder"] == ["physical"] and rule["steps"] == []
    cal = rule["calibration"]
    assert cal["tiers_taken"] == {"physical": 3} and cal["steps"] == []
    assert 0 < cal["auto_error"] == cal["tier_error"]["physical"] < 1 and cal["tier_seconds_256"]["physical"] > 0
    assert "no step to calibrate" in calibration_table(rule)
    p = tmp_path / "auto.json"
    p.write_text(json.dumps(rule))
    assert auto_tier.load_rule(str(p))["ladder"] == ["physical"]
