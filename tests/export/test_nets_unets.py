"""Deformable convolution, GAD-Conv / GAD-UNet, plain UNet, cost counting, ONNX export."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from torch import nn

from export.nets.cost import count_macs, count_parameters, describe
from export.nets.deform import DeformConv2d, deform_conv2d, set_deform_export
from export.nets.gad import GADConv, GADUNet
from export.nets.unet import UNet

torch.set_num_threads(1)


def _reference_deform_conv(x, offset, weight, bias, stride, padding, dilation):
    """Slow, obvious deformable convolution: loops over output pixels, taps and channels,
    bilinear interpolation by hand, zero outside the image (per corner)."""
    x = x.detach().double().numpy()
    offset = offset.detach().double().numpy()
    weight = weight.detach().double().numpy()
    n_, c_, h, w = x.shape
    o_, _, kh, kw = weight.shape
    oh = (h + 2 * padding - dilation * (kh - 1) - 1) // stride + 1
    ow = (w + 2 * padding - dilation * (kw - 1) - 1) // stride + 1
    assert offset.shape == (n_, 2 * kh * kw, oh, ow)

    def pixel(n, c, yy, xx):
        if 0 <= yy < h and 0 <= xx < w:
            return x[n, c, yy, xx]
        return 0.0

    def bilinear(n, c, y, xf):
        y0, x0 = math.floor(y), math.floor(xf)
        ly, lx = y - y0, xf - x0
        return (
            (1 - ly) * (1 - lx) * pixel(n, c, y0, x0)
            + (1 - ly) * lx * pixel(n, c, y0, x0 + 1)
            + ly * (1 - lx) * pixel(n, c, y0 + 1, x0)
            + ly * lx * pixel(n, c, y0 + 1, x0 + 1)
        )

    out = np.zeros((n_, o_, oh, ow))
    for n in range(n_):
        for oy in range(oh):
            for ox in range(ow):
                for i in range(kh):
                    for j in range(kw):
                        t = i * kw + j
                        y = oy * stride - padding + i * dilation + offset[n, 2 * t, oy, ox]
                        xf = ox * stride - padding + j * dilation + offset[n, 2 * t + 1, oy, ox]
                        for c in range(c_):
                            out[n, :, oy, ox] += weight[:, c, i, j] * bilinear(n, c, y, xf)
    if bias is not None:
        out += bias.detach().double().numpy()[None, :, None, None]
    return out


@pytest.mark.parametrize("stride", [1, 2])
def test_deform_conv_matches_loop_reference(stride):
    g = torch.Generator().manual_seed(stride)
    x = torch.randn(2, 3, 7, 6, generator=g)
    weight = torch.randn(4, 3, 3, 3, generator=g)
    bias = torch.randn(4, generator=g)
    oh = (7 + 2 - 2 - 1) // stride + 1
    ow = (6 + 2 - 2 - 1) // stride + 1
    # Offsets up to several pixels: many taps land partly or wholly outside the image.
    offset = torch.randn(2, 18, oh, ow, generator=g) * 2.5
    offset[0, 0, 0, 0] = -1.5  # a tap between -2 and -1 rows: all four corners outside
    offset[0, 1, 0, 0] = 0.5
    offset[1, 3, -1, -1] = 30.0  # far outside
    got = deform_conv2d(x, offset, weight, bias, stride, 1, 1).double().numpy()
    want = _reference_deform_conv(x, offset, weight, bias, stride, 1, 1)
    assert got.shape == want.shape
    np.testing.assert_allclose(got, want, atol=2e-5, rtol=1e-5)


def test_deform_conv_matches_reference_dilation_no_bias():
    g = torch.Generator().manual_seed(7)
    x = torch.randn(1, 2, 6, 6, generator=g)
    weight = torch.randn(3, 2, 3, 3, generator=g)
    offset = torch.randn(1, 18, 6, 6, generator=g) * 1.5
    got = deform_conv2d(x, offset, weight, None, 1, 2, 2).double().numpy()
    want = _reference_deform_conv(x, offset, weight, None, 1, 2, 2)
    np.testing.assert_allclose(got, want, atol=2e-5, rtol=1e-5)


@pytest.mark.parametrize("stride", [1, 2])
def test_zero_offsets_equal_plain_conv(stride):
    torch.manual_seed(0)
    m = DeformConv2d(5, 7, 3, stride, 1)
    conv = nn.Conv2d(5, 7, 3, stride, 1)
    with torch.no_grad():
        conv.weight.copy_(m.weight)
        conv.bias.copy_(m.bias)
    x = torch.randn(2, 5, 12, 10)
    assert torch.count_nonzero(m.offset(x)) == 0  # fresh module predicts zero offsets
    torch.testing.assert_close(m(x), conv(x), atol=1e-5, rtol=1e-5)


def test_gradients_reach_input_weights_and_offset_predictor():
    torch.manual_seed(1)
    m = DeformConv2d(3, 4, stride=2)
    with torch.no_grad():
        m.offset.weight.normal_(0, 0.3)  # non-zero offsets: bilinear weights depend on them
    x = torch.randn(2, 3, 9, 9, requires_grad=True)
    m(x).square().sum().backward()
    for name, t in [
        ("input", x),
        ("weight", m.weight),
        ("bias", m.bias),
        ("offset.weight", m.offset.weight),
        ("offset.bias", m.offset.bias),
    ]:
        assert t.grad is not None, name
        assert torch.isfinite(t.grad).all(), name
        assert t.grad.abs().sum() > 0, name


def test_deform_conv_gradcheck():
    g = torch.Generator().manual_seed(3)
    x = torch.randn(1, 2, 5, 4, generator=g, dtype=torch.float64, requires_grad=True)
    w = torch.randn(3, 2, 3, 3, generator=g, dtype=torch.float64, requires_grad=True)
    b = torch.randn(3, generator=g, dtype=torch.float64, requires_grad=True)
    # Offsets away from integer positions (bilinear is not differentiable at the kinks).
    off = (torch.rand(1, 18, 5, 4, generator=g, dtype=torch.float64) * 0.8 + 0.1)
    off = (off + torch.randint(-2, 2, off.shape, generator=g)).requires_grad_(True)
    assert torch.autograd.gradcheck(
        lambda *a: deform_conv2d(*a, stride=1, padding=1, dilation=1), (x, off, w, b)
    )


def test_gad_conv_eq12():
    torch.manual_seed(2)
    m = GADConv(4, 6, stride=2)
    x = torch.randn(1, 4, 16, 16)
    out, sigma = m(x, return_gate=True)
    assert out.shape == sigma.shape == (1, 6, 8, 8)
    feat = m.act(m.feature(x))
    gated = sigma * feat
    inpaint = m.act(m.deform(gated))
    torch.testing.assert_close(out, sigma * feat + (1 - sigma) * inpaint)


def _onnx_roundtrip(model, x, path, **kw):
    ort = pytest.importorskip("onnxruntime")
    pytest.importorskip("onnx", reason="torch.onnx.export needs the onnx package")
    model.eval()
    with torch.no_grad():
        want = model(x).numpy()
    torch.onnx.export(
        model, (x,), str(path), dynamo=False, opset_version=19,
        input_names=["x"], output_names=["y"], **kw,
    )
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    ops = {n.op_type for n in __import__("onnx").load(str(path)).graph.node}
    return sess, want, ops


def test_onnx_deformconv_node_matches_torch(tmp_path):
    torch.manual_seed(4)
    m = DeformConv2d(3, 5, stride=2)
    with torch.no_grad():
        m.offset.weight.normal_(0, 0.5)
        m.offset.bias.normal_(0, 1.0)
    x = torch.randn(1, 3, 20, 24)
    sess, want, ops = _onnx_roundtrip(
        m, x, tmp_path / "dc.onnx", dynamic_axes={"x": {2: "h", 3: "w"}, "y": {2: "oh", 3: "ow"}}
    )
    assert "DeformConv" in ops and "GridSample" not in ops
    got = sess.run(None, {"x": x.numpy()})[0]
    np.testing.assert_allclose(got, want, atol=1e-4, rtol=1e-4)
    # The DeformConv graph has no baked-in sizes: another size runs and still agrees.
    x2 = torch.randn(1, 3, 14, 10)
    with torch.no_grad():
        want2 = m(x2).numpy()
    np.testing.assert_allclose(sess.run(None, {"x": x2.numpy()})[0], want2, atol=1e-4, rtol=1e-4)


def test_onnx_gridsample_fallback_matches_torch(tmp_path):
    torch.manual_seed(5)
    m = DeformConv2d(3, 4)
    with torch.no_grad():
        m.offset.weight.normal_(0, 0.5)
    set_deform_export(m, "gridsample")
    x = torch.randn(1, 3, 16, 16)
    sess, want, ops = _onnx_roundtrip(m, x, tmp_path / "gs.onnx")
    assert "GridSample" in ops and "DeformConv" not in ops
    np.testing.assert_allclose(sess.run(None, {"x": x.numpy()})[0], want, atol=1e-4, rtol=1e-4)


def _perturb_offsets(model, std=0.3):
    with torch.no_grad():
        for mod in model.modules():
            if isinstance(mod, DeformConv2d):
                mod.offset.weight.normal_(0, std)


def test_onnx_gadunet_matches_torch(tmp_path):
    torch.manual_seed(6)
    m = GADUNet(6, 3, base=8, depth=3)
    _perturb_offsets(m)  # exercise real deformation, not the zero-offset start
    x = torch.rand(1, 6, 64, 64)
    sess, want, ops = _onnx_roundtrip(m, x, tmp_path / "gad.onnx")
    assert "DeformConv" in ops
    got = sess.run(None, {"x": x.numpy()})[0]
    assert got.shape == (1, 3, 64, 64)
    np.testing.assert_allclose(got, want, atol=1e-4, rtol=1e-4)


@pytest.mark.parametrize("norm", ["none", "group"])
def test_onnx_unet_matches_torch(tmp_path, norm):
    torch.manual_seed(7)
    m = UNet(9, 3, base=8, depth=5, norm=norm)
    x = torch.rand(1, 9, 64, 64)
    sess, want, _ = _onnx_roundtrip(m, x, tmp_path / "unet.onnx")
    np.testing.assert_allclose(sess.run(None, {"x": x.numpy()})[0], want, atol=1e-4, rtol=1e-4)


@pytest.mark.parametrize("size", [64, 256])
def test_output_shapes_and_ranges(size):
    torch.manual_seed(8)
    gad = GADUNet(9, 3, base=4, depth=5).eval()
    unet = UNet(6, 3, base=4, depth=5).eval()
    tanh = UNet(6, 3, base=4, depth=5, out_activation="tanh").eval()
    raw = UNet(6, 1, base=4, depth=5, out_activation=None, norm="group").eval()
    with torch.no_grad():
        y = gad(torch.rand(2, 9, size, size))
        assert y.shape == (2, 3, size, size)
        assert y.min() >= 0 and y.max() <= 1
        x = torch.rand(2, 6, size, size)
        y = unet(x)
        assert y.shape == (2, 3, size, size) and y.min() >= 0 and y.max() <= 1
        y = tanh(x)
        assert y.shape == (2, 3, size, size) and y.min() >= -1 and y.max() <= 1
        assert raw(x).shape == (2, 1, size, size)


def test_train_and_eval_agree_and_batch_independent():
    torch.manual_seed(9)
    for m in (UNet(3, 3, base=4, depth=3, norm="group"), GADUNet(3, 3, base=4, depth=3)):
        x = torch.rand(3, 3, 32, 32)
        with torch.no_grad():
            a = m.train()(x)
            b = m.eval()(x)
            c = m(x[1:2])
        torch.testing.assert_close(a, b)
        torch.testing.assert_close(b[1:2], c, atol=1e-6, rtol=1e-5)


def test_gadunet_trains_one_step():
    torch.manual_seed(10)
    m = GADUNet(6, 3, base=4, depth=2)
    x, t = torch.rand(2, 6, 16, 16), torch.rand(2, 3, 16, 16)
    (m(x) - t).abs().mean().backward()
    assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in m.parameters())
    offset_grads = [mod.offset.weight.grad.abs().sum() for mod in m.modules()
                    if isinstance(mod, DeformConv2d)]
    assert offset_grads and all(g > 0 for g in offset_grads)


def test_count_macs_conv_hand_formula():
    conv = nn.Conv2d(6, 10, 3, stride=2, padding=1, groups=2)
    macs = count_macs(conv, (2, 6, 32, 32))
    assert macs == 2 * 10 * 16 * 16 * (6 // 2) * 3 * 3
    lin = nn.Linear(7, 5)
    assert count_macs(lin, torch.zeros(4, 7)) == 4 * 5 * 7
    tconv = nn.ConvTranspose2d(4, 3, 2, stride=2)
    assert count_macs(tconv, (1, 4, 8, 8)) == 4 * 8 * 8 * 3 * 2 * 2


def test_count_macs_deform_and_describe():
    m = DeformConv2d(4, 8, stride=1)
    k, hw = 9, 16 * 16
    main, sampling, offset_conv = 8 * hw * 4 * k, 4 * 4 * k * hw, 18 * hw * 4 * k
    assert count_macs(m, (1, 4, 16, 16)) == main + sampling + offset_conv
    assert count_parameters(m) == 8 * 4 * 9 + 8 + 18 * 4 * 9 + 18
    line = describe(UNet(6, 3, base=4, depth=3), size=64)
    assert "UNet" in line and "GMACs" in line and "\n" not in line
