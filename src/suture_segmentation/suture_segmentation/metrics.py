# SPDX-License-Identifier: Apache-2.0
"""Segmentation metrics: the paper's IoU, precision, recall and F1 (Section III.A) and
thin-structure measures of the centreline, per image or pooled over many.

Thin-structure measures (a thread a few pixels wide loses much IoU to a one-pixel shift
of its edges, yet is found as well as before):

* centreline recall: share of the true mask's skeleton within 1 px (Euclidean, so the
  4-neighbours) of the predicted mask;
* centreline precision: share of the predicted mask's skeleton within 1 px of the true mask;
* clDice (Shit et al., CVPR 2021): 2 Tprec Tsens / (Tprec + Tsens), with Tprec the share of
  the predicted skeleton inside the true mask and Tsens the share of the true skeleton inside
  the predicted mask, without tolerance.

Skeletons are scikit-image's ``skeletonize`` of the masks.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import cv2
import numpy as np
from skimage.morphology import skeletonize

_WITHIN_1PX = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))


@dataclass(frozen=True)
class MaskScores:
    """Scores of one predicted mask against its ground truth, each in [0, 1].

    An empty prediction has precision 0; an empty ground truth has recall 1 when the
    prediction is empty too (nothing to find, nothing found) and 0 otherwise. The
    centreline figures follow the same rule; None where not measured.
    """

    iou: float
    precision: float
    recall: float
    f1: float
    centreline_recall: float | None = None
    centreline_precision: float | None = None
    cldice: float | None = None

    def as_dict(self) -> dict[str, float | None]:
        return asdict(self)


@dataclass
class CentrelineCounts:
    """Skeleton pixel counts of one or more mask pairs; pooled figures by :meth:`figures`.

    ``true_near``/``true_inside``: true skeleton pixels within 1 px of / inside the predicted
    mask, of ``true_total``; ``predicted_near``/``predicted_inside`` likewise of ``predicted_total``.
    """

    true_total: int = 0
    true_near: int = 0
    true_inside: int = 0
    predicted_total: int = 0
    predicted_near: int = 0
    predicted_inside: int = 0

    def __add__(self, other: CentrelineCounts) -> CentrelineCounts:
        return CentrelineCounts(*(getattr(self, f.name) + getattr(other, f.name) for f in fields(self)))

    def figures(self) -> dict[str, float | None]:
        """``centreline_recall``, ``centreline_precision`` and ``cldice``; None when no skeleton at all."""
        if self.true_total == 0 and self.predicted_total == 0:
            return {"centreline_recall": None, "centreline_precision": None, "cldice": None}
        recall = _share(self.true_near, self.true_total, self.predicted_total)
        precision = _share(self.predicted_near, self.predicted_total, self.true_total)
        sensitivity = _share(self.true_inside, self.true_total, self.predicted_total)
        topology_precision = _share(self.predicted_inside, self.predicted_total, self.true_total)
        both = sensitivity + topology_precision
        return {
            "centreline_recall": recall,
            "centreline_precision": precision,
            "cldice": 2 * sensitivity * topology_precision / both if both else 0.0,
        }


def _share(hits: int, total: int, other_total: int) -> float:
    """hits / total; with nothing to find, 1 when the other side is empty too, else 0."""
    if total:
        return hits / total
    return 1.0 if other_total == 0 else 0.0


def centreline_counts(predicted: np.ndarray, truth: np.ndarray) -> CentrelineCounts:
    """Skeleton counts of (H, W) ``predicted`` against (H, W) ``truth``; nonzero = suture."""
    predicted, truth = _masks(predicted, truth)
    true_skeleton, predicted_skeleton = skeletonize(truth), skeletonize(predicted)
    near_predicted = cv2.dilate(predicted.view(np.uint8), _WITHIN_1PX).view(bool)
    near_truth = cv2.dilate(truth.view(np.uint8), _WITHIN_1PX).view(bool)
    return CentrelineCounts(
        true_total=int(np.count_nonzero(true_skeleton)),
        true_near=int(np.count_nonzero(true_skeleton & near_predicted)),
        true_inside=int(np.count_nonzero(true_skeleton & predicted)),
        predicted_total=int(np.count_nonzero(predicted_skeleton)),
        predicted_near=int(np.count_nonzero(predicted_skeleton & near_truth)),
        predicted_inside=int(np.count_nonzero(predicted_skeleton & truth)),
    )


def _masks(predicted: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    predicted, truth = np.asarray(predicted) > 0, np.asarray(truth) > 0
    if predicted.shape != truth.shape:
        raise ValueError(f"mask shapes differ: {predicted.shape} vs {truth.shape}")
    return np.ascontiguousarray(predicted), np.ascontiguousarray(truth)


def score_mask(predicted: np.ndarray, truth: np.ndarray) -> MaskScores:
    """Scores of (H, W) ``predicted`` against (H, W) ``truth``; nonzero = suture in both."""
    predicted, truth = _masks(predicted, truth)
    tp = int(np.count_nonzero(predicted & truth))
    n_pred, n_true = int(np.count_nonzero(predicted)), int(np.count_nonzero(truth))
    if n_pred == 0 and n_true == 0:
        return MaskScores(1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0)
    precision = tp / n_pred if n_pred else 0.0
    recall = tp / n_true if n_true else 0.0
    iou = tp / (n_pred + n_true - tp)
    f1 = 2 * precision * recall / (precision + recall) if precision + recall else 0.0
    return MaskScores(iou, precision, recall, f1, **centreline_counts(predicted, truth).figures())


def mean_scores(scores: list[MaskScores]) -> MaskScores:
    """Average of per-image scores (the paper's "ave" rows); a figure measured nowhere stays None."""
    if not scores:
        raise ValueError("no scores to average")
    means: dict[str, float | None] = {}
    for name in (f.name for f in fields(MaskScores)):
        values = [getattr(s, name) for s in scores if getattr(s, name) is not None]
        means[name] = float(np.mean(values)) if values else None
    return MaskScores(**means)
