import numpy as np
import pytest
import torch

ort = pytest.importorskip("onnxruntime")
pytest.importorskip("onnx")

from export.nets.chain import PHYSICAL_CHANNELS, SVBRDFNet, Tier  # noqa: E402
from export.onnx_export import IO, PHYSICAL, export_stage, stage_io  # noqa: E402

TINY = Tier(mask_width=0.25, aux_base=8, map_base=8, depth=3)


def _net(refine=True):
    """A tiny chain; a refining one gets random (not zero) correction heads, so that parity means something."""
    net = SVBRDFNet(TINY, pretrained=False, refine=refine).eval()
    if refine:
        for m in net.maps.values():
            torch.nn.init.normal_(m.decoder.head.weight, std=0.05)
    return net


def _feeds(net, stage, h, w):
    feeds = {n: np.random.default_rng(i).random((1, PHYSICAL_CHANNELS if n == PHYSICAL else 3, h, w), dtype=np.float32)
             for i, n in enumerate(stage_io(net, stage)[0])}
    if PHYSICAL in feeds:  # an estimate's normals point up (stored x, y near 0.5, z near 1)
        feeds[PHYSICAL][:, :2] = 0.4 + 0.2 * feeds[PHYSICAL][:, :2]
        feeds[PHYSICAL][:, 2] = 1.0
    return feeds


@pytest.mark.parametrize("refine", [True, False])
@pytest.mark.parametrize("stage", ["masks", "aux", "maps"])
def test_stage_parity_with_onnxruntime(tmp_path, stage, refine):
    torch.manual_seed(0)
    net = _net(refine)
    path = export_stage(net, stage, str(tmp_path / f"{stage}.onnx"), size=64)
    ins, outs = stage_io(net, stage)
    assert (PHYSICAL in ins) == (refine and stage == "maps")
    # A size other than the traced one: the graph is size-dynamic.
    feeds = _feeds(net, stage, 96, 64)
    sess = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
    got = sess.run(list(outs), feeds)
    from export.onnx_export import StageModule

    with torch.no_grad():
        ref = StageModule(net, stage)(*(torch.from_numpy(feeds[n]) for n in ins))
    for name, a, b in zip(outs, got, ref):
        assert a.shape == tuple(b.shape), name
        assert np.abs(a - b.numpy()).max() < 1e-4, name
    meta = sess.get_modelmeta().custom_metadata_map
    assert meta["stage"] == stage and meta["inputs"] == ",".join(ins) and meta["size_multiple"] == "32"


def test_float16_storage_halves_the_file_and_keeps_the_numbers(tmp_path):
    import os

    torch.manual_seed(0)
    net = _net()
    full = export_stage(net, "maps", str(tmp_path / "f32.onnx"), size=64)
    half = export_stage(net, "maps", str(tmp_path / "f16.onnx"), size=64, weights="float16")
    assert os.path.getsize(half) < 0.6 * os.path.getsize(full)
    feeds = _feeds(net, "maps", 64, 64)
    a = ort.InferenceSession(full, providers=["CPUExecutionProvider"]).run(None, feeds)
    b = ort.InferenceSession(half, providers=["CPUExecutionProvider"]).run(None, feeds)
    for x, y in zip(a, b):
        assert np.abs(x - y).max() < 5e-3


def test_runtime_chain_matches_torch(tmp_path):
    """svbrdf_cli.infer.chain.Chain (onnxruntime only) reproduces the torch chain, padding and the
    physical estimate it refines included."""
    from svbrdf_cli.infer.chain import BORDER_MARGIN, Chain
    from svbrdf_cli.infer.physical import network_input

    torch.manual_seed(0)
    net = _net()
    for stage in IO:
        export_stage(net, stage, str(tmp_path / f"{stage}.onnx"), size=64)
    img = np.random.default_rng(3).random((70, 90, 3), dtype=np.float32)  # not a multiple of 32
    out = Chain(tmp_path)(img)
    m = BORDER_MARGIN  # a reflected margin, then up to a multiple of 32; the estimate of the photo, padded alike
    pad = ((m, m + (-(70 + 2 * m)) % 32), (m, m + (-(90 + 2 * m)) % 32), (0, 0))
    chw = lambda a: torch.from_numpy(np.ascontiguousarray(a.transpose(2, 0, 1)))[None]  # noqa: E731
    with torch.no_grad():
        ref = net(chw(np.pad(img, pad, mode="reflect")), physical=chw(np.pad(network_input(img)[0], pad, mode="reflect")))
    for k, v in out.items():
        r = ref[k][0].numpy().transpose(1, 2, 0)[m:m + 70, m:m + 90]
        assert v.shape == r.shape, k
        assert np.abs(v - r).max() < 1e-4, k


