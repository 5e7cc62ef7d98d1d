# SPDX-License-Identifier: Apache-2.0
"""The suture U-Net: a frozen-able 13-layer feature extractor and a trainable decoder.

The paper (Section II.A) extends the first 11 layers of U-Net to 13 and uses them as the
feature extractor that transfer learning freezes. Counting layers as Keras does (a convolution
with its activation is one layer, a pooling is one layer), our extractor is exactly these 13:

====  ==========================  ====  ==========================
  1   conv 3x3, C1   (full res)     8   conv 3x3, C3
  2   conv 3x3, C1                  9   max-pool 2 (1/8 res)
  3   max-pool 2     (1/2 res)     10   conv 3x3, C4
  4   conv 3x3, C2                 11   conv 3x3, C4
  5   conv 3x3, C2                 12   max-pool 2 (1/16 res)
  6   max-pool 2     (1/4 res)     13   conv 3x3, C5 (bottleneck, first half)
  7   conv 3x3, C3
====  ==========================  ====  ==========================

Everything after it (the second bottleneck convolution, four up-sampling stages with skip
connections and the 1x1 classifier) is the part that fine-tuning trains. A "conv" is
Conv2d + BatchNorm2d + ReLU; when the extractor is frozen its batch-norm statistics are frozen
too (:meth:`SutureUNet.freeze_feature_extractor`).

**Half-resolution variant** (``half_resolution=True``, the shipped ``m_onsite_half``). About 70 %
of the full-resolution model's CPU time goes to the five layers that run at full resolution.
This variant moves them to half resolution without losing a pixel: layer 1 folds each 2x2 block
of pixels into 12 channels (``pixel_unshuffle``), layers 2 and 3 are 3x3 convolutions of C1
channels at half resolution (no pooling), and the last decoder stage, also at half resolution,
ends in a classifier of 2x4 channels that ``pixel_shuffle`` unfolds into (2, H, W) logits. The
layers from 4 on are the table's, one level coarser. C1 is wider (24 against 8: the fine level
carries four pixels per position), and the network runs in about half the time.

The widths are small (default C1..C5 = 8, 16, 32, 48, 64) so that a 640x480 stereo pair runs
fast on two CPU cores with ONNX Runtime. Input: (B, 3, H, W) float32 RGB scaled to [0, 1] with
H and W multiples of the model's ``stride`` (:func:`pad_to_multiple` handles other sizes). Output:
(B, 2, H, W) logits for (background, suture); the paper's cross-entropy loss applies directly.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn
from torch.nn import functional

#: A model's input sizes must be multiples of its ``stride``: 16 for the full-resolution model
#: (four poolings), 32 for the half-resolution one (the fold and four poolings).
FULL_RESOLUTION_STRIDE, HALF_RESOLUTION_STRIDE = 16, 32
#: Inference pads every image to multiples of this (:func:`pad_to_multiple`), which serves both
#: variants.
STRIDE = HALF_RESOLUTION_STRIDE

#: Default channel widths C1..C5 of the five resolution levels.
DEFAULT_WIDTHS: tuple[int, ...] = (8, 16, 32, 48, 64)
#: Default widths of the half-resolution variant: its C1 level holds four pixels per position.
HALF_RESOLUTION_WIDTHS: tuple[int, ...] = (24, 16, 32, 48, 64)

#: Class indices of the output logits.
BACKGROUND, SUTURE = 0, 1


def _conv(in_channels: int, out_channels: int) -> nn.Sequential:
    """One U-Net "layer": 3x3 convolution (same padding), batch norm, ReLU."""
    return nn.Sequential(
        nn.Conv2d(in_channels, out_channels, 3, padding=1, bias=False),
        nn.BatchNorm2d(out_channels),
        nn.ReLU(inplace=True),
    )


class FeatureExtractor(nn.Module):
    """The 13 layers of the table above; returns the four skip tensors and the bottleneck input."""

    def __init__(self, widths: Sequence[int], half_resolution: bool = False) -> None:
        super().__init__()
        c1, c2, c3, c4, c5 = widths
        if half_resolution:
            first = [nn.PixelUnshuffle(2), _conv(12, c1), _conv(c1, c1)]
        else:
            first = [_conv(3, c1), _conv(c1, c1), nn.MaxPool2d(2)]
        self.half_resolution = half_resolution
        self.layers = nn.ModuleList(
            [
                *first,
                _conv(c1, c2),
                _conv(c2, c2),
                nn.MaxPool2d(2),
                _conv(c2, c3),
                _conv(c3, c3),
                nn.MaxPool2d(2),
                _conv(c3, c4),
                _conv(c4, c4),
                nn.MaxPool2d(2),
                _conv(c4, c5),
            ]
        )

    def forward(self, image: torch.Tensor) -> tuple[list[torch.Tensor], torch.Tensor]:
        skips: list[torch.Tensor] = []
        x = image
        for index, layer in enumerate(self.layers):
            if isinstance(layer, nn.MaxPool2d):
                skips.append(x)
            x = layer(x)
            if self.half_resolution and index == 2:  # the fine level's skip, at half resolution
                skips.append(x)
        return skips, x


class _Up(nn.Module):
    """Decoder stage: 2x bilinear up-sampling (unless ``upsample`` is false), concatenation with
    the skip, two convs."""

    def __init__(self, in_channels: int, skip_width: int, out_channels: int, upsample: bool = True) -> None:
        super().__init__()
        self.upsample = upsample
        self.reduce = nn.Conv2d(in_channels, out_channels, 1)
        self.convs = nn.Sequential(
            _conv(out_channels + skip_width, out_channels), _conv(out_channels, out_channels)
        )

    def forward(self, x: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
        x = self.reduce(x)
        if self.upsample:
            x = functional.interpolate(x, scale_factor=2.0, mode="bilinear", align_corners=False)
        return self.convs(torch.cat([x, skip], dim=1))


class SutureUNet(nn.Module):
    """U-Net for suture segmentation, see the module docstring for the layer table."""

    def __init__(self, widths: Sequence[int] = DEFAULT_WIDTHS, half_resolution: bool = False) -> None:
        super().__init__()
        if len(widths) != 5 or any(int(w) < 1 for w in widths):
            raise ValueError(f"widths must be five positive channel counts, got {tuple(widths)}")
        self.widths = tuple(int(w) for w in widths)
        self.half_resolution = bool(half_resolution)
        self.stride = HALF_RESOLUTION_STRIDE if self.half_resolution else FULL_RESOLUTION_STRIDE
        c1, c2, c3, c4, c5 = self.widths
        self.feature_extractor = FeatureExtractor(self.widths, self.half_resolution)
        self.bottleneck = _conv(c5, c5)
        finest = _Up(c2, c1, c1, upsample=not self.half_resolution)
        self.decoder = nn.ModuleList([_Up(c5, c4, c4), _Up(c4, c3, c3), _Up(c3, c2, c2), finest])
        # Half resolution: two logits for each of the four pixels a position folds (module docstring).
        self.classifier = nn.Conv2d(c1, 8 if self.half_resolution else 2, 1)
        self._extractor_frozen = False

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        skips, x = self.feature_extractor(image)
        x = self.bottleneck(x)
        for up, skip in zip(self.decoder, reversed(skips), strict=True):
            x = up(x, skip)
        logits = self.classifier(x)
        return functional.pixel_shuffle(logits, 2) if self.half_resolution else logits

    def freeze_feature_extractor(self) -> None:
        """Freeze the 13 extractor layers (weights and batch-norm statistics) for fine-tuning."""
        for parameter in self.feature_extractor.parameters():
            parameter.requires_grad_(False)
        self._extractor_frozen = True
        self.feature_extractor.eval()

    def train(self, mode: bool = True) -> SutureUNet:
        super().train(mode)
        if self._extractor_frozen:
            self.feature_extractor.eval()  # frozen batch-norm statistics stay frozen
        return self

    def trainable_parameters(self) -> list[nn.Parameter]:
        return [p for p in self.parameters() if p.requires_grad]


def pad_to_multiple(batch: torch.Tensor, multiple: int = STRIDE) -> tuple[torch.Tensor, tuple[int, int]]:
    """Reflect-pad (B, C, H, W) on the bottom/right to multiples of ``multiple``; returns (padded, (H, W))."""
    height, width = batch.shape[-2:]
    pad_h, pad_w = (-height) % multiple, (-width) % multiple
    if pad_h or pad_w:
        batch = functional.pad(batch, (0, pad_w, 0, pad_h), mode="replicate")
    return batch, (height, width)


def suture_probability(model: SutureUNet, batch: torch.Tensor) -> torch.Tensor:
    """(B, H, W) suture probability of a (B, 3, H, W) [0, 1] batch of any size (padded inside).

    Runs without gradients; the caller puts ``model`` in eval mode and on the batch's device.
    """
    padded, (height, width) = pad_to_multiple(batch)
    with torch.inference_mode():
        return torch.softmax(model(padded).float(), dim=1)[:, SUTURE, :height, :width]
