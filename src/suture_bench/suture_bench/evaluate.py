# SPDX-License-Identifier: Apache-2.0
"""Offline evaluation over MCAP bags: the same core functions as the nodes, scored against ground truth.

``evaluate(paths, masks=..., sequences=...)`` walks every frame of the bags,
runs the stages that the sources ask for, and returns the summary of docs/interfaces.md's
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

Definitions (docs/interfaces.md): IoU, precision, recall and F1 pooled over the pixels of
all frames; ordering success per ``suture_bench.ordering_metrics``, of the left view's sequence
(``ordering``) and of the right view's (``ordering.right_view``); reconstruction
error is the distance from each reconstructed path point to the true 3D
centreline (mean over frames of the per-frame mean, max over frames of the
per-frame max); grasp error is the 3D distance between predicted and true grasp
points; ``within_5mm`` is the share of *all* frames whose grasp point is within 5 mm
(a frame without a grasp point is a miss), except where the true grasp point is hidden:
a frame whose true grasp point is hidden in either view (the true sequences' visibility is 0 at
it, see :func:`true_grasp_hidden`) is a success when the 3D stage refuses it as not seen
(``GraspNotSeenError``) and a miss when it grasps there (``grasp.hidden``). Latencies are
wall-clock milliseconds per stereo frame (``latency_ms`` medians, ``latency_p95_ms`` 95th percentiles).

Bags without 3D truth (true masks only, or nothing; see ``suture_bench.frames``) are
run through every stage and scored on what they carry: segmentation where true masks
exist, ordering where true sequences exist, the 3D errors where a true path and grasp pose
exist. Every frame also reports whether a grasp was produced or, if not, the refusal
(``grasp.produced``, ``grasp.refused``: 'stage: error type' -> frames; ``grasp.beyond_10mm``:
scored grasps more than 10 mm from the true grasp point, the wrong grasps a refusal should have
prevented; ``grasp.hidden``: frames whose true grasp point is hidden, refused as not seen or
grasped), and the stereo
self-consistency of its reconstruction (``self_consistency``: the 3D path projected onto
the masks the 3D stage worked from, px; ``reconstruction_metrics.reprojection_to_masks``).
Frames that could not be scored, stamps that are not frames and frames lost to a damaged
bag are counted (``unscored``, ``skipped``, ``damaged``) and explained in ``notes``.

Thin-structure figures beside IoU: ``segmentation.centreline_recall``,
``centreline_precision`` and ``cldice`` (``suture_segmentation.metrics``), pooled over the
skeleton pixels of all frames.

Running and scoring are separate: :class:`Scoreboard` scores a frame's
:class:`StageOutputs` however they were made, so the node graph's recorded outputs
(``suture-graph-report``) are scored by the very same code as ``suture-eval``.
"""

from __future__ import annotations

import time
from collections import Counter, defaultdict
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from suture_bench.frames import EvaluationError, Frame, find_bags, read_frames
from suture_bench.mask_cache import MaskCache, weights_digest
from suture_common import topics
from suture_common.bag_io import BagDamage, BagError
from suture_segmentation.metrics import CentrelineCounts, centreline_counts

SOURCES = ("predicted", "ground_truth")
WITHIN = 0.005
"""A grasp point within this distance (m) of the true one is a success."""
WRONG_GRASP = 0.010
"""A scored grasp point farther than this (m) from the true one is a wrong grasp (``beyond_10mm``)."""
NOT_SEEN_REFUSAL = "reconstruction: GraspNotSeenError"
"""The refusal that is the right answer for a frame whose true grasp point is hidden."""


