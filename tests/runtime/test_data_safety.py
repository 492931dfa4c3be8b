"""Nothing the tool did not write is ever deleted or replaced, ``--force`` included (issue 35, items 1-6).

Each test builds a tree of the user's own files (hidden folders, notes in a set, another tool's
``material.json``, an ``index.html``), runs commands over it and checks that every one of those files
is still there, byte for byte.
"""

import json
import os
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
from click.testing import CliRunner

from svbrdf_cli.write import atomic
from svbrdf_cli.write import ownership
from svbrdf_cli.cli.main import cli
from svbrdf_cli.errors import ImageWriteError
from svbrdf_cli.imageio import write_image

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
ENV = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=ROOT)


def run(*args):
    r = CliRunner().invoke(cli, [str(a) for a in args])
    assert r.exception is None or isinstance(r.exception, SystemExit), r.output
    return r.exit_code, r.output


def photo(path, h=200, w=260, seed=0):
    y, x = np.mgrid[0:h, 0:w]
    base = np.random.default_rng(seed).uniform(0.2, 0.5, 3) * (0.8 + 0.2 * np.sin(x / 7.0)[..., None])
    hl = np.exp(-((x - w / 2) ** 2 + (y - h / 2) ** 2) / (2 * 30.0 ** 2))[..., None]
    write_image(path, np.clip(base + 0.6 * hl, 0, 1).astype(np.float32))
    return path


def snapshot(root, paths):
    """{path: bytes} of the user's files (each must survive as it is)."""
    return {p: (root / p).read_bytes() for p in paths}


def user_tree(out):
    """An output folder full of the user's files; returns their paths (relative to ``out``'s parent)."""
    files = {
        ".thesis.20240101.old/chapter1.tex": b"\\chapter{One}",
        ".backup.v2_final.partial/data.csv": b"1,2,3",
        ".svbrdf-1-notmine.partial/keep.txt": b"a name like ours, but no marker of ours",
        "index.html": b"<html>my own page</html>",
        "blender_mat/material.json": json.dumps({"tool": "matgen 2.1", "files": ["albedo.png"]}).encode(),
        "blender_mat/texture_set.json": b'{"files": {"albedo.png": {}}}',
        "blender_mat/scene.blend": b"BLENDER-v300 an artist's scene",
        "notes.txt": b"shoot notes",
    }
    for rel, data in files.items():
        p = out / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(data)
    return [os.path.join(out.name, rel) for rel in files]


# --------------------------------------------------------------------------
# 1. hidden user folders
# --------------------------------------------------------------------------

def test_a_capture_never_deletes_hidden_user_folders(tmp_path):
    """Item 1: the older temp naming's pattern matched `.thesis.20240101.old` and `.backup.v2_final.partial`."""
    out = tmp_path / "out"
    paths = user_tree(out)
    before = snapshot(tmp_path, paths)
    photo(tmp_path / "wood.png")
    code, text = run("capture", tmp_path / "wood.png", "-o", out, "--size", 256)
    assert code == 0, text
    assert snapshot(tmp_path, paths) == before


