# SPDX-License-Identifier: Apache-2.0
"""Tests of the kornia training augmentation: image and mask stay aligned."""

from __future__ import annotations

import cv2
import numpy as np
import torch

from suture_segmentation.augment import augment_batch, make_augmenter
from suture_segmentation.train import TrainConfig


def _lines(count: int, size: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(B, 3, S, S) float32 images, bright lines of 1 to 5 px on dark, and their (B, S, S) labels."""
    rng = np.random.default_rng(seed)
    labels = np.zeros((count, size, size), np.int64)
    for k in range(count):
        mask = np.zeros((size, size), np.uint8)
        start = (int(rng.integers(0, size // 4)), int(rng.integers(0, size)))
        end = (int(rng.integers(3 * size // 4, size)), int(rng.integers(0, size)))
        cv2.line(mask, start, end, 1, int(rng.integers(1, 6)))
        labels[k] = mask
    images = np.repeat(labels[:, None].astype(np.float32), 3, axis=1) * np.float32(0.6) + np.float32(0.2)
    return images, labels


def test_geometric_augmentation_moves_image_and_mask_alike() -> None:
    torch.manual_seed(0)
    images, labels = _lines(16, 96, seed=1)
    out_images, out_labels = augment_batch(make_augmenter(photometric=False), images, labels)
    assert out_images.shape == images.shape and out_images.dtype == np.float32
    assert out_labels.shape == labels.shape and out_labels.dtype == np.int64
    assert set(np.unique(out_labels)) <= {0, 1}
    warped = [k for k in range(16) if not np.array_equal(out_labels[k], labels[k])]
    assert len(warped) >= 4  # most crops are warped
    cross = np.ones((3, 3), np.uint8)
    for k in warped:
        on = (out_labels[k] == 1).astype(np.uint8)
        bright = (out_images[k, 0] > 0.5).astype(np.uint8)
        lit = (out_images[k, 0] > 0.3).astype(np.uint8)
        # The line of the warped image is where the warped mask says, and back: within one pixel
        # (two nearest-neighbour resamplings of the mask may each move it by half a pixel).
        if bright.any():
            assert (cv2.dilate(on, cross)[bright > 0]).mean() > 0.9
            assert (cv2.dilate(on, cross, iterations=2)[bright > 0]).mean() == 1.0
        if on.sum() >= 20:
            assert (cv2.dilate(lit, cross)[on > 0]).mean() > 0.95


def test_full_augmentation_keeps_the_thread_on_its_mask() -> None:
    torch.manual_seed(3)
    images, labels = _lines(16, 96, seed=2)
    out_images, out_labels = augment_batch(make_augmenter(), images, labels)
    assert out_images.min() >= 0.0 and out_images.max() <= 1.0
    for k in range(16):
        on = out_labels[k] == 1
        if on.sum() < 20:
            continue
        grey = out_images[k].mean(axis=0)
        # photometric changes alone keep the bright line brighter than its dark background
        assert grey[on].mean() > grey[~on].mean() + 0.1


def test_augment_is_a_training_option() -> None:
    assert TrainConfig().augment is False
    assert TrainConfig(augment=True).augment is True
