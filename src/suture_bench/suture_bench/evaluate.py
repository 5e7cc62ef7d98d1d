"""Offline evaluation over MCAP bags: the same core functions as the nodes, scored against ground truth.

``evaluate(paths, masks=..., sequences=...)`` walks every frame of the bags,
runs the stages that the sources ask for, and returns the summary of DESIGN.md's
evaluation contract (every key present; a value that could not be measured is
None, with the reason in ``notes``):

* ``masks="ground_truth"`` starts the ordering stage from the true masks;
  ``"predicted"`` runs the segmentation stage (``suture_segmentation``).
* ``sequences="ground_truth"`` starts the 3D stage from the true ordered
  sequences (the visibility column dropped), isolating it; ``"predicted"`` runs the
  ordering stage on the masks.

Definitions (DESIGN.md): IoU, precision, recall and F1 pooled over the pixels of
all frames; ordering success per ``suture_bench.ordering_metrics``; reconstruction
error is the distance from each reconstructed path point to the true 3D
centreline (mean over frames of the per-frame mean, max over frames of the
per-frame max); grasp error is the 3D distance between predicted and true grasp
points. Latencies are wall-clock milliseconds per stereo frame (medians).
"""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from suture_bench.frames import EvaluationError, Frame, find_bags, read_frames
from suture_common.bag_io import BagError

SOURCES = ("predicted", "ground_truth")


@dataclass
class _Tally:
    """Running sums and per-frame records over the whole evaluation."""

    frames: int = 0
    pixels: np.ndarray = field(default_factory=lambda: np.zeros(3, dtype=np.int64))  # tp, fp, fn
    ordering: dict[str, list[bool]] = field(default_factory=lambda: defaultdict(list))
    recon_mean: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))
    recon_max: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))
    grasp: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))
    length_error: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))
    keypoints: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))
    latency: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))
    failures: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    notes: list[str] = field(default_factory=list)
    per_frame: list[dict[str, Any]] = field(default_factory=list)

    def note(self, text: str) -> None:
        if text not in self.notes:
            self.notes.append(text)


def evaluate(
    paths: Iterable[str | Path],
    masks: str = "predicted",
    sequences: str = "predicted",
    seg_weights: str | None = None,
) -> dict:
    """Run and score the pipeline over the bags at ``paths``; returns the JSON summary (a dict).

    ``seg_weights`` picks the segmentation model for ``masks="predicted"`` (a checkpoint path or
    a shipped name, ``m_tosot`` or ``m_ost``); None is the stage's default (shipped M-ToSOT).
    """
    if masks not in SOURCES or sequences not in SOURCES:
        raise EvaluationError(f"masks and sequences must be one of {SOURCES}, got {masks!r}, {sequences!r}")
    stages = _Stages(masks, sequences, seg_weights)
    tally = _Tally()
    for bag in find_bags(paths):
        try:
            for frame in read_frames(bag, images=masks == "predicted"):
                _evaluate_frame(frame, stages, tally)
        except BagError as error:
            raise EvaluationError(str(error)) from error
    return _summary(tally, masks, sequences)


class _Stages:
    """The stage entry points the sources need; a stage that is not run is not imported
    (segmentation pulls in torch and loads a model).

    ``segment(left_image, right_image) -> (left_mask, right_mask)`` is
    :meth:`suture_segmentation.core.Segmenter.segment_pair`;
    ``order(left_mask, right_mask, tip_hint, camera)`` is
    :func:`suture_ordering.core.order_stereo` (``.left``/``.right`` (N, 2) sequences);
    ``reconstruct(left, right, camera)`` is :func:`suture_reconstruction.core.reconstruct`
    (``.path``, ``.grasp_position``).
    """

    def __init__(self, masks: str, sequences: str, seg_weights: str | None) -> None:
        from suture_reconstruction.core import reconstruct

        self.masks, self.sequences = masks, sequences
        self.segment: Callable[..., tuple[np.ndarray, np.ndarray]] | None = None
        self.order: Callable[..., Any] | None = None
        self.reconstruct = reconstruct
        if masks == "predicted":
            from suture_segmentation.core import Segmenter

            self.segment = Segmenter(seg_weights).segment_pair
        if sequences == "predicted":
            from suture_ordering.core import order_stereo

            self.order = order_stereo


