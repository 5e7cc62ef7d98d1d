# SPDX-License-Identifier: Apache-2.0
"""Shared fixtures: a small random-weights checkpoint and tiny labelled PNG folders."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from suture_segmentation.checkpoint import save_checkpoint
from suture_segmentation.model import SutureUNet


@pytest.fixture(scope="session")
def random_checkpoint(tmp_path_factory: pytest.TempPathFactory) -> Path:
    torch.manual_seed(0)
    return save_checkpoint(SutureUNet((4, 4, 8, 8, 8)), tmp_path_factory.mktemp("weights") / "random.pt")


def line_image(rng: np.random.Generator, size: tuple[int, int] = (96, 64)) -> tuple[np.ndarray, np.ndarray]:
    """A noisy reddish background with one dark random line: (H, W, 3) uint8 RGB and (H, W) mask."""
    width, height = size
    image = np.empty((height, width, 3), np.uint8)
    image[:] = (170, 80, 70)
    image = np.clip(image + rng.normal(0, 12, image.shape), 0, 255).astype(np.uint8)
    mask = np.zeros((height, width), np.uint8)
    p0 = (int(rng.integers(0, width)), 0)
    p1 = (int(rng.integers(0, width)), height - 1)
    cv2.line(mask, p0, p1, 255, 2)
    image[mask > 0] = (40, 20, 90)
    return image, mask


def write_folder(folder: Path, count: int, seed: int, size: tuple[int, int] = (96, 64)) -> Path:
    """Write ``count`` :func:`line_image` pairs as images/NAME.png and masks/NAME.png."""
    rng = np.random.default_rng(seed)
    (folder / "images").mkdir(parents=True, exist_ok=True)
    (folder / "masks").mkdir(parents=True, exist_ok=True)
    for k in range(count):
        image, mask = line_image(rng, size)
        cv2.imwrite(str(folder / "images" / f"{k:03d}.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
        cv2.imwrite(str(folder / "masks" / f"{k:03d}.png"), mask)
    return folder


@pytest.fixture()
def line_folder(tmp_path: Path) -> Path:
    return write_folder(tmp_path / "lines", 6, seed=1)


@pytest.fixture()
def make_folder():
    """The :func:`write_folder` function, for tests that need several folders."""
    return write_folder
