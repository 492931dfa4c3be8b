"""Des19 evaluation: reading the set, the relighting error, the rescalings and the scoring, on tiny constructed sets."""

import numpy as np
import pytest
import torch

from export.studies import evaluate
from export.files import shared_root
from export.render.brdf import render_maps
from svbrdf_cli import conventions as cv
from svbrdf_cli.errors import SvbrdfError
from svbrdf_cli.imageio import write_image

SIZE = 16
#: Ground truth of the constructed samples, as Des19 stores it (albedo linear), in 8-bit steps.
GT = {"diffuse": 51 / 255, "roughness": 102 / 255, "specular": 10 / 255}


def _maps(diffuse=0.2, roughness=0.4, specular=0.04, tilt=0.0, size=SIZE):
    """Linear (C, H, W) maps, constant; ``tilt`` turns the normal towards +x."""
    n = torch.tensor([tilt, 0.0, 1.0])
    return {"normal": (n / n.norm()).reshape(3, 1, 1).expand(3, size, size).clone(),
            "diffuse": torch.full((3, size, size), diffuse), "roughness": torch.full((1, size, size), roughness),
            "specular": torch.full((3, size, size), specular)}


def _write_des19(root, names=("a", "b")):
    """A Des19-like folder: per sample the input photo and the ground-truth maps (albedo stored linear)."""
    for name in names:
        d = root / name
        d.mkdir(parents=True)
        write_image(d / "input.png", np.full((SIZE, SIZE, 3), 0.4, np.float32))
        write_image(d / "normal.png", np.broadcast_to(np.float32(cv.FLAT_NORMAL_ENCODED), (SIZE, SIZE, 3)))
        for k, v in GT.items():
            write_image(d / f"{k}.png", np.full((SIZE, SIZE, 3), v, np.float32))
    return root


@pytest.fixture
def scorer():
    """The reference scorer ``<shared>/tools/score_maps.py``, or skip."""
    path = shared_root() / "tools" / "score_maps.py"
    if not path.is_file():
        pytest.skip("../shared/tools/score_maps.py is not present (a user's fresh clone)")
    return path


def test_load_des19_reads_albedo_as_linear(tmp_path):
    _write_des19(tmp_path)
    (tmp_path / "notes").mkdir()  # a folder without input.png is not a sample
    samples = evaluate.load_des19(str(tmp_path))
    assert [s[0] for s in samples] == ["a", "b"]
    _, photo, gt = samples[0]
    assert photo.shape == (3, SIZE, SIZE) and gt["roughness"].shape == (1, SIZE, SIZE)
    # Des19's PNGs hold linear albedo: read as they are, not decoded from gamma 2.2 (0.2 ** 2.2 = 0.029).
    assert torch.allclose(gt["diffuse"], torch.tensor(GT["diffuse"]), atol=1e-6)
    assert torch.allclose(gt["specular"], torch.tensor(GT["specular"]), atol=1e-6)
    assert torch.allclose(gt["normal"][2], torch.ones(1), atol=1e-4)


def test_relight_rmse_is_zero_for_the_same_maps_and_grows_with_the_error():
    gt = _maps()
    assert evaluate.relight_rmse(gt, gt) == 0.0
    small, large = evaluate.relight_rmse(_maps(diffuse=0.25), gt), evaluate.relight_rmse(_maps(diffuse=0.4), gt)
    assert 0 < small < large
    assert evaluate.relight_rmse(_maps(tilt=0.3), gt) > 0  # the normal matters too
    assert len(evaluate.RELIGHT) == 9


def test_oracle_scale_undoes_an_albedo_scale():
    gt = _maps(diffuse=0.3, specular=0.05)
    pred = _maps(diffuse=0.1, specular=0.05 / 3)
    scaled, k = evaluate.oracle_scale(pred, gt)
    assert k == pytest.approx(3.0, rel=1e-5)
    assert torch.allclose(scaled["diffuse"], gt["diffuse"], atol=1e-6)
    assert torch.allclose(scaled["specular"], gt["specular"], atol=1e-6)
    assert scaled["roughness"] is pred["roughness"]


def test_fit_intensity_recovers_the_light_and_ignores_saturated_pixels():
    rendered = np.random.default_rng(0).uniform(0.01, 0.2, (8, 8, 3)).astype(np.float32)
    photo = cv.image_to_encoded(3.0 * rendered)
    assert evaluate.fit_intensity(rendered, photo) == pytest.approx(3.0, rel=1e-4)
    photo[0, 0] = 1.0  # a clipped pixel says nothing about the intensity
    assert evaluate.fit_intensity(rendered, photo) == pytest.approx(3.0, rel=1e-4)