def _dead_pid():
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_only_marked_temporaries_of_dead_runs_are_removed(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    dead = _dead_pid()
    # a temporary folder of a run that died (made as write_set makes them, by a process now gone)
    code = subprocess.run([sys.executable, "-c", "import sys; from svbrdf_cli.write import atomic; "
                           "t = atomic.make_temporary(sys.argv[1]); open(t + '/normal.png', 'wb').write(b'half')",
                           str(out)], env=ENV).returncode
    assert code == 0
    stale = [n for n in os.listdir(out)]
    assert len(stale) == 1 and ownership.stale_temporary(out / stale[0])
    # our name, a dead pid, but not our marker (a different token, another host, none at all)
    fakes = {}
    for i, record in enumerate(({"tool": "svbrdf", "pid": dead, "token": "zzzzzzzz", "host": socket.gethostname()},
                                {"tool": "svbrdf", "pid": dead, "token": "tok1aaaa", "host": "elsewhere"},
                                None)):
        d = out / f".svbrdf-{dead}-tok{i}aaaa.partial"
        d.mkdir()
        (d / "thesis.pdf").write_bytes(b"%PDF")
        if record is not None:
            (d / ownership.TEMP_MARKER).write_text(json.dumps(record))
        fakes[d] = True
    # killed before its marker was written: empty, or only an empty marker; removed
    empty = out / f".svbrdf-{dead}-emptyabc.partial"
    empty.mkdir()
    unmarked = out / f".svbrdf-{dead}-unmarked.partial"
    unmarked.mkdir()
    (unmarked / ownership.TEMP_MARKER).write_bytes(b"")
    assert ownership.unmarked_orphan(empty) and ownership.unmarked_orphan(unmarked)
    # an empty marker beside another file, a live run's empty folder: not judged ours, kept
    beside = out / f".svbrdf-{dead}-besideab.partial"
    beside.mkdir()
    (beside / ownership.TEMP_MARKER).write_bytes(b"")
    (beside / "thesis.pdf").write_bytes(b"%PDF")
    live = out / f".svbrdf-{os.getpid()}-liveabcd.partial"
    live.mkdir()
    atomic.clean_partials(out)
    assert not (out / stale[0]).exists() and not empty.exists() and not unmarked.exists()
    assert all((d / "thesis.pdf").read_bytes() == b"%PDF" for d in fakes)
    assert sorted(os.listdir(beside)) == sorted([ownership.TEMP_MARKER, "thesis.pdf"])
    assert (beside / ownership.TEMP_MARKER).read_bytes() == b"" and (beside / "thesis.pdf").read_bytes() == b"%PDF"
    assert live.is_dir()


# --------------------------------------------------------------------------
# 2 and 5. the gallery
# --------------------------------------------------------------------------

def test_batch_never_replaces_the_users_index_html(tmp_path, caplog):
    """Item 2, with and without --force."""
    (tmp_path / "in").mkdir()
    photo(tmp_path / "in" / "oak.png")
    out = tmp_path / "out"
    out.mkdir()
    (out / "index.html").write_bytes(b"<html>mine</html>")
    for force in ((), ("--force",)):
        code, text = run("batch", tmp_path / "in", "-o", out, "--size", 256, *force)
        assert code == 0, text
        assert (out / "index.html").read_bytes() == b"<html>mine</html>"
        assert "not written by svbrdf" in caplog.text
    assert (out / "oak" / "material.json").is_file()
    # our own gallery is rewritten run after run
    (out / "index.html").unlink()
    assert run("batch", tmp_path / "in", "-o", out, "--size", 256)[0] == 0
    first = (out / "index.html").read_text()
    assert ownership.GENERATOR_META in first
    assert run("batch", tmp_path / "in", "-o", out, "--size", 256, "--force")[0] == 0
    assert ownership.is_our_page(out / "index.html")


def test_a_photo_named_like_the_gallery_fails_alone(tmp_path):
    """Item 5: `index.html.jpg` made OUT/index.html/, and the gallery write raised IsADirectoryError."""
    d = tmp_path / "in"
    d.mkdir()
    photo(d / "index.html.png")
    photo(d / "oak.png", seed=1)
    out = tmp_path / "out"
    code, text = run("batch", d, "-o", out, "--size", 256)
    assert code == 1 and "Traceback" not in text
    errors = [line for line in text.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "index.html.png" in errors[0] and "rename the photo" in errors[0], text
    assert (out / "index.html").is_file() and ownership.is_our_page(out / "index.html")
    assert (out / "oak" / "material.json").is_file()


def test_the_gallery_steps_aside_from_a_folder_named_index_html(tmp_path, caplog):
    """A capture may make OUT/index.html/ (no gallery there); a later batch warns instead of failing."""
    photo(tmp_path / "index.html.png")
    out = tmp_path / "out"
    assert run("capture", tmp_path / "index.html.png", "-o", out, "--size", 256)[0] == 0
    (tmp_path / "in").mkdir()
    photo(tmp_path / "in" / "oak.png")
    code, text = run("batch", tmp_path / "in", "-o", out, "--size", 256)
    assert code == 0 and "Traceback" not in text and "not written by svbrdf" in caplog.text, text
    assert (out / "index.html" / "material.json").is_file()


# --------------------------------------------------------------------------
# 3 and 4. --force
# --------------------------------------------------------------------------

def test_force_keeps_the_files_the_user_added_to_a_set(tmp_path):
    """Item 3: --force replaced the whole folder, the user's notes and painted maps with it."""
    photo(tmp_path / "wood.png")
    out = tmp_path / "out"
    assert run("capture", tmp_path / "wood.png", "-o", out, "--size", 256, "--debug")[0] == 0
    s = out / "wood"
    (s / "my_notes.txt").write_text("darker than it looks")
    (s / "painted").mkdir()
    (s / "painted" / "height_fixed.png").write_bytes(b"\x89PNG hand-painted")
    (s / "debug" / "mine.txt").write_text("in a folder of ours")
    before = json.loads((s / "material.json").read_text())
    # the photo changes and the second run writes no debug/ and no preview: ours are removed, the rest stay
    photo(tmp_path / "wood.png", seed=5)
    code, text = run("capture", tmp_path / "wood.png", "-o", out, "--size", 256, "--force", "--no-preview")
    assert code == 0, text
    after = json.loads((s / "material.json").read_text())
    assert after["input"]["sha256"] != before["input"]["sha256"]
    assert (s / "my_notes.txt").read_text() == "darker than it looks"
    assert (s / "painted" / "height_fixed.png").read_bytes() == b"\x89PNG hand-painted"
    assert (s / "debug" / "mine.txt").is_file()
    assert sorted(os.listdir(s / "debug")) == ["mine.txt"] and not (s / "preview.png").exists()
    manifest = ownership.read_manifest(s)
    assert "my_notes.txt" not in manifest and "normal.png" in manifest
    assert not [n for n in os.listdir(out) if n.startswith(".")]
    # and again: the manifest now lists the new set only
    assert run("capture", tmp_path / "wood.png", "-o", out, "--size", 256, "--force")[0] == 0
    assert (s / "my_notes.txt").is_file() and (s / "preview.png").is_file()


def test_force_never_replaces_a_file_the_user_changed(tmp_path):
    photo(tmp_path / "wood.png")
    out = tmp_path / "out"
    assert run("capture", tmp_path / "wood.png", "-o", out, "--size", 256)[0] == 0
    (out / "wood" / "roughness.png").write_bytes(b"the user's own roughness")
    listing = sorted(os.listdir(out / "wood"))
    code, text = run("capture", tmp_path / "wood.png", "-o", out, "--size", 256, "--force")
    assert code == 1 and "roughness.png" in text and "Move it away" in text
    assert (out / "wood" / "roughness.png").read_bytes() == b"the user's own roughness"
    assert sorted(os.listdir(out / "wood")) == listing and not [n for n in os.listdir(out) if n.startswith(".")]


def test_force_never_takes_over_a_folder_by_its_file_names(tmp_path):
    """Item 4: any folder holding material.json or texture_set.json counted as ours."""
    photo(tmp_path / "leather.png")
    out = tmp_path / "out"
    s = out / "leather"
    s.mkdir(parents=True)
    for name, data in (("material.json", b'{"tool": "substance", "files": ["scene.blend"]}'),
                       ("texture_set.json", b'{"generator": "other 1.0", "files": {"scene.blend": {}}}'),
                       ("scene.blend", b"an artist's file")):
        (s / name).write_bytes(data)
    before = snapshot(out, ["leather/material.json", "leather/texture_set.json", "leather/scene.blend"])
    code, text = run("capture", tmp_path / "leather.png", "-o", out, "--size", 256, "--force")
    assert code == 1 and "not a texture set written by svbrdf" in text
    assert snapshot(out, list(before)) == before and os.listdir(out) == ["leather"]
    assert not atomic.is_our_set(s)


def test_a_set_is_recognised_by_its_manifest(tmp_path):
    def files(tmp):
        open(os.path.join(tmp, "a.txt"), "w").close()
        return ["a.txt"]

    atomic.write_set(tmp_path / "s", files, force=False)
    manifest = ownership.read_manifest(tmp_path / "s")
    assert set(manifest) == {"a.txt", "texture_set.json"} and manifest["a.txt"] == ownership.sha256(tmp_path / "s" / "a.txt")
    meta = json.loads((tmp_path / "s" / "texture_set.json").read_text())
    assert meta["svbrdf_set"]["tool"] == "svbrdf" and meta["svbrdf_set"]["version"]
    # a manifest naming files outside the folder never reaches them
    (tmp_path / "victim.txt").write_text("outside")
    meta["svbrdf_set"]["files"] = {"../victim.txt": None, "/etc/passwd": None, "a.txt": None, "texture_set.json": None}
    (tmp_path / "s" / "texture_set.json").write_text(json.dumps(meta))
    assert set(ownership.read_manifest(tmp_path / "s")) == {"a.txt", "texture_set.json"}

    def other(tmp):
        open(os.path.join(tmp, "b.txt"), "w").close()
        return ["b.txt"]

    atomic.write_set(tmp_path / "s", other, force=True)
    assert sorted(os.listdir(tmp_path / "s")) == ["b.txt", "texture_set.json"]
    assert (tmp_path / "victim.txt").read_text() == "outside"


# --------------------------------------------------------------------------
# 6. leftovers: a killed batch, a symlinked set
# --------------------------------------------------------------------------

def test_force_on_a_symlinked_set_leaves_nothing_behind(tmp_path):
    """Item 6: `--force` where OUT/<stem> is a symlink left a `.svbrdf-*.old` symlink for good."""
    photo(tmp_path / "wood.png")
    assert run("capture", tmp_path / "wood.png", "-o", tmp_path / "real", "--size", 256)[0] == 0
    out = tmp_path / "out"
    out.mkdir()
    os.symlink(tmp_path / "real" / "wood", out / "wood")
    target = snapshot(tmp_path, [f"real/wood/{n}" for n in os.listdir(tmp_path / "real" / "wood")])
    code, text = run("capture", tmp_path / "wood.png", "-o", out, "--size", 256, "--force")
    assert code == 1 and "symbolic link" in text
    assert os.listdir(out) == ["wood"] and os.path.islink(out / "wood")
    assert snapshot(tmp_path, list(target)) == target


def _batch_until_writing(tmp_path, n=8):
    d = tmp_path / "in"
    d.mkdir()
    for i in range(n):
        photo(d / f"p{i}.png", 300, 400, seed=i)
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "svbrdf_cli.cli.main", "batch", str(d), "-o", str(out), "--size", "1024", "-q",
           "--threads", "1"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=ENV)
    deadline = time.time() + 120
    while time.time() < deadline:
        assert proc.poll() is None, "the batch ended before a set was being written"
        if out.is_dir() and any(n.endswith(".partial") for n in os.listdir(out)):
            return proc, out, cmd
        time.sleep(0.005)
    proc.kill()
    pytest.fail("no set was ever being written")


def test_a_terminated_batch_leaves_no_temporary_folder(tmp_path):
    """SIGTERM (what `kill` and service managers send) ends the run through its clean-up."""
    proc, out, _ = _batch_until_writing(tmp_path)
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=60) != 0
    assert not [n for n in os.listdir(out) if n.startswith(".")], os.listdir(out)
    for name in os.listdir(out):
        if name != "index.html":
            assert (out / name / "material.json").is_file(), name


