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
* ``use_images`` (default True, as ``reconstruction_node``'s parameter of that name)
  gives the 3D stage the bag's rectified images, with which it refines the disparity
  photometrically; False reconstructs from the sequences alone.
* ``use_low_masks`` (default True, as the node graph: segmentation_node publishes low masks and
  ordering_node uses them) gives the ordering stage the predicted low masks too; False orders
  the masks alone. True masks have none.

Definitions (DESIGN.md): IoU, precision, recall and F1 pooled over the pixels of
all frames; ordering success per ``suture_bench.ordering_metrics``; reconstruction
error is the distance from each reconstructed path point to the true 3D
centreline (mean over frames of the per-frame mean, max over frames of the
per-frame max); grasp error is the 3D distance between predicted and true grasp
points; ``within_5mm`` is the share of *all* frames whose grasp point is within 5 mm
(a frame without a grasp point is a miss). Latencies are wall-clock milliseconds per
stereo frame (``latency_ms`` medians, ``latency_p95_ms`` 95th percentiles).

Running and scoring are separate: :class:`Scoreboard` scores a frame's
:class:`StageOutputs` however they were made, so the node graph's recorded outputs
(``suture-graph-report``) are scored by the very same code as ``suture-eval``.
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
    grasp_missing: dict[str, int] = field(default_factory=lambda: defaultdict(int))
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
    use_images: bool = True,
    use_low_masks: bool = True,
) -> dict:
    """Run and score the pipeline over the bags at ``paths``; returns the JSON summary (a dict).

    ``seg_weights`` picks the segmentation model for ``masks="predicted"`` (a checkpoint path or
    a shipped name, ``m_tosot`` or ``m_ost``); None is the stage's default (shipped M-ToSOT).
    ``use_images``: refine the 3D stage's disparity with the images; ``use_low_masks``: give the
    ordering the low masks of the predicted masks (module docstring).
    """
    if masks not in SOURCES or sequences not in SOURCES:
        raise EvaluationError(f"masks and sequences must be one of {SOURCES}, got {masks!r}, {sequences!r}")
    stages = _Stages(masks, sequences, seg_weights, use_images, use_low_masks)
    scoreboard = Scoreboard(ordering_ran=sequences == "predicted")
    if not use_images:
        scoreboard.tally.note("reconstruction: from the sequences alone (images not used)")
    if masks == "predicted" and not use_low_masks:
        scoreboard.tally.note("ordering: from the masks alone (low masks not used)")
    for bag in find_bags(paths):
        try:
            for frame in read_frames(bag, images=masks == "predicted" or use_images):
                scoreboard.add(frame, _run_frame(frame, stages))
        except BagError as error:
            raise EvaluationError(str(error)) from error
    return scoreboard.summary(masks, sequences)


class _Stages:
    """The stage entry points the sources need; a stage that is not run is not imported
    (segmentation pulls in torch and loads a model).

    ``segment(left_image, right_image) -> ((left_mask, right_mask), low_masks or None)`` is
    :meth:`suture_segmentation.core.Segmenter.segment_pair_with_low`;
    ``order(left_mask, right_mask, tip_hint, camera, low_masks=...)`` is
    :func:`suture_ordering.core.order_stereo` (``.left``/``.right`` (N, 2) sequences);
    ``reconstruct(left, right, camera, images=...)`` is
    :func:`suture_reconstruction.core.reconstruct` (``.path``, ``.grasp_position``);
    ``use_images``: whether it is given the frame's images.
    """

    def __init__(
        self,
        masks: str,
        sequences: str,
        seg_weights: str | None,
        use_images: bool = True,
        use_low_masks: bool = True,
    ) -> None:
        from suture_reconstruction.core import reconstruct

        self.masks, self.sequences, self.use_images = masks, sequences, use_images
        self.segment: Callable[..., Any] | None = None
        self.order: Callable[..., Any] | None = None
        self.reconstruct = reconstruct
        if masks == "predicted":
            from suture_segmentation.core import LOW_THRESHOLD, Segmenter

            low_threshold = LOW_THRESHOLD if use_low_masks else None  # segmentation_node's default
            self.segment = Segmenter(seg_weights, low_threshold=low_threshold).segment_pair_with_low
        if sequences == "predicted":
            from suture_ordering.core import order_stereo

            self.order = order_stereo


@dataclass
class StageOutputs:
    """What the pipeline produced for one frame, however it ran (core functions or node graph).

    ``masks``: predicted (left, right) (H, W) masks, None when the true masks were used;
    ``sequences``: predicted (left, right) (N, 2) sequences, None when the ordering stage did
    not run or failed; ``path`` (M, 3) m and ``grasp`` (3,) m, None when the 3D stage failed;
    ``failure``: 'stage: reason' of the first stage that gave nothing; ``latency_ms``: per stage.
    """

    masks: tuple[np.ndarray, np.ndarray] | None = None
    sequences: tuple[np.ndarray, np.ndarray] | None = None
    path: np.ndarray | None = None
    grasp: np.ndarray | None = None
    failure: str | None = None
    detail: str | None = None
    latency_ms: dict[str, float] = field(default_factory=dict)


