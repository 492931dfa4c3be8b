"""The public library entry (``svbrdf_cli.capture``, ``load_model``, ``read_map_set``, ``write_preset``)."""

import os

import svbrdf_cli

SAMPLE = os.path.join(os.path.dirname(__file__), "..", "..", "examples", "glazed_tiles.jpg")


def test_capture_and_re_target_through_the_public_entry(tmp_path):
    steps = []
    folder, record = svbrdf_cli.capture(SAMPLE, tmp_path / "sets", model=svbrdf_cli.load_model("physical"),
                                        size=256, refine=4, progress=lambda done, total: steps.append((done, total)))
    assert steps == [(1, 4), (2, 4), (3, 4), (4, 4)]  # the library reports; it draws nothing
    assert record["model"]["tier"] == "physical" and record["size"] == 256
    maps = svbrdf_cli.read_map_set(folder)
    svbrdf_cli.write_preset("unreal", tmp_path / "ue" / "glazed_tiles", maps)
    assert os.path.isfile(tmp_path / "ue" / "glazed_tiles" / "T_glazed_tiles_BC.png")
