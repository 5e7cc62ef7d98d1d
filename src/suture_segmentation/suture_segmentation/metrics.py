"""Segmentation metrics of the paper (Section III.A): IoU, precision, recall and F1 per image."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np


@dataclass(frozen=True)
class MaskScores:
    """Scores of one predicted mask against its ground truth, each in [0, 1].

    An empty prediction has precision 0; an empty ground truth has recall 1 when the
    prediction is empty too (nothing to find, nothing found) and 0 otherwise.
    """

    iou: float
    precision: float
    recall: float
    f1: float

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def score_mask(predicted: np.ndarray, truth: np.ndarray) -> MaskScores:
    """Scores of (H, W) ``predicted`` against (H, W) ``truth``; nonzero = suture in both."""
    predicted, truth = np.asarray(predicted) > 0, np.asarray(truth) > 0
    if predicted.shape != truth.shape:
        raise ValueError(f"mask shapes differ: {predicted.shape} vs {truth.shape}")
    tp = int(np.count_nonzero(predicted & truth))
    n_pred, n_true = int(np.count_nonzero(predicted)), int(np.count_nonzero(truth))
    if n_pred == 0 and n_true == 0:
        return MaskScores(1.0, 1.0, 1.0, 1.0)
    precision = tp / n_pred if n_pred else 0.0
    recall = tp / n_true if n_true else 0.0
    iou = tp / (n_pred + n_true - tp)
    f1 = 2 * precision * recall / (precision + recall) if precision + recall else 0.0
    return MaskScores(iou, precision, recall, f1)


def mean_scores(scores: list[MaskScores]) -> MaskScores:
    """Average of per-image scores (the paper's "ave" rows)."""
    if not scores:
        raise ValueError("no scores to average")
    return MaskScores(
        *(float(np.mean([getattr(s, k) for s in scores])) for k in ("iou", "precision", "recall", "f1"))
    )
