"""The fast training engine: bank, batches, flash context, exact resume, clean stop."""

import dataclasses
import os
import signal
import subprocess
import sys

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from export.data.noise import luminance
from export.engine import bank as bank_mod
from export.engine import batches, flash, nets
from export.engine.run import Run, RunConfig
from export.render.brdf import render_maps
from export.render import targets as render_targets
from svbrdf_cli import conventions as cv
from svbrdf_cli.infer import flash_fields

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


@pytest.fixture(scope="module", autouse=True)
def small_shards():
    """Procedural shards of 16 materials: a bank of a few seconds."""
    old = bank_mod.CC0_FRACTION, bank_mod.SHARD
    bank_mod.CC0_FRACTION, bank_mod.SHARD = 0.0, 16
    yield
    bank_mod.CC0_FRACTION, bank_mod.SHARD = old


@pytest.fixture(scope="module")
def small_bank(tmp_path_factory, small_shards):
    """Two procedural shards."""
    root = str(tmp_path_factory.mktemp("bank"))
    bank_mod.grow(root, 2 * bank_mod.SHARD, progress=None)
    return root


def test_bank_round_trip_keeps_the_maps(small_bank):
    bank = bank_mod.Bank(small_bank)
    assert len(bank) == 2 * bank_mod.SHARD
    assert bank_mod.count(small_bank) == len(bank)
    maps = bank.maps(torch.tensor([0, 5]))
    again = bank_mod.decode(bank_mod.encode(maps))
    for k in cv.MAP_NAMES:
        assert torch.allclose(maps[k], again[k], atol=3e-3), k
    n = maps["normal"]
    assert torch.allclose((n * n).sum(1), torch.ones_like(n[:, 0]), atol=1e-5)


def test_bank_grows_the_same_in_two_sittings(tmp_path, small_bank):
    bank_mod.grow(str(tmp_path), bank_mod.SHARD, progress=None)
    bank_mod.grow(str(tmp_path), 2 * bank_mod.SHARD, progress=None)
    a, b = bank_mod.Bank(str(tmp_path)), bank_mod.Bank(small_bank)
    for k in a.arrays:
        assert torch.equal(a.arrays[k], b.arrays[k]), k


def test_the_bank_is_mapped_from_disk_as_its_shards_hold_it_and_follows_its_growth(tmp_path):
    root = str(tmp_path / "bank")
    bank_mod.grow(root, bank_mod.SHARD, progress=None)
    bank = bank_mod.Bank(root)
    shards = bank_mod.read_manifest(root)["shards"]
    with open("/proc/self/maps") as f:  # the tensors' memory is the flat files' mapping
        mapped = [[int(x, 16) for x in line.split()[0].split("-")] + [line.split()[-1]] for line in f]
    with np.load(os.path.join(root, shards[0]["file"])) as z:
        for k in bank_mod.MAPS:
            at = bank.arrays[k].data_ptr()
            assert any(a <= at < b and name.endswith(f"{k}.npy") for a, b, name in mapped), k
            assert np.array_equal(bank.arrays[k].numpy(), z[k]), k
    flat = os.path.join(root, bank_mod.FLAT, "diffuse.npy")
    made = os.stat(flat).st_mtime_ns
    bank_mod.grow(root, 2 * bank_mod.SHARD, progress=None)
    assert len(bank_mod.Bank(root, limit_shards=1)) == bank_mod.SHARD
    assert os.stat(flat).st_mtime_ns == made  # a prefix the flat files hold: not written again
    grown = bank_mod.Bank(root)
    assert len(grown) == 2 * bank_mod.SHARD and os.stat(flat).st_mtime_ns != made
    with np.load(os.path.join(root, bank_mod.read_manifest(root)["shards"][1]["file"])) as z:
        assert np.array_equal(grown.arrays["normal"][bank_mod.SHARD:].numpy(), z["normal"])
    for k in bank_mod.MAPS:
        assert torch.equal(grown.arrays[k][:bank_mod.SHARD], bank.arrays[k]), k
    assert not [f for f in os.listdir(os.path.dirname(flat)) if "tmp" in f]


def test_a_bank_grown_past_its_print_shards_holds_prints_and_keeps_its_earlier_shards(tmp_path, small_bank,
                                                                                      monkeypatch):
    from click.testing import CliRunner

    from export.engine.cli import main

    monkeypatch.setattr(bank_mod, "PRINT_SHARDS", range(2, 3))
    root = str(tmp_path / "bank")
    bank_mod.grow(root, 3 * bank_mod.SHARD, progress=None)
    shards = bank_mod.read_manifest(root)["shards"]
    assert [s["kind"] for s in shards][2] == "print" and all(x.startswith("print:") for x in shards[2]["sources"])
    before, bank = bank_mod.Bank(small_bank), bank_mod.Bank(root)
    for k in before.arrays:  # the first shards are those of a bank grown before the prints
        assert torch.equal(before.arrays[k], bank.arrays[k][:len(before)]), k
    prints = bank.maps(torch.arange(2 * bank_mod.SHARD, 3 * bank_mod.SHARD))
    tilt = prints["normal"][:, :2].norm(dim=1).mean((1, 2))
    spread = prints["diffuse"].std((2, 3)).mean(1)
    assert float(tilt.max()) < 0.12 and float(spread.median()) > 0.03  # colour patterns, next to no relief
    # a run takes a larger bank from the command line, and keeps it
    import shutil

    own = str(tmp_path / "own")
    shutil.copytree(small_bank, own)
    run = _run(tmp_path / "run", own)
    run.train(steps=1, evaluate=False)
    del run
    res = CliRunner().invoke(main, ["train", "--run", str(tmp_path / "run"), "--steps", "1", "--checkpoint", "",
                                    "--bank-count", str(3 * bank_mod.SHARD)])
    assert res.exit_code == 0, res.output
    resumed = Run(str(tmp_path / "run"), log=lambda m: None, des19=[])
    assert resumed.config.bank_count == 3 * bank_mod.SHARD
    assert bank_mod.read_manifest(own)["shards"][2]["kind"] == "print"
    # it trains on its bank_count materials, not on more that another run left in the folder
    resumed.config = dataclasses.replace(resumed.config, bank_count=2 * bank_mod.SHARD)
    assert len(resumed.load_bank().sources) == 2 * bank_mod.SHARD


def _grown_with_shard(tmp_path, monkeypatch, kind):
    """A bank of 3 shards whose third is of ``kind`` ("dark", "grey", "relief_metal", "wavy"): (its manifest entry, its maps,
    the first two shards' maps)."""
    for name, k in (("PRINT_SHARDS", "print"), ("DARK_SHARDS", "dark"), ("GREY_SHARDS", "grey"),
                    ("RELIEF_METAL_SHARDS", "relief_metal"), ("WAVY_SHARDS", "wavy")):
        monkeypatch.setattr(bank_mod, name, range(2, 3) if k == kind else range(0))
    root = str(tmp_path / "bank")
    bank_mod.grow(root, 3 * bank_mod.SHARD, progress=None)
    bank = bank_mod.Bank(root)
    return (bank_mod.read_manifest(root)["shards"][2], bank.maps(torch.arange(2 * bank_mod.SHARD, 3 * bank_mod.SHARD)),
            bank.maps(torch.arange(0, 2 * bank_mod.SHARD)))


def test_dark_shards_hold_dark_glossy_dielectrics(tmp_path, small_bank, monkeypatch):
    shard, dark, rest = _grown_with_shard(tmp_path, monkeypatch, "dark")
    assert shard["kind"] == "dark" and all(x.startswith("dark:") for x in shard["sources"])
    assert float(dark["diffuse"].mean()) < 0.3 * float(rest["diffuse"].mean())
    assert float(dark["roughness"].mean()) < float(rest["roughness"].mean())
    assert float(dark["specular"].amax()) < 0.1  # dielectrics only


