# SPDX-License-Identifier: Apache-2.0
"""Training and fine-tuning loops (the paper's offline training and transfer, Section II.A).

* :func:`train` fits every layer: M-oST on legacy synthetic images, M-TOT on the 40 on-site ones.
* :func:`finetune` starts from a checkpoint, freezes the 13-layer feature extractor and fits the
  rest: M-ToSOT.

Both draw random crops (:class:`~suture_segmentation.data.CropSampler`), minimise the
cross-entropy of the paper (``loss="ce"``) or another loss of :func:`segmentation_loss`, use
Adam with a cosine learning-rate decay, log one JSON line of metrics per epoch (loss, and
IoU/precision/recall/F1 on the validation images at full size), and keep the checkpoint of the
last epoch and of the best validation IoU.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
from skimage.morphology import skeletonize
from torch.nn import functional
from tqdm import tqdm

from suture_segmentation.checkpoint import load_checkpoint, save_checkpoint
from suture_segmentation.data import CropSampler, LabelledImages
from suture_segmentation.metrics import mean_scores, score_mask
from suture_segmentation.model import FULL_RESOLUTION_STRIDE, SUTURE, SutureUNet, suture_probability

LOSSES = ("ce", "ce_dice", "ce_skeleton")
SKELETON_WEIGHT = 0.1
"""Default weight of the skeleton recall term of ``ce_skeleton``; at 1 models paint threads twice as thick."""


@dataclass
class TrainConfig:
    """Hyper-parameters; every field is a CLI option of ``suture-seg train|finetune``.

    Attributes:
        epochs: number of epochs; one epoch is ``steps_per_epoch`` batches.
        steps_per_epoch: batches per epoch.
        batch_size: crops per batch.
        crop: crop side in pixels (a multiple of 16; of 32 for a half-resolution model).
        learning_rate: initial Adam learning rate (cosine decay to 5 % of it).
        loss: "ce" (the paper), "ce_dice" or "ce_skeleton" (:func:`segmentation_loss`).
        skeleton_weight: weight of the skeleton recall term of "ce_skeleton".
        on_thread: fraction of crops centred on the thread.
        structure_crops: fraction of crops centred on the thread's ends and junctions (part of
            ``on_thread``; :class:`~suture_segmentation.data.CropSampler`).
        photometric: vary the look of the crops (:func:`~suture_segmentation.data.photometric_jitter`).
        augment: warp and re-colour every batch with kornia
            (:func:`~suture_segmentation.augment.make_augmenter`), after ``photometric``.
        all_layers: :func:`finetune` trains the feature extractor too instead of freezing it
            (:func:`train` always trains every layer).
        seed: seeds numpy and torch.
        threads: torch CPU threads (None: the default).
    """

    epochs: int = 20
    steps_per_epoch: int = 100
    batch_size: int = 8
    crop: int = 192
    learning_rate: float = 3e-3
    loss: str = "ce"
    skeleton_weight: float = SKELETON_WEIGHT
    on_thread: float = 0.7
    structure_crops: float = 0.0
    photometric: bool = False
    augment: bool = False
    all_layers: bool = False
    seed: int = 0
    threads: int | None = None

    def __post_init__(self) -> None:
        if self.loss not in LOSSES:
            raise ValueError(f"unknown loss {self.loss!r}; choose {' or '.join(LOSSES)}")
        if self.skeleton_weight < 0:
            raise ValueError(f"skeleton weight must be at least 0, got {self.skeleton_weight}")
        if not 0.0 <= self.structure_crops <= self.on_thread:
            raise ValueError(
                f"structure crops must be in [0, on_thread={self.on_thread}], got {self.structure_crops}"
            )
        if self.crop % FULL_RESOLUTION_STRIDE or self.crop <= 0:
            raise ValueError(f"crop must be a positive multiple of {FULL_RESOLUTION_STRIDE}, got {self.crop}")
        if min(self.epochs, self.steps_per_epoch, self.batch_size) < 1:
            raise ValueError("epochs, steps per epoch and batch size must be at least 1")


def tubed_skeleton(labels: np.ndarray) -> np.ndarray:
    """(B, H, W) float32: 1 on the suture's centre line in each (B, H, W) label map, thickened by
    one pixel (a 3x3 cross) and kept inside the suture."""
    cross = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
    tubes = np.zeros(labels.shape, np.float32)
    for k, crop in enumerate(labels == SUTURE):
        skeleton = skeletonize(crop).astype(np.uint8)
        tubes[k] = cv2.dilate(skeleton, cross) & crop
    return tubes


def segmentation_loss(
    logits: torch.Tensor, labels: torch.Tensor, loss: str, skeleton_weight: float = SKELETON_WEIGHT
) -> torch.Tensor:
    """Loss of (B, 2, H, W) logits against (B, H, W) int64 labels.

    "ce": the paper's cross-entropy. "ce_dice": plus one minus the soft Dice of the suture class
    per crop. "ce_skeleton": plus one minus the soft recall of the suture's tubed centre line
    (:func:`tubed_skeleton`; the skeleton recall loss of Kirchhoff et al., ECCV 2024), which
    penalises a gap across a thin thread far more than cross-entropy does, and a gap is what
    ends the ordering's walk early.
    """
    value = functional.cross_entropy(logits, labels)
    if loss == "ce_dice":
        suture = torch.softmax(logits, dim=1)[:, SUTURE]
        truth = (labels == SUTURE).float()
        intersection = (suture * truth).sum(dim=(1, 2))
        dice = (2 * intersection + 1.0) / (suture.sum(dim=(1, 2)) + truth.sum(dim=(1, 2)) + 1.0)
        value = value + (1.0 - dice).mean()
    elif loss == "ce_skeleton":
        suture = torch.softmax(logits, dim=1)[:, SUTURE]
        tube = torch.from_numpy(tubed_skeleton(labels.cpu().numpy())).to(logits.device)
        recall = ((suture * tube).sum() + 1.0) / (tube.sum() + 1.0)
        value = value + skeleton_weight * (1.0 - recall)
    return value


def predict_probabilities(model: SutureUNet, image: np.ndarray, device: str = "cpu") -> np.ndarray:
    """(H, W) float32 suture probability of one (H, W, 3) uint8 RGB image."""
    was_training = model.training
    model.eval()
    batch = torch.from_numpy(image).permute(2, 0, 1)[None].float().div_(255.0)
    probability = suture_probability(model, batch.to(device))[0].cpu().numpy()
    model.train(was_training)
    return probability


def evaluate_model(
    model: SutureUNet, data: LabelledImages, threshold: float = 0.5, device: str = "cpu"
) -> dict[str, float]:
    """Mean IoU, precision, recall and F1 of ``model`` over ``data`` (full images)."""
    scores = [
        score_mask(predict_probabilities(model, image, device) > threshold, mask)
        for image, mask in zip(data.images, data.masks, strict=True)
    ]
    return mean_scores(scores).as_dict()


def train(
    model: SutureUNet,
    training: LabelledImages,
    validation: LabelledImages,
    config: TrainConfig,
    out_dir: str | Path,
    meta: dict[str, Any] | None = None,
    device: str = "cpu",
    progress: bool = True,
) -> dict[str, Any]:
    """Fit the trainable parameters of ``model``; writes ``last.pt``, ``best.pt`` and ``log.jsonl``.

    Returns the log line of the best epoch (by validation IoU).
    """
    if config.crop % model.stride:
        raise ValueError(f"crop must be a multiple of the model's stride {model.stride}, got {config.crop}")
    if config.threads:
        torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    sampler = CropSampler(
        training,
        config.crop,
        config.on_thread,
        np.random.default_rng(config.seed),
        config.photometric,
        config.structure_crops,
    )
    augmenter = None
    if config.augment:
        from suture_segmentation.augment import augment_batch, make_augmenter

        augmenter = make_augmenter()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    model.to(device).train()
    parameters = model.trainable_parameters()
    optimiser = torch.optim.Adam(parameters, lr=config.learning_rate)
    total_steps = config.epochs * config.steps_per_epoch
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(
        optimiser, total_steps, eta_min=0.05 * config.learning_rate
    )
    meta = {**(meta or {}), "config": asdict(config), "training_images": len(training)}
    best: dict[str, Any] = {"val_iou": -1.0}
    log_path = out_dir / "log.jsonl"
    log_path.write_text("")
    started = time.monotonic()
    for epoch in range(1, config.epochs + 1):
        losses = []
        bar = tqdm(
            range(config.steps_per_epoch),
            desc=f"epoch {epoch}/{config.epochs}",
            disable=not progress,
            leave=False,
        )
        for _ in bar:
            images, labels = sampler.batch(config.batch_size)
            if augmenter is not None:
                images, labels = augment_batch(augmenter, images, labels, device)
            logits = model(torch.from_numpy(images).to(device))
            loss = segmentation_loss(
                logits, torch.from_numpy(labels).to(device), config.loss, config.skeleton_weight
            )
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            optimiser.step()
            schedule.step()
            losses.append(loss.item())
            bar.set_postfix(loss=f"{np.mean(losses[-20:]):.4f}")
        scores = evaluate_model(model, validation, device=device)
        line = {
            "epoch": epoch,
            "loss": float(np.mean(losses)),
            "lr": schedule.get_last_lr()[0],
            **{f"val_{k}": v for k, v in scores.items()},
            "elapsed_s": round(time.monotonic() - started, 1),
        }
        with log_path.open("a") as log:
            log.write(json.dumps(line) + "\n")
        if progress:
            print(
                f"epoch {epoch}/{config.epochs}  loss {line['loss']:.4f}  val IoU {scores['iou']:.3f}  "
                f"precision {scores['precision']:.3f}  recall {scores['recall']:.3f}  F1 {scores['f1']:.3f}  "
                f"({line['elapsed_s']:.0f} s)",
                flush=True,
            )
        save_checkpoint(model, out_dir / "last.pt", {**meta, "epoch": epoch, **line})
        if scores["iou"] > best["val_iou"]:
            best = line
            save_checkpoint(model, out_dir / "best.pt", {**meta, "epoch": epoch, **line})
    return best


def finetune(
    checkpoint: str | Path,
    training: LabelledImages,
    validation: LabelledImages,
    config: TrainConfig,
    out_dir: str | Path,
    meta: dict[str, Any] | None = None,
    device: str = "cpu",
    progress: bool = True,
) -> dict[str, Any]:
    """Transfer: load ``checkpoint``, freeze its feature extractor, train the rest (see :func:`train`);
    with ``config.all_layers`` train every layer.

    ``checkpoint`` is a .pt path or a shipped model's name (``"m_ost"``, ``"m_onsite_half"`` ...).
    """
    model, source_meta = load_checkpoint(checkpoint, device)
    if not config.all_layers:
        model.freeze_feature_extractor()
    meta = {**(meta or {}), "finetuned_from": str(checkpoint), "source": source_meta.get("command")}
    return train(model, training, validation, config, out_dir, meta, device, progress)
