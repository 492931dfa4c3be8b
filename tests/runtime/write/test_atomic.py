"""Data safety: sets are written whole, ``--force`` replaces only our own sets (never the input, never
a folder of other files), concurrent runs never silently replace each other, and a run never deletes
another live run's temporary folders."""

import json
import os
import socket
import subprocess
import sys


import numpy as np
import pytest
from click.testing import CliRunner

from svbrdf_cli.write import atomic
from svbrdf_cli.write import ownership
from svbrdf_cli.cli.main import cli
from svbrdf_cli.errors import ImageWriteError
from svbrdf_cli.imageio import write_image

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))


def run(*args):
    r = CliRunner().invoke(cli, [str(a) for a in args])
    return r.exit_code, r.output


def photo(path, h=300, w=400, seed=0):
    y, x = np.mgrid[0:h, 0:w]
    base = np.random.default_rng(seed).uniform(0.2, 0.5, 3) * (0.8 + 0.2 * np.sin(x / 7.0)[..., None])
    hl = np.exp(-((x - w / 2) ** 2 + (y - h / 2) ** 2) / (2 * 30.0 ** 2))[..., None]
    write_image(path, np.clip(base + 0.6 * hl, 0, 1).astype(np.float32))
    return path


def tree(folder):
    """Every file below ``folder`` with its bytes (what must survive a refused run)."""
    out = {}
    for d, _, names in os.walk(folder):
        for n in names:
            p = os.path.join(d, n)
            with open(p, "rb") as f:
                out[os.path.relpath(p, folder)] = f.read()
    return out


@pytest.fixture
def textures(tmp_path):
    """textures/ with three captured sets."""
    for i in range(3):
        photo(tmp_path / f"p{i}.png", seed=i)
        assert run("capture", tmp_path / f"p{i}.png", "-o", tmp_path / "textures", "--size", 256)[0] == 0
    return tmp_path / "textures"


def test_export_force_never_replaces_a_folder_of_sets(textures):
    """Issue case 1: `export SET -o PARENT --force` used to replace PARENT (all its sets) by one set."""
    before = tree(textures)
    code, out = run("export", textures / "p0", "-o", textures, "--preset", "gltf", "--force")
    assert code == 1 and "holds the input" in out and str(textures) in out
    assert tree(textures) == before
    # the same with the source elsewhere: textures/ is still no set of ours
    import shutil

    shutil.move(str(textures / "p0"), str(textures.parent / "p0"))
    before = tree(textures)
    code, out = run("export", textures.parent / "p0", "-o", textures, "--preset", "gltf", "--force")
    assert code == 1 and "not a texture set written by svbrdf" in out and str(textures) in out
    assert tree(textures) == before


def test_export_force_never_replaces_its_source(textures):
    before = tree(textures)
    code, out = run("export", textures / "p0", "-o", textures / "p0", "--preset", "unreal", "--force")
    assert code == 1 and "holds the input" in out
    assert tree(textures) == before


def test_export_force_replaces_an_export(textures, tmp_path):
    assert run("export", textures / "p0", "-o", tmp_path / "ue", "--preset", "unreal")[0] == 0
    code, out = run("export", textures / "p1", "-o", tmp_path / "ue", "--preset", "unreal", "--force")
    assert code == 0, out


def test_capture_force_never_replaces_the_folder_holding_the_photo(tmp_path):
    """Issue case 2: `capture wood/wood.jpg -o . --force` used to delete wood/ with the photo in it."""
    (tmp_path / "wood").mkdir()
    photo(tmp_path / "wood" / "wood.png")
    (tmp_path / "wood" / "notes.txt").write_text("keep me")
    before = tree(tmp_path)
    code, out = run("capture", tmp_path / "wood" / "wood.png", "-o", tmp_path, "--size", 256, "--force")
    assert code == 1 and "holds the input" in out
    assert tree(tmp_path) == before


