"""Generated captures under known lights (``export.engine.known_lights``) and their relighting score
(``python -m export.studies.known_lights``)."""

import numpy as np
import pytest

from export.files import shared_root
from export.engine import known_lights as gen
from export.studies import known_lights as kl
from export.studies.methods import Floor

SIZE = 64


@pytest.fixture(scope="module")
def caps():
    return [gen.generate(i, size=SIZE) for i in range(3)]


def test_a_capture_is_nine_photos_from_one_camera_with_the_lights_round_its_lens(caps):
    c = caps[0]
    assert c["photos"].shape == (1 + gen.LIGHTS, SIZE, SIZE, 3) and c["photos"].dtype == np.uint8
    assert c["truth"]["normal"].shape == (SIZE, SIZE, 3) and c["truth"]["roughness"].shape == (SIZE, SIZE, 1)
    cam = c["cameras"][0]
    assert (c["cameras"] == cam).all()
    h = cam[2]
    ring = c["lights"][1:]
    r = np.hypot(*(ring[:, :2] - cam[:2]).T) / h
    assert (r >= gen.RING_RADIUS[0] - 1e-9).all() and (r <= gen.RING_RADIUS[1] + 1e-9).all()
    assert (ring[:, 2] >= gen.RING_HEIGHT[0] * h - 1e-9).all() and (ring[:, 2] <= gen.RING_HEIGHT[1] * h + 1e-9).all()
    assert np.hypot(*(c["lights"][0, :2] - cam[:2])) <= 0.1 * h + 1e-6  # photo 0: the flash beside the lens
    # the photos differ as their lights do (the same exposure: none is a re-exposed copy)
    assert all(np.abs(c["photos"][i].astype(int) - c["photos"][0]).mean() > 0.5 for i in range(1, len(ring) + 1))


def test_the_floor_is_scored_and_the_true_maps_relight_their_captures_far_better(caps):
    rows = {r["method"]: r for r in kl.run(caps, [], log=lambda *_: None)}
    floor, truth = np.array(rows["floor"]["per_capture"]), np.array(rows["truth"]["per_capture"])
    assert len(floor) == len(caps) and np.isfinite(floor).all() and (floor > 0.02).all()
    assert (truth < 0.5 * floor).all(), (truth, floor)
    assert rows["truth"]["worse_than_floor"] == 0 and rows["floor"]["worse_than_floor"] is None
    assert "| floor | – |" in kl.table(list(rows.values()))


def test_the_score_can_fail_another_materials_maps_relight_a_capture_badly(caps):
    own = gen.score(caps[0]["truth"], caps[0])
    assert gen.score(caps[1]["truth"], caps[0]) > 2 * own
    assert gen.score(Floor()(gen.photo_input(caps[0])), caps[0]) > 2 * own


def test_a_methods_maps_are_scored_as_the_command_writes_them_at_the_photos_level_as_shot(caps):
    """The command writes the diffuse of the photo as shot (``docs/conventions.md``): the floor's, 0.6 x the
    photo the method was given (exposed for the networks), comes back to 0.6 x photo 0 as shot, and the
    F0 stays where it was; relighting then scores a different diffuse-to-F0 ratio than the exposed maps'."""
    from svbrdf_cli import conventions as cv
    from svbrdf_cli.imageops import resize
    from svbrdf_cli.write.mapset import stored_to_linear

    c = max(caps, key=lambda c: abs(gen.photo_gain(c)))
    assert abs(gen.photo_gain(c)) > 0.3  # a capture the auto exposure changes
    floor = Floor()(gen.photo_input(c))
    shot = stored_to_linear(gen.as_shot(floor, c))
    side = floor["diffuse"].shape[0]  # photo_input's
    photo = resize(cv.image_to_linear(gen.encoded(c["photos"][0])), side)
    unclipped = (cv.image_to_encoded(photo) < 0.9).all(-1)
    assert np.allclose(shot["diffuse"][unclipped], 0.6 * photo[unclipped], atol=0.01)
    assert np.allclose(shot["specular"], stored_to_linear(floor)["specular"])
    assert abs(gen.score_as_shot(floor, c) - gen.score(floor, c)) > 1e-3


def test_colocated_captures_take_each_photo_from_its_light_and_keep_photo_0():
    """``--colocated``: the card's rig, the view moving with each light; photo 0 and the material are the
    standard capture's, the other photos differ from it only in where they were taken from."""
    plain, colo = gen.generate(2, size=SIZE), gen.generate(2, size=SIZE, colocated=True)
    assert np.array_equal(colo["cameras"][1:], colo["lights"][1:])
    assert np.array_equal(colo["cameras"][0], plain["cameras"][0]) and np.array_equal(colo["lights"], plain["lights"])
    assert np.array_equal(colo["photos"][0], plain["photos"][0])
    assert all(np.array_equal(colo["truth"][k], plain["truth"][k]) for k in plain["truth"])
    assert np.abs(colo["photos"][1:].astype(int) - plain["photos"][1:]).mean() > 0.5
    own = gen.score(colo["truth"], colo)
    assert own < 0.5 * gen.score(plain["truth"], colo) or own < 0.5 * gen.score(Floor()(gen.photo_input(colo)), colo)


def test_the_same_seed_gives_the_same_captures_and_another_seed_others():
    a, b, other = gen.generate(1, seed=7, size=SIZE), gen.generate(1, seed=7, size=SIZE), gen.generate(1, seed=8, size=SIZE)
    for k in ("photos", "lights", "cameras"):
        assert np.array_equal(a[k], b[k])
    assert all(np.array_equal(a["truth"][k], b["truth"][k]) for k in a["truth"])
    assert not np.array_equal(a["photos"], other["photos"])


def test_the_cache_gives_back_the_captures_it_kept(tmp_path, caps):
    made = gen.captures(2, gen.SEED, SIZE, str(tmp_path))
    assert (tmp_path / f"{gen.SEED}_2_{SIZE}.npz").is_file()
    again = gen.captures(2, gen.SEED, SIZE, str(tmp_path))
    for m, a, c in zip(made, again, caps):  # capture i is the same whatever the count
        for k in ("photos", "lights", "cameras"):
            assert np.array_equal(m[k], a[k]) and np.array_equal(m[k], c[k])
        assert all(np.array_equal(a["truth"][k], c["truth"][k]) for k in c["truth"])


def test_the_score_is_the_cards_when_the_camera_moves_with_the_light():
    folder = shared_root() / "data" / "real" / "card_blue_9lights"
    if not folder.is_dir():
        pytest.skip("../shared/data/real/card_blue_9lights is not present (a user's fresh clone)")
    from export.render.relight import NineLights

    card = NineLights(str(folder))
    maps = Floor()(card.network_input())
    lights = np.array(card.lights)
    assert gen.relight_rmse(maps, np.stack(card.photos), lights, lights) == pytest.approx(card.relight_rmse(maps), rel=1e-6)
