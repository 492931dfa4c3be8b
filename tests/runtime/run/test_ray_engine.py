"""``svbrdf batch --engine ray`` on a local Ray instance: same sets as the local engine, resume, bad files, URIs."""

import json
import os

import numpy as np
import pytest
from click.testing import CliRunner

from svbrdf_cli.cli.main import cli
from svbrdf_cli.imageio import read_image, write_image
from svbrdf_cli.infer.registry import DEFAULT_MODEL

ray = pytest.importorskip("ray", reason="the scale extra (Ray) is not installed")

MAPS = ("normal.png", "diffuse.png", "roughness.png", "specular.png")


@pytest.fixture(scope="module")
def local_ray():
    ray.init(num_cpus=2, include_dashboard=False, logging_level="ERROR", log_to_driver=False)
    yield
    ray.shutdown()


def run(*args):
    r = CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)
    return r.exit_code, r.output


@pytest.fixture
def photos(tmp_path):
    d = tmp_path / "in"
    d.mkdir()
    for i in range(4):
        rng = np.random.default_rng(i)
        y, x = np.mgrid[0:280, 0:320]
        img = rng.uniform(0.15, 0.4, 3) * (0.8 + 0.2 * np.cos(x / (3.0 + i)))[..., None]
        img = img + 0.5 * np.exp(-((x - 160) ** 2 + (y - 140) ** 2) / 800.0)[..., None]
        write_image(d / f"shot{i}.png", np.clip(img, 0, 1).astype(np.float32))
    (d / "shot_broken.jpg").write_bytes(b"\xff\xd8\xff\xe0 truncated")  # a bad file in the middle
    return d


@pytest.mark.parametrize("model", [DEFAULT_MODEL, "swift_model"])
def test_ray_engine_matches_the_local_engine(local_ray, photos, tmp_path, model, request):
    # the default model, and a network from a folder (each worker loads it)
    model = str(request.getfixturevalue(model)) if model == "swift_model" else model
    code, out = run("batch", photos, "-o", tmp_path / "local", "--size", 320, "--model", model)
    assert code == 1 and "4 done, 1 failed" in out
    code, out = run("batch", photos, "-o", tmp_path / "ray", "--size", 320, "--engine", "ray", "--model", model)
    assert code == 1 and "4 done, 1 failed" in out, out
    errors = [line for line in out.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "shot_broken.jpg" in errors[0]
    sets = ["index.html"] + [f"shot{i}" for i in range(4)]  # (index.html: the gallery)
    assert sorted(os.listdir(tmp_path / "ray")) == sorted(os.listdir(tmp_path / "local")) == sets
    for i in range(4):
        for m in MAPS:
            a = read_image(tmp_path / "local" / f"shot{i}" / m)
            b = read_image(tmp_path / "ray" / f"shot{i}" / m)
            assert np.array_equal(a, b), (i, m)
        rec = json.loads((tmp_path / "ray" / f"shot{i}" / "material.json").read_text())
        assert rec["crop"]["mode"] == "auto" and rec["model"]["name"] == model
        assert rec["model"]["tier"] == (DEFAULT_MODEL if model == DEFAULT_MODEL else "swift")


def test_ray_engine_resumes(local_ray, photos, tmp_path):
    out_dir = tmp_path / "out"
    # An interrupted run: shot0 finished, shot1 killed mid-write (a temporary folder left behind).
    assert run("capture", photos / "shot0.png", "-o", out_dir)[0] == 0
    stamp = (out_dir / "shot0" / "material.json").stat().st_mtime_ns
    (out_dir / ".svbrdf-999999999-x1x1x1x1.partial").mkdir()  # (empty: killed before its marker)
    code, out = run("batch", photos, "-o", out_dir, "--engine", "ray")
    assert code == 1 and "3 done, 1 already done, 1 failed" in out, out
    assert (out_dir / "shot0" / "material.json").stat().st_mtime_ns == stamp
    assert sorted(os.listdir(out_dir)) == ["index.html"] + [f"shot{i}" for i in range(4)]


def test_ray_engine_writes_to_a_uri(local_ray, photos, tmp_path):
    uri = (tmp_path / "remote").as_uri()
    code, out = run("batch", photos, "-o", uri, "--engine", "ray", "--preset", "gltf")
    assert code == 1 and "4 done" in out, out
    for i in range(4):
        files = os.listdir(tmp_path / "remote" / f"shot{i}")
        assert {"baseColor.png", "material.gltf", "material.json", "preview.png"} <= set(files)
    code, out = run("batch", photos, "-o", uri, "--engine", "ray", "--preset", "gltf")
    assert "0 done, 4 already done" in out


def test_local_engine_refuses_a_uri(photos, tmp_path):
    code, out = run("batch", photos, "-o", "s3://bucket/textures")
    assert code == 2 and "--engine ray" in out
