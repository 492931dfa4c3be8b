"""One capture reads the photo once and computes the physical estimate once."""

import builtins
import hashlib
import os

import pytest

from svbrdf_cli.infer import physical
from svbrdf_cli.infer.exposure import NETWORK_SIZE, network_input
from svbrdf_cli.infer.registry import load_model
from svbrdf_cli.run import pipeline

SAMPLE = os.path.join(os.path.dirname(__file__), "..", "..", "..", "examples", "glazed_tiles.jpg")


@pytest.fixture
def counted(monkeypatch):
    """{what: calls}: Python's opens of the sample, OpenImageIO's, and the physical estimate's runs."""
    import OpenImageIO as oiio

    sample = os.path.realpath(SAMPLE)
    calls = {"open": 0, "oiio": 0, "estimate": 0}
    real_open, real_oiio, real_estimate = builtins.open, oiio.ImageInput.open, physical.estimate

    def counting_open(file, *args, **kwargs):
        if isinstance(file, (str, bytes, os.PathLike)) and os.path.realpath(file) == sample:
            calls["open"] += 1
        return real_open(file, *args, **kwargs)

    def counting_oiio(name, *args):
        calls["oiio"] += os.path.realpath(name) == sample
        return real_oiio(name, *args)

    def counting_estimate(*args, **kwargs):
        calls["estimate"] += 1
        return real_estimate(*args, **kwargs)

    monkeypatch.setattr(builtins, "open", counting_open)
    monkeypatch.setattr(oiio.ImageInput, "open", staticmethod(counting_oiio))
    monkeypatch.setattr(physical, "estimate", counting_estimate)
    return calls


def test_one_capture_reads_the_photo_once_and_computes_the_estimate_once(tmp_path, counted):
    opts = pipeline.Options(size=NETWORK_SIZE)  # (above it the estimate runs again at the output size)
    assert opts.refine  # the fit to the photo wants the flash height and the EXIF: neither is recomputed
    folder, record = pipeline.capture(pipeline.prepare(SAMPLE, opts), load_model("physical"), tmp_path, opts,
                                      model_name="physical")
    assert counted == {"open": 1, "oiio": 1, "estimate": 1}
    with open(SAMPLE, "rb") as f:
        assert record["input"]["sha256"] == hashlib.sha256(f.read()).hexdigest()
    assert os.path.isfile(os.path.join(folder, "diffuse.png"))


def test_a_network_that_refines_the_estimate_hands_its_findings_over(counted):
    """The estimate a refining network takes as input is the one the fit's geometry uses (not a second)."""
    from svbrdf_cli.infer import geometry

    image = network_input(pipeline.prepare(SAMPLE, pipeline.Options()).small)
    _, found = physical.network_input(image)
    assert counted["estimate"] == 1
    geo = geometry.for_capture(image, None, (768, 1024), {"mode": "auto", "box": (128, 0, 768, 768)}, found)
    assert counted["estimate"] == 1 and geo.light[2] == pytest.approx(found["flash_height"])
