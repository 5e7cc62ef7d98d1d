# SPDX-License-Identifier: Apache-2.0
"""Stereo pairing of two ordered thread sequences under the parallel-optical-axis (rectified) model.

In a rectified pair a 3D point appears on the same image row v in both views, at
columns u_left and u_right = u_left - d, with disparity d = fx * baseline / z.
The two sequences describe the same thread from the cut tip, but each view is
sampled on its own (about 1 px apart, independently noisy, possibly of different
lengths), so their indices do not correspond. Both are resampled every 1 px of
their own arc length first; s (left) and t (right) below are those arc lengths.
Pairing then works on rows:

1. **Candidates** (:func:`row_crossings`): for every left sample, every place
   where the right polyline crosses that sample's row, with a sub-pixel column
   by linear interpolation along the right segment, and its fractional index t.
   A pair exists only on the epipolar line (the same row); a left sample whose
   row the right polyline does not cross gets none ("off the epipolar line").
   Crossings outside the disparity limits of the working depth range, on a jump
   of the right sequence, or flatter than ``min_crossing_angle_deg`` to the rows
   (ill-conditioned: a row error e moves the column by e / tan(angle)) are
   rejected. Each pair is weighted by sin^2 of that angle (the smaller of the
   two views' tangent angles), the inverse of its disparity variance.
2. **Monotone selection** (:func:`pair_sequences`), where a row crosses the
   thread several times (loops, horizontal stretches), in two passes. Pass 1
   keeps steep, reliable crossings near the identity correspondence (|t - s|
   within ``max_arc_drift_px`` + ``max_arc_drift_rel`` s: the two views' arc
   lengths from the tip differ only by about the change of disparity) and picks
   one per left sample by a shortest path over a directed acyclic graph
   (:func:`select_monotone`): nodes are the candidates, edges join candidates of
   rows i' < i (lags up to 512 samples, so gaps can be skipped) with t
   non-decreasing along the thread and advancing at a plausible speed; edge
   cost ``skip_cost`` per skipped sample plus ``speed_cost`` |dt - di| and
   ``disparity_cost`` |dd|, scaled by how well the crossings are conditioned.
   Those anchors, and the end pairs (:func:`end_pairs`: both sequences start at
   the cut tip), give a smooth correspondence t(s). Pass 2 takes, for every left
   sample, the usable crossing nearest to t(s), if within ``band_px``.
3. **Disparity regularisation** (:func:`regularise_disparity`): each pair's
   disparity carries the noise of both sequences (about 0.4 px for 0.3 px per
   view: 2 mm of depth at 120 mm), so disparity is smoothed along the thread by
   a weighted Whittaker smoother (a discrete cubic smoothing spline) whose
   smoothing length is chosen per sample by the intersection of confidence
   intervals: long where the pairs are weak or the depth varies slowly, short
   where the thread is lifted sharply over a crossing. Only depth is smoothed
   this way; the image position of the thread keeps the resolution of the
   light pre-smoothing. Depth errors matter more than they seem: where the
   thread rises over the other strand 1 px of disparity is 3 mm of depth, and
   a flattened lift is arc length lost before the grasp point (the grasp is
   then millimetres off along the thread), so the smoother must be able to
   follow precise pairs closely (fine scales, outliers judged against the
   adaptive fit, no steps between scales: see :func:`regularise_disparity`).
   The noise level behind the smoothing lengths is estimated from the pairs'
   residuals, but not below a floor read from the two sequences
   (:func:`pair_noise_floor`): centrelines traced on pixel masks carry a
   quantisation saw-tooth correlated over tens of px, which the residuals miss
   and which a fit that trusts them turns into a depth ripple of several mm,
   i.e. extra arc length and a grasp point too early along the thread.
   Where the thread runs within ``min_crossing_angle_deg`` of the rows there
   are no pairs and the depth is interpolated from both sides.

Units: pixels throughout; t in right-sequence samples (px).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import gaussian_filter1d, minimum_filter1d
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from suture_common.parameters import described
from suture_reconstruction.sequences import roughness, row_alignment
from suture_reconstruction.smoothing import whittaker

LAGS = np.array([1, 2, 3, 4, 5, 6, 8, 11, 16, 23, 32, 45, 64, 91, 128, 181, 256, 362, 512])
"""Left-sample lags of the selection graph's edges: every lag up to 6, then about x1.4 steps."""