def test_known_flash_scale_uses_the_photo_alone():
    pred = _maps(diffuse=0.1, specular=0.02)
    # The photo of maps twice as bright under the known flash: the same as these maps under twice the flash.
    photo = cv.image_to_encoded(render_maps({k: v[None] for k, v in pred.items()},
                                            intensity=2.0 * cv.FLASH_INTENSITY))[0]
    scaled, k = evaluate.known_flash_scale(pred, photo)
    assert k == pytest.approx(2.0, rel=1e-3)
    assert torch.allclose(scaled["diffuse"], torch.full_like(pred["diffuse"], 0.2), atol=1e-3)
    assert torch.allclose(scaled["roughness"], pred["roughness"])


class _Stub:
    """A three-stage net that records what each stage was given."""

    def __init__(self):
        self.calls = []

    def run_masks(self, x):
        self.calls.append("masks")
        return {"M_b": x[:, :1], "M_h": x[:, :1]}

    def run_aux(self, x, masks):
        self.calls.append(("aux", float(masks["M_b"].mean())))
        return {k: x for k in ("I_bf", "I_hr", "I_hr2")}

    def run_maps(self, x, aux):
        self.calls.append(("maps", float(aux["I_bf"].mean())))
        return {k: x[:, :1] for k in cv.MAP_NAMES}


@pytest.mark.parametrize("mode, expected", [
    ("full", ["masks", ("aux", 0.5), ("maps", 0.5)]),
    ("gt_masks", [("aux", 0.25), ("maps", 0.5)]),
    ("gt_aux", [("maps", 0.75)]),
])
def test_predict_replaces_the_stages_the_mode_takes_from_the_ground_truth(mode, expected):
    photo = torch.full((3, 4, 4), 0.5)
    gt = {"M_b": torch.full((1, 4, 4), 0.25), "M_h": torch.zeros(1, 4, 4),
          **{k: torch.full((3, 4, 4), 0.75) for k in ("I_bf", "I_hr", "I_hr2")}}
    net = _Stub()
    out = evaluate.predict(net, photo, mode, gt)
    assert net.calls == expected
    assert set(out) == set(cv.MAP_NAMES) and out["normal"].shape == (1, 4, 4)  # the batch axis is gone


def test_evaluate_names_a_missing_des19_folder(tmp_path):
    with pytest.raises(SvbrdfError, match="Des19 validation samples not found"):
        evaluate.evaluate(run=str(tmp_path), des19=str(tmp_path / "absent"))


def test_score_predictions_gives_the_known_errors(scorer, tmp_path):
    des19 = str(_write_des19(tmp_path / "des19"))
    samples = evaluate.load_des19(des19)
    truth = {name: cv.encode_maps(gt) for name, _, gt in samples}

    exact, rel, scales, line = evaluate.score_predictions(samples, des19, str(tmp_path / "exact"),
                                                   lambda name, photo: truth[name])
    assert line.startswith("samples=2 missing=0") and scales == [] and len(rel) == 2
    assert all(exact[k] < 2e-3 for k in cv.MAP_NAMES), exact  # 8-bit rounding of the gamma-encoded albedo
    assert exact["relight"] < 1e-5

    def worse(name, photo):
        stored = dict(truth[name])
        stored["diffuse"] = cv.albedo_to_stored(torch.full_like(stored["diffuse"], 0.3))
        stored["roughness"] = torch.full_like(stored["roughness"], 0.6)
        return stored

    off, rel, _, _ = evaluate.score_predictions(samples, des19, str(tmp_path / "off"), worse)
    assert off["diffuse"] == pytest.approx(0.3 - GT["diffuse"], abs=3e-3)
    assert off["roughness"] == pytest.approx(0.9 * (0.6 - GT["roughness"]), abs=3e-3)  # the scorer's 0.9 r + 0.1
    assert off["normal"] < 2e-3 and off["specular"] < 2e-3
    assert off["relight"] == pytest.approx(np.mean(rel)) and off["relight"] > 0.01


def test_score_predictions_applies_the_rescaling(scorer, tmp_path):
    des19 = str(_write_des19(tmp_path / "des19", names=("a",)))
    samples = evaluate.load_des19(des19)

    def half(name, photo):  # the right maps at half the albedo
        gt = samples[0][2]
        return cv.encode_maps(dict(gt, diffuse=gt["diffuse"] / 2, specular=gt["specular"] / 2))

    _, rescale = evaluate.RESCALINGS["oracle"]
    res, _, scales, _ = evaluate.score_predictions(samples, des19, str(tmp_path / "out"), half, rescale)
    assert scales == [pytest.approx(2.0, rel=1e-4)]
    assert res["diffuse"] < 2e-3 and res["relight"] < 1e-4
