"""The benchmark's methods: the floor's documented maps, one interface for every method, what is available."""

import os

import numpy as np
import pytest

from export.studies import methods as method_zoo
from svbrdf_cli import conventions as cv
from svbrdf_cli.infer.chain import Chain, ModelError, installed_tiers
from svbrdf_cli.infer.physical import PhysicalModel
from svbrdf_cli.infer.swift import SwiftModel


def _photo(h=24, w=32, seed=0):
    return np.random.default_rng(seed).uniform(0.05, 0.9, (h, w, 3)).astype(np.float32)


def _check_map_set(maps, h, w):
    assert list(maps) == list(cv.MAP_NAMES)
    for k, v in maps.items():
        assert v.shape == (h, w, cv.MAP_CHANNELS[k]) and v.dtype == np.float32, k


def test_floor_returns_the_documented_maps():
    x = _photo()
    maps = method_zoo.Floor()(x)
    _check_map_set(maps, 24, 32)
    lin = cv.decode_maps(maps)
    assert np.allclose(lin["normal"], cv.FLAT_NORMAL, atol=1e-6)  # flat
    assert np.allclose(lin["diffuse"], 0.6 * cv.image_to_linear(x), atol=1e-5)  # 0.6 x the linear input
    assert np.all(maps["roughness"] == 0.5)
    assert np.allclose(lin["specular"], 0.04, atol=1e-6) and cv.DIELECTRIC_F0 == 0.04  # a dielectric's F0


def test_floor_maps_are_writable_copies():
    maps = method_zoo.Floor()(_photo(8, 8))
    maps["normal"][0, 0] = 0  # not a read-only broadcast view
    assert method_zoo.Floor()(_photo(8, 8))["normal"][0, 0, 2] == 1.0


def test_physical_returns_only_the_four_maps():
    from svbrdf_cli.infer.physical import PhysicalModel

    x = _photo(48, 48)
    maps = method_zoo.Physical()(x)
    _check_map_set(maps, 48, 48)
    full = PhysicalModel()(x)
    assert set(full) > set(cv.MAP_NAMES)  # it also returns its flash fit, which a method does not
    for k in cv.MAP_NAMES:
        np.testing.assert_array_equal(maps[k], full[k])


@pytest.mark.parametrize("network", ["chain_model", "swift_model"])
def test_network_runs_the_runtime_chain_and_keeps_the_maps(network, request):
    from svbrdf_cli.infer.swift import SwiftModel

    folder = request.getfixturevalue(network)  # per-stage networks (Chain) or a swift chain (SwiftModel)
    x = _photo(64, 64)
    net = method_zoo.Network("net", folder, threads=1)
    assert net.name == net.label == "net"
    maps = net(x)
    _check_map_set(maps, 64, 64)
    runtime = (Chain if network == "chain_model" else SwiftModel)(folder, threads=1)
    assert type(net.chain) is type(runtime)
    ref = runtime(x)
    for k in cv.MAP_NAMES:
        np.testing.assert_allclose(maps[k], ref[k], atol=1e-6)


def test_auto_rule_is_none_only_when_the_rule_cannot_be_loaded(monkeypatch):
    from svbrdf_cli.infer import auto as auto_tier
    def missing():
        raise ModelError("no rule")

    monkeypatch.setattr(auto_tier, "load_rule", missing)
    assert method_zoo.auto_rule() is None

    def broken():
        raise ValueError("a bug")

    monkeypatch.setattr(auto_tier, "load_rule", broken)
    with pytest.raises(ValueError):  # only a missing model means "not available"
        method_zoo.auto_rule()


def test_auto_returns_the_maps_of_the_tier_it_took():
    rule = method_zoo.auto_rule()
    if rule is None:
        pytest.skip("--model auto's rule or a tier it needs is not installed")
    auto = method_zoo.Auto(rule, threads=1)
    x = _photo(64, 64)
    maps = auto(x)
    _check_map_set(maps, 64, 64)
    taken = auto.model.decision["chosen"]
    assert taken in rule["ladder"]
    ref = auto.model.chain(taken)(x)  # the physical estimate or an installed network
    expected = (PhysicalModel,) if taken == "physical" else (Chain, SwiftModel)
    assert isinstance(auto.model.chain(taken), expected)
    np.testing.assert_allclose(maps["diffuse"], ref["diffuse"], atol=1e-6)


def test_available_lists_what_is_installed_cheapest_kind_first():
    methods = method_zoo.available(threads=1)
    names = [m.name for m in methods]
    assert names[:2] == ["floor", "physical"] and len(set(names)) == len(names)
    assert [n for n in names if n in installed_tiers()] == installed_tiers()
    assert ("e2e" in names) == os.path.isfile(os.path.join(method_zoo.BASELINES_DIR, "e2e-fast", "maps.onnx"))
    assert ("auto" in names) == (method_zoo.auto_rule() is not None)
    if "auto" in names:
        assert names[-1] == "auto"
    assert all(m.label and m.label != m.name for m in methods)  # every method says what it is