def _evaluate_frame(frame: Frame, stages: _Stages, tally: _Tally) -> None:
    from suture_bench.ordering_metrics import ordering_success
    from suture_bench.reconstruction_metrics import score_reconstruction

    tally.frames += 1
    record: dict[str, Any] = {"stamp_ns": frame.stamp_ns, "topology": frame.topology}
    tally.per_frame.append(record)
    total = 0.0

    masks = (frame.true_left_mask, frame.true_right_mask)
    if stages.segment is not None:
        start = time.perf_counter()
        masks = stages.segment(frame.left_image, frame.right_image)
        total += _lap(tally, "segmentation", start)
        for predicted, truth in zip(masks, (frame.true_left_mask, frame.true_right_mask), strict=True):
            predicted = np.asarray(predicted) > 0
            tally.pixels += [
                np.sum(predicted & truth),
                np.sum(predicted & ~truth),
                np.sum(~predicted & truth),
            ]

    sequences: tuple[np.ndarray, np.ndarray] | None = (
        frame.true_left_sequence[:, :2],
        frame.true_right_sequence[:, :2],
    )
    if stages.order is not None:
        start = time.perf_counter()
        try:
            ordering = stages.order(masks[0], masks[1], frame.tip_hint, frame.camera)
        except ValueError as error:
            tally.failures[f"ordering: {type(error).__name__}"] += 1
            record["ordering_error"] = str(error)
            ordering = None
        total += _lap(tally, "ordering", start)
        success = ordering is not None and ordering_success(ordering.left, frame.true_left_sequence).success
        tally.ordering[frame.topology].append(bool(success))
        record["ordering_success"] = bool(success)
        sequences = None if ordering is None else (ordering.left, ordering.right)

    if sequences is None:
        return
    start = time.perf_counter()
    try:
        result = stages.reconstruct(sequences[0], sequences[1], frame.camera)
    except ValueError as error:
        _lap(tally, "reconstruction", start)
        tally.failures[f"reconstruction: {type(error).__name__}"] += 1
        record["reconstruction_error"] = str(error)
        return
    total += _lap(tally, "reconstruction", start)
    tally.latency["total"].append(total)
    score = score_reconstruction(result.path, frame.true_path, result.grasp_position, frame.true_grasp)
    tally.recon_mean[frame.topology].append(score.mean_error)
    tally.recon_max[frame.topology].append(score.max_error)
    tally.length_error[frame.topology].append(abs(score.length_error))
    tally.keypoints[frame.topology].append(float(np.mean(score.keypoint_errors)))
    tally.grasp[frame.topology].append(score.grasp_error)
    record.update(score.as_mm(), grasp_position=np.asarray(result.grasp_position).tolist())


def _lap(tally: _Tally, stage: str, start: float) -> float:
    elapsed = 1000 * (time.perf_counter() - start)
    tally.latency[stage].append(elapsed)
    return elapsed


def _mean(values: Iterable[float], scale: float = 1.0) -> float | None:
    values = list(values)
    return float(np.mean(values)) * scale if values else None


def _summary(tally: _Tally, masks: str, sequences: str) -> dict:
    tp, fp, fn = (int(v) for v in tally.pixels)
    segmentation: dict[str, float | None] = {"iou": None, "precision": None, "recall": None, "f1": None}
    if tp + fp + fn > 0:
        precision = tp / (tp + fp) if tp + fp else 0.0
        recall = tp / (tp + fn) if tp + fn else 0.0
        segmentation = {
            "iou": tp / (tp + fp + fn),
            "precision": precision,
            "recall": recall,
            "f1": 2 * precision * recall / (precision + recall) if precision + recall else 0.0,
        }
    elif masks == "ground_truth":
        tally.note("segmentation: not run (--masks ground_truth)")
    all_ordering = [ok for values in tally.ordering.values() for ok in values]
    if sequences == "ground_truth":
        tally.note("ordering: not run (--sequences ground_truth)")
    all_means = [v for values in tally.recon_mean.values() for v in values]
    all_max = [v for values in tally.recon_max.values() for v in values]
    all_grasp = [v for values in tally.grasp.values() for v in values]
    for failure, count in sorted(tally.failures.items()):
        tally.note(f"{failure} in {count} frame(s): counted as failures, excluded from error figures")
    return {
        "frames": tally.frames,
        "masks": masks,
        "sequences": sequences,
        "segmentation": segmentation,
        "ordering": {
            "success_rate": _mean(all_ordering),
            "by_topology": {t: _mean(v) for t, v in sorted(tally.ordering.items())},
        },
        "reconstruction": {
            "mean_error_mm": _mean(all_means, 1000),
            "max_error_mm": float(np.max(all_max)) * 1000 if all_max else None,
            "by_topology": {
                t: {
                    "mean_error_mm": _mean(tally.recon_mean[t], 1000),
                    "max_error_mm": float(np.max(tally.recon_max[t])) * 1000,
                    "worst_frame_mean_error_mm": float(np.max(tally.recon_mean[t])) * 1000,
                    "grasp_median_error_mm": float(np.median(tally.grasp[t])) * 1000,
                    "grasp_max_error_mm": float(np.max(tally.grasp[t])) * 1000,
                    "length_error_mm": _mean(tally.length_error[t], 1000),
                    "keypoint_error_mm": _mean(tally.keypoints[t], 1000),
                    "frames": len(tally.recon_mean[t]),
                }
                for t in sorted(tally.recon_mean)
            },
        },
        "grasp": {
            "median_error_mm": float(np.median(all_grasp)) * 1000 if all_grasp else None,
            "max_error_mm": float(np.max(all_grasp)) * 1000 if all_grasp else None,
            "within_5mm": _mean(np.asarray(all_grasp) <= 0.005) if all_grasp else None,
        },
        "latency_ms": {
            stage: (float(np.median(tally.latency[stage])) if tally.latency.get(stage) else None)
            for stage in ("segmentation", "ordering", "reconstruction", "total")
        },
        "notes": tally.notes,
        "per_frame": tally.per_frame,
    }