@dataclass
class _Tally:
    """Running sums and per-frame records over the whole evaluation."""

    frames: int = 0
    pixels: np.ndarray = field(default_factory=lambda: np.zeros(3, dtype=np.int64))  # tp, fp, fn
    centreline: CentrelineCounts = field(default_factory=CentrelineCounts)
    produced: int = 0
    reprojection_mean: list[float] = field(default_factory=list)
    reprojection_max: list[float] = field(default_factory=list)
    unscored: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    skipped: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    visibility: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    damaged: list[dict[str, Any]] = field(default_factory=list)
    ordering: dict[str, list[bool]] = field(default_factory=lambda: defaultdict(list))
    ordering_right: dict[str, list[bool]] = field(default_factory=lambda: defaultdict(list))
    recon_mean: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))
    recon_max: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))
    grasp: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))
    length_error: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))
    keypoints: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))
    latency: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))
    failures: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    grasp_missing: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    hidden: dict[str, int] = field(default_factory=lambda: defaultdict(int))
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
    report: str | Path | None = None,
    max_overlays: int = 20,
    flip_average: bool = True,
    mask_cache: str | Path | None = None,
) -> dict:
    """Run and score the pipeline over the bags at ``paths``; returns the JSON summary (a dict).

    ``seg_weights`` picks the segmentation model for ``masks="predicted"`` (a checkpoint path or
    a shipped name such as ``m_onsite_half`` or ``m_ost``); None is the stage's default
    (``m_onsite_half``).
    ``use_images``: refine the 3D stage's disparity with the images; ``use_low_masks``: give the
    ordering the low masks of the predicted masks (module docstring); ``flip_average``: average
    each image's suture probability with its mirror image's (segmentation_node's default).
    ``report``: a folder for the per-frame JSON and pictures (``suture_bench.report``), at most
    ``max_overlays`` overlays. ``mask_cache``: an ``.npz`` file for the predicted masks
    (:mod:`suture_bench.mask_cache`): written with every frame's masks where it does not exist,
    read instead of segmenting where it does.
    """
    if masks not in SOURCES or sequences not in SOURCES:
        raise EvaluationError(f"masks and sequences must be one of {SOURCES}, got {masks!r}, {sequences!r}")
    stages = _Stages(masks, sequences, seg_weights, use_images, use_low_masks, flip_average)
    scoreboard = Scoreboard(ordering_ran=sequences == "predicted")
    if mask_cache is not None and masks == "predicted":
        stages.mask_cache = _open_mask_cache(mask_cache, seg_weights, use_low_masks, flip_average)
        if stages.mask_cache.loaded:
            scoreboard.tally.note(
                f"segmentation: masks read from the mask cache {mask_cache}; segmentation latency not "
                "measured, total latency without it"
            )
    if not use_images:
        scoreboard.tally.note("reconstruction: from the sequences alone (images not used)")
    if masks == "predicted" and not use_low_masks:
        scoreboard.tally.note("ordering: from the masks alone (low masks not used)")
    if masks == "predicted" and not flip_average:
        scoreboard.tally.note("segmentation: the images alone, not averaged with their mirror images")
    writer = None
    if report is not None:
        from suture_bench.report import ReportWriter

        writer = ReportWriter(report, max_overlays)
    images = masks == "predicted" or use_images or writer is not None
    for bag in find_bags(paths):
        skipped: Counter = Counter()
        damage = BagDamage()
        read = 0
        try:
            for frame in read_frames(bag, images=images, complete=False, skipped=skipped, damage=damage):
                read += 1
                outputs = _run_frame(frame, stages, f"{bag.name}/{frame.stamp_ns}")
                record = scoreboard.add(frame, outputs)
                if writer is not None:
                    writer.add(frame, outputs, record)
        except BagError as error:
            raise EvaluationError(str(error)) from error
        scoreboard.bag_done(bag, read, skipped, damage)
    if stages.mask_cache is not None:
        stages.mask_cache.save()
    summary = scoreboard.summary(masks, sequences)
    if writer is not None:
        writer.finish(summary)
    return summary


