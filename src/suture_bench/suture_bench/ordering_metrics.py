# SPDX-License-Identifier: Apache-2.0
"""Ordering success (docs/interfaces.md, "Offline evaluation contract") as a pure function.

An ordering succeeds when the predicted sequence

1. starts within ``tip_tolerance_px`` (5 px) of the true cut tip (the truth's first sample);
2. stays within ``corridor_px`` (3 px) of the true centreline **of the same thread**: every
   predicted point (segments up to ``max_segment_px`` long are first resampled to <= 1 px
   spacing) lies within the corridor of the true centreline at the place the ordering has
   reached. Hidden parts of the truth (under another strand or an instrument) count as
   centreline here. A longer segment is a *jump* (e.g. across a gap under an instrument,
   which no ordering can see): only its two ends are checked, and it covers nothing;
3. is **in the true order**: each predicted point is mapped to a true arc-length position
   (see below), and these positions never go back by more than ``corridor_px``;
4. **covers** at least ``min_coverage`` (90 %) of the truth's **visible length**.

Definitions
-----------
Truth: (M, 3) (u, v, visible) from the cut tip, as ``/ground_truth/*/sequence`` carries
it; it is resampled to 0.5 px spacing and each sample takes the flag of the nearer
original sample. *Visible length* is the arc length of the samples with
``visible > 0.5``. Where the target passes under another strand, its own upper strand
or an instrument (visible = 0) the stretch is excluded from both the visible length and
the covered length: no ordering can see it, but it must still pass there (criterion 2).

Mapping ("same thread", "in order"): for each predicted point in turn, the candidate
truth samples are those within the corridor. Among those not behind the furthest
position reached so far (minus the tolerance), the candidates are split into runs of
consecutive arc length (a self-crossing gives two runs at the same pixel: the first and
the second pass); the first run ahead is taken, and in it the nearest sample. A point
with no candidate at all is off the thread (criterion 2 fails); a point whose candidates
all lie behind goes backwards (criterion 3 fails).

Coverage: two consecutive mapped points cover the truth between their positions when
they are less than ``2 * corridor_px + 1`` px of arc apart and not the two ends of a jump
(a skip covers nothing); each mapped point also covers +-0.5 px. So a jump across a hidden
stretch costs nothing, and a jump across visible thread costs its length.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

_TRUTH_SPACING = 0.5


@dataclass(frozen=True)
class OrderingScore:
    """Result of :func:`ordering_success`.

    ``tip_error_px``: distance of the first predicted point to the true tip. ``max_deviation_px``:
    largest distance of a predicted point to the true centreline where it was mapped (to the
    nearest true point when it could not be mapped). ``coverage``: covered fraction of the
    visible length, 0..1. ``in_order``: the mapped positions never went backwards.
    ``reason``: 'ok', or the first criterion that failed, with numbers.
    """

    success: bool
    tip_error_px: float
    max_deviation_px: float
    coverage: float
    in_order: bool
    reason: str


def _points(array: np.ndarray, columns: int, what: str) -> np.ndarray:
    values = np.asarray(array, dtype=np.float64)
    if values.ndim != 2 or values.shape[1] != columns:
        raise ValueError(f"{what} must have shape (N, {columns}), got {values.shape}")
    if not np.all(np.isfinite(values)):
        raise ValueError(f"{what} contains NaN or inf")
    return values


def _resample(
    points: np.ndarray, spacing: float, max_segment: float = np.inf
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points every <= ``spacing`` along the polyline: (P, 2) points, (P,) arc length,
    (P,) index of the nearer original vertex. Segments longer than ``max_segment`` are
    not subdivided."""
    if len(points) == 1:
        return points.copy(), np.zeros(1), np.zeros(1, dtype=int)
    lengths = np.linalg.norm(np.diff(points, axis=0), axis=1)
    counts = np.maximum(1, np.ceil(lengths / spacing).astype(int))
    counts[lengths > max_segment] = 1
    segment = np.repeat(np.arange(len(lengths)), counts)
    within = np.concatenate([np.arange(c) / c for c in counts])
    resampled = points[segment] + within[:, None] * (points[segment + 1] - points[segment])
    arc = np.concatenate([[0.0], np.cumsum(lengths)])
    position = arc[segment] + within * lengths[segment]
    nearest = segment + (within > 0.5)
    return (
        np.vstack([resampled, points[-1:]]),
        np.append(position, arc[-1]),
        np.append(nearest, len(points) - 1),
    )