@dataclass(frozen=True)
class Candidates:
    """Row crossings of the right polyline, one entry per (left sample, crossing), sorted by (left, t).

    ``left`` (C,) int left-sample index; ``t`` (C,) fractional right index;
    ``u_right`` (C,) column (px); ``disparity`` (C,) u_left - u_right (px);
    ``weight`` (C,) sin^2 of the thread's angle to the row (the smaller of both views).
    """

    left: np.ndarray
    t: np.ndarray
    u_right: np.ndarray
    disparity: np.ndarray
    weight: np.ndarray

    def take(self, keep: np.ndarray) -> Candidates:
        return Candidates(
            self.left[keep], self.t[keep], self.u_right[keep], self.disparity[keep], self.weight[keep]
        )

    def __len__(self) -> int:
        return int(self.left.size)


def row_crossings(
    left: np.ndarray,
    right: np.ndarray,
    right_jumps: np.ndarray,
    left_alignment: np.ndarray,
    right_alignment: np.ndarray,
) -> Candidates:
    """Every crossing of each left sample's row by the right polyline.

    ``left`` (N, 2) and ``right`` (M, 2) pixels; ``right_jumps`` (M - 1,) bool marks
    right segments that are jumps (not observed thread), which are never used.
    ``left_alignment`` (N,) and ``right_alignment`` (M,): sin^2 of each sample's
    tangent angle to the rows (:func:`suture_reconstruction.sequences.row_alignment`);
    a candidate's weight is the smaller of the two at its ends.
    Segments are bucketed by integer row, so the cost is O(N + M), not O(N M).
    A segment covers rows [min v, max v) (half-open), so a row through a vertex
    is counted once; horizontal segments cross no row.
    """
    v0, v1 = right[:-1, 1], right[1:, 1]
    lo, hi = np.minimum(v0, v1), np.maximum(v0, v1)
    segments = np.flatnonzero(~right_jumps & (hi > lo))
    row_lo = np.floor(lo[segments]).astype(np.int64)
    counts = np.floor(hi[segments]).astype(np.int64) - row_lo + 1
    bucket_segment = np.repeat(segments, counts)
    bucket_row = np.repeat(row_lo, counts) + _ranges(counts)
    order = np.argsort(bucket_row, kind="stable")
    bucket_row, bucket_segment = bucket_row[order], bucket_segment[order]

    rows = left[:, 1]
    row_int = np.floor(rows).astype(np.int64)
    start = np.searchsorted(bucket_row, row_int, side="left")
    found = np.searchsorted(bucket_row, row_int, side="right") - start
    left_index = np.repeat(np.arange(len(left)), found)
    segment = bucket_segment[np.repeat(start, found) + _ranges(found)]
    v = rows[left_index]
    hit = (lo[segment] <= v) & (v < hi[segment])
    left_index, segment, v = left_index[hit], segment[hit], v[hit]

    dv = v1[segment] - v0[segment]
    du = right[segment + 1, 0] - right[segment, 0]
    fraction = (v - v0[segment]) / dv
    u_right = right[segment, 0] + fraction * du
    t = segment + fraction
    weight = np.minimum(left_alignment[left_index], np.interp(t, np.arange(len(right)), right_alignment))
    order = np.lexsort((t, left_index))
    candidates = Candidates(left_index, t, u_right, left[left_index, 0] - u_right, weight)
    return candidates.take(order)


def _ranges(counts: np.ndarray) -> np.ndarray:
    """Concatenated aranges: [0..counts[0]), [0..counts[1]), ... (vectorised)."""
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, dtype=np.int64)
    offsets = np.repeat(np.cumsum(counts) - counts, counts)
    return np.arange(total, dtype=np.int64) - offsets


@dataclass(frozen=True)
class SelectionCosts:
    """Edge costs and limits of the monotone selection graph (see module docstring)."""

    skip_cost: float = 1.0
    speed_cost: float = 0.5
    disparity_cost: float = 2.0
    back_tolerance: float = 1.0
    max_speed: float = 1.5
    speed_slack: float = 3.0
    start_slack: float = 8.0
    max_candidates: int = 8


def cap_candidates(candidates: Candidates, n_left: int, max_candidates: int) -> Candidates:
    """Keep at most ``max_candidates`` per left sample: the best-conditioned (largest weight) ones."""
    counts = np.bincount(candidates.left, minlength=n_left)
    if counts.max(initial=0) <= max_candidates:
        return candidates
    order = np.lexsort((-candidates.weight, candidates.left))
    rank = np.empty(len(candidates), dtype=np.int64)
    rank[order] = _ranges(counts)
    keep = rank < max_candidates
    return candidates.take(keep)