def test_grey_shards_hold_dark_grey_glossy_dielectrics(tmp_path, small_bank, monkeypatch):
    shard, grey, rest = _grown_with_shard(tmp_path, monkeypatch, "grey")
    assert shard["kind"] == "grey" and all(x.startswith("grey:") for x in shard["sources"])

    def chroma(d):  # mean distance of a colour from its grey, over its brightness
        return float((d - d.mean(1, keepdim=True)).abs().mean() / d.mean())

    assert float(grey["diffuse"].mean()) < 0.3 * float(rest["diffuse"].mean())
    assert chroma(grey["diffuse"]) < 0.5 * chroma(rest["diffuse"])
    assert float(grey["roughness"].mean()) < float(rest["roughness"].mean())
    assert float(grey["specular"].amax()) < 0.1  # dielectrics only
    assert float((grey["specular"] - grey["specular"].mean(1, keepdim=True)).abs().amax()) < 0.01  # grey F0


def test_relief_metal_shards_hold_metals_with_relief_half_of_them_foil_over_a_dielectric(tmp_path, small_bank, monkeypatch):
    shard, metal, rest = _grown_with_shard(tmp_path, monkeypatch, "relief_metal")
    foil = int(round(bank_mod.FOIL_SHARE * bank_mod.SHARD))
    assert shard["kind"] == "relief_metal"
    assert all(x.startswith("foil:") for x in shard["sources"][:foil])
    assert all(x.startswith("relief_metal:") for x in shard["sources"][foil:])

    def tilt(n):
        return float(n[:, :2].norm(dim=1).mean())

    pure = {k: v[foil:] for k, v in metal.items()}
    f0 = luminance(pure["specular"])
    assert float(f0.amin()) > 0.25 and float(pure["diffuse"].amax()) < 0.03  # metal everywhere: no diffuse
    assert tilt(pure["normal"]) > tilt(rest["normal"])
    lum = luminance(metal["specular"][:foil]).flatten(1)
    metal_share = (lum > 0.25).float().mean(1)
    assert float(metal_share.amin()) < 0.9 and float(metal_share.amax()) > 0.1 and float(metal_share.mean()) > 0.2
    warm = (pure["specular"][:, 2] < 0.8 * pure["specular"][:, 0]).float().mean((1, 2))  # gold, copper, brass, bronze
    assert 0.25 < float((warm > 0.5).float().mean()) < 0.95


