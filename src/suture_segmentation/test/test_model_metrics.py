# SPDX-License-Identifier: Apache-2.0
"""The U-Net's shape contract, the 13-layer frozen extractor, and the paper's metrics."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from suture_segmentation.checkpoint import copy_fitting_tensors, load_checkpoint, save_checkpoint
from suture_segmentation.metrics import MaskScores, mean_scores, score_mask
from suture_segmentation.model import HALF_RESOLUTION_WIDTHS, FeatureExtractor, SutureUNet, pad_to_multiple
from suture_segmentation.train import segmentation_loss


def test_logits_have_the_input_size_and_two_classes() -> None:
    model = SutureUNet().eval()
    with torch.inference_mode():
        out = model(torch.rand(2, 3, 48, 80))
    assert out.shape == (2, 2, 48, 80)


def test_feature_extractor_is_the_papers_13_layers() -> None:
    extractor = FeatureExtractor((8, 16, 32, 48, 64))
    assert len(extractor.layers) == 13
    kinds = ["pool" if isinstance(layer, nn.MaxPool2d) else "conv" for layer in extractor.layers]
    assert kinds == ["conv", "conv", "pool"] * 4 + ["conv"]


def test_half_resolution_model_folds_the_first_level_and_gives_full_size_logits() -> None:
    model = SutureUNet(HALF_RESOLUTION_WIDTHS, half_resolution=True).eval()
    assert model.stride == 32 and SutureUNet().stride == 16
    kinds = [type(layer).__name__ for layer in model.feature_extractor.layers]
    assert len(kinds) == 13 and kinds[:6] == [
        "PixelUnshuffle",
        "Sequential",
        "Sequential",
        "Sequential",
        "Sequential",
        "MaxPool2d",
    ]
    with torch.inference_mode():
        image = torch.rand(2, 3, 64, 96)
        out = model(image)
        skips, _ = model.feature_extractor(image)
    assert out.shape == (2, 2, 64, 96)
    assert [tuple(s.shape[1:]) for s in skips] == [(24, 32, 48), (16, 32, 48), (32, 16, 24), (48, 8, 12)]


def test_half_resolution_logits_keep_each_pixel_of_a_fold_apart() -> None:
    # The classifier's eight channels are (class, row in the fold, column in the fold): a change
    # of one output channel moves exactly the logits of that pixel of every 2x2 block.
    model = SutureUNet((4, 4, 8, 8, 8), half_resolution=True).eval()
    image = torch.rand(1, 3, 32, 32)
    with torch.inference_mode():
        before = model(image)
        model.classifier.bias[4 + 3] += 1.0  # suture class, bottom-right pixel of each block
        changed = (model(image) - before).abs() > 1e-6
    assert changed[0, 1, 1::2, 1::2].all() and changed.sum() == 16 * 16


@pytest.mark.parametrize("half_resolution", [False, True])
def test_frozen_extractor_is_unchanged_by_training_and_the_decoder_learns(half_resolution: bool) -> None:
    torch.manual_seed(0)
    model = SutureUNet((4, 4, 8, 8, 8), half_resolution)
    model.freeze_feature_extractor()
    model.train()
    extractor_before = {k: v.clone() for k, v in model.feature_extractor.state_dict().items()}
    decoder_before = {k: v.clone() for k, v in model.decoder.state_dict().items()}
    optimiser = torch.optim.Adam(model.trainable_parameters(), lr=1e-2)
    for _ in range(3):
        labels = (torch.rand(2, 32, 32) > 0.9).long()
        loss = segmentation_loss(model(torch.rand(2, 3, 32, 32)), labels, "ce")
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    for key, value in model.feature_extractor.state_dict().items():  # weights and BN statistics
        assert torch.equal(value, extractor_before[key]), key
    assert any(not torch.equal(v, decoder_before[k]) for k, v in model.decoder.state_dict().items())
    assert all(not p.requires_grad for p in model.feature_extractor.parameters())


def test_a_half_resolution_model_starts_from_a_full_resolution_ones_coarser_layers(tmp_path) -> None:
    torch.manual_seed(1)
    source = SutureUNet()
    target = SutureUNet(HALF_RESOLUTION_WIDTHS, half_resolution=True)
    copied = copy_fitting_tensors(source, target)
    target_state, source_state = target.state_dict(), source.state_dict()
    coarse = [
        k
        for k in source_state
        if k.startswith(("bottleneck.", "decoder.0.", "decoder.1.", "decoder.2."))
        or (k.startswith("feature_extractor.layers.") and int(k.split(".")[2]) >= 4)
    ]
    assert len(coarse) == 84 and copied >= len(coarse)
    assert all(torch.equal(target_state[k], source_state[k]) for k in coarse)
    # The checkpoint records the variant, and loads it back the same.
    model, _ = load_checkpoint(save_checkpoint(target, tmp_path / "half.pt"))
    image = torch.rand(1, 3, 64, 64)
    with torch.inference_mode():
        assert model.half_resolution and torch.equal(model(image), target.eval()(image))


def test_bad_widths_are_refused() -> None:
    with pytest.raises(ValueError, match="five positive"):
        SutureUNet((8, 16, 32))


def test_padding_to_a_multiple_of_32_keeps_the_original_size() -> None:
    padded, size = pad_to_multiple(torch.rand(1, 3, 50, 70))
    assert padded.shape[-2:] == (64, 96) and size == (50, 70)


def test_scores_of_a_known_prediction() -> None:
    truth = np.zeros((10, 10), bool)
    truth[2:4, :] = True  # 20 pixels
    predicted = np.zeros((10, 10), bool)
    predicted[3:6, :] = True  # 30 pixels, 10 of them right
    scores = score_mask(predicted, truth)
    assert scores.iou == pytest.approx(10 / 40)
    assert scores.precision == pytest.approx(10 / 30)
    assert scores.recall == pytest.approx(10 / 20)
    assert scores.f1 == pytest.approx(2 * (1 / 3) * 0.5 / (1 / 3 + 0.5))


def test_scores_of_empty_masks() -> None:
    empty = np.zeros((4, 4), bool)
    full = np.ones((4, 4), bool)
    assert score_mask(empty, empty) == MaskScores(1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0)
    assert score_mask(empty, full).recall == 0.0 and score_mask(empty, full).iou == 0.0
    assert score_mask(full, empty).precision == 0.0
    with pytest.raises(ValueError, match="shapes differ"):
        score_mask(empty, np.zeros((3, 4)))


def test_mean_scores_average_per_image() -> None:
    mean = mean_scores([MaskScores(1.0, 1.0, 1.0, 1.0), MaskScores(0.0, 0.5, 0.0, 0.0)])
    assert mean == MaskScores(0.5, 0.75, 0.5, 0.5)