def select_monotone(candidates: Candidates, n_left: int, costs: SelectionCosts) -> np.ndarray:
    """Indices into ``candidates`` of the chosen crossing per paired left sample, in left order.

    The shortest source-to-sink path of the selection graph (module docstring);
    an empty array when there is no candidate at all.
    """
    n = len(candidates)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    counts = np.bincount(candidates.left, minlength=n_left)
    width = int(counts.max())
    table = np.full((n_left, width), -1, dtype=np.int64)
    table[candidates.left, _ranges(counts)] = np.arange(n)  # candidates are sorted by left index

    t, d, row, w = candidates.t, candidates.disparity, candidates.left, candidates.weight
    sources, targets, weights = [], [], []
    for lag in LAGS[n_left > LAGS]:
        child = table[lag:][:, :, None]
        parent = table[:-lag][:, None, :]
        valid = (child >= 0) & (parent >= 0)
        child, parent = np.broadcast_arrays(child, parent)
        child, parent = child[valid], parent[valid]
        dt = t[child] - t[parent]
        ok = (dt >= -costs.back_tolerance) & (dt <= costs.max_speed * lag + costs.speed_slack)
        child, parent, dt = child[ok], parent[ok], dt[ok]
        # Speed and disparity changes are measured as well as the crossings are conditioned:
        # a crossing at angle a to the row moves by (row noise) / tan(a).
        trust = np.sqrt(np.minimum(w[child], w[parent]))
        cost = costs.skip_cost * (lag - 1) + trust * (
            costs.speed_cost * np.abs(dt - lag) + costs.disparity_cost * np.abs(d[child] - d[parent])
        )
        sources.append(parent)
        targets.append(child)
        weights.append(cost)
    source, sink = n, n + 1
    # Both sequences start at the cut tip: the first pair must lie near t = left index.
    start = np.abs(t - row) <= costs.start_slack + (costs.max_speed - 1.0) * row
    sources += [np.full(int(start.sum()), source), np.arange(n)]
    targets += [np.flatnonzero(start), np.full(n, sink)]
    weights += [costs.skip_cost * row[start] + costs.speed_cost * np.abs(t[start] - row[start])]
    weights += [costs.skip_cost * (n_left - 1 - row)]
    # A tiny positive floor: csgraph must see every edge, including free ones.
    graph = coo_matrix(
        (np.concatenate(weights) + 1e-9, (np.concatenate(sources), np.concatenate(targets))),
        shape=(n + 2, n + 2),
    ).tocsr()
    distance, predecessors = dijkstra(graph, directed=True, indices=source, return_predecessors=True)
    if not np.isfinite(distance[sink]):
        return np.zeros(0, dtype=np.int64)
    path = []
    node = predecessors[sink]
    while node != source:
        path.append(node)
        node = predecessors[node]
    return np.asarray(path[::-1], dtype=np.int64)


@dataclass(frozen=True)
class PairingParams:
    """Parameters of :func:`pair_sequences` (pixels and degrees; depths in metres).

    ``min_depth``/``max_depth``: working range whose disparities fx*b/z bound the
    pairs (50-150 mm, the simulator's range, with 10 % margin). ``tangent_window``:
    samples of the tangent estimate behind the crossing weights. ``min_crossing_angle_deg``:
    flatter crossings are ill-conditioned and dropped. ``reliable_angle_deg``:
    crossings at least this steep anchor the correspondence (pass 1).
    ``max_arc_drift_px``/``max_arc_drift_rel``: in pass 1, |t - s| may not exceed
    this (px + fraction of s): the two views' image arc lengths from the tip
    differ only by about the change of disparity (at most a few px).
    ``drift_bandwidth_px``: smoothing of the correspondence. ``band_px``: in pass 2,
    a crossing must lie within this many px of the predicted correspondence.
    ``end_pair_weight``, ``end_row_tolerance_px``, ``end_length_tolerance``: see
    :func:`end_pairs`. ``selection``: the pass-1 graph (:class:`SelectionCosts`).
    """

    min_depth: float = field(
        default=0.045,
        metadata=described(
            "nearest depth (m) of a pair: the largest disparity accepted",
            (0.0, 100.0),
        ),
    )
    max_depth: float = field(
        default=0.165,
        metadata=described(
            "farthest depth (m) of a pair: the smallest disparity accepted",
            (0.0, 100.0),
        ),
    )
    tangent_window: int = 21
    min_crossing_angle_deg: float = 1.5
    reliable_angle_deg: float = 10.0
    max_arc_drift_px: float = 20.0
    max_arc_drift_rel: float = 0.1
    drift_bandwidth_px: float = 40.0
    band_px: float = 3.0
    end_pair_weight: float = 0.25
    end_row_tolerance_px: float = 2.0
    end_length_tolerance: float = 0.03
    selection: SelectionCosts = SelectionCosts()

    def __post_init__(self) -> None:
        if not 0 < self.min_depth < self.max_depth:
            raise ValueError(f"need 0 < min_depth < max_depth, got {self.min_depth}, {self.max_depth} m")
        for name in ("max_arc_drift_px", "drift_bandwidth_px", "band_px", "end_row_tolerance_px"):
            if not getattr(self, name) > 0:
                raise ValueError(f"pairing parameter {name} must be positive, got {getattr(self, name)}")


