"""The card's relighting harness against the capture's own reference maps: its renderer and geometry
reproduce the real photos only if MaterialGAN's maps, fitted to all nine, relight them closely."""

import os

import numpy as np

from export.render.relight import NineLights


def test_the_reference_maps_relight_the_card_closely_once_their_roughness_is_decoded(shared_data):
    card = NineLights(os.path.join(shared_data, "real", "card_blue_9lights"))
    maps = card.reference_maps()
    decoded = card.relight_rmse(maps)
    assert decoded < 0.09  # 0.0815: the harness reproduces the real capture to about 0.08
    as_linear = dict(maps, roughness=(maps["roughness"] ** (1 / 2.2)).astype(np.float32))
    assert card.relight_rmse(as_linear) > 1.5 * decoded  # rgh.png read as linear: 0.170