class Scoreboard:
    """Scores frames against their ground truth and builds the evaluation summary.

    ``ordering_ran``: whether the ordering stage produced the sequences (its success is
    then scored per frame; with true sequences it is not).
    """

    def __init__(self, ordering_ran: bool = True) -> None:
        self.ordering_ran = ordering_ran
        self.tally = _Tally()

    def add(self, frame: Frame, outputs: StageOutputs) -> dict[str, Any]:
        """Score one frame's outputs; returns its per-frame record (also kept in the summary)."""
        from suture_bench.ordering_metrics import ordering_success
        from suture_bench.reconstruction_metrics import score_reconstruction

        tally = self.tally
        tally.frames += 1
        record: dict[str, Any] = {"stamp_ns": frame.stamp_ns, "topology": frame.topology}
        tally.per_frame.append(record)
        for stage, ms in outputs.latency_ms.items():
            tally.latency[stage].append(ms)
        if outputs.masks is not None:
            truths = (frame.true_left_mask, frame.true_right_mask)
            for predicted, truth in zip(outputs.masks, truths, strict=True):
                predicted = np.asarray(predicted) > 0
                tally.pixels += [
                    np.sum(predicted & truth),
                    np.sum(predicted & ~truth),
                    np.sum(~predicted & truth),
                ]
        if outputs.failure is not None:
            tally.failures[outputs.failure] += 1
            record["failure"] = outputs.failure
            if outputs.detail:
                record["failure_detail"] = outputs.detail
        if self.ordering_ran:
            success = outputs.sequences is not None and bool(
                ordering_success(outputs.sequences[0], frame.true_left_sequence).success
            )
            tally.ordering[frame.topology].append(success)
            record["ordering_success"] = success
        if outputs.path is None or outputs.grasp is None:
            tally.grasp_missing[frame.topology] += 1
            return record
        score = score_reconstruction(outputs.path, frame.true_path, outputs.grasp, frame.true_grasp)
        tally.recon_mean[frame.topology].append(score.mean_error)
        tally.recon_max[frame.topology].append(score.max_error)
        tally.length_error[frame.topology].append(abs(score.length_error))
        tally.keypoints[frame.topology].append(float(np.mean(score.keypoint_errors)))
        tally.grasp[frame.topology].append(score.grasp_error)
        record.update(score.as_mm(), grasp_position=np.asarray(outputs.grasp).tolist())
        return record

    def summary(self, masks: str, sequences: str) -> dict:
        """The JSON summary of DESIGN.md's evaluation contract (plus ``per_frame``)."""
        return _summary(self.tally, masks, sequences)


def _run_frame(frame: Frame, stages: _Stages) -> StageOutputs:
    """Run the stages the sources ask for on one frame (the nodes' core functions)."""
    outputs = StageOutputs()
    masks, low_masks = (frame.true_left_mask, frame.true_right_mask), None
    if stages.segment is not None:
        start = time.perf_counter()
        masks, low_masks = stages.segment(frame.left_image, frame.right_image)
        outputs.latency_ms["segmentation"] = _elapsed_ms(start)
        outputs.masks = masks

    sequences = (frame.true_left_sequence[:, :2], frame.true_right_sequence[:, :2])
    if stages.order is not None:
        start = time.perf_counter()
        try:
            ordering = stages.order(masks[0], masks[1], frame.tip_hint, frame.camera, low_masks=low_masks)
        except ValueError as error:
            outputs.latency_ms["ordering"] = _elapsed_ms(start)
            outputs.failure, outputs.detail = f"ordering: {type(error).__name__}", str(error)
            return outputs
        outputs.latency_ms["ordering"] = _elapsed_ms(start)
        sequences = outputs.sequences = (ordering.left, ordering.right)

    images = None
    if stages.use_images and frame.left_image is not None and frame.right_image is not None:
        images = (frame.left_image, frame.right_image)
    start = time.perf_counter()
    try:
        result = stages.reconstruct(sequences[0], sequences[1], frame.camera, images=images)
    except ValueError as error:
        outputs.latency_ms["reconstruction"] = _elapsed_ms(start)
        outputs.failure, outputs.detail = f"reconstruction: {type(error).__name__}", str(error)
        return outputs
    outputs.latency_ms["reconstruction"] = _elapsed_ms(start)
    outputs.latency_ms["total"] = sum(outputs.latency_ms.values())
    outputs.path, outputs.grasp = result.path, result.grasp_position
    return outputs


def _elapsed_ms(start: float) -> float:
    return 1000 * (time.perf_counter() - start)


def _latency(tally: _Tally, percentile: float) -> dict[str, float | None]:
    return {
        stage: (float(np.percentile(tally.latency[stage], percentile)) if tally.latency.get(stage) else None)
        for stage in ("segmentation", "ordering", "reconstruction", "total")
    }


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
    # Frames without a grasp point count as misses: "within 5 mm" is a share of all frames.
    scored_frames = len(all_grasp) + sum(tally.grasp_missing.values())
    for failure, count in sorted(tally.failures.items()):
        tally.note(
            f"{failure} in {count} frame(s): excluded from the error figures, counted as misses in within_5mm"
        )
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
                    "within_5mm": float(np.sum(np.asarray(tally.grasp[t]) <= 0.005))
                    / (len(tally.grasp[t]) + tally.grasp_missing[t]),
                    "frames": len(tally.recon_mean[t]),
                }
                for t in sorted(tally.recon_mean)
            },
        },
        "grasp": {
            "median_error_mm": float(np.median(all_grasp)) * 1000 if all_grasp else None,
            "max_error_mm": float(np.max(all_grasp)) * 1000 if all_grasp else None,
            "within_5mm": (
                float(np.sum(np.asarray(all_grasp) <= 0.005)) / scored_frames if scored_frames else None
            ),
        },
        "latency_ms": _latency(tally, 50),
        "latency_p95_ms": _latency(tally, 95),
        "notes": tally.notes,
        "per_frame": tally.per_frame,
    }
