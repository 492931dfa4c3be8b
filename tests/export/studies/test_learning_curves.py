"""export.studies.learning_curves: runs' validation histories joined in order, steps following on."""

import json

import pytest
import torch

from export.studies.learning_curves import load_curve, plot
from svbrdf_cli.errors import SvbrdfError


def _val(x):
    return {"step": 0, **{f"{p}_{m}": x for p in ("rmse", "physical") for m in
                          ("normal", "diffuse", "roughness", "specular")}}


def _checkpoint(path, steps, vals):
    hist = [{"step": s, "loss": 1.0} for s in range(1, steps + 1)]
    for s, v in vals.items():
        hist[s - 1]["val"] = _val(v)
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"history": hist, "step": steps, "physical_version": "4"}, path)
    return str(path)


def test_runs_join_with_steps_following_on(tmp_path):
    a = _checkpoint(tmp_path / "run_a" / "maps.pt", 10, {5: 0.3, 10: 0.2})
    b = _checkpoint(tmp_path / "run_b" / "maps.pt", 6, {3: 0.15, 6: 0.1})
    curve = load_curve([a, b])
    assert [e["step"] for e in curve] == [5, 10, 13, 16]
    assert [e["run"] for e in curve] == ["run_a", "run_a", "run_b", "run_b"]
    assert [e["rmse_normal"] for e in curve] == [0.3, 0.2, 0.15, 0.1]
    prov = tmp_path / "provenance.json"
    prov.write_text(json.dumps({"learning_curve": curve}))
    c = _checkpoint(tmp_path / "run_c" / "maps.pt", 4, {4: 0.05})
    joined = load_curve([str(prov), c])
    assert joined[-1]["step"] == 20 and len(joined) == 5
    plot(joined, tmp_path / "curve.png")
    assert (tmp_path / "curve.png").stat().st_size > 1000


def test_provenance_without_a_curve_is_a_clear_error(tmp_path):
    prov = tmp_path / "provenance.json"
    prov.write_text("{}")
    with pytest.raises(SvbrdfError, match="no learning_curve"):
        load_curve([str(prov)])
