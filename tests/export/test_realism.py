import math

import cv2
import numpy as np
import pytest

from export.data import realism

N = 256


def _grid():
    yy, xx = np.mgrid[0:N, 0:N]
    return yy, xx


def _flash(cx=N / 2, cy=N / 2, sigma=30.0, base=0.2, peak=0.6, colour=(1.0, 1.0, 1.0)):
    """A smooth Gaussian 'flash highlight' on a grey floor."""
    yy, xx = _grid()
    lum = base + peak * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * sigma ** 2))
    return np.clip(lum[..., None] * np.asarray(colour), 0, 1)


def test_constant_image():
    s = realism.image_statistics(np.full((N, N, 3), 0.4))
    assert set(s) == set(realism.STATISTICS)
    assert s["mean"] == pytest.approx(0.4) and s["p50"] == pytest.approx(0.4)
    assert s["contrast"] == pytest.approx(0, abs=1e-9)
    assert s["hf_energy"] == 0
    assert s["clipped"] == 0
    assert s["hl_size"] == 0 and math.isnan(s["hl_offset"])
    assert s["falloff"] == pytest.approx(1)
    assert s["noise"] == pytest.approx(0, abs=1e-9)


def test_clipped_disc_area():
    yy, xx = _grid()
    radius = 40
    disc = (xx - 100) ** 2 + (yy - 140) ** 2 < radius ** 2
    img = np.full((N, N, 3), 0.3)
    img[disc] = 1.0
    s = realism.image_statistics(img)
    assert s["clipped"] == pytest.approx(disc.mean(), rel=1e-6)
    assert s["clipped"] == pytest.approx(math.pi * radius ** 2 / N ** 2, rel=0.02)
    img[disc] = 0.98  # just under the clip level
    assert realism.image_statistics(img)["clipped"] == 0


@pytest.mark.parametrize("sigma", [0.01, 0.03])
def test_noise_estimate(sigma):
    rng = np.random.default_rng(0)
    smooth = _flash(peak=0.3)  # smooth shading must not count as noise
    s0 = realism.image_statistics(smooth)["noise"]
    assert s0 < 0.002
    noisy = smooth + rng.normal(0, sigma, smooth.shape[:2])[..., None]  # grey noise: luma std = sigma
    s = realism.image_statistics(noisy)
    assert s["noise"] == pytest.approx(sigma, rel=0.25)
    assert s["hf_energy"] > realism.image_statistics(smooth)["hf_energy"]


def test_colour_saturation():
    grey = realism.image_statistics(_flash())
    assert grey["colour_sat"] == pytest.approx(0, abs=1e-9) and grey["chroma"] == pytest.approx(0, abs=1e-9)
    red = np.zeros((N, N, 3))
    red[..., 0] = 0.8
    s = realism.image_statistics(red)
    assert s["colour_sat"] == pytest.approx(1) and s["chroma"] == pytest.approx(0.8)


def test_centred_highlight_and_falloff():
    s = realism.image_statistics(_flash())
    assert s["hl_offset"] < 0.02
    assert 0 < s["hl_size"] < 0.2
    assert s["falloff"] < 0.5
    assert s["hl_peak"] == pytest.approx(0.6, abs=0.05)


def test_off_centre_highlight_direction():
    s = realism.image_statistics(_flash(cx=N / 2 + 64, cy=N / 2 - 32))  # right and up
    assert s["hl_dx"] == pytest.approx(0.5, abs=0.05)
    assert s["hl_dy"] == pytest.approx(-0.25, abs=0.05)
    assert s["hl_offset"] == pytest.approx(math.hypot(0.5, 0.25), abs=0.05)


def test_highlight_is_the_brightest_blob_not_bright_texture():
    img = _flash(cx=80, cy=80, sigma=20, peak=0.7)
    img[200:230, 200:230] += 0.3  # a secondary, dimmer bright patch
    s = realism.image_statistics(np.clip(img, 0, 1))
    assert s["hl_dx"] < 0 and s["hl_dy"] < 0


def test_summarize_percentiles_ignore_nan():
    stats = [{"mean": float(v), "hl_offset": float("nan") if v < 5 else 1.0} for v in range(11)]
    out = realism.summarize(stats)
    assert out["mean"] == pytest.approx((1, 5, 9))
    assert out["hl_offset"] == pytest.approx((1, 1, 1))


def _set(rng, n, **kw):
    return [np.clip(_flash(sigma=rng.uniform(20, 40), base=rng.uniform(0.15, 0.3), **kw)
                    + rng.normal(0, 0.01, (N, N, 1)), 0, 1) for _ in range(n)]


def test_compare_flags_only_what_differs():
    rng = np.random.default_rng(1)
    real = _set(rng, 6)
    rows = realism.compare(real, real)
    assert [r["stat"] for r in rows] == list(realism.STATISTICS)
    assert not any(r["differs"] for r in rows)
    assert all(r["norm_diff"] == 0 or math.isnan(r["norm_diff"]) for r in rows)

    red = [im * np.array([1.0, 0.2, 0.2]) for im in real]  # same shading, strongly coloured
    rows = {r["stat"]: r for r in realism.compare(red, real)}
    assert rows["colour_sat"]["differs"] and rows["colour_sat"]["norm_diff"] > 0
    assert not rows["hl_offset"]["differs"]
    table = realism.format_table(list(rows.values()))
    assert "colour_sat" in table and "differs" in table


def test_main_with_arrays_and_folder(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("SVBRDF_SHARED", str(tmp_path / "absent"))
    sims = _set(np.random.default_rng(2), 3)
    assert realism.main([], simulated=sims) == 0
    assert "hf_energy" in capsys.readouterr().out
    for i, im in enumerate(sims):
        cv2.imwrite(str(tmp_path / f"{i}.png"), (im[..., ::-1] * 255 + 0.5).astype(np.uint8))
    assert realism.main(["--sim", str(tmp_path), "--size", "128"]) == 0
    assert "Simulated 3" in capsys.readouterr().out


def test_load_real_photos_absent(tmp_path):
    assert realism.load_real_photos(root=tmp_path / "nothing") == {}


def test_load_real_photos(shared_data):
    real = realism.load_real_photos(root=shared_data.parent, size=64, sets=["des18_real", "luo2024"])
    if not real:
        pytest.skip("no real photos under the shared data")
    for name, imgs in real.items():
        assert imgs, name
        for im in imgs:
            assert im.shape == (64, 64, 3) and im.dtype == np.float32
            assert 0 <= im.min() and im.max() <= 1
    s = realism.image_statistics(real["des18_real"][0])
    assert all(np.isfinite(v) for k, v in s.items() if not k.startswith("hl_"))