@dataclass(frozen=True)
class Pairs:
    """Stereo pairs of one frame, sorted by left sample (end pairs included).

    ``rows`` (P,) left-sample indices; ``t`` (P,) fractional right-sample indices;
    ``disparity`` (P,) px; ``weight`` (P,) sin^2 of the crossing angle (or the end
    pair weight); ``predicted_t`` (N,) the smooth correspondence of every left
    sample; ``rejected``: left samples without a pair, by reason.
    """

    rows: np.ndarray
    t: np.ndarray
    disparity: np.ndarray
    weight: np.ndarray
    predicted_t: np.ndarray
    rejected: dict[str, int]


def end_pairs(
    left: np.ndarray,
    right: np.ndarray,
    left_length: float,
    right_length: float,
    d_range: tuple[float, float],
    params: PairingParams,
) -> list[tuple[int, int, float]]:
    """The ends of the two sequences as pairs (left index, right index, disparity).

    Both sequences start at the cut tip (the interface contract), so their first
    samples are the same 3D point; their last samples are taken to be one too
    when the two sequences have about the same image length (within
    ``end_length_tolerance`` relative, plus 3 px). An end pair must lie on one row
    (``end_row_tolerance_px``) and within the disparity limits. Where the thread
    runs along the rows, rows alone cannot pair it and these pairs fix its depth.
    """
    ends = [(0, 0)]
    if abs(left_length - right_length) <= params.end_length_tolerance * max(left_length, right_length) + 3.0:
        ends.append((len(left) - 1, len(right) - 1))
    pairs = []
    for i, j in ends:
        d = float(left[i, 0] - right[j, 0])
        if abs(left[i, 1] - right[j, 1]) <= params.end_row_tolerance_px and d_range[0] <= d <= d_range[1]:
            pairs.append((i, j, d))
    return pairs


def pair_sequences(
    left: np.ndarray,
    left_observed: np.ndarray,
    right: np.ndarray,
    right_observed: np.ndarray,
    d_range: tuple[float, float],
    params: PairingParams,
) -> Pairs:
    """Pair two sequences resampled every 1 px (module docstring), in two passes.

    ``left`` (N, 2) and ``right`` (M, 2) pixels with their ``*_observed`` masks
    (False inside a jump); ``d_range`` (min, max) disparity in px.

    Pass 1 anchors the correspondence t(s) on steep, unambiguous crossings chosen
    by the monotone selection graph (within the arc-drift limit of the identity),
    plus the end pairs, and smooths t(s) - s. Pass 2 takes, for every left sample,
    the usable crossing (steeper than ``min_crossing_angle_deg``) nearest to the
    predicted t(s), if it is within ``band_px``.
    """
    n_left = len(left)
    s = np.arange(n_left, dtype=np.float64)
    candidates = row_crossings(
        left,
        right,
        ~(right_observed[:-1] & right_observed[1:]),
        row_alignment(left, params.tangent_window),
        row_alignment(right, params.tangent_window),
    )
    crossed = np.zeros(n_left, dtype=bool)
    crossed[candidates.left] = True
    in_range = (candidates.disparity >= d_range[0]) & (candidates.disparity <= d_range[1])
    usable = in_range & left_observed[candidates.left]
    in_range_rows = np.zeros(n_left, dtype=bool)
    in_range_rows[candidates.left[in_range]] = True
    weight_min = np.sin(np.radians(params.min_crossing_angle_deg)) ** 2
    weight_reliable = np.sin(np.radians(params.reliable_angle_deg)) ** 2
    conditioned = usable & (candidates.weight >= weight_min)
    conditioned_rows = np.zeros(n_left, dtype=bool)
    conditioned_rows[candidates.left[conditioned]] = True
    ends = end_pairs(
        left,
        right,
        float(np.hypot(*np.diff(left, axis=0).T).sum()),
        float(np.hypot(*np.diff(right, axis=0).T).sum()),
        d_range,
        params,
    )

    # Pass 1: anchors of the correspondence.
    drift_limit = params.max_arc_drift_px + params.max_arc_drift_rel * s[candidates.left]
    reliable = (
        conditioned
        & (candidates.weight >= weight_reliable)
        & (np.abs(candidates.t - s[candidates.left]) <= drift_limit)
    )
    anchors = cap_candidates(candidates.take(reliable), n_left, params.selection.max_candidates)
    chosen = select_monotone(anchors, n_left, params.selection)
    anchor_rows = np.concatenate([anchors.left[chosen], [i for i, _, _ in ends]]).astype(np.int64)
    anchor_t = np.concatenate([anchors.t[chosen], [float(j) for _, j, _ in ends]])
    predicted_t = s + _robust_drift(
        n_left, anchor_rows, anchor_t - anchor_rows, params.drift_bandwidth_px, params.band_px
    )

    # Pass 2: every usable crossing near the predicted correspondence.
    distance = np.abs(candidates.t - predicted_t[candidates.left])
    near = np.flatnonzero(conditioned & (distance <= params.band_px))
    order = near[np.lexsort((distance[near], candidates.left[near]))]
    _, first = np.unique(candidates.left[order], return_index=True)
    pick = order[first]
    rows = candidates.left[pick]
    t = candidates.t[pick]
    disparity = candidates.disparity[pick]
    weight = candidates.weight[pick]
    rejected = {
        "unobserved": int((~left_observed).sum()),
        "off_epipolar": int((left_observed & ~crossed).sum()),
        "disparity_range": int((left_observed & crossed & ~in_range_rows).sum()),
        "ill_conditioned": int((left_observed & in_range_rows & ~conditioned_rows).sum()),
        "inconsistent": int(conditioned_rows.sum()) - rows.size,
    }
    if ends:
        end_rows = np.array([i for i, _, _ in ends], dtype=np.int64)
        rows = np.concatenate([rows, end_rows])
        t = np.concatenate([t, [float(j) for _, j, _ in ends]])
        disparity = np.concatenate([disparity, [d for _, _, d in ends]])
        weight = np.concatenate([weight, np.full(len(ends), params.end_pair_weight)])
        order = np.argsort(rows, kind="stable")
        rows, t, disparity, weight = rows[order], t[order], disparity[order], weight[order]
        keep = weight > 0
        rows, t, disparity, weight = rows[keep], t[keep], disparity[keep], weight[keep]
    return Pairs(rows, t, disparity, weight, predicted_t, rejected)


