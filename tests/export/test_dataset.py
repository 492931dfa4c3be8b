import json

import pytest
import torch

from export.data import dataset
from svbrdf_cli import conventions as cv

SMALL = dataset.DataConfig(size=32, mix_fraction=0.5)


def _batch(seed=0, config=SMALL, bank=None, n=4):
    return dataset.make_batch(dataset.worker_generator(seed, 0), n, config, bank)


def test_batch_is_deterministic_from_a_seed():
    a, b, c = _batch(3), _batch(3), _batch(4)
    for k in dataset.SAMPLE_NAMES:
        assert torch.equal(a[k], b[k]), k
    assert a["source"] == b["source"]
    assert not torch.equal(a["photo"], c["photo"])


def test_every_array_in_range():
    b = _batch(1, n=6)
    for k in ("photo", "I") + dataset.AUX_NAMES + ("diffuse", "roughness", "specular"):
        v = b[k]
        assert v.shape[0] == 6 and v.shape[-2:] == (32, 32), k
        assert torch.isfinite(v).all() and v.min() >= 0 and v.max() <= 1, k
    n = b["normal"]
    assert torch.allclose(n.norm(dim=1), torch.ones(1), atol=1e-4) and (n[:, 2] > 0).all()
    assert b["diffuse"].max() <= 0.9 + 1e-6


def test_mixtures_and_sources_are_reported():
    b = _batch(2, config=dataset.DataConfig(size=32, mix_fraction=1.0, targets=()), n=3)
    assert all("+" in s for s in b["source"])
    b = _batch(2, config=dataset.DataConfig(size=32, mix_fraction=0.0, targets=()), n=3)
    assert all("+" not in s and s.startswith("procedural:") for s in b["source"])


def test_targets_use_the_capture_geometry():
    """The clean I of a batch equals a re-render with its capture's camera, flash and exposure."""
    from export.render import targets as render_targets
    g = dataset.worker_generator(5, 0)
    b = dataset.make_batch(g, 2, dataset.DataConfig(size=32, targets=("I_bf",)))
    cap = b["capture"]
    maps = {k: b[k] for k in cv.MAP_NAMES}
    intensity = render_targets.auto_exposure(maps, light=cap["light"].float(), camera=cap["camera"].float(),
                                target=cap["exposure"].float())
    again = render_targets.flash_image(maps, cap["light"].float(), intensity, camera=cap["camera"].float())
    assert torch.allclose(again, b["I"], atol=1e-4)


def test_shards_round_trip_and_resume(tmp_path):
    cfg = dataset.DataConfig(size=16, targets=("I_bf", "M_b", "M_h"))
    n = dataset.write_shards(tmp_path, 5, seed=7, shard_size=2, config=cfg, progress=False)
    assert n == 3
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert manifest["count"] == 5 and manifest["conventions"] == cv.CONVENTIONS_VERSION
    ds = dataset.Shards(tmp_path)
    assert len(ds) == 5
    s = ds[4]
    assert s["photo"].shape == (3, 16, 16) and s["roughness"].shape == (1, 16, 16)
    # Shard 1 regenerated alone matches what was written (to 8 bits).
    ref = dataset.make_batch(dataset.worker_generator(7, 1001), 2, cfg)
    assert torch.allclose(ds[2]["photo"], ref["photo"][0], atol=0.6 / 255)
    assert torch.allclose(ds[3]["normal"], ref["normal"][1], atol=0.02)
    # Resume: a deleted shard is rewritten, the others are kept as they are.
    kept = (tmp_path / "shard-00000.npz").stat().st_mtime_ns
    (tmp_path / "shard-00002.npz").unlink()
    dataset.write_shards(tmp_path, 5, seed=7, shard_size=2, config=cfg, progress=False)
    assert (tmp_path / "shard-00002.npz").exists()
    assert (tmp_path / "shard-00000.npz").stat().st_mtime_ns == kept
    assert not list(tmp_path.glob("*.part"))
    with pytest.raises(FileExistsError):
        dataset.write_shards(tmp_path, 6, seed=7, shard_size=2, config=cfg, progress=False)


def test_worker_streams_differ():
    g1, g2 = dataset.worker_generator(1, 1), dataset.worker_generator(1, 2)
    assert not torch.equal(torch.rand(4, generator=g1), torch.rand(4, generator=g2))


def test_seed_bank_crops(shared_data):
    bank = dataset.SeedBank(str(shared_data), size=64)
    assert len(bank) >= 18
    s = bank.sample(torch.Generator().manual_seed(0), 3, 32)
    assert s["normal"].shape == (3, 3, 32, 32)
    assert torch.allclose(s["normal"].norm(dim=1), torch.ones(1), atol=1e-4)
    assert all(x.startswith("cc0:") for x in s["source"])