def _open_mask_cache(
    path: str | Path, seg_weights: str | None, use_low_masks: bool, flip_average: bool
) -> MaskCache:
    """The mask cache at ``path`` for masks made by ``seg_weights`` with these options."""
    from suture_segmentation.checkpoint import resolve_weights
    from suture_segmentation.core import LOW_THRESHOLD

    settings = {
        "weights_sha256": weights_digest(resolve_weights(seg_weights)),
        "flip_average": flip_average,
        "low_threshold": LOW_THRESHOLD if use_low_masks else None,
    }
    return MaskCache(path, settings)


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
        flip_average: bool = True,
    ) -> None:
        from suture_reconstruction.core import reconstruct

        self.masks, self.sequences, self.use_images = masks, sequences, use_images
        self.segment: Callable[..., Any] | None = None
        self.mask_cache: MaskCache | None = None
        self.order: Callable[..., Any] | None = None
        self.reconstruct = reconstruct
        if masks == "predicted":
            from suture_segmentation.core import LOW_THRESHOLD, Segmenter

            low_threshold = LOW_THRESHOLD if use_low_masks else None  # segmentation_node's default
            segmenter = Segmenter(seg_weights, low_threshold=low_threshold, flip_average=flip_average)
            self.segment = segmenter.segment_pair_with_low
        if sequences == "predicted":
            from suture_ordering.core import order_stereo

            self.order = order_stereo


@dataclass
class StageOutputs:
    """What the pipeline produced for one frame, however it ran (core functions or node graph).

    ``masks``: predicted (left, right) (H, W) masks, None when the true masks were used;
    ``sequences``: predicted (left, right) (N, 2) sequences, None when the ordering stage did
    not run or failed; ``path`` (M, 3) m and ``grasp`` (3,) m, None when the 3D stage failed;
    ``failure``: 'stage: reason' of the first stage that gave nothing (a refusal);
    ``not_run``: why the stages could not start on this frame (the bag lacks the true masks or
    sequences they were asked to start from); ``used_masks``: the (left, right) masks the
    ordering worked from (predicted or true); ``latency_ms``: per stage.
    """

    masks: tuple[np.ndarray, np.ndarray] | None = None
    sequences: tuple[np.ndarray, np.ndarray] | None = None
    path: np.ndarray | None = None
    grasp: np.ndarray | None = None
    failure: str | None = None
    detail: str | None = None
    latency_ms: dict[str, float] = field(default_factory=dict)
    not_run: str | None = None
    used_masks: tuple[np.ndarray, np.ndarray] | None = None