def test_wavy_shards_hold_relief_wider_than_the_texture_on_metals_and_dielectrics(tmp_path, small_bank, monkeypatch):
    shard, wavy, rest = _grown_with_shard(tmp_path, monkeypatch, "wavy")
    assert shard["kind"] == "wavy" and all(x.startswith("wavy:") for x in shard["sources"])

    def tilt(n):
        return n[:, :2] / n[:, 2:]

    def broad_share(n):  # share of the tilt's variance left in means over blocks of 1/32 of the width
        t = tilt(n)
        t = t - t.mean((2, 3), keepdim=True)
        return float((F.avg_pool2d(t, bank_mod.SIZE // 32) ** 2).mean() / (t ** 2).mean())

    assert broad_share(wavy["normal"]) > 0.5 > 2.5 * broad_share(rest["normal"])  # measured 0.67-0.70, 0.08-0.11
    steepest = tilt(wavy["normal"]).norm(dim=1).flatten(1).amax(1)
    assert float(steepest.amin()) > bank_mod.WAVY_SLOPE[0] * 0.8
    metal = (luminance(wavy["specular"]).flatten(1).mean(1) > 0.25).float().mean()
    assert 0.15 < float(metal) < 0.7


def test_a_wave_has_its_drawn_steepest_slope_and_direction():
    slopes = bank_mod.wave_slopes(torch.Generator().manual_seed(5), 6, size=128)
    g = torch.Generator().manual_seed(5)
    theta = bank_mod.uniform(g, 6, 0.0, 2.0 * np.pi)
    mag = slopes.norm(dim=1).flatten(1).amax(1)
    assert bool(((mag >= bank_mod.WAVY_SLOPE[0] - 1e-5) & (mag <= bank_mod.WAVY_SLOPE[1] + 1e-5)).all())
    direction = torch.stack([theta.cos(), theta.sin()], 1)
    across = (slopes - (slopes * direction[:, :, None, None]).sum(1, keepdim=True) * direction[:, :, None, None])
    assert float(across.abs().amax()) < 1e-4  # the slope points along the wave's direction only


def test_a_batch_has_what_each_stage_needs(small_bank):
    bank = bank_mod.Bank(small_bank)
    g = torch.Generator().manual_seed(0)
    for stage, names in batches.STAGE_TARGETS.items():
        b = batches.make(bank, g, 3, 64, stage)
        assert b["photo"].shape == (3, 3, 64, 64) and b["context"].shape == (3, 4, 64, 64)
        assert b["base"].shape == (3, 10, 64, 64)
        for k in names:
            assert b[k].shape == (3, 3, 64, 64) and torch.isfinite(b[k]).all(), k
    assert set(cv.MAP_NAMES) <= set(b)
    # every photo as the runtime feeds the networks: exposed to its encoded mean
    assert (b["photo"].mean((1, 2, 3)) - cv.AUTO_EXPOSURE_MEAN).abs().max() < 0.02


def test_relief_scale_keeps_the_direction_and_changes_the_depth(small_bank):
    bank = bank_mod.Bank(small_bank)
    stored = bank.stored(torch.arange(4))
    g = torch.Generator().manual_seed(5)
    out = bank_mod.linearize(batches.relief_scale(stored, g, 0.5, 0.5))
    before = bank_mod.linearize(stored)["normal"]
    tilt = lambda n: n[:, :2].norm(dim=1)  # noqa: E731
    steep = tilt(before) > 0.1
    assert (tilt(out["normal"])[steep] < tilt(before)[steep]).all()  # shallower
    cos = (F.normalize(out["normal"][:, :2], dim=1) * F.normalize(before[:, :2], dim=1)).sum(1)
    assert (cos[steep] > 0.999).all()  # the same way
    assert torch.allclose(out["normal"].norm(dim=1), torch.ones(()), atol=1e-5)
    a = batches.relief_scale(stored, torch.Generator().manual_seed(1))["normal"]
    b = batches.relief_scale(stored, torch.Generator().manual_seed(1))["normal"]
    assert torch.equal(a, b)


def test_gloss_scale_makes_a_material_glossier_and_keeps_its_pattern(small_bank):
    bank = bank_mod.Bank(small_bank)
    rough = bank.maps(torch.arange(8))["roughness"]
    out = batches.gloss_scale(rough, torch.Generator().manual_seed(2))
    k = out.mean((1, 2, 3)) / rough.mean((1, 2, 3))
    assert (k >= batches.GLOSS_SCALE[0] - 1e-6).all() and (k <= batches.GLOSS_SCALE[1] + 1e-6).all()
    assert float(k.std()) > 0.01  # one factor per sample, not one for all
    assert torch.allclose(out, rough * k.reshape(-1, 1, 1, 1), atol=1e-6)  # the pattern kept
    keep = torch.tensor([True, False] * 4)
    kept = batches.gloss_scale(rough, torch.Generator().manual_seed(2), keep=keep)
    assert torch.equal(kept[keep], rough[keep])  # scanned materials keep their roughness
    assert torch.equal(kept[~keep], out[~keep])  # the others get the same factors as without the mask
    assert not bank.scanned.any()  # a procedural bank
    made = batches.materials(bank, torch.Generator().manual_seed(3), 16, 32)
    assert float(made["roughness"].min()) >= 0.02 and float(made["roughness"].max()) <= 1.0


def test_fast_highlight_removed_matches_the_reference(small_bank):
    bank = bank_mod.Bank(small_bank)
    g = torch.Generator().manual_seed(3)
    maps = batches.materials(bank, g, 6, 96)
    cap = {k: v.float() for k, v in batches.simulate.sample_capture(g, 6).items()}
    shot = batches.photograph(maps, cap, g)
    ref = render_targets.highlight_removed_pair(maps, cap["camera"], shot["intensity"])
    fast = batches.highlight_removed_fast(maps, cap["camera"], shot["intensity"])
    for r, f in zip(ref, fast):
        assert float((r - f).abs().mean()) < 0.03
    # and it is not the photo: the flash image's highlight is gone
    assert float((fast[0] - cv.image_to_encoded(shot["linear"])).abs().mean()) > 0.005


def _four_captures(small_bank):
    """Four bank materials, their sampled captures, and the flash power at which each clips the most
    a fixed power may (:func:`export.engine.batches.highlight_cap`)."""
    bank = bank_mod.Bank(small_bank)
    g = torch.Generator().manual_seed(5)
    maps = batches.materials(bank, g, 4, 64)
    cap = {k: v.float() for k, v in batches.simulate.sample_capture(g, 4).items()}
    unit = render_maps(maps, light=cap["light"], camera=cap["camera"], intensity=1.0)
    return maps, cap, unit, batches.highlight_cap(unit[..., ::4, ::4])


def test_a_fixed_power_photo_that_would_clip_is_exposed_down_and_one_that_would_not_keeps_its_power(small_bank):
    maps, cap, unit, cap_at = _four_captures(small_bank)
    clipped = ((unit[..., ::4, ::4] * cap_at.reshape(-1, 1, 1, 1)).amax(1) >= 1.0).float().mean((1, 2))
    assert (clipped <= batches.MAX_CLIPPED_SHARE + 0.02).all()
    for scale, capped in ((20.0, True), (0.05, False)):  # far above the cap; far below it
        c = dict(cap, power=cap_at * scale)
        shot = batches.photograph(maps, c, torch.Generator().manual_seed(1))
        want = cap_at if capped else cap_at * scale
        assert torch.allclose(shot["intensity"], want, rtol=1e-4), (scale, shot["intensity"], want)


def test_a_batch_photo_is_exposed_as_the_runtime_exposes_it_a_clipped_highlight_grey(small_bank):
    from svbrdf_cli.infer.exposure import auto_exposure_gain

    maps, cap, _, cap_at = _four_captures(small_bank)
    cap["power"] = cap_at * 4.0  # bright: clipped, and mean above the runtime's
    shot = batches.photograph(maps, cap, torch.Generator().manual_seed(1), cap=False)
    seen = batches.as_the_runtime_exposes(shot)
    for i in range(4):
        want = auto_exposure_gain(cv.image_to_linear(shot["photo"][i].permute(1, 2, 0).numpy()))
        got = float(torch.log2(seen["intensity"][i] / shot["intensity"][i]))
        assert abs(got - want) < 0.05, (i, got, want)
        assert abs(float(seen["photo"][i].mean()) - cv.AUTO_EXPOSURE_MEAN) < 0.01
        clipped = shot["photo"][i].amax(0) >= 1.0
        assert clipped.float().mean() > 0.003  # the camera clipped it
        top = float(seen["photo"][i].amax(0)[clipped].min())
        assert top < 0.97 and float(seen["photo"][i].amax(0)[clipped].max()) == pytest.approx(top, abs=1e-5)
    assert torch.allclose(seen["linear"] / shot["linear"].clamp_min(1e-12),
                          (seen["intensity"] / shot["intensity"]).reshape(-1, 1, 1, 1).expand_as(shot["linear"]),
                          rtol=1e-4)


def test_flash_context_and_base_agree_with_numpy():
    g = torch.Generator().manual_seed(1)
    photo = torch.rand(2, 3, 32, 32, generator=g)
    light = torch.tensor([[0.2, -0.1, 2.5], [-0.4, 0.3, 1.8]])
    ctx, base = flash.context(light, light, 32), flash.base(photo, light, light)
    for i in range(2):
        c = flash_fields.context(light[i].numpy(), 32)
        b = flash_fields.base(photo[i].permute(1, 2, 0).numpy(), light[i].numpy())
        assert np.allclose(ctx[i].permute(1, 2, 0).numpy(), c, atol=1e-5)
        assert np.allclose(base[i].permute(1, 2, 0).numpy(), b, atol=1e-4)


def test_base_reads_the_albedo_of_a_matte_photo_at_the_conventions_flash():
    maps = {"normal": torch.tensor([0.0, 0, 1]).reshape(1, 3, 1, 1).expand(1, 3, 64, 64),
            "diffuse": torch.full((1, 3, 64, 64), 0.3), "roughness": torch.ones(1, 1, 64, 64),
            "specular": torch.zeros(1, 3, 64, 64)}
    light = torch.tensor([cv.FLASH_POSITION], dtype=torch.float32)
    photo = render_targets.flash_image(maps, light=light, intensity=cv.FLASH_INTENSITY)
    d = cv.albedo_to_linear(flash.base(photo, light, light)[:, 3:6])
    inside = d[..., 16:48, 16:48]
    assert torch.allclose(inside, torch.full_like(inside, 0.3), atol=0.01)


def test_untrained_chain_returns_the_base_estimate():
    net = nets.build()
    photo = torch.rand(1, 3, 64, 64)
    light = torch.tensor([cv.FLASH_POSITION], dtype=torch.float32)
    base = flash.base(photo, light, light)
    with torch.no_grad():
        _, aux, maps = net.eval()(photo, flash.context(light, light, 64), base)
    assert torch.allclose(aux, photo.repeat(1, 3, 1, 1), atol=1e-6)
    stored = torch.cat([maps[k] for k in cv.MAP_NAMES], 1)
    assert torch.allclose(stored, base, atol=1e-5)


CFG = RunConfig(size=32, batch=2, schedule=(("masks", 6), ("aux", 4), ("maps", 4)), val_samples=2,
                checkpoint_minutes=1e9, eval_minutes=1e9)


def _run(folder, bank_root):
    import dataclasses

    return Run(str(folder), dataclasses.replace(CFG, bank_root=bank_root, bank_count=2 * bank_mod.SHARD),
               log=lambda m: None, des19=[])


def test_a_run_stopped_and_resumed_equals_the_run_that_never_stopped(tmp_path, small_bank):
    torch.manual_seed(0)
    full = _run(tmp_path / "full", small_bank)
    full.train(steps=8, evaluate=False)  # crosses two stage boundaries (3 masks, 2 aux, 2 maps steps)
    part = _run(tmp_path / "part", small_bank)
    part.train(steps=4, evaluate=False)
    del part
    torch.manual_seed(123)  # the process's own state must not matter
    resumed = _run(tmp_path / "part", small_bank)
    assert resumed.step == 4
    resumed.train(steps=4, evaluate=False)
    assert resumed.step == full.step == 7 and resumed.stage is None
    a, b = full.net.state_dict(), resumed.net.state_dict()
    assert all(torch.allclose(a[k], b[k], atol=1e-6, rtol=1e-5) for k in a)
    assert not all(torch.equal(a[k], nets.build().state_dict()[k]) for k in a)  # it did train


def test_a_run_whose_batches_a_child_makes_ahead_is_the_same_run(tmp_path, small_bank, monkeypatch):
    import time

    from export.engine import prefetch

    torch.manual_seed(0)
    alone = _run(tmp_path / "alone", small_bank)
    alone.train(steps=8, evaluate=False)  # crosses two stage boundaries: the child starts again at each
    monkeypatch.setattr(prefetch, "_idle_priority", lambda: None)  # a busy test machine leaves no idle time
    step = Run.train_step
    monkeypatch.setattr(Run, "train_step", lambda self, made=None: (time.sleep(1.0), step(self, made))[1])
    helped = _run(tmp_path / "helped", small_bank)
    helped.train(steps=8, evaluate=False, prefetch=True)
    assert helped.prefetched >= 2  # steps trained on the child's batches
    assert helped.step == alone.step == 7
    a, b = alone.net.state_dict(), helped.net.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert helped.cpu > 0 and helped.prefetcher is None


def test_the_prefetcher_hands_over_each_step_once_skips_ahead_and_stops(tmp_path):
    import time

    from export.engine.prefetch import Prefetcher

    p = Prefetcher(lambda step, stage: (stage, step * 10), "maps", first=5)

    def wait_for(k):
        return p.take(k, wait=60)

    try:
        assert wait_for(5) == ("maps", 50)
        assert p.take(5) is None  # handed over once
        time.sleep(0.5)  # the child has made 6 and 7 and waits
        assert p.take(40) is None  # not made: the trainer makes it itself, the child skips to 41
        assert wait_for(41) == ("maps", 410)
        assert p.spent() >= 0.0
    finally:
        p.close()
    assert not p.process.is_alive()


def test_a_finished_stage_keeps_its_averaged_weights_and_evaluation_sees_them(tmp_path, small_bank):
    import dataclasses

    avg = _run(tmp_path / "avg", small_bank)
    raw = Run(str(tmp_path / "raw"), dataclasses.replace(avg.config, ema_decay=0.0), log=lambda m: None, des19=[])
    avg.train(steps=2, evaluate=False)
    raw.train(steps=2, evaluate=False)
    trained = {k: v.clone() for k, v in avg.net.masks.named_parameters()}
    assert all(torch.equal(trained[k], v) for k, v in raw.net.masks.named_parameters())  # the average changes no step
    assert avg.ema is not None and raw.ema is None
    assert not all(torch.equal(avg.ema[k], trained[k]) for k in trained)
    with avg.averaged() as net:
        assert all(torch.equal(avg.ema[k], p) for k, p in net.masks.named_parameters())
    assert all(torch.equal(trained[k], p) for k, p in avg.net.masks.named_parameters())  # put back
    before = {k: v.clone() for k, v in avg.ema.items()}
    avg.train(steps=1, evaluate=False)  # the masks' last step: the stage ends
    raw.train(steps=1, evaluate=False)
    assert avg.stage == raw.stage == "aux" and avg.ema is None
    last = dict(raw.net.masks.named_parameters())
    for k, p in avg.net.masks.named_parameters():
        assert torch.allclose(p, torch.lerp(before[k], last[k], 1 - avg.config.ema_decay), atol=1e-7), k


def test_a_finished_stage_is_the_same_file_in_every_compact_checkpoint(tmp_path, small_bank):
    run = _run(tmp_path / "run", small_bank)
    run.train(steps=3, evaluate=False)  # the masks finished, the aux stage about to start
    run.save_compact(str(tmp_path / "a"))
    run.train(steps=1, evaluate=False)
    run.save_compact(str(tmp_path / "b"))
    files = sorted(f for f in os.listdir(tmp_path / "a") if f.startswith("part_"))
    same = [f for f in files if os.path.isfile(tmp_path / "b" / f)
            and (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes()]
    assert same == ["part_00.pt"], same
    assert all(k.startswith("/model/masks.") for k in torch.load(tmp_path / "a" / "part_00.pt", weights_only=True))


def test_a_schedule_given_on_resume_is_the_runs_from_then_on(tmp_path, small_bank):
    from click.testing import CliRunner

    from export.engine.cli import main

    run = _run(tmp_path / "run", small_bank)
    run.train(steps=4, evaluate=False)  # 3 masks steps, one aux step: 2 of the aux stage's 4 samples
    assert run.stage == "aux"
    del run
    res = CliRunner().invoke(main, ["train", "--run", str(tmp_path / "run"), "--steps", "1", "--checkpoint", "",
                                    "--schedule", "masks=6,aux=2,maps=4"])
    assert res.exit_code == 0, res.output
    resumed = Run(str(tmp_path / "run"), log=lambda m: None, des19=[])  # the run's saved configuration
    assert resumed.config.schedule == (("masks", 6), ("aux", 2), ("maps", 4))
    assert resumed.stage == "maps" and resumed.step == 5  # the aux stage had its 2 samples: one maps step
    res = CliRunner().invoke(main, ["train", "--run", str(tmp_path / "run"), "--schedule", "aux=2,masks=6,maps=4"])
    assert res.exit_code == 2 and "in that order" in res.output


def test_a_restarted_stage_starts_again_and_the_run_keeps_its_counts(tmp_path, small_bank):
    from click.testing import CliRunner

    from export.engine.cli import main

    run = _run(tmp_path / "run", small_bank)
    run.train(steps=6, evaluate=False)  # 3 masks, 2 aux, 1 maps step
    assert run.stage == "maps"
    trained = {k: v.clone() for k, v in run.net.state_dict().items()}
    old_weights = dict(CFG.weights, relief=0.0)
    run.config = dataclasses.replace(run.config, weights=tuple(old_weights.items()))
    run.save()
    del run
    res = CliRunner().invoke(main, ["train", "--run", str(tmp_path / "run"), "--steps", "0", "--checkpoint", "",
                                    "--restart-stage", "maps"])
    assert res.exit_code == 0, res.output
    again = Run(str(tmp_path / "run"), log=lambda m: None, des19=[])
    assert (again.step, again.samples, again.stage, again.stage_samples) == (6, 12, "maps", 0)
    assert dict(again.config.weights) == dict(RunConfig().weights)  # this code's loss settings
    torch.manual_seed(CFG.seed)
    start = nets.build().state_dict()  # the run's seeded start
    now = again.net.state_dict()
    assert all(torch.equal(now[k], start[k]) for k in now if k.startswith("maps."))
    assert all(torch.equal(now[k], trained[k]) for k in now if not k.startswith("maps."))
    assert not all(torch.equal(now[k], start[k]) for k in now if k.startswith("masks."))
    res = CliRunner().invoke(main, ["train", "--run", str(tmp_path / "run"), "--restart-stage", "shading"])
    assert res.exit_code == 2


JOINT_CFG = dataclasses.replace(CFG, schedule=CFG.schedule + (("joint", 8),), real_fraction=0.0)


def _joint_run(folder, bank_root, **changes):
    return Run(str(folder), dataclasses.replace(JOINT_CFG, bank_root=bank_root, bank_count=2 * bank_mod.SHARD, **changes),
               log=lambda m: None, des19=[])


def test_the_joint_stage_trains_every_stage_at_its_own_rate(tmp_path, small_bank):
    run = _joint_run(tmp_path / "run", small_bank, ema_decay=0.0)
    run.train(steps=7, evaluate=False)  # 3 masks, 2 aux, 2 maps steps
    assert run.stage == "joint" and run.stage_samples == 0
    before = {k: v.clone() for k, v in run.net.state_dict().items()}
    run.train(steps=1, evaluate=False)
    after = run.net.state_dict()
    for stage in ("masks", "aux", "maps"):  # the maps stage alone leaves the others as they are
        assert any(not torch.equal(before[k], after[k]) for k in after if k.startswith(stage + ".")), stage
    assert run.optimizer.param_groups[0]["lr"] == pytest.approx(JOINT_CFG.joint_lr)
    run.train(steps=3, evaluate=False)
    assert run.stage is None and run.stage_samples == 0


def test_the_joint_loss_is_the_maps_loss_plus_the_masks_and_aux_held_to_their_targets(small_bank):
    from export.engine.run import INTERMEDIATE, joint_loss, stage_loss

    net = _speaking_net()
    b = batches.make(bank_mod.Bank(small_bank), torch.Generator().manual_seed(3), 2, 32, "joint")
    net.loss_weights = dict(CFG.weights, masks=0.0, aux=0.0)
    with torch.no_grad():
        maps_only = float(stage_loss(net, "maps", b))
        assert float(joint_loss(net, b)) == pytest.approx(maps_only, rel=1e-5)
        masks = net.run_masks(b["photo"], b["context"])
        aux = net.run_aux(b["photo"], masks.clamp(0, 1), b["context"])
        m_err = float(((masks.float() - torch.cat([b["M_b"], b["M_h"]], 1)) ** 2).mean())
        a_err = float((aux.float() - torch.cat([b["I_bf"], b["I_hr"], b["I_hr2"]], 1)).abs().mean())
        net.loss_weights = dict(CFG.weights, masks=3.0, aux=2.0)
        assert float(joint_loss(net, b)) == pytest.approx(maps_only + 3.0 * m_err + 2.0 * a_err, rel=1e-3)
        net.loss_weights = dict(CFG.weights)  # a run that does not weigh them: the defaults
        want = maps_only + INTERMEDIATE["masks"] * m_err + INTERMEDIATE["aux"] * a_err
        assert float(joint_loss(net, b)) == pytest.approx(want, rel=1e-3)


def test_real_photos_reach_the_masks_only_in_the_joint_stage():
    from export.engine.run import real_loss

    net = _speaking_net().train()
    g = torch.Generator().manual_seed(0)
    b = {"photo": torch.rand(2, 3, 64, 64, generator=g) * 0.5, "light": torch.tensor([[0.1, 0.0, 2.4]] * 2)}
    grads = {}
    for stage in ("maps", "joint"):
        net.zero_grad(set_to_none=True)
        real_loss(net, b, stage).backward()
        grads[stage] = {s: [p.grad for p in getattr(net, s).parameters()] for s in ("masks", "aux", "maps")}
    assert all(x is None for x in grads["maps"]["masks"] + grads["maps"]["aux"])
    assert any(x is not None and bool(x.abs().sum() > 0) for x in grads["maps"]["maps"])
    for s in ("masks", "aux", "maps"):
        assert any(x is not None and bool(x.abs().sum() > 0) for x in grads["joint"][s]), s


def test_a_run_stopped_and_resumed_in_the_joint_stage_equals_the_run_that_never_stopped(tmp_path, small_bank):
    full = _joint_run(tmp_path / "full", small_bank)
    full.train(steps=10, evaluate=False)
    part = _joint_run(tmp_path / "part", small_bank)
    part.train(steps=8, evaluate=False)  # one joint step in
    part.save_compact(str(tmp_path / "compact"))
    del part
    resumed = _resumed_elsewhere(tmp_path, small_bank, JOINT_CFG)
    assert resumed.step == 8 and resumed.stage == "joint"
    resumed.train(steps=2, evaluate=False)
    _assert_the_same_run(full, resumed)
    assert set(full.ema) == {k for k, _ in full.net.named_parameters()}  # the average is the whole chain's


def test_a_schedule_may_end_with_the_joint_stage_and_nowhere_else():
    from export.engine.cli import _schedule

    assert _schedule("masks=6,aux=2,maps=4,joint=3")[-1] == ("joint", 3)
    for bad in ("joint=3,masks=6,aux=2,maps=4", "masks=6,aux=2,joint=3,maps=4", "masks=6,aux=2,maps=4,joint=0"):
        with pytest.raises(Exception, match="joint=N after them"):
            _schedule(bad)


def test_the_relief_term_rewards_the_tilt_pattern_at_any_depth():
    from export.engine.run import relief_loss

    g = torch.Generator().manual_seed(0)
    tilt = torch.randn(2, 2, 16, 16, generator=g) * 0.1
    truth = cv.encode_normals(cv.normalize(torch.cat([tilt, torch.ones(2, 1, 16, 16)], 1), axis=1))
    shallow = cv.encode_normals(cv.normalize(torch.cat([tilt * 0.2, torch.ones(2, 1, 16, 16)], 1), axis=1))
    flipped = cv.encode_normals(cv.normalize(torch.cat([-tilt, torch.ones(2, 1, 16, 16)], 1), axis=1))
    flat = cv.encode_normals(torch.tensor([0.0, 0.0, 1.0]).reshape(1, 3, 1, 1).expand(2, 3, 16, 16))
    assert float(relief_loss(shallow, truth)) < 1e-3
    assert abs(float(relief_loss(flat, truth)) - 1.0) < 1e-6
    assert float(relief_loss(flipped, truth)) > 1.99


def test_the_render_term_scores_the_maps_relit_and_trains_the_roughness():
    from export.engine.run import RENDER_EACH, render_loss, render_views

    g = torch.Generator().manual_seed(0)
    lights, cameras = render_views(g, 2)
    assert lights.shape == cameras.shape == (3 * RENDER_EACH, 2, 3)
    assert bool((lights[..., 2] > 0).all() and (cameras[..., 2] > 0).all())  # all above the surface
    tilt = torch.randn(2, 2, 128, 128, generator=g) * 0.1
    truth = {"normal": cv.encode_normals(cv.normalize(torch.cat([tilt, torch.ones(2, 1, 128, 128)], 1), axis=1)),
             "diffuse": torch.full((2, 3, 128, 128), 0.5), "roughness": torch.full((2, 1, 128, 128), 0.3),
             "specular": torch.full((2, 3, 128, 128), 0.2)}
    assert float(render_loss(truth, truth, lights, cameras)) < 1e-6
    rough = torch.full((2, 1, 128, 128), 0.7, requires_grad=True)
    loss = render_loss(dict(truth, roughness=rough), truth, lights, cameras)
    loss.backward()
    assert float(loss) > 0.01
    assert float(rough.grad.sum()) > 0  # lowering the too-rough map lowers the loss
    # validation batches carry no lights: the term is left out, so the validation loss keeps its meaning
    from export.engine.run import maps_loss

    weights = {"roughness": 1.0, "render": 0.5}
    with_lights = dict(truth, lights=lights, cameras=cameras)
    plain = float(maps_loss(dict(truth, roughness=rough), truth, weights))
    assert plain == pytest.approx(0.4, abs=1e-5)
    assert float(maps_loss(dict(truth, roughness=rough), with_lights, weights)) == pytest.approx(plain + 0.5 * float(loss))


def test_real_batches_cost_f0_under_a_dielectrics_when_the_run_weighs_it():
    from export.engine import real
    from export.engine.run import real_loss

    zero, dielectric, metal = (torch.full((2, 3, 8, 8), v) for v in (0.0, real.F0_FLOOR, 0.8))
    assert float(real.f0_floor_loss(dielectric)) == pytest.approx(0.0, abs=1e-7)
    assert float(real.f0_floor_loss(metal)) == 0.0
    low = zero.clone().requires_grad_(True)
    real.f0_floor_loss(low).backward()
    assert float(real.f0_floor_loss(zero)) == pytest.approx(real.F0_FLOOR) and bool((low.grad < 0).all())

    net = _speaking_net()
    maps = {"normal": cv.encode_normals(torch.tensor([0.0, 0.0, 1.0]).reshape(1, 3, 1, 1).expand(2, 3, 64, 64)),
            "diffuse": torch.full((2, 3, 64, 64), 0.5), "roughness": torch.full((2, 1, 64, 64), 0.4),
            "specular": torch.zeros(2, 3, 64, 64)}
    net.run_maps = lambda *args: maps  # a chain that says F0 is 0
    g = torch.Generator().manual_seed(0)
    b = {"photo": torch.rand(2, 3, 64, 64, generator=g) * 0.5, "light": torch.tensor([[0.1, 0.0, 2.4]] * 2)}
    net.loss_weights = {"real_f0": 0.0}
    plain = float(real_loss(net, b))
    net.loss_weights = {"real_f0": 2.0}
    assert float(real_loss(net, b)) == pytest.approx(plain + 2.0 * real.F0_FLOOR, rel=1e-5)


def test_a_weight_given_on_resume_is_the_runs_from_then_on(tmp_path, small_bank):
    from click.testing import CliRunner

    from export.engine.cli import main

    run = _run(tmp_path / "run", small_bank)
    run.train(steps=6, evaluate=False)  # into the maps stage
    run.save()
    del run
    res = CliRunner().invoke(main, ["train", "--run", str(tmp_path / "run"), "--steps", "1", "--checkpoint", "",
                                    "--weight", "render=0.25", "--weight", "relief=0"])
    assert res.exit_code == 0, res.output
    again = Run(str(tmp_path / "run"), log=lambda m: None, des19=[])
    assert dict(again.config.weights) == dict(CFG.weights, render=0.25, relief=0.0) and again.step == 7
    res = CliRunner().invoke(main, ["train", "--run", str(tmp_path / "run"), "--weight", "shading=1"])
    assert res.exit_code == 2 and "NAME is one of" in res.output
    res = CliRunner().invoke(main, ["train", "--run", str(tmp_path / "run"), "--steps", "1", "--checkpoint", "",
                                    "--halve-every", "3"])
    assert res.exit_code == 0, res.output
    halved = Run(str(tmp_path / "run"), log=lambda m: None, des19=[])
    halved.stage_samples = 7
    assert halved.config.halve_every == 3 and halved._lr() == pytest.approx(halved.config.lr / 4)  # kept, in force


def test_sigterm_saves_and_exits_zero(tmp_path, small_bank):
    folder = tmp_path / "run"
    code = (
        "import dataclasses, os, signal, sys, threading\n"
        "sys.path.insert(0, sys.argv[3])\n"
        "from export.engine.run import Run, RunConfig\n"
        "cfg = RunConfig(size=32, batch=2, schedule=(('masks', 10**9),), val_samples=2,\n"
        "                checkpoint_minutes=1e9, eval_minutes=1e9, bank_root=sys.argv[2], bank_count=32)\n"
        "run = Run(sys.argv[1], cfg, log=lambda m: None, des19=[])\n"
        "threading.Timer(3.0, lambda: os.kill(os.getpid(), signal.SIGTERM)).start()\n"
        "run.train(evaluate=False)\n"
        "print('stopped at', run.step)\n"
    )
    res = subprocess.run([sys.executable, "-c", code, str(folder), small_bank, ROOT], capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 0, res.stderr
    state = torch.load(folder / "state.pt", weights_only=False)
    assert state["step"] == int(res.stdout.split()[-1]) > 0
    assert signal.getsignal(signal.SIGTERM) is not None


def test_a_compact_checkpoint_resumes_the_run_exactly(tmp_path, small_bank):
    full = _run(tmp_path / "full", small_bank)
    full.train(steps=6, evaluate=False)
    part = _run(tmp_path / "part", small_bank)
    part.train(steps=4, evaluate=False)  # in the aux stage: masks trained, maps not yet
    import export.engine.run as run_mod

    old = run_mod.PART_BYTES
    run_mod.PART_BYTES = 200_000  # several parts even for these small networks
    try:
        part.save_compact(str(tmp_path / "compact"))
    finally:
        run_mod.PART_BYTES = old
    files = sorted(os.listdir(tmp_path / "compact"))
    assert "manifest.json" in files and sum(f.startswith("part_") for f in files) > 1
    assert not any(k.startswith("maps.") for k in run_mod.read_compact(str(tmp_path / "compact"))["model"])
    del part
    resumed = _resumed_elsewhere(tmp_path, small_bank, CFG)
    assert resumed.step == 4 and resumed.stage == "aux"
    resumed.train(steps=2, evaluate=False)
    _assert_the_same_run(full, resumed)


def _resumed_elsewhere(tmp_path, small_bank, cfg):
    """A run of ``cfg`` in a new folder, resumed from the compact checkpoint ``tmp_path/compact``."""
    return Run(str(tmp_path / "elsewhere"), dataclasses.replace(cfg, bank_root=small_bank, bank_count=32),
               log=lambda m: None, des19=[], checkpoint=str(tmp_path / "compact"))


def _assert_the_same_run(full, resumed):
    a, b = full.net.state_dict(), resumed.net.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert full.ema is not None and all(torch.equal(full.ema[k], resumed.ema[k]) for k in full.ema)


def _speaking_net():
    """The engine's chain, seeded, its zero heads given something to say."""
    torch.manual_seed(0)
    net = nets.build().eval()
    for m in (net.aux, net.maps):
        torch.nn.init.normal_(m.head.weight, std=0.01)
    return net


def test_the_exported_chain_matches_torch(tmp_path):
    ort = pytest.importorskip("onnxruntime")
    from export.engine import onnx as engine_onnx

    net = _speaking_net()
    path = engine_onnx.export(net, str(tmp_path / "chain.onnx"), provenance={"test": True})
    photo = torch.rand(1, 3, 96, 64)
    light = torch.tensor([[0.1, 0.2, 2.4]])
    feeds = {"photo": photo, "context": flash.context(light, light, 96)[..., :64], "base": flash.base(photo, light, light)}
    with torch.no_grad():
        masks, aux, maps = net(**feeds)
    sess = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
    got = sess.run(None, {k: v.numpy() for k, v in feeds.items()})
    want = [masks, aux.clamp(0, 1), torch.cat([maps[k] for k in cv.MAP_NAMES], 1)]
    for g, w in zip(got, want):
        assert g.shape == tuple(w.shape)
        assert np.abs(g - w.numpy()).max() < 1e-4


def test_the_runtime_runs_the_exported_chain_as_torch_does(tmp_path):
    pytest.importorskip("onnxruntime")
    from click.testing import CliRunner

    from export.engine import onnx as engine_onnx
    from svbrdf_cli.cli.main import cli
    from svbrdf_cli.infer.chain import padding
    from svbrdf_cli.infer.swift import MARGIN
    from svbrdf_cli.infer.registry import load_model

    net = _speaking_net()
    folder = tmp_path / "swift"
    engine_onnx.export(net, str(folder / "chain.onnx"), provenance={"samples": 7})
    model = load_model(str(folder))
    model.passes = ((0, False),)  # one pass: the network's own outputs (the averaging has its own test)
    g = torch.Generator().manual_seed(3)
    photo = (0.3 + 0.4 * torch.rand(1, 3, 96, 96, generator=g)).clamp(0, 1)
    img = photo[0].permute(1, 2, 0).numpy()
    out = model.network(img)
    light = torch.from_numpy(model.flash(img)).float()[None]
    m, pad, mode = padding(96, 96, 32, MARGIN)  # the runtime's reflected margin, made here the same way

    def padded(x):
        return torch.from_numpy(np.pad(x[0].permute(1, 2, 0).numpy(), pad, mode=mode)).permute(2, 0, 1)[None]

    with torch.no_grad():
        masks, aux, maps = net(padded(photo), padded(flash.context(light, light, 96)),
                               padded(flash.base(photo, light, light)))
    for k in cv.MAP_NAMES:
        want = maps[k][0].permute(1, 2, 0).numpy()[m:m + 96, m:m + 96]
        assert np.abs(out[k] - want).max() < 1e-3, k
    assert np.abs(out["M_h"] - masks[0, 3:].permute(1, 2, 0).numpy()[m:m + 96, m:m + 96]).max() < 1e-3
    assert np.abs(out["I_hr2"] - aux[0, 6:].clamp(0, 1).permute(1, 2, 0).numpy()[m:m + 96, m:m + 96]).max() < 1e-3
    assert model.describe()["trained"] == {"samples": 7}
    res = CliRunner().invoke(cli, ["capture", os.path.join(ROOT, "examples", "glazed_tiles.jpg"), "-o",
                                   str(tmp_path / "out"), "--model", str(folder), "--debug", "--size", "256"])
    assert res.exit_code == 0, res.output
    debug = sorted(os.listdir(tmp_path / "out" / "glazed_tiles" / "debug"))
    assert {"M_b.png", "M_h.png", "I_bf.png", "I_hr.png", "I_hr2.png"} <= set(debug), debug


@pytest.mark.parametrize("passes", [None, ((1, False), (3, False))])
@pytest.mark.parametrize("shape", [(96, 96), (64, 96)])
def test_the_runtime_averages_the_photo_turned(tmp_path, shape, passes):
    """The maps are the mean of the chain's on the photo turned as each pass says (``PASSES``: as it is
    and half round), its flash turned alike, brought back; the normals unit vectors again. A photo that
    is not square too, on the quarter turns (its sides swapped)."""
    pytest.importorskip("onnxruntime")
    from export.engine import onnx as engine_onnx
    from svbrdf_cli.infer import tta
    from svbrdf_cli.infer.registry import load_model
    from svbrdf_cli.infer.swift import PASSES

    assert PASSES == ((0, False), (2, False))
    net = _speaking_net()
    folder = tmp_path / "swift"
    engine_onnx.export(net, str(folder / "chain.onnx"), provenance={})
    model = load_model(str(folder))
    g = torch.Generator().manual_seed(4)
    img = (0.3 + 0.4 * torch.rand(*shape, 3, generator=g)).numpy()
    light = np.array([0.2, -0.3, 2.4])
    both = model.run_at(img, light, None, passes=passes)
    (k1, _), (k2, _) = passes or PASSES

    def turned(k):  # the chain's maps on the photo turned k quarters (one pass), brought back
        maps = model.run_at(tta.transform_image(img, k, False), tta.transform_point(light, k, False), None,
                            passes=((0, False),))
        return tta.untransform_maps({n: v for n, v in maps.items() if n in cv.MAP_NAMES}, k, False)

    one, two = turned(k1), turned(k2)
    for k in ("diffuse", "roughness", "specular"):
        assert np.abs(both[k] - (one[k] + two[k]) / 2).max() < 1e-4, k
    n = cv.normalize(cv.decode_normals((one["normal"] + two["normal"]) / 2))
    assert np.abs(cv.decode_normals(both["normal"]) - n).max() < 1e-3
    assert np.allclose(np.linalg.norm(cv.decode_normals(both["normal"]), axis=-1), 1.0, atol=1e-4)
    assert np.abs(one["diffuse"] - two["diffuse"]).max() > 1e-3  # the passes differ: the test can fail


def test_the_runtime_runs_the_chain_at_the_size_it_trained_at(tmp_path):
    """A photo larger than the run's image size is shrunk to it, and the maps come back to the photo's size:
    roughness and specular bicubic, the diffuse with the photo's detail (``to_photo_size``)."""
    pytest.importorskip("onnxruntime")
    import cv2

    from export.engine import onnx as engine_onnx
    from svbrdf_cli.imageops import shrink_to
    from svbrdf_cli.infer.chain import padding
    from svbrdf_cli.infer.swift import MARGIN, to_photo_size
    from svbrdf_cli.infer.registry import load_model

    net = _speaking_net()
    folder = tmp_path / "swift"
    engine_onnx.export(net, str(folder / "chain.onnx"), provenance={}, run_size=64)
    model = load_model(str(folder))
    model.passes = ((0, False),)
    assert model.run_size == 64
    g = torch.Generator().manual_seed(5)
    img = (0.3 + 0.4 * torch.rand(128, 128, 3, generator=g)).numpy()
    out = model.run_at(img, model.flash(img), model.run_size)  # the network's reading at the run's size (the
    assert all(v.shape[:2] == (128, 128) for v in out.values())  # second sizes' have their own test)
    small = shrink_to(img, (64, 64))
    photo = torch.from_numpy(small).permute(2, 0, 1)[None]
    light = torch.from_numpy(model.flash(img)).float()[None]
    m, pad, mode = padding(64, 64, 32, MARGIN)

    def padded(x):
        return torch.from_numpy(np.pad(x[0].permute(1, 2, 0).numpy(), pad, mode=mode)).permute(2, 0, 1)[None]

    with torch.no_grad():
        _, _, maps = net(padded(photo), padded(flash.context(light, light, 64)), padded(flash.base(photo, light, light)))
    for k in ("diffuse", "roughness", "specular"):
        low = np.ascontiguousarray(maps[k][0].permute(1, 2, 0).numpy()[m:m + 64, m:m + 64])
        if k == "diffuse":
            want = to_photo_size({k: low}, small, img)[k]
        else:
            want = np.clip(cv2.resize(low, (128, 128), interpolation=cv2.INTER_CUBIC), 0, 1)
        assert np.abs(out[k] - want.reshape(out[k].shape)).max() < 1e-3, k
    n = out["normal"] * 2 - 1
    assert np.allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-4)
    # the maps are the network's at 64 px: no detail finer than the shrunk photo's
    assert np.abs(out["roughness"][::2, ::2] - out["roughness"][1::2, 1::2]).mean() < 0.02


def test_the_normals_are_also_read_at_the_second_sizes_and_averaged(tmp_path):
    """A photo larger than the run's size: the maps are the chain's at the run's size but the normals, the
    unit mean of its normals there (on ``PASSES``) and at each of ``SECOND_SIZES`` (on the quarter turns,
    ``SECOND_PASSES``); a photo no larger than the run's size is read once."""
    pytest.importorskip("onnxruntime")
    from export.engine import onnx as engine_onnx
    from svbrdf_cli.infer import swift
    from svbrdf_cli.infer.registry import load_model

    assert swift.SECOND_SIZES == (160,) and swift.SECOND_PASSES == ((1, False), (3, False))
    assert swift.SECOND_MAPS == ("normal",)
    net = _speaking_net()
    folder = tmp_path / "swift"
    engine_onnx.export(net, str(folder / "chain.onnx"), provenance={}, run_size=64)
    model = load_model(str(folder))
    g = torch.Generator().manual_seed(6)
    img = (0.3 + 0.4 * torch.rand(192, 192, 3, generator=g)).numpy()
    light = np.array([0.1, 0.2, 2.2])
    model.flash = lambda image: light
    out = model.network(img)
    at64, at160 = model.run_at(img, light, 64), model.run_at(img, light, 160, passes=swift.SECOND_PASSES)
    for k in ("diffuse", "roughness", "specular", "M_h", "I_hr"):
        assert np.array_equal(out[k], at64[k]), k
    mean = cv.normalize(cv.decode_normals(at64["normal"]) + cv.decode_normals(at160["normal"]))
    assert np.abs(cv.decode_normals(out["normal"]) - mean).max() < 2e-3
    assert np.abs(at64["normal"] - at160["normal"]).max() > 1e-2  # the two readings differ: the test can fail
    halves = model.run_at(img, light, 160)  # on PASSES: the quarter turns are what is read at 160
    assert np.abs(halves["normal"] - at160["normal"]).max() > 1e-3
    small = img[:64, :64]
    assert np.array_equal(model.network(small)["normal"], model.run_at(small, light, 64)["normal"])


def test_the_engine_exports_the_averaged_weights_and_the_run_size(tmp_path, small_bank):
    ort = pytest.importorskip("onnxruntime")
    pytest.importorskip("onnx")
    from click.testing import CliRunner

    from export.engine.cli import main

    run = _run(tmp_path / "run", small_bank)
    run.train(steps=2, evaluate=False)  # masks stage: their average differs from their weights
    res = CliRunner().invoke(main, ["onnx", "--run", str(tmp_path / "run"), "--out", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    sess = ort.InferenceSession(str(tmp_path / "out" / "chain.onnx"), providers=["CPUExecutionProvider"])
    meta = sess.get_modelmeta().custom_metadata_map
    assert meta["run_size"] == "32" and '"moving average"' in meta["provenance"]
    photo = torch.rand(1, 3, 64, 64, generator=torch.Generator().manual_seed(1))
    light = torch.tensor([[0.0, 0.0, 2.4]])
    feeds = {"photo": photo, "context": flash.context(light, light, 64), "base": flash.base(photo, light, light)}
    got = sess.run(["masks"], {k: v.numpy() for k, v in feeds.items()})[0]
    net = run.net.eval().float()
    with torch.no_grad():
        with run.averaged():
            want = net.run_masks(feeds["photo"], feeds["context"]).clamp(0, 1).numpy()
        trained = net.run_masks(feeds["photo"], feeds["context"]).clamp(0, 1).numpy()
    assert np.abs(got - want).max() < 1e-4
    assert np.abs(got - trained).max() > 1e-4


def test_the_runs_twin_of_the_runtime_gives_the_exported_chains_maps(tmp_path):
    """What the run scores the card with (:func:`export.engine.run.runtime_twin`) is what ``svbrdf capture`` runs."""
    pytest.importorskip("onnxruntime")
    from export.engine import onnx as engine_onnx
    from export.engine.run import runtime_twin
    from svbrdf_cli.infer.registry import load_model

    net = _speaking_net()
    engine_onnx.export(net, str(tmp_path / "swift" / "chain.onnx"), provenance={}, run_size=64)
    g = torch.Generator().manual_seed(7)
    img = (0.2 + 0.5 * torch.rand(128, 128, 3, generator=g)).numpy()
    img[50:60, 60:70] = 1.0  # a clipped highlight: the fill runs too
    want = load_model(str(tmp_path / "swift"))(img)
    got = runtime_twin(net, 64)(img)
    for k in cv.MAP_NAMES:
        assert got[k].shape == want[k].shape
        assert np.abs(got[k] - want[k]).mean() < 5e-3, k  # bf16 against fp32


def test_the_run_scores_its_chain_on_generated_captures_under_known_lights():
    """``known_lights`` in ``curve.jsonl``: the chain's maps as ``svbrdf capture`` makes them, relit under
    each capture's known lights; the true maps relight far better, so the score can tell."""
    from export.engine import known_lights
    from export.engine.run import score_known_lights

    caps = [known_lights.generate(i, size=64) for i in range(2)]
    got = score_known_lights(_speaking_net(), caps, 64, refine_steps=5)
    assert set(got) == {"known_lights", "known_lights_refined"}
    truth = np.mean([known_lights.score(c["truth"], c) for c in caps])
    assert 0 < truth < 0.5 * got["known_lights"] < 1 and 0 < got["known_lights_refined"] < 1


def test_the_run_scores_the_card_with_its_maps_as_the_command_writes_them():
    """``card`` in ``curve.jsonl``: photo 00's maps with the diffuse brought back to the photo as shot, as
    ``svbrdf capture`` writes them (``docs/conventions.md``), not at the level exposed for the networks."""
    from export.engine.run import load_card, score_card

    card = load_card()
    if card is None:
        pytest.skip("needs ../shared/data/real/card_blue_9lights")
    got = score_card(_speaking_net(), card, 64, refine_steps=0)
    assert set(got) == {"card", "card_refined"} and 0 < got["card"] < 1
    from export.engine.run import captured_maps, runtime_twin

    exposed, _ = captured_maps(runtime_twin(_speaking_net(), 64), card.network_input(), 0)
    assert abs(card.relight_rmse(exposed) - got["card"]) > 1e-4  # photo 00 was exposed down: a brighter diffuse


def test_the_f0_target_at_the_photos_level_scales_as_the_diffuse():
    g = torch.Generator().manual_seed(6)
    up = torch.tensor([0, 0, 2.0]).reshape(1, 3, 1, 1)
    maps = {"normal": F.normalize(torch.rand(2, 3, 8, 8, generator=g) + up, dim=1),
            "diffuse": 0.5 * torch.rand(2, 3, 8, 8, generator=g), "roughness": torch.rand(2, 1, 8, 8, generator=g),
            "specular": torch.full((2, 3, 8, 8), 0.04)}
    level = torch.tensor([0.5, 2.0]).reshape(-1, 1, 1, 1)
    plain = cv.decode_maps(batches.stored_targets(maps, level), axis=1)
    scaled = cv.decode_maps(batches.stored_targets(maps, level, "photo"), axis=1)
    assert torch.allclose(plain["specular"], maps["specular"], atol=1e-5)  # the material's F0
    assert torch.allclose(scaled["specular"], maps["specular"] * level, atol=1e-5)  # read as the diffuse is
    assert torch.allclose(scaled["diffuse"], plain["diffuse"])
    assert torch.allclose(scaled["diffuse"], maps["diffuse"] * level, atol=1e-5)
    with pytest.raises(ValueError):
        batches.stored_targets(maps, level, "relative")


def test_an_export_trained_on_f0_at_the_photos_level_has_its_f0_scaled_as_the_diffuse(tmp_path):
    """The export records the F0 target; ``svbrdf capture`` then brings F0 to the photo as shot with the
    diffuse (both twice as bright from a photo one stop brighter), and keeps an absolute model's F0."""
    pytest.importorskip("onnxruntime")
    import json

    from click.testing import CliRunner

    from export.engine import onnx as engine_onnx
    from svbrdf_cli.cli.main import cli
    from svbrdf_cli.infer.chain import ModelError
    from svbrdf_cli.imageio import read_image
    from svbrdf_cli.infer.registry import load_model

    net = _speaking_net()
    specs = {}
    for level in ("absolute", "photo"):
        folder = tmp_path / level
        engine_onnx.export(net, str(folder / "chain.onnx"), provenance={}, run_size=64, specular_level=level)
        assert load_model(str(folder)).specular_level == level
        for stops in ("0", "1"):
            out = tmp_path / f"out-{level}-{stops}"
            res = CliRunner().invoke(cli, ["capture", os.path.join(ROOT, "examples", "glazed_tiles.jpg"), "-o", str(out),
                                           "--model", str(folder), "--size", "256", "--no-preview", "--refine", "0",
                                           "--exposure", stops])
            assert res.exit_code == 0, res.output
            specs[level, stops] = cv.albedo_to_linear(read_image(str(out / "glazed_tiles" / "specular.png")))
            assert json.loads((out / "glazed_tiles" / "material.json").read_text())["albedo_level"]["scale"] == 1.0
    # --exposure STOPS reads the photo as exposed: the network sees a brighter photo at 1 stop
    for stops in ("0", "1"):
        assert np.abs(specs["absolute", stops] - specs["photo", stops]).max() < 2e-2  # the same network, scale 1
    res = {}
    for level in ("absolute", "photo"):
        folder = tmp_path / level
        out = tmp_path / f"auto-{level}"
        r = CliRunner().invoke(cli, ["capture", os.path.join(ROOT, "examples", "glazed_tiles.jpg"), "-o", str(out),
                                     "--model", str(folder), "--size", "256", "--no-preview", "--refine", "0"])
        assert r.exit_code == 0, r.output
        rec = json.loads((out / "glazed_tiles" / "material.json").read_text())
        assert rec["model"]["specular_level"] == level and rec["albedo_level"]["specular_scaled"] == (level == "photo")
        res[level] = (cv.albedo_to_linear(read_image(str(out / "glazed_tiles" / "specular.png"))), rec["albedo_level"]["scale"])
    engine_onnx.export(net, str(tmp_path / "odd" / "chain.onnx"), provenance={}, specular_level="relative")
    with pytest.raises(ModelError, match="relative"):
        load_model(str(tmp_path / "odd"))
    (absolute, scale), (photo, _) = res["absolute"], res["photo"]
    assert abs(scale - 1.0) > 0.2  # the sample is exposed by the tool, so the scaling shows
    ok = (photo > 0.005) & (photo < 0.99)
    assert np.abs(np.median(photo[ok] / np.maximum(absolute[ok], 1e-6)) - scale) < 0.05 * scale


def test_bf16_autocast_only_where_the_cpu_has_it(tmp_path, monkeypatch):
    from export.engine import run as run_mod

    monkeypatch.delenv("SVBRDF_AUTOCAST", raising=False)
    avx2, bf16 = tmp_path / "avx2", tmp_path / "bf16"
    avx2.write_text("processor\t: 0\nflags\t\t: fpu sse avx2 fma\n")
    bf16.write_text("processor\t: 0\nflags\t\t: fpu avx2 avx512f avx512_bf16\n")
    assert not run_mod.native_bf16(str(avx2)) and run_mod.native_bf16(str(bf16))
    assert not run_mod.native_bf16(str(tmp_path / "missing"))
    monkeypatch.setenv("SVBRDF_AUTOCAST", "bf16")
    assert run_mod.native_bf16(str(avx2))
    monkeypatch.setenv("SVBRDF_AUTOCAST", "fp32")
    assert not run_mod.native_bf16(str(bf16))


def test_the_flash_context_can_be_the_runtimes_fit_on_the_photo(small_bank):
    """``--flash-context fit``: the networks get the flash where ``svbrdf capture`` reads it from the photo
    (its foot found in the photo, its height one of the fit's grid), not the true one jittered."""
    from svbrdf_cli.infer.physical import HEIGHT_GRID

    g = torch.Generator().manual_seed(3)
    b = batches.make(bank_mod.Bank(small_bank), g, 4, 64, "maps", flash_context="fit")
    seen = batches.fitted_flash(b["photo"])
    assert torch.allclose(b["context"], flash.context(seen, seen, 64))  # what the batch's context was made from
    grid = HEIGHT_GRID * cv.CAMERA_HEIGHT
    assert all(np.abs(grid - h).min() < 1e-3 for h in seen[:, 2].tolist())
    assert (seen[:, :2] - b["light"][:, :2]).abs().max() < 0.6  # the highlight's foot, near the flash's
    jitter = batches.context_flash(b["photo"], b["light"], torch.Generator().manual_seed(0), "jitter")
    assert ((jitter[:, 2] / b["light"][:, 2]).log().abs() < 0.5).all()
    with pytest.raises(ValueError):
        batches.context_flash(b["photo"], b["light"], g, "exif")


def test_des19_is_scored_with_the_flash_the_run_trains_the_chain_with():
    """``flash_context`` "fit": the run scores Des19 with the flash where the runtime reads it from each input,
    as it trains the chain; else at the conventions' position. A chain that reads its context scores the two
    differently."""
    from export.engine.run import score_des19

    g = torch.Generator().manual_seed(5)
    photo = 0.2 + 0.1 * torch.rand(1, 3, 64, 64, generator=g)
    y, x = torch.meshgrid(torch.linspace(-1, 1, 64), torch.linspace(-1, 1, 64), indexing="ij")
    photo = (photo + 0.7 * torch.exp(-((x - 0.4) ** 2 + (y + 0.3) ** 2) / 0.02)).clamp(0, 1)  # a highlight off centre
    gt = {"normal": np.full((64, 64, 3), 0.5) * np.array([1, 1, 2]), "diffuse": np.full((64, 64, 3), 0.2),
          "roughness": np.full((64, 64, 3), 0.4), "specular": np.full((64, 64, 3), 0.04)}
    des19 = [("one", photo, gt)]
    net = _speaking_net()
    at_conventions, fitted = score_des19(net, des19, 64), score_des19(net, des19, 64, "fit")
    assert set(fitted) == set(at_conventions) and all(np.isfinite(v) for v in fitted.values())
    assert any(abs(fitted[k] - at_conventions[k]) > 1e-4 for k in ("normal", "diffuse", "roughness", "specular"))