def test_capture_force_never_replaces_a_folder_of_other_files(tmp_path):
    photo(tmp_path / "leather.png")
    (tmp_path / "out" / "leather").mkdir(parents=True)
    (tmp_path / "out" / "leather" / "scene.blend").write_bytes(b"an artist's file")
    code, out = run("capture", tmp_path / "leather.png", "-o", tmp_path / "out", "--size", 256, "--force")
    assert code == 1 and "not a texture set written by svbrdf" in out
    assert (tmp_path / "out" / "leather" / "scene.blend").read_bytes() == b"an artist's file"


def test_concurrent_captures_of_one_photo_never_both_succeed(tmp_path):
    """Issue case 3: two runs writing the same set; without --force exactly one may write it."""
    photo(tmp_path / "tile.png", 900, 1200)
    cmd = [sys.executable, "-m", "svbrdf_cli.cli.main", "capture", str(tmp_path / "tile.png"), "-o",
           str(tmp_path / "out"), "--size", "2048", "-q"]
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=ROOT)
    procs = [subprocess.Popen(cmd + ["--preset", preset], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
             for preset in ("svbrdf", "unreal")]
    results = [(p.wait(), p.stdout.read().decode()) for p in procs]
    assert sorted(code for code, _ in results) == [0, 1], results
    assert "already exists" in [text for code, text in results if code == 1][0]
    assert os.listdir(tmp_path / "out") == ["tile"]


def test_a_run_leaves_live_runs_temporaries_alone(tmp_path):
    """Issue case 3: a new run used to delete a running batch's temporary folders."""
    out = tmp_path / "out"
    out.mkdir()
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        live = out / f".svbrdf-{sleeper.pid}-abcd1234.partial"
        dead_pid = subprocess.Popen([sys.executable, "-c", "pass"])
        dead_pid.wait()
        dead = out / f".svbrdf-{dead_pid.pid}-efgh5678.partial"
        legacy = out / ".wood.k2j4h5g6.partial"  # the older naming: a user's folder may look like it (issue 35)
        mine = out / ".my-notes.partial"  # not a name we use: never touched
        for d in (live, dead, legacy, mine):
            d.mkdir()
            (d / "a.txt").write_text("x")
        for d, pid, token in ((live, sleeper.pid, "abcd1234"), (dead, dead_pid.pid, "efgh5678")):
            (d / ownership.TEMP_MARKER).write_text(json.dumps(
                {"tool": "svbrdf", "pid": pid, "token": token, "host": socket.gethostname()}))
        photo(tmp_path / "p.png")
        code, text = run("capture", tmp_path / "p.png", "-o", out, "--size", 256)
        assert code == 0, text
        assert live.is_dir() and mine.is_dir() and legacy.is_dir() and not dead.exists()
    finally:
        sleeper.kill()
        sleeper.wait()


def test_write_set_rechecks_under_the_lock(tmp_path):
    """A set that appears while ours is being written is not replaced (without force)."""
    folder = tmp_path / "set"

    def files(tmp):
        folder.mkdir()  # another run finished first
        (folder / "texture_set.json").write_text("{}")
        open(os.path.join(tmp, "a.txt"), "w").close()
        return ["a.txt"]

    with pytest.raises(ImageWriteError, match="already exists"):
        atomic.write_set(folder, files, force=False)
    assert sorted(os.listdir(folder)) == ["texture_set.json"]
    assert [n for n in os.listdir(tmp_path) if n.startswith(".")] == []


def test_is_our_set(tmp_path):
    assert not atomic.is_our_set(tmp_path)
    (tmp_path / "material.json").write_text("{}")  # a name alone is not enough (issue 35)
    assert not atomic.is_our_set(tmp_path)
    (tmp_path / "material.json").write_text('{"tool": "svbrdf 0.1.0", "files": ["normal.png", "material.json"]}')
    assert atomic.is_our_set(tmp_path)  # a set written before the manifest, by its record