def test_a_killed_batchs_temporary_folder_goes_with_the_next_write_there(tmp_path):
    """SIGKILL cannot be caught: the folder it leaves is recognisably ours (marker: pid, host, token; or,
    killed before it was marked, empty or only an empty marker), and the next write of any set into that
    folder (capture, batch or export) removes it."""
    proc, out, _ = _batch_until_writing(tmp_path)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    left = [n for n in os.listdir(out) if n.endswith(".partial")]
    if not left:
        pytest.skip("the set was renamed into place before the kill landed")
    assert all(ownership.orphan_temporary(out / n) for n in left)
    photo(tmp_path / "src.png")
    assert run("capture", tmp_path / "src.png", "-o", tmp_path / "sets", "--size", 256)[0] == 0
    code, text = run("export", tmp_path / "sets" / "src", "-o", out / "exported", "--preset", "gltf")
    assert code == 0, text
    assert not [n for n in os.listdir(out) if n.startswith(".")]


# --------------------------------------------------------------------------
# every command over a tree of user files
# --------------------------------------------------------------------------

def test_a_tree_of_user_files_survives_every_command(tmp_path):
    out = tmp_path / "out"
    paths = user_tree(out)
    (tmp_path / "in").mkdir()
    for i, name in enumerate(("oak", "blender_mat", "index.html", "notes")):
        photo(tmp_path / "in" / f"{name}.png", seed=i)
    # a set of ours with the user's notes in it
    assert run("capture", tmp_path / "in" / "oak.png", "-o", out, "--size", 256)[0] == 0
    (out / "oak" / "my_notes.txt").write_text("keep")
    (out / "oak" / "painted").mkdir()
    (out / "oak" / "painted" / "height_fixed.png").write_bytes(b"painted")
    (out / "oak" / "viewer.html").write_text("<html>the user's own viewer</html>")
    paths += ["out/oak/my_notes.txt", "out/oak/painted/height_fixed.png", "out/oak/viewer.html"]
    before = snapshot(tmp_path, paths)
    commands = [
        ("capture", tmp_path / "in", "-o", out, "--size", 256),
        ("capture", tmp_path / "in", "-o", out, "--size", 256, "--force"),
        ("capture", tmp_path / "in" / "oak.png", "-o", out, "--size", 256, "--force", "--preset", "unreal"),
        ("batch", tmp_path / "in", "-o", out, "--size", 256),
        ("batch", tmp_path / "in", "-o", out, "--size", 256, "--force", "--preset", "gltf"),
        ("export", out / "oak", "-o", out / "blender_mat", "--preset", "gltf", "--force"),
        ("export", out / "notes", "-o", out / "oak", "--preset", "blender", "--force"),
        ("render", out / "oak", "-o", out / "index.html"),
        ("view", out / "oak", "--no-open"),
    ]
    for args in commands:
        code, text = run(*args)
        assert "Traceback" not in text, (args, text)
        assert snapshot(tmp_path, paths) == before, (args, text)
    assert [n for n in os.listdir(out) if n.startswith(".svbrdf-")] == [".svbrdf-1-notmine.partial"]


def test_write_set_refuses_a_new_file_where_the_user_has_one(tmp_path):
    def files(tmp):
        open(os.path.join(tmp, "a.txt"), "w").close()
        return ["a.txt"]

    atomic.write_set(tmp_path / "s", files, force=False)
    (tmp_path / "s" / "b.txt").write_text("user's")

    def more(tmp):
        for n in ("a.txt", "b.txt"):
            open(os.path.join(tmp, n), "w").close()
        return ["a.txt", "b.txt"]

    with pytest.raises(ImageWriteError, match="b.txt"):
        atomic.write_set(tmp_path / "s", more, force=True)
    assert (tmp_path / "s" / "b.txt").read_text() == "user's"
    assert not [n for n in os.listdir(tmp_path) if n.startswith(".")]
