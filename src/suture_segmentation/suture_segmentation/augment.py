# SPDX-License-Identifier: Apache-2.0
"""On-the-fly photometric and geometric augmentation of training batches (kornia).

:func:`make_augmenter` builds one kornia ``AugmentationSequential`` that draws, per crop of a
batch, a geometric warp (rotation, scale, shear, shift, perspective) applied to the image and to
its label map alike (the labels by nearest-neighbour sampling, so they stay 0/1), then a
photometric change of the image alone (brightness, contrast, saturation, hue, gamma, blur,
motion blur, noise). Its randomness is torch's (seeded by the training loop).

Used by ``suture-seg train|finetune --augment``; the older ``--photometric`` jitter
(:func:`suture_segmentation.data.photometric_jitter`) is independent of it.
"""

from __future__ import annotations

import numpy as np
import torch


def make_augmenter(photometric: bool = True, geometric: bool = True) -> torch.nn.Module:
    """The kornia augmentation pipeline (module docstring).

    Args:
        photometric: include the changes of the image alone.
        geometric: include the warps of image and labels.

    Returns:
        A module called as ``augmenter(images, masks)`` on (B, 3, H, W) float32 images in [0, 1]
        and (B, 1, H, W) float32 masks in {0, 1}; returns both, warped alike.
    """
    import kornia.augmentation as k

    steps: list[torch.nn.Module] = []
    if geometric:
        steps += [
            k.RandomAffine(
                degrees=30.0,
                translate=(0.05, 0.05),
                scale=(0.8, 1.25),
                shear=8.0,
                padding_mode="reflection",
                p=0.5,
            ),
            k.RandomPerspective(distortion_scale=0.2, p=0.2),
        ]
    if photometric:
        steps += [
            k.ColorJiggle(brightness=0.3, contrast=0.35, saturation=0.5, hue=0.08, p=0.6),
            k.RandomGamma(gamma=(0.6, 1.6), p=0.4),
            k.RandomGaussianBlur(kernel_size=(5, 5), sigma=(0.2, 1.2), p=0.25),
            k.RandomMotionBlur(kernel_size=5, angle=90.0, direction=0.5, p=0.15),
            k.RandomGaussianNoise(mean=0.0, std=0.03, p=0.4),
        ]
    return k.AugmentationSequential(*steps, data_keys=["input", "mask"])


def augment_batch(
    augmenter: torch.nn.Module, images: np.ndarray, labels: np.ndarray, device: str = "cpu"
) -> tuple[np.ndarray, np.ndarray]:
    """Apply ``augmenter`` to a training batch.

    Args:
        augmenter: from :func:`make_augmenter`.
        images: (B, 3, H, W) float32 in [0, 1].
        labels: (B, H, W) int64 in {0, 1}.
        device: where the warps and colour changes run ("cuda" when training there: on the CPU
            they cost more than the training step itself).

    Returns:
        (B, 3, H, W) float32 images clipped to [0, 1] and (B, H, W) int64 labels, warped alike.
    """
    with torch.no_grad():
        image_t = torch.from_numpy(np.ascontiguousarray(images)).to(device)
        mask_t = torch.from_numpy(np.ascontiguousarray(labels)).to(device).float()[:, None]
        out_image, out_mask = augmenter(image_t, mask_t)
    out_labels = (out_mask[:, 0] > 0.5).long().cpu().numpy()
    return out_image.clamp_(0.0, 1.0).cpu().numpy().astype(np.float32, copy=False), out_labels
