# SPDX-License-Identifier: Apache-2.0
"""The U-Net's shape contract, the 13-layer frozen extractor, and the paper's metrics."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from suture_segmentation.metrics import MaskScores, mean_scores, score_mask
from suture_segmentation.model import FeatureExtractor, SutureUNet, pad_to_multiple
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


def test_frozen_extractor_is_unchanged_by_training_and_the_decoder_learns() -> None:
    torch.manual_seed(0)
    model = SutureUNet((4, 4, 8, 8, 8))
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


def test_bad_widths_are_refused() -> None:
    with pytest.raises(ValueError, match="five positive"):
        SutureUNet((8, 16, 32))


def test_padding_to_a_multiple_of_16_keeps_the_original_size() -> None:
    padded, size = pad_to_multiple(torch.rand(1, 3, 50, 70))
    assert padded.shape[-2:] == (64, 80) and size == (50, 70)


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