class Scoreboard:
    """Scores frames against their ground truth and builds the evaluation summary.

    ``ordering_ran``: whether the ordering stage produced the sequences (its success is
    then scored per frame; with true sequences it is not).
    """

    def __init__(self, ordering_ran: bool = True) -> None:
        self.ordering_ran = ordering_ran
        self.tally = _Tally()

    def add(self, frame: Frame, outputs: StageOutputs) -> dict[str, Any]:
        """Score one frame's outputs; returns its per-frame record (also kept in the summary).

        The record's ``success`` says whether the frame counts in ``within_5mm`` (absent where
        the bag has no true 3D path and grasp point to score it against)."""
        from suture_bench.ordering_metrics import ordering_success
        from suture_bench.reconstruction_metrics import reprojection_to_masks, score_reconstruction

        tally = self.tally
        tally.frames += 1
        record: dict[str, Any] = {"stamp_ns": frame.stamp_ns, "topology": frame.topology}
        tally.per_frame.append(record)
        for stage, ms in outputs.latency_ms.items():
            tally.latency[stage].append(ms)
        if outputs.not_run is not None:
            tally.unscored[f"not run: {outputs.not_run}"] += 1
            record.update(not_run=outputs.not_run, grasp_produced=False)
            return record
        if outputs.masks is not None:
            record["segmentation"] = self._score_masks(frame, outputs.masks)
        if outputs.failure is not None:
            tally.failures[outputs.failure] += 1
            record["failure"] = outputs.failure
            if outputs.detail:
                record["failure_detail"] = outputs.detail
        if self.ordering_ran:
            if frame.true_left_sequence is None:
                tally.unscored["ordering: the bag has no true sequence"] += 1
            else:
                tally.visibility[frame.visibility] += 1
                views = [("", 0, frame.true_left_sequence, tally.ordering)]
                if frame.true_right_sequence is not None:
                    views.append(("_right", 1, frame.true_right_sequence, tally.ordering_right))
                for suffix, view, truth, scores in views:
                    score = None
                    if outputs.sequences is not None:
                        score = ordering_success(outputs.sequences[view], truth)
                    success = score is not None and bool(score.success)
                    scores[frame.topology].append(success)
                    record[f"ordering{suffix}_success"] = success
                    record[f"ordering{suffix}"] = "no sequence" if score is None else score.reason
        record["grasp_produced"] = outputs.path is not None and outputs.grasp is not None
        hidden = true_grasp_hidden(frame)
        if hidden is not None:
            record["grasp_hidden"] = hidden
        tally.hidden["hidden"] += bool(hidden)
        if not record["grasp_produced"]:
            if frame.true_path is not None and frame.true_grasp is not None:
                tally.grasp_missing[frame.topology] += 1
                record["success"] = bool(hidden) and outputs.failure == NOT_SEEN_REFUSAL
                if record["success"]:
                    tally.hidden["refused_not_seen"] += 1
                elif hidden:
                    tally.hidden["refused_otherwise"] += 1
            return record
        tally.hidden["grasped"] += bool(hidden)
        tally.produced += 1
        record["grasp_position"] = np.asarray(outputs.grasp).tolist()
        masks = outputs.used_masks if outputs.used_masks is not None else outputs.masks
        if masks is not None:
            consistency = reprojection_to_masks(np.asarray(outputs.path), frame.camera, masks)
            if np.isfinite(consistency["max_px"]):
                tally.reprojection_mean.append(consistency["mean_px"])
                tally.reprojection_max.append(consistency["max_px"])
                record["reprojection_px"] = consistency
            else:  # an empty mask, or the path leaves a view: no distance to measure
                tally.unscored["self-consistency: an empty mask or a path outside a view"] += 1
        if frame.true_path is None or frame.true_grasp is None:
            tally.unscored["reconstruction: the bag has no true 3D path and grasp pose"] += 1
            return record
        score = score_reconstruction(outputs.path, frame.true_path, outputs.grasp, frame.true_grasp)
        tally.recon_mean[frame.topology].append(score.mean_error)
        tally.recon_max[frame.topology].append(score.max_error)
        tally.length_error[frame.topology].append(abs(score.length_error))
        tally.keypoints[frame.topology].append(float(np.mean(score.keypoint_errors)))
        tally.grasp[frame.topology].append(score.grasp_error)
        record.update(score.as_mm())
        record["success"] = not hidden and score.grasp_error <= WITHIN
        return record

    def _score_masks(self, frame: Frame, masks: tuple[np.ndarray, np.ndarray]) -> dict[str, Any]:
        """Pool the views that have a true mask; per-view figures for the frame's record."""
        tally = self.tally
        scores: dict[str, Any] = {}
        truths = (frame.true_left_mask, frame.true_right_mask)
        for view, predicted, truth in zip(("left", "right"), masks, truths, strict=True):
            if truth is None:
                continue
            predicted = np.asarray(predicted) > 0
            counts = [np.sum(predicted & truth), np.sum(predicted & ~truth), np.sum(~predicted & truth)]
            tally.pixels += counts
            centreline = centreline_counts(predicted, truth)
            tally.centreline = tally.centreline + centreline
            tp, fp, fn = (int(c) for c in counts)
            scores[view] = {"iou": tp / (tp + fp + fn) if tp + fp + fn else None, **centreline.figures()}
        if not scores:
            tally.unscored["segmentation: the bag has no true masks"] += 1
        return scores

    def bag_done(self, bag: Path, frames: int, skipped: Counter, damage: BagDamage) -> None:
        """Count what one bag did not give as frames: stamps without a frame's topics, damage."""
        tally = self.tally
        for reason, count in skipped.items():
            tally.skipped[reason] += count
            tally.note(f"{bag}: {count} stamp(s) skipped as not a stereo frame ({reason})")
        if damage.damaged:
            lost = damage.lost(topics.LEFT_CAMERA_INFO)  # stamps read but not a frame are in skipped
            tally.damaged.append({"bag": str(bag), "error": damage.error, "frames": frames, "lost": lost})
            shown = "an unknown number (the bag has no metadata.yaml)" if lost is None else str(lost)
            tally.note(f"{damage.error}: {frames} frame(s) read, {shown} lost")

    def summary(self, masks: str, sequences: str) -> dict:
        """The JSON summary of the evaluation contract (plus ``per_frame``)."""
        return _summary(self.tally, masks, sequences)


