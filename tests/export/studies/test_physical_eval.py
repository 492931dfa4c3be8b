"""The physical estimate against the floor on the validation sets, and its colour on the real photos
(the numbers of docs/benchmarks.md, kept from regressing). Skipped without ../shared."""

import tempfile

import numpy as np

from export.files import REAL_PHOTOS
from export.studies import colour
from export.studies import methods


def test_physical_beats_the_floor_on_des19_and_the_card(shared_data):
    from export.studies.benchmark import NineLights, des19_accuracy
    from export.studies.evaluate import load_des19

    des19 = str(shared_data / "validation" / "des19")
    samples = load_des19(des19)
    floor, phys = methods.Floor(), methods.Physical()
    f, _ = des19_accuracy(floor, samples, des19, tempfile.mkdtemp())
    p, _ = des19_accuracy(phys, samples, des19, tempfile.mkdtemp())
    assert p["diffuse"] < 0.6 * f["diffuse"] and p["roughness"] < f["roughness"]
    assert p["relight"] < 0.8 * f["relight"]
    assert p["specular"] <= f["specular"] + 1e-4 and p["normal"] <= f["normal"] + 1e-4
    nine = NineLights(str(shared_data / "real" / "card_blue_9lights"))
    x = nine.network_input()
    assert nine.relight_rmse(phys(x)) < 0.9 * nine.relight_rmse(floor(x))


def test_physical_keeps_the_colour_of_the_real_photos(shared_data):
    from export.studies import stability

    from svbrdf_cli.infer.exposure import network_input

    real = stability.real_crops(shared_data / "real", REAL_PHOTOS)
    inputs = [(name, network_input(lin)) for name, lin in real]
    rows = colour.evaluate([methods.Physical()], inputs, log=lambda *a: None)["physical"]
    assert len(rows) == REAL_PHOTOS
    assert all(r["ok"] is not False for r in rows), [r for r in rows if r["ok"] is False]


def test_colour_fidelity_on_constructed_images():
    rng = np.random.default_rng(0)
    photo = np.clip(np.array([0.6, 0.3, 0.2]) * (0.7 + 0.3 * rng.random((32, 32, 1))), 0, 1).astype(np.float32)
    same = colour.fidelity(photo, photo)
    assert same["hue_error"] < 1 and same["ok"] is True
    shifted = colour.fidelity(photo, photo[..., ::-1].copy())  # red-orange -> blue
    assert shifted["hue_error"] > 90 and shifted["ok"] is False
    grey = np.full((32, 32, 3), 0.4, np.float32)
    assert colour.fidelity(grey, grey)["ok"] is True and colour.fidelity(grey, photo)["ok"] is False