def _robust_drift(
    n: int, rows: np.ndarray, drift: np.ndarray, bandwidth: float, tolerance: float
) -> np.ndarray:
    """Smooth drift t(s) - s (n,) through the anchors; those off by over ``tolerance`` px drop out once."""
    if rows.size == 0:
        return np.zeros(n)
    lam = float(bandwidth) ** 4
    fit = _whittaker(n, rows, drift, np.ones(rows.size), lam)
    good = np.abs(drift - fit[rows]) <= tolerance
    if 0 < good.sum() < rows.size:
        fit = _whittaker(n, rows[good], drift[good], np.ones(int(good.sum())), lam)
    return fit


@dataclass(frozen=True)
class Disparity:
    """Regularised disparity along the left samples.

    ``value`` (N,) px, NaN where unsupported; ``supported`` (N,) bool; ``inlier``
    (P,) bool over the pairs given to :func:`regularise_disparity`; ``bandwidth``
    (N,) the smoothing length h used at each sample (px, blended between scales).
    """

    value: np.ndarray
    supported: np.ndarray
    inlier: np.ndarray
    bandwidth: np.ndarray | None = None


@dataclass(frozen=True)
class DisparitySmoothing:
    """Parameters of :func:`regularise_disparity` (pixels along the left sequence).

    The ladder of smoothing lengths h: the standard scales from
    ``min_bandwidth_px`` (a little over the 9-sample Savitzky-Golay pre-smoothing
    window, over which the pairs' noise is correlated; on predicted masks the
    two views' centrelines also differ by runs of a pixel-edge flip, which a
    scale as short as the window would follow) up to ``max_bandwidth_px`` in steps of
    x``bandwidth_ratio``, and below them fine scales, down to the h that reaches
    only ``min_reach_px`` even where the pairs are weakest (see :meth:`bandwidths`).
    ``threshold`` and ``fine_threshold``: Gamma of the intersection-of-confidence-intervals
    rule for the standard and the fine scales; ``noise_reach_px``: reach of the
    fit whose residuals give the noise level; ``outlier_sigma`` and
    ``min_outlier_px``: pair rejection; ``max_gap_px``: extrapolation beyond the
    first and last pair. ``roughness_window``, ``roughness_fast_window``,
    ``roughness_order``, ``roughness_white_ratio``, ``roughness_gain`` and
    ``roughness_exact_px``: the noise floor of traced centrelines (:func:`pair_noise_floor`).
    """

    min_bandwidth_px: float = 12.0
    max_bandwidth_px: float = 120.0
    bandwidth_ratio: float = 1.5
    min_reach_px: float = 3.0
    threshold: float = 1.5
    fine_threshold: float = 4.0
    noise_reach_px: float = 20.0
    outlier_sigma: float = 4.0
    min_outlier_px: float = 0.5
    max_gap_px: float = 40.0
    roughness_window: int = 31
    roughness_fast_window: int = 15
    roughness_order: int = 4
    roughness_white_ratio: float = 3.0
    roughness_gain: float = 14.0
    roughness_exact_px: float = 0.002

    def __post_init__(self) -> None:
        if not (self.roughness_gain >= 0 and self.roughness_exact_px >= 0):
            raise ValueError(
                "roughness_gain and roughness_exact_px must not be negative, got "
                f"{self.roughness_gain}, {self.roughness_exact_px}"
            )
        if not self.roughness_window > self.roughness_fast_window > self.roughness_order >= 2:
            raise ValueError(
                "need roughness_window > roughness_fast_window > roughness_order >= 2, got "
                f"{self.roughness_window}, {self.roughness_fast_window}, {self.roughness_order}"
            )
        if not self.roughness_white_ratio >= 0:
            raise ValueError(f"roughness_white_ratio must not be negative, got {self.roughness_white_ratio}")
        if not 0 < self.min_reach_px <= self.min_bandwidth_px <= self.max_bandwidth_px:
            raise ValueError(
                "need 0 < min_reach_px <= min_bandwidth_px <= max_bandwidth_px, got "
                f"{self.min_reach_px}, {self.min_bandwidth_px}, {self.max_bandwidth_px}"
            )
        if not self.bandwidth_ratio > 1:
            raise ValueError(f"bandwidth_ratio must exceed 1, got {self.bandwidth_ratio}")

    def bandwidths(self, min_weight: float = 1.0) -> np.ndarray:
        """The ladder of h, ascending: ``min_bandwidth_px`` x ratio^k up to ``max_bandwidth_px``,
        from the first k <= 0 at which h reaches only ``min_reach_px`` where the local pair weight
        is ``min_weight`` (reach h w^(-1/4); ``min_weight`` at least that of a crossing at 1.5 deg)."""
        weakest = min(1.0, max(float(min_weight), _WEAKEST_PAIR))
        ratio = np.log(self.bandwidth_ratio)
        high = int(np.floor(np.log(self.max_bandwidth_px / self.min_bandwidth_px) / ratio + 1e-9))
        low = int(np.ceil(np.log(self.min_bandwidth_px / (self.min_reach_px * weakest**0.25)) / ratio - 1e-9))
        return self.min_bandwidth_px * self.bandwidth_ratio ** np.arange(-low, high + 1)


