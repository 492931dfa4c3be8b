import numpy as np
import pytest
import torch

ort = pytest.importorskip("onnxruntime")
pytest.importorskip("onnx")

from export.nets.chain import SVBRDFNet, Tier  # noqa: E402
from export.onnx_export import IO, export_stage  # noqa: E402

TINY = Tier(mask_width=0.25, aux_base=8, map_base=8, depth=3)


@pytest.mark.parametrize("stage", ["masks", "aux", "maps"])
def test_stage_parity_with_onnxruntime(tmp_path, stage):
    torch.manual_seed(0)
    net = SVBRDFNet(TINY, pretrained=False).eval()
    path = export_stage(net, stage, str(tmp_path / f"{stage}.onnx"), size=64)
    ins, outs = IO[stage]
    # A size other than the traced one: the graph is size-dynamic.
    feeds = {n: np.random.default_rng(i).random((1, 3, 96, 64), dtype=np.float32) for i, n in enumerate(ins)}
    sess = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
    got = sess.run(list(outs), feeds)
    from export.onnx_export import _Stage

    with torch.no_grad():
        ref = _Stage(net, stage)(*(torch.from_numpy(feeds[n]) for n in ins))
    for name, a, b in zip(outs, got, ref):
        assert a.shape == tuple(b.shape), name
        assert np.abs(a - b.numpy()).max() < 1e-4, name
    meta = sess.get_modelmeta().custom_metadata_map
    assert meta["stage"] == stage and meta["inputs"] == ",".join(ins) and meta["size_multiple"] == "32"


def test_float16_storage_halves_the_file_and_keeps_the_numbers(tmp_path):
    import os

    torch.manual_seed(0)
    net = SVBRDFNet(TINY, pretrained=False).eval()
    full = export_stage(net, "maps", str(tmp_path / "f32.onnx"), size=64)
    half = export_stage(net, "maps", str(tmp_path / "f16.onnx"), size=64, weights="float16")
    assert os.path.getsize(half) < 0.6 * os.path.getsize(full)
    feeds = {n: np.random.default_rng(i).random((1, 3, 64, 64), dtype=np.float32) for i, n in enumerate(IO["maps"][0])}
    a = ort.InferenceSession(full, providers=["CPUExecutionProvider"]).run(None, feeds)
    b = ort.InferenceSession(half, providers=["CPUExecutionProvider"]).run(None, feeds)
    for x, y in zip(a, b):
        assert np.abs(x - y).max() < 5e-3


def test_runtime_chain_matches_torch(tmp_path):
    """svbrdf_cli.inference.Chain (onnxruntime only) reproduces the torch chain, padding included."""
    from svbrdf_cli.inference import Chain

    torch.manual_seed(0)
    net = SVBRDFNet(TINY, pretrained=False).eval()
    for stage in IO:
        export_stage(net, stage, str(tmp_path / f"{stage}.onnx"), size=64)
    img = np.random.default_rng(3).random((70, 90, 3), dtype=np.float32)  # not a multiple of 32
    out = Chain(tmp_path)(img)
    pad = np.pad(img, ((0, 26), (0, 6), (0, 0)), mode="reflect")
    with torch.no_grad():
        ref = net(torch.from_numpy(pad.transpose(2, 0, 1).copy())[None])
    for k, v in out.items():
        r = ref[k][0].numpy().transpose(1, 2, 0)[:70, :90]
        assert v.shape == r.shape, k
        assert np.abs(v - r).max() < 1e-4, k


def test_runtime_chain_refuses_other_conventions(tmp_path):
    import onnx

    from svbrdf_cli.inference import Chain, ModelError

    net = SVBRDFNet(TINY, pretrained=False).eval()
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
    net = SVBRDFNet(TINY, pretrained=False).eval()
    full = export_stage(net, "maps", str(tmp_path / "f32.onnx"), size=64)
    q = export_stage(net, "maps", str(tmp_path / "i8.onnx"), size=64, weights="int8")
    assert os.path.getsize(q) < 0.4 * os.path.getsize(full)
    feeds = {n: np.random.default_rng(i).random((1, 3, 64, 64), dtype=np.float32) for i, n in enumerate(IO["maps"][0])}
    a = ort.InferenceSession(full, providers=["CPUExecutionProvider"]).run(None, feeds)
    b = ort.InferenceSession(q, providers=["CPUExecutionProvider"]).run(None, feeds)
    for x, y in zip(a, b):
        assert 0 < np.abs(x - y).max() < 3e-2


def test_end_to_end_baseline_exports_with_the_photo_only(tmp_path):
    from export.nets.chain import EndToEndNet
    from svbrdf_cli.inference import Chain

    torch.manual_seed(0)
    net = EndToEndNet("fast", base=8, depth=3).eval()
    export_stage(net, "maps", str(tmp_path / "maps.onnx"), size=64)
    img = np.random.default_rng(3).random((64, 64, 3), dtype=np.float32)
    out = Chain(tmp_path)(img)
    with torch.no_grad():
        ref = net.run_maps(torch.from_numpy(img).permute(2, 0, 1)[None])
    for k, v in ref.items():
        assert np.abs(out[k] - v[0].permute(1, 2, 0).numpy()).max() < 1e-4