def test_runtime_chain_refuses_other_conventions(tmp_path):
    import onnx

    from svbrdf_cli.infer.chain import Chain, ModelError

    net = _net()
    for stage in IO:
        export_stage(net, stage, str(tmp_path / f"{stage}.onnx"), size=64)
    m = onnx.load(str(tmp_path / "aux.onnx"))
    for p in m.metadata_props:
        if p.key == "conventions":
            p.value = "0"
    onnx.save(m, str(tmp_path / "aux.onnx"))
    with pytest.raises(ModelError, match="conventions"):
        Chain(tmp_path)
    (tmp_path / "maps.onnx").unlink()
    with pytest.raises(ModelError, match="maps.onnx"):
        Chain(tmp_path)


def test_int8_weights_stay_close(tmp_path):
    import os

    torch.manual_seed(0)
    net = _net()
    full = export_stage(net, "maps", str(tmp_path / "f32.onnx"), size=64)
    q = export_stage(net, "maps", str(tmp_path / "i8.onnx"), size=64, weights="int8")
    assert os.path.getsize(q) < 0.4 * os.path.getsize(full)
    feeds = _feeds(net, "maps", 64, 64)
    a = ort.InferenceSession(full, providers=["CPUExecutionProvider"]).run(None, feeds)
    b = ort.InferenceSession(q, providers=["CPUExecutionProvider"]).run(None, feeds)
    for x, y in zip(a, b):
        assert 0 < np.abs(x - y).max() < 3e-2


def test_end_to_end_baseline_exports_with_the_photo_only(tmp_path):
    from export.nets.chain import EndToEndNet
    from svbrdf_cli.infer.chain import BORDER_MARGIN, Chain

    torch.manual_seed(0)
    net = EndToEndNet("fast", base=8, depth=3, refine=False).eval()
    export_stage(net, "maps", str(tmp_path / "maps.onnx"), size=64)
    img = np.random.default_rng(3).random((64, 64, 3), dtype=np.float32)
    out = Chain(tmp_path)(img)
    m = BORDER_MARGIN
    padded = np.pad(img, ((m, m), (m, m), (0, 0)), mode="reflect")  # 64 + 2m: a multiple of 32 already
    with torch.no_grad():
        ref = net.run_maps(torch.from_numpy(padded).permute(2, 0, 1)[None])
    for k, v in ref.items():
        assert np.abs(out[k] - v[0].permute(1, 2, 0).numpy()[m:m + 64, m:m + 64]).max() < 1e-4


def test_untrained_refining_models_return_the_physical_estimate(tmp_path):
    """A freshly initialised chain and end-to-end net, exported and run by the runtime, give the
    physical estimate back: weak networks cannot make the maps worse than physics by noise."""
    from export.nets.chain import EndToEndNet
    from svbrdf_cli.infer.chain import Chain
    from svbrdf_cli.infer.physical import estimate

    torch.manual_seed(0)
    img = np.random.default_rng(5).random((64, 64, 3), dtype=np.float32) * 0.6
    est, _ = estimate(img)
    for name, net in (("chain", SVBRDFNet(TINY, pretrained=False).eval()),
                      ("e2e", EndToEndNet("fast", base=8, depth=3).eval())):
        folder = tmp_path / name
        folder.mkdir()
        for stage in (IO if name == "chain" else ("maps",)):
            export_stage(net, stage, str(folder / f"{stage}.onnx"), size=64)
        out = Chain(folder)(img)
        for k, v in est.items():
            assert np.abs(out[k] - v).max() < 1e-5, (name, k)
        with torch.no_grad():
            ref = net(torch.from_numpy(img).permute(2, 0, 1)[None])
        for k, v in est.items():
            assert np.abs(ref[k][0].permute(1, 2, 0).numpy() - v).max() < 1e-5, (name, k)


def test_a_run_on_another_estimate_version_is_not_exported(tmp_path):
    """A refining run trained on another version of the physical estimate would be fed an estimate it never
    learnt: exporting it is refused (the runtime would refuse to load it too)."""
    from export.files import read_json, write_json
    from export.onnx_export import export_run
    from export.train import RunConfig, train_stage
    from svbrdf_cli.errors import SvbrdfError

    cfg = RunConfig(tier="lite", variant="e2e", size=32, batch=2, val_samples=2)
    train_stage("maps", str(tmp_path / "run"), cfg, steps=1, progress=False, log=lambda *a: None)
    prov = read_json(tmp_path / "run" / "provenance.json")
    prov["stages"]["maps"]["physical_version"] = "0"
    write_json(tmp_path / "run" / "provenance.json", prov)
    with pytest.raises(SvbrdfError, match="version 0"):
        export_run(str(tmp_path / "run"), str(tmp_path / "out"))