_WEAKEST_PAIR = float(np.sin(np.radians(1.5)) ** 2)
"""Weight of a crossing at the default ``min_crossing_angle_deg``: the fine ladder needs to go no lower."""
_KERNEL_L2 = 3.0 / (8.0 * np.sqrt(2.0))
"""Integral of the squared equivalent kernel of the cubic smoothing spline (Silverman 1984), 0.265."""


def pair_noise_floor(left: np.ndarray, right: np.ndarray, params: DisparitySmoothing) -> float:
    """Lower bound (px, for a pair of unit weight) of the pairs' noise level, from the two sequences.

    A centreline traced on a pixel mask carries the mask's quantisation: an error
    across the thread of a few tenths of a px that runs along it as a saw-tooth,
    correlated over tens of px, and different in the two views (their pixel
    grids cut the thread at different phases). Its slow part moves the row
    crossings of both views coherently over tens of px, so the pairs' residuals
    from a fit reaching ``noise_reach_px`` see only a fraction of it, and the
    adaptive fit takes the rest for depth: a depth ripple of several mm along
    the thread, which adds arc length (``length_error`` of +5 to +40 mm and the
    grasp 5-17 mm too early along the thread on masks of simulated frames,
    threads 20-30 deg off the rows the worst).

    What shows the saw-tooth in a single view is that it is not smooth at the
    scale of tens of px, which the image of a thread is:
    :func:`suture_reconstruction.sequences.roughness` about a local quartic over
    ``roughness_window`` (31) samples. Part of that is white noise, which the
    pairs' residuals do measure, and which shows nearly as much about a quartic
    over ``roughness_fast_window`` (15) samples: after the Savitzky-Golay
    pre-smoothing it is at most ``roughness_white_ratio`` (3) times rougher over
    31 samples than over 15 (2.2-2.6 in the tests' scenes), while the
    saw-tooth is 4-12 times rougher. So the correlated part of a view is
    c^2 = slow^2 - (ratio fast)^2 - ``roughness_exact_px``^2 (not below 0), the
    last term the local fit's own error on an exact image curve (the most seen
    on exact simulated sequences, tight loops included), so exact sequences
    get no floor and their fit follows the pairs' 0.01 px precision (a floor of
    0.008 px already flattens a lift enough to move a grasp point by 0.3 mm).
    An error e across
    the thread moves a crossing at angle a to the rows by e / sin(a), so for a
    pair of unit weight the views add as hypot(c_left, c_right), and
    ``roughness_gain`` scales that to the correlated error's equivalent white
    noise level, which is far larger than its roughness because it is
    correlated over tens of px (calibrated on masks of simulated frames: 14
    puts the floor at 0.25-0.7 px for traced centrelines, 0.43 px typically).
    """
    order = params.roughness_order
    total = 0.0
    for points in (left, right):
        slow = roughness(points, params.roughness_window, order)
        fast = roughness(points, params.roughness_fast_window, order)
        total += max(slow**2 - (params.roughness_white_ratio * fast) ** 2 - params.roughness_exact_px**2, 0.0)
    return params.roughness_gain * float(np.sqrt(total))