def true_grasp_hidden(frame: Frame) -> bool | None:
    """Whether the frame's true grasp point is hidden in either view; None without the truth.

    The true sequences' rows are the same 3D samples in both views (docs/interfaces.md), so each
    row triangulates exactly; the row nearest the true grasp point in 3D is the grasp point's,
    and its visibility (third column, 1 visible) in each view says whether the view sees it.
    """
    left, right = frame.true_left_sequence, frame.true_right_sequence
    if left is None or right is None or frame.true_grasp is None or len(left) != len(right):
        return None
    samples = frame.camera.triangulate(left[:, :2], right[:, 0])
    row = int(np.argmin(np.linalg.norm(samples - np.asarray(frame.true_grasp), axis=1)))
    return bool(left[row, 2] < 0.5 or right[row, 2] < 0.5)


def _within(tally: _Tally, topology: str | None = None) -> int:
    """Frames that count as successes: grasps within 5 mm of a true grasp point that is not hidden,
    and refusals of a hidden one as not seen: the per-frame records' ``success`` (over every
    topology when ``topology`` is None)."""
    records = tally.per_frame
    return sum(bool(r.get("success")) for r in records if topology is None or r["topology"] == topology)


def _run_frame(frame: Frame, stages: _Stages, key: str = "") -> StageOutputs:
    """Run the stages the sources ask for on one frame (the nodes' core functions); ``key``
    names the frame in the mask cache (bag name / stamp)."""
    outputs = StageOutputs()
    masks, low_masks = (frame.true_left_mask, frame.true_right_mask), None
    if stages.segment is None and stages.order is not None and (masks[0] is None or masks[1] is None):
        outputs.not_run = "the bag has no true masks to start the ordering from (--masks ground_truth)"
        return outputs
    if stages.order is None and (frame.true_left_sequence is None or frame.true_right_sequence is None):
        outputs.not_run = (
            "the bag has no true sequences to start the 3D stage from (--sequences ground_truth)"
        )
        return outputs
    cached = None if stages.mask_cache is None else stages.mask_cache.get(key)
    if stages.mask_cache is not None and stages.mask_cache.loaded and cached is None:
        raise EvaluationError(
            f"mask cache {stages.mask_cache.path} has no masks of frame {key}: it was made on other bags; "
            "give another file"
        )
    if cached is not None:
        masks, low_masks = cached
        outputs.masks = masks
    elif stages.segment is not None:
        start = time.perf_counter()
        masks, low_masks = stages.segment(frame.left_image, frame.right_image)
        outputs.latency_ms["segmentation"] = _elapsed_ms(start)
        outputs.masks = masks
        if stages.mask_cache is not None:
            stages.mask_cache.put(key, masks, low_masks)

    if stages.order is None:
        sequences = (frame.true_left_sequence[:, :2], frame.true_right_sequence[:, :2])
        if masks[0] is not None and masks[1] is not None:
            outputs.used_masks = masks
    else:
        outputs.used_masks = masks
        start = time.perf_counter()
        try:
            ordering = stages.order(masks[0], masks[1], frame.tip_hint, frame.camera, low_masks=low_masks)
        except ValueError as error:
            outputs.latency_ms["ordering"] = _elapsed_ms(start)
            outputs.failure, outputs.detail = f"ordering: {type(error).__name__}", str(error)
            return outputs
        outputs.latency_ms["ordering"] = _elapsed_ms(start)
        outputs.sequences = (ordering.left, ordering.right)
        sequences = (ordering.left_sequence, ordering.right_sequence)  # z: not seen (bridged)

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
    segmentation.update(tally.centreline.figures())
    all_ordering = [ok for values in tally.ordering.values() for ok in values]
    if sequences == "ground_truth":
        tally.note("ordering: not run (--sequences ground_truth)")
    all_means = [v for values in tally.recon_mean.values() for v in values]
    all_max = [v for values in tally.recon_max.values() for v in values]
    all_grasp = [v for values in tally.grasp.values() for v in values]
    # Frames without a grasp point count as misses: "within 5 mm" is a share of all frames.
    scored_frames = len(all_grasp) + sum(tally.grasp_missing.values())
    for failure, count in sorted(tally.failures.items()):
        if scored_frames:
            tally.note(
                f"{failure} in {count} frame(s): excluded from the error figures, "
                "counted as misses in within_5mm"
            )
        else:
            tally.note(f"{failure} in {count} frame(s): no grasp produced")
    for reason, count in sorted(tally.unscored.items()):
        tally.note(f"{reason}: {count} frame(s) not scored there")
    if tally.visibility.get("mask"):
        tally.note(
            f"ordering: {tally.visibility['mask']} frame(s) have true sequences without a visibility flag "
            "(z = 0): visibility from the true masks"
        )
    if tally.visibility.get("assumed"):
        tally.note(
            f"ordering: {tally.visibility['assumed']} frame(s) have true sequences without a visibility flag "
            "and no true mask: the whole sequence counted as visible"
        )
    if tally.frames == 0:
        why = "; ".join(f"{n} stamp(s) with {r}" for r, n in sorted(tally.skipped.items())) or "no messages"
        tally.note(f"no stereo frame (both camera_info messages and both images) in the bags: {why}")
    return {
        "frames": tally.frames,
        "masks": masks,
        "sequences": sequences,
        "segmentation": segmentation,
        "ordering": {
            "success_rate": _mean(all_ordering),
            "by_topology": {t: _mean(v) for t, v in sorted(tally.ordering.items())},
            "right_view": {
                "success_rate": _mean([ok for values in tally.ordering_right.values() for ok in values]),
                "by_topology": {t: _mean(v) for t, v in sorted(tally.ordering_right.items())},
            },
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
                    "within_5mm": _within(tally, t) / (len(tally.grasp[t]) + tally.grasp_missing[t]),
                    "frames": len(tally.recon_mean[t]),
                }
                for t in sorted(tally.recon_mean)
            },
        },
        "grasp": {
            "median_error_mm": float(np.median(all_grasp)) * 1000 if all_grasp else None,
            "max_error_mm": float(np.max(all_grasp)) * 1000 if all_grasp else None,
            "within_5mm": _within(tally) / scored_frames if scored_frames else None,
            "produced": tally.produced,
            "beyond_10mm": int(np.sum(np.asarray(all_grasp) > WRONG_GRASP)) if all_grasp else None,
            "refused": dict(sorted(tally.failures.items())),
            "hidden": {
                key: tally.hidden.get(key, 0)
                for key in ("hidden", "refused_not_seen", "grasped", "refused_otherwise")
            },
        },
        "self_consistency": {
            "reprojection_mean_px": _mean(tally.reprojection_mean),
            "reprojection_max_px": float(np.max(tally.reprojection_max)) if tally.reprojection_max else None,
            "frames": len(tally.reprojection_mean),
        },
        "unscored": dict(sorted(tally.unscored.items())),
        "skipped": dict(sorted(tally.skipped.items())),
        "damaged": tally.damaged,
        "latency_ms": _latency(tally, 50),
        "latency_p95_ms": _latency(tally, 95),
        "notes": tally.notes,
        "per_frame": tally.per_frame,
    }
