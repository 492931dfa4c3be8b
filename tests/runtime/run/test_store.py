"""The Ray engine's output store: replacing a remote set removes only what svbrdf wrote."""

import os

import pytest

from svbrdf_cli.errors import SvbrdfError
from svbrdf_cli.write import ownership

pytest.importorskip("pyarrow", reason="the scale extra (pyarrow) is not installed")
from svbrdf_cli.run.ray_engine import Store  # noqa: E402


def _set(folder, text):
    os.makedirs(folder / "debug", exist_ok=True)
    for name in ("normal.png", "debug/M_b.png", "material.json"):
        (folder / name).write_text(f"{name} {text}")
    ownership.stamp_manifest(str(folder))
    return folder


def test_replacing_a_remote_set_keeps_the_files_svbrdf_did_not_write(tmp_path):
    store = Store((tmp_path / "remote").as_uri())
    store.upload(str(_set(tmp_path / "first", "one")), "oak")
    remote = tmp_path / "remote" / "oak"
    (remote / "notes.txt").write_text("the artist's")
    (remote / "debug" / "mine.png").write_text("the artist's too")
    store.upload(str(_set(tmp_path / "second", "two")), "oak")
    assert (remote / "notes.txt").read_text() == "the artist's"
    assert (remote / "debug" / "mine.png").read_text() == "the artist's too"
    assert (remote / "normal.png").read_text() == "normal.png two"
    assert ownership.read_manifest(str(remote))["normal.png"] == ownership.sha256(str(remote / "normal.png"))


def test_a_remote_file_svbrdf_did_not_write_is_never_replaced(tmp_path):
    store = Store((tmp_path / "remote").as_uri())
    store.upload(str(_set(tmp_path / "first", "one")), "oak")
    remote = tmp_path / "remote" / "oak"
    (remote / "normal.png").write_text("edited by hand")  # no longer what svbrdf wrote
    with pytest.raises(SvbrdfError, match="normal.png"):
        store.upload(str(_set(tmp_path / "second", "two")), "oak")
    assert (remote / "normal.png").read_text() == "edited by hand"
    (tmp_path / "remote" / "pine").mkdir()
    (tmp_path / "remote" / "pine" / "material.json").write_text("{}")  # not a set: nothing is ours
    with pytest.raises(SvbrdfError, match="material.json"):
        store.upload(str(_set(tmp_path / "third", "three")), "pine")
    assert (tmp_path / "remote" / "pine" / "material.json").read_text() == "{}"