def regularise_disparity(
    n_left: int,
    rows: np.ndarray,
    disparity: np.ndarray,
    weight: np.ndarray,
    params: DisparitySmoothing,
    noise_floor: float = 0.0,
) -> Disparity:
    """Adaptive smoothing of the pairs' ``disparity`` (P,) at left samples ``rows`` (P,) on the 1 px grid.

    The smoother is the Whittaker smoother (:func:`suture_reconstruction.smoothing.whittaker`,
    a discrete cubic smoothing spline) with weights ``weight`` (the inverse
    noise variance of each pair up to one factor sigma^2) and lam = h^4: where
    the pairs have unit weight it averages over about h px, where they are weak
    (a thread nearly along the rows) it reaches further, by weight^(-1/4), and
    across gaps it interpolates (a cubic spline; linear where nothing else
    constrains it, which is exact for a straight thread, whose disparity is
    affine along its image).

    The smoothing length is chosen per sample by the intersection of confidence
    intervals (ICI, Katkovnik): fits for a ladder of h (x1.5 steps) are compared
    from the smallest h up, each with the standard deviation
    sigma * sqrt(0.265 / (h rho^(3/4))) of the spline's equivalent kernel (rho:
    local weight per px, sigma estimated from the residuals of a fit reaching
    about ``noise_reach_px``, but at least ``noise_floor``: see
    :func:`pair_noise_floor`), and the largest h whose interval
    [z - Gamma sd, z + Gamma sd] still meets all the smaller ones' is used. So a
    sharp depth change where the thread is lifted over a crossing keeps its
    shape while long weak stretches are averaged widely.

    Why each part is as it is (each prevents grasp errors of 2-4 mm on
    ground-truth sequences, where the pairs are exact to about 0.01 px: where
    the thread rises steeply over a crossing 1 px of disparity is about 3 mm of
    depth against 0.2 mm of image position, so a fit that cannot follow a 2 px
    disparity bump flattens the lift, and the lost depth excursion is lost arc
    length, which moves the grasp point along the thread):

    * **Fine scales.** The standard ladder starts at ``min_bandwidth_px`` (12 px,
      about the pre-smoothing window over which the pairs' noise is correlated, so
      below it the independent-noise variances above are optimistic). At weight
      w a scale reaches h w^(-1/4), so on a stretch 5 deg off the rows (w 0.008)
      even h = 12 px averages over 40 px. Below the standard scales the ladder
      therefore goes on down until a scale reaches only ``min_reach_px`` (3 px)
      at the weakest pairs present (a fine scale counts only where it reaches
      at least that much), but a fine scale needs the stronger evidence
      ``fine_threshold`` (Gamma 4 instead of 1.5) to be preferred: with noisy
      pairs (0.3 px per view) that is rare and the standard scales decide, with
      exact pairs sigma is tiny and the lifts are followed.
    * **Outliers against the adaptive fit.** Pairs whose weighted residual from
      a first adaptive fit of all pairs exceeds ``outlier_sigma`` robust sigmas
      and ``min_outlier_px`` are rejected and the rest fitted again. An isolated
      wrong crossing moves even the shortest scale by a fraction of its error,
      so it stands out; a run of correct pairs along a real disparity change is
      followed by the adaptive fit and kept. (A fixed mid-scale fit reaches over
      100 px on a stretch a few degrees off the rows and would reject exactly
      those pairs: 20-35 of them on a lifted stretch.)
    * **No steps between scales.** Neighbouring samples may pick different
      scales, whose fits differ by up to a few tenths of a px; taken as they
      are, those are steps of the depth (0.5 mm at 100 mm), a saw-tooth along
      the thread that adds length and that Algorithm 1 then cuts short. The
      chosen scale index is eroded over one shortest reach (never a longer
      scale than ICI allows nearby), smoothed with a Gaussian of that width,
      and the fits of the two scales around the fractional index are blended.

    Beyond the first and last remaining pair the result extrapolates at most
    ``max_gap_px``; samples farther out are unsupported (NaN).
    """
    value, bandwidth = _adaptive_fit(n_left, rows, disparity, weight, params, noise_floor)
    residual = disparity - value[rows]
    scaled = np.abs(residual) * np.sqrt(weight)
    sigma = 1.4826 * float(np.median(scaled)) + 1e-12
    inlier = ~((scaled > params.outlier_sigma * sigma) & (np.abs(residual) > params.min_outlier_px))
    if inlier.sum() < 3:
        inlier[:] = True
    if not inlier.all():
        rows = rows[inlier]
        value, bandwidth = _adaptive_fit(n_left, rows, disparity[inlier], weight[inlier], params, noise_floor)
    grid = np.arange(n_left)
    supported = (grid >= rows.min() - params.max_gap_px) & (grid <= rows.max() + params.max_gap_px)
    supported &= np.isfinite(value)
    return Disparity(np.where(supported, value, np.nan), supported, inlier, bandwidth)


