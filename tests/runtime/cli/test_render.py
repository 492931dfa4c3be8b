import numpy as np
import pytest
from click.testing import CliRunner

from svbrdf_cli import conventions as cv
from svbrdf_cli.cli.main import cli
from svbrdf_cli.imageio import read_image
from svbrdf_cli.write.mapset import read_map_set, write_map_set
from svbrdf_cli.shading import render_maps


@pytest.fixture
def runner():
    return CliRunner()


@pytest.fixture
def mapset(tmp_path):
    rng = np.random.default_rng(0)
    n = cv.normalize(rng.normal(size=(32, 32, 3)) * 0.2 + [0, 0, 1])
    maps = {"normal": n, "diffuse": rng.uniform(0.1, 0.6, (32, 32, 3)),
            "roughness": rng.uniform(0.2, 0.8, (32, 32, 1)), "specular": np.full((32, 32, 3), 0.04)}
    write_map_set(tmp_path / "maps", maps, bits=16)
    return tmp_path / "maps"


def test_version(runner):
    res = runner.invoke(cli, ["--version"])
    assert res.exit_code == 0 and "svbrdf" in res.output


def test_render_matches_library(runner, mapset, tmp_path):
    out = tmp_path / "flash.png"
    res = runner.invoke(cli, ["render", str(mapset), "-o", str(out)])
    assert res.exit_code == 0, res.output
    img = read_image(out)
    expect = cv.image_to_encoded(render_maps(read_map_set(mapset)))
    assert img.shape == (32, 32, 3)
    assert np.abs(img - expect).max() <= 1 / 255 + 1e-6


def test_render_light_and_exposure_change_the_image(runner, mapset, tmp_path):
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    assert runner.invoke(cli, ["render", str(mapset), "-o", str(a)]).exit_code == 0
    assert runner.invoke(cli, ["render", str(mapset), "-o", str(b), "--light", "1.5,0,1", "--exposure", "1"]).exit_code == 0
    ia, ib = read_image(a), read_image(b)
    # side light: the right half (towards +x) brighter than the left half
    assert ib[:, 16:].mean() > ib[:, :16].mean() and not np.allclose(ia, ib)


def test_render_refuses_to_overwrite(runner, mapset, tmp_path):
    out = tmp_path / "x.png"
    out.write_bytes(b"keep")
    res = runner.invoke(cli, ["render", str(mapset), "-o", str(out)])
    # a file error (exit 1), not a usage error (exit 2), naming the file and the flag
    assert res.exit_code == 1 and "--force" in res.output and str(out) in res.output
    assert out.read_bytes() == b"keep"
    res = runner.invoke(cli, ["render", str(mapset), "-o", str(out), "--force"])
    assert res.exit_code == 0 and out.read_bytes() != b"keep"


def test_render_overwrite_is_an_alias_of_force(runner, mapset, tmp_path):
    out = tmp_path / "x.png"
    out.write_bytes(b"keep")
    res = runner.invoke(cli, ["render", str(mapset), "-o", str(out), "--overwrite"])
    assert res.exit_code == 0 and out.read_bytes() != b"keep"


def test_render_missing_map_is_one_line_error(runner, mapset, tmp_path):
    (mapset / "roughness.png").unlink()
    out = tmp_path / "x.png"
    res = runner.invoke(cli, ["render", str(mapset), "-o", str(out)])
    assert res.exit_code == 1 and "roughness.png" in res.output and "Traceback" not in res.output
    assert not out.exists()


def test_render_bad_light(runner, mapset, tmp_path):
    res = runner.invoke(cli, ["render", str(mapset), "-o", str(tmp_path / "x.png"), "--light", "1,2"])
    assert res.exit_code == 2 and "X,Y,Z" in res.output
