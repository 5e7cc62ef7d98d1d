# SPDX-License-Identifier: Apache-2.0
"""Thin-structure measures (centreline recall, precision, clDice) on shapes with known answers."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from suture_segmentation.metrics import CentrelineCounts, centreline_counts, mean_scores, score_mask


def thread(width: int = 5, shape: tuple[int, int] = (120, 160)) -> np.ndarray:
    """A curved thread ``width`` px wide, as a mask."""
    mask = np.zeros(shape, np.uint8)
    u = np.arange(10, 150)
    points = np.column_stack([u, 60 + 30 * np.sin(u / 25.0)]).round().astype(np.int32)
    cv2.polylines(mask, [points], False, 255, width)
    return mask > 0


def test_a_one_pixel_shift_keeps_the_centreline_while_iou_drops():
    truth = thread()
    shifted = np.roll(truth, 1, axis=1)
    scores = score_mask(shifted, truth)
    assert scores.centreline_recall == 1.0 and scores.centreline_precision == 1.0
    assert scores.cldice == 1.0
    assert scores.iou < 0.85


def test_a_mask_missing_half_the_thread_finds_half_the_centreline():
    truth = thread()
    half = truth.copy()
    half[:, 80:] = False
    scores = score_mask(half, truth)
    assert scores.centreline_recall == pytest.approx(0.5, abs=0.06)
    assert scores.centreline_precision == 1.0  # what it found is on the thread
    assert scores.cldice == pytest.approx(2 * 0.5 / 1.5, abs=0.05)


def test_a_thinner_prediction_is_complete_but_a_wrong_one_is_not():
    truth = thread(width=7)
    assert score_mask(thread(width=3), truth).centreline_recall == 1.0
    elsewhere = np.roll(truth, 20, axis=0)
    scores = score_mask(elsewhere, truth)
    assert scores.centreline_recall < 0.2 and scores.centreline_precision < 0.2


def test_counts_pool_over_images_and_empty_masks_follow_the_iou_rule():
    truth = thread()
    empty = np.zeros_like(truth)
    pooled = centreline_counts(truth, truth) + centreline_counts(empty, truth)
    assert pooled.figures()["centreline_recall"] == pytest.approx(0.5)
    assert CentrelineCounts().figures()["cldice"] is None
    nothing = score_mask(empty, empty)
    assert (nothing.centreline_recall, nothing.centreline_precision, nothing.cldice) == (1.0, 1.0, 1.0)
    assert score_mask(empty, truth).centreline_recall == 0.0
    mean = mean_scores([score_mask(truth, truth), score_mask(empty, truth)])
    assert mean.centreline_recall == pytest.approx(0.5)