def _adaptive_fit(
    n: int,
    rows: np.ndarray,
    values: np.ndarray,
    weight: np.ndarray,
    params: DisparitySmoothing,
    noise_floor: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """The ICI fit of :func:`regularise_disparity`: (n,) values and (n,) h used (px)."""
    scales = params.bandwidths(float(weight.min()) if weight.size else 1.0)
    w = np.zeros(n)
    wy = np.zeros(n)
    np.add.at(w, rows, weight)
    np.add.at(wy, rows, weight * values)
    y = np.divide(wy, w, out=np.zeros(n), where=w > 0)
    fits = np.stack([whittaker(y, w, float(h) ** 4) for h in scales], axis=1)  # (n, K)
    density = np.stack(
        [gaussian_filter1d(w, max(float(h), 1.0), mode="constant", truncate=3.0) for h in scales], axis=1
    )
    density += 1e-12
    reach = scales * density**-0.25  # local half-width of each fit, px
    fine = scales < params.min_bandwidth_px * (1 - 1e-9)
    usable = ~fine | (reach >= params.min_reach_px)  # a fine scale, where it reaches min_reach_px
    at = np.arange(n)
    # Noise of a pair of unit weight: residuals from the fit that reaches about noise_reach_px.
    wide = np.column_stack([reach[:, :-1] >= params.noise_reach_px, np.ones(n, dtype=bool)])
    short = fits[at, np.argmax(wide, axis=1)]
    sigma = 1.4826 * float(np.median(np.abs(values - short[rows]) * np.sqrt(weight))) + 1e-9
    sigma = max(sigma, float(noise_floor))  # correlated noise the residuals miss (pair_noise_floor)
    to_end = np.minimum(at, n - 1 - at)
    edge = 1.0 + 2.9 * np.exp(-to_end[:, None] / reach)  # the boundary kernel's larger variance
    gamma = np.where(fine, params.fine_threshold, params.threshold)
    half = gamma * sigma * np.sqrt(_KERNEL_L2 * edge / (reach * density))
    half[~usable] = np.inf  # constrains nothing
    lower = np.maximum.accumulate(fits - half, axis=1)
    upper = np.minimum.accumulate(fits + half, axis=1)
    first = np.argmax(usable, axis=1)
    chosen = np.maximum(np.cumprod(lower <= upper, axis=1).sum(axis=1) - 1, first)
    # No steps between scales (see regularise_disparity).
    span = int(2 * np.ceil(params.min_reach_px) + 1)
    index = minimum_filter1d(chosen.astype(np.float64), span, mode="nearest")
    index = np.maximum(gaussian_filter1d(index, params.min_reach_px, mode="nearest"), first)
    below = np.minimum(np.floor(index).astype(np.int64), len(scales) - 1)
    above = np.minimum(below + 1, len(scales) - 1)
    fraction = index - below
    value = (1.0 - fraction) * fits[at, below] + fraction * fits[at, above]
    return value, scales[below] * (scales[above] / scales[below]) ** fraction


def _whittaker(n: int, rows: np.ndarray, values: np.ndarray, weight: np.ndarray, lam: float) -> np.ndarray:
    """Whittaker smoother of weighted samples at ``rows`` of the grid 0..n-1."""
    w = np.zeros(n)
    wy = np.zeros(n)
    np.add.at(w, rows, weight)
    np.add.at(wy, rows, weight * values)
    y = np.divide(wy, w, out=np.zeros(n), where=w > 0)
    return whittaker(y, w, lam)
