"""The metal study's parts (``python -m export.studies.metal_study``): the regression and the fit's evidence."""

import numpy as np

from export.studies import metal_study
from svbrdf_cli import conventions as cv
from svbrdf_cli.infer import physical as ph


def _photo(diffuse, f0, roughness=0.3, size=128):
    """An encoded photo of a flat surface under the conventions' flash: a diffuse level and a lobe."""
    geo = ph.Geometry()
    x, y = ph.surface_grid(size, size)
    rho = np.sqrt(x * x + y * y)
    shading, d = ph.shading_at(rho, geo.height, geo.height)
    lum = geo.intensity * (diffuse * shading + f0 * ph.lobe(d, geo.height, roughness))
    return np.clip(cv.image_to_encoded(np.repeat(lum[..., None], 3, -1)), 0, 1).astype(np.float32)


def test_the_regression_separates_what_is_separable():
    rng = np.random.default_rng(0)
    x = np.r_[rng.normal(-2, 0.5, (50, 2)), rng.normal(2, 0.5, (50, 2))]
    y = np.r_[np.zeros(50), np.ones(50)]
    p = metal_study.fit_logistic(x, y)(x)
    assert (p[:50] < 0.5).all() and (p[50:] > 0.5).all()


def test_a_lobe_without_diffuse_reads_as_a_metal_and_a_matte_plane_does_not():
    metal = metal_study.features(_photo(0.0, 0.08))
    matte = metal_study.features(_photo(0.3, 0.0))
    for f in (metal, matte):
        assert set(metal_study.NAMES) <= set(f) and all(np.isfinite(v) for v in f.values())
    assert metal["m1"] > 0.04 > matte["m1"]            # the lobe's height is read as F0
    assert metal["lm0"] < matte["lm0"] and metal["contrast"] > matte["contrast"]


def _coloured(diffuse_rgb, f0_rgb, roughness=0.15, size=128):
    """An encoded photo like :func:`_photo` with per-channel diffuse and F0 (a white flash)."""
    geo = ph.Geometry()
    x, y = ph.surface_grid(size, size)
    rho = np.sqrt(x * x + y * y)
    shading, d = ph.shading_at(rho, geo.height, geo.height)
    lobe = ph.lobe(d, geo.height, roughness)
    lin = np.stack([geo.intensity * (a * shading + f * lobe) for a, f in zip(diffuse_rgb, f0_rgb)], -1)
    return np.clip(cv.image_to_encoded(lin), 0, 1).astype(np.float32)


def test_the_colour_rule_calls_a_gold_highlight_and_not_a_white_one_over_a_coloured_diffuse():
    gold = metal_study.features(_coloured((0.0, 0.0, 0.0), (0.5, 0.4, 0.15)))
    glossy_red = metal_study.features(_coloured((0.3, 0.05, 0.03), (0.04, 0.04, 0.04)))
    matte_red = metal_study.features(_coloured((0.3, 0.05, 0.03), (0.0, 0.0, 0.0)))
    steel = metal_study.features(_coloured((0.0, 0.0, 0.0), (0.5, 0.5, 0.5)))
    assert metal_study.colour_rule(gold)
    assert glossy_red["hl_sat"] < glossy_red["lo_sat"]       # the light's white in the highlight
    assert not metal_study.colour_rule(glossy_red)
    assert not metal_study.colour_rule(matte_red)            # coloured, but nothing outshines the rest
    assert not metal_study.colour_rule(steel)                # a grey metal has no colour to tell it by