def ordering_success(
    predicted: np.ndarray,
    truth: np.ndarray,
    tip_tolerance_px: float = 5.0,
    corridor_px: float = 3.0,
    min_coverage: float = 0.9,
    max_segment_px: float = 10.0,
) -> OrderingScore:
    """Score a predicted ordered sequence against the ground truth (docs/interfaces.md definition).

    Parameters
    ----------
    predicted : (N, 2) float
        Predicted (u, v) pixels from the cut tip, in order (any spacing).
    truth : (M, 3) float
        True (u, v, visible) from the cut tip, ~1 px apart; visible is 1.0 where the
        target is the front-most surface, 0.0 where something covers it.
    tip_tolerance_px, corridor_px : float
        Pixel tolerances of criteria 1 and 2 (also the backward tolerance of criterion 3).
    min_coverage : float
        Required covered fraction of the visible length, 0..1.
    max_segment_px : float
        Longer segments of ``predicted`` are jumps: their interior is not checked and they
        cover nothing (an ordering outputs ~1 px spaced points and jumps only across gaps).

    Returns
    -------
    OrderingScore

    Raises
    ------
    ValueError
        For arrays of the wrong shape or with NaN, or a truth with fewer than 2 samples.
    """
    truth = _points(truth, 3, "truth")
    if len(truth) < 2:
        raise ValueError(f"truth needs at least 2 samples, got {len(truth)}")
    predicted = np.asarray(predicted, dtype=np.float64)
    if predicted.size == 0:
        return OrderingScore(False, float("inf"), float("inf"), 0.0, False, "empty predicted sequence")
    predicted = _points(predicted, 2, "predicted")

    true_points, true_arc, nearest = _resample(truth[:, :2], _TRUTH_SPACING)
    visible = truth[nearest, 2] > 0.5
    weights = np.gradient(true_arc) if len(true_arc) > 1 else np.ones(1)
    visible_length = float(weights[visible].sum())
    pred_points, _, _ = _resample(predicted, 1.0, max_segment_px)
    jump = np.linalg.norm(np.diff(pred_points, axis=0), axis=1) > max_segment_px  # (P - 1,)

    tip_error = float(np.hypot(*(predicted[0] - truth[0, :2])))
    tree = cKDTree(true_points)
    nearest_distance, _ = tree.query(pred_points)
    neighbours = tree.query_ball_point(pred_points, r=corridor_px, return_sorted=True)

    run_gap = 2.0 * corridor_px + 1.0
    reached = -np.inf
    mapped = np.full(len(pred_points), np.nan)
    deviation = nearest_distance.copy()
    off_thread = backwards = -1
    for i, candidates in enumerate(neighbours):
        if not candidates:
            if off_thread < 0:
                off_thread = i
            continue
        index = np.asarray(candidates)
        arc = true_arc[index]
        ahead = arc >= reached - corridor_px
        if not ahead.any():
            if backwards < 0:
                backwards = i
            continue
        index, arc = index[ahead], arc[ahead]
        breaks = np.flatnonzero(np.diff(arc) > run_gap)
        if breaks.size:
            index, arc = index[: breaks[0] + 1], arc[: breaks[0] + 1]
        distance = np.hypot(*(true_points[index] - pred_points[i]).T)
        best = int(np.argmin(distance))
        mapped[i] = arc[best]
        deviation[i] = distance[best]
        reached = max(reached, mapped[i])

    covered = np.zeros(len(true_arc) + 1, dtype=np.int64)
    valid = np.flatnonzero(np.isfinite(mapped))
    positions = mapped[valid]
    starts, ends = positions - 0.5, positions + 0.5
    if len(valid) > 1:
        consecutive = np.diff(valid) == 1
        step = np.diff(positions)
        link = consecutive & (step >= 0) & (step <= run_gap) & ~jump[valid[:-1]]
        starts = np.concatenate([starts, positions[:-1][link]])
        ends = np.concatenate([ends, positions[1:][link]])
    first = np.searchsorted(true_arc, starts, side="left")
    last = np.searchsorted(true_arc, ends, side="right")
    np.add.at(covered, first, 1)
    np.add.at(covered, last, -1)
    is_covered = np.cumsum(covered)[:-1] > 0
    coverage = float(weights[visible & is_covered].sum() / visible_length) if visible_length > 0 else 0.0

    max_deviation = float(deviation.max())
    in_order = backwards < 0
    if tip_error > tip_tolerance_px:
        reason = f"starts {tip_error:.1f} px from the true cut tip (> {tip_tolerance_px:g} px)"
    elif off_thread >= 0:
        reason = (
            f"leaves the true centreline: point {off_thread} (of {len(pred_points)} at 1 px) is "
            f"{nearest_distance[off_thread]:.1f} px from it (> {corridor_px:g} px)"
        )
    elif not in_order:
        reason = f"goes backwards along the thread at point {backwards} (of {len(pred_points)} at 1 px)"
    elif coverage < min_coverage:
        reason = f"covers {100 * coverage:.1f} % of the visible length (< {100 * min_coverage:g} %)"
    else:
        reason = "ok"
    return OrderingScore(
        success=reason == "ok",
        tip_error_px=tip_error,
        max_deviation_px=max_deviation,
        coverage=coverage,
        in_order=in_order,
        reason=reason,
    )
