# SPDX-License-Identifier: Apache-2.0
"""ROS-free entry points of the ordering stage: :func:`order_sequence` (one view) and
:func:`order_stereo` (a rectified pair), as called by ``ordering_node`` and the offline evaluator.

Shapes and units: masks are (H, W) uint8 (0/255) or bool; pixels are (u, v) =
(column, row) float64, the centre of the top-left pixel at (0, 0); sequences are
(N, 2) float64 (u, v) from the cut tip, about 1 px apart.

Pipeline per view: :func:`suture_ordering.cleaning.clean_mask` (holes, specks),
cut tip (:mod:`suture_ordering.tip`), then the search of the paper's Section II.B
(:mod:`suture_ordering.search`). The right view's tip follows from the left one
(same row, disparity in the range of ``min_depth_m``..``max_depth_m``). A cut end that curls
into a hook or hairpin starts with a walk through the hook (:mod:`suture_ordering.hooks`).
"""

from __future__ import annotations

import dataclasses
import functools
import time
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from suture_common.camera import StereoCamera
from suture_ordering.cleaning import CleanMask, as_binary_mask, clean_binary
from suture_ordering.errors import InvalidInputError, NoFreeEndError, OrderingError, TipNotOnThreadError
from suture_ordering.hooks import HOOK_WINDOW, HookStart, hook_after_search, hook_start, on_mask, stereo_tip
from suture_ordering.not_seen import flagged_sequence, seen_in_low_mask
from suture_ordering.params import OrderingParams, ScaledParams
from suture_ordering.search import Searcher
from suture_ordering.skipped_loop import skipped_loop_index
from suture_ordering.stereo_fill import arc_length, continue_from_other_view, splice_skipped_stretch
from suture_ordering.strand_switch import strand_switch_index
from suture_ordering.tip import (
    automatic_tip,
    check_hint,
    right_tip,
    right_tip_across_gap,
    tip_across_gap,
    tip_from_hint,
)
from suture_ordering.tip_check import check_tip_explained

#: Arc (px at 640 px width) by which either view's low-mask sequence may fall short of the masks'
#: near the tip and still be taken (:func:`_holds_more_of_the_tip`); also how near it must pass
#: to where the masks' sequence leaves the hook window, and how far from that sequence its
#: thread counts as thread the masks' sequence does not pass.
TIP_ARC_SLACK_PX = 2.0


@dataclass(frozen=True)
class OrderingResult:
    """The ordered centreline of one view.

    ``points``: (N, 2) float64 (u, v) from the cut tip, ~1 px apart (an open polyline).
    ``bridged``: (N,) bool, True where a point was interpolated across a gap in the mask
    (e.g. under an instrument). ``tip``: (2,) the free end the search started from.
    ``tip_source``: 'hint', 'automatic' or 'epipolar' (right view from the left tip).
    ``status``: how the search ended: 'free_end', 'image_border' or 'max_steps'.
    ``eps``: (ε1, ε2, ε3) chosen by the tuning of Eq. (7). ``steps``: search loops of the
    chosen run; ``bridges``: gaps bridged; ``forks``: times the parameter sets disagreed.
    ``elapsed_ms``: wall time of the whole call (cleaning, tip, search).
    """

    points: np.ndarray
    bridged: np.ndarray
    tip: np.ndarray
    tip_source: str
    status: str
    eps: tuple[float, float, float]
    steps: int
    bridges: int
    forks: int
    elapsed_ms: float

    @property
    def visible(self) -> np.ndarray:
        """(M, 2) ``points`` without those interpolated across gaps (the published sequence)."""
        return self.points[~self.bridged]

    @property
    def length_px(self) -> float:
        """Length of the ordered polyline in pixels."""
        return float(np.linalg.norm(np.diff(self.points, axis=0), axis=1).sum())


@dataclass(frozen=True)
class StereoOrdering:
    """Ordered sequences of both views of a rectified pair.

    ``left`` and ``right``: (N, 2) and (M, 2) float64 (u, v) from the cut tip: the visible
    centreline, ~1 px apart; a gap the search bridged (e.g. under an instrument) appears as
    one longer segment between the last point before and the first point after it, since
    nothing under the occluder can be seen, matched between the views or triangulated.
    ``left_result`` / ``right_result``: the per-view :class:`OrderingResult` (with the gap
    interpolation in ``points``, status and diagnostics) of each view's own search.
    ``left_sequence`` and ``right_sequence``: (N', 3) and (M', 3) float64 u, v, not seen: the
    published sequences, ``left`` and ``right`` with the stretches each view's search bridged
    across gaps put back and flagged 1.0 in the third column (0.0: seen in the mask;
    :mod:`suture_ordering.not_seen`); ordering_node publishes them and the 3D stage takes depth
    across the flagged stretches from the seen thread on either side.
    ``filled``: points of ``left`` and ``right`` found by following the other view, across a gap
    in this view's mask or round a loop this view's search cut across
    (:mod:`suture_ordering.stereo_fill`); 0 where none was needed. ``cut``: points cut from the
    end of ``left`` and ``right`` where the sequence turned off its thread onto a crossing strand
    (:mod:`suture_ordering.strand_switch`) or passed by a loop its mask shows
    (:mod:`suture_ordering.skipped_loop`); 0 where it did neither. ``low_masks_used``: the
    sequences are those of the low masks (:func:`order_stereo`).
    """

    left: np.ndarray
    right: np.ndarray
    left_result: OrderingResult
    right_result: OrderingResult
    left_sequence: np.ndarray
    right_sequence: np.ndarray
    filled: tuple[int, int] = (0, 0)
    cut: tuple[int, int] = (0, 0)
    low_masks_used: bool = False


@dataclass(frozen=True)
class _Prepared:
    clean: CleanMask
    scaled: ScaledParams
    searcher: Searcher


@functools.lru_cache(maxsize=32)
def _scaled_params(params: OrderingParams, width: int) -> ScaledParams:
    """The parameters in pixels for masks ``width`` px wide, computed once per (params, width)."""
    return ScaledParams.from_params(params, width)


def _prepare(mask: np.ndarray, params: OrderingParams, view: str | None) -> _Prepared:
    binary = as_binary_mask(mask, view)
    fraction = np.count_nonzero(binary) / binary.size
    if fraction > params.max_mask_fraction:
        raise InvalidInputError(
            f"mask covers {100 * fraction:.0f} % of the image, more than max_mask_fraction "
            f"({100 * params.max_mask_fraction:.0f} %): not a thread mask (noise, a wrong threshold "
            "or encoding?)",
            view,
        )
    scaled = _scaled_params(params, binary.shape[1])
    pad = scaled.max_reach + scaled.step_radius + 3
    if np.may_share_memory(binary, mask):  # a bool mask's view: cleaned in a copy
        binary = binary.copy()
    clean = clean_binary(binary, scaled, int(params.zone_margin_px), pad, view)
    return _Prepared(clean, scaled, Searcher(clean, params, scaled))


def _search(
    prepared: _Prepared, tip: np.ndarray, source: str, started: float, hook: HookStart | None = None
) -> OrderingResult:
    found = prepared.searcher.run(tip, hook)
    tip = tip if hook is None else hook.points[0]
    return OrderingResult(
        points=found.points,
        bridged=found.bridged,
        tip=np.asarray(tip, dtype=np.float64),
        tip_source=source,
        status=found.status,
        eps=found.eps,
        steps=found.steps,
        bridges=found.bridges,
        forks=found.forks,
        elapsed_ms=(time.perf_counter() - started) * 1e3,
    )


def order_sequence(
    mask: np.ndarray,
    tip: np.ndarray | None,
    params: OrderingParams | None = None,
    *,
    view: str | None = None,
) -> OrderingResult:
    """Order the centreline of the thread whose cut tip is at (or near) ``tip``.

    Parameters
    ----------
    mask : (H, W) uint8 (0/255) or bool
        Every thread pixel of the view.
    tip : (2,) float (u, v) or None
        A pixel near the cut tip (within ``params.tip_radius_px``); the search starts at the
        free end nearest to it. A cut tip inside a hook or hairpin (no free end there, or the
        nearest one is the hook's bend) starts with a walk through the hook from the pixel
        (:mod:`suture_ordering.hooks`). None: the automatic rule of :mod:`suture_ordering.tip`.
    params : OrderingParams, optional
    view : str, optional
        'left' or 'right', only used to prefix error messages.

    Returns
    -------
    OrderingResult
        ``points`` (N, 2) float64 from the cut tip.

    Raises
    ------
    InvalidInputError, EmptyMaskError, TipOutsideImageError, TipNotOnThreadError, NoFreeEndError
        All subclasses of :class:`suture_ordering.errors.OrderingError` (a ``ValueError``).
    """
    return _order_view(mask, tip, OrderingParams() if params is None else params, view)[0]


def _order_view(
    mask: np.ndarray, tip: np.ndarray | None, params: OrderingParams, view: str | None
) -> tuple[OrderingResult, _Prepared, HookStart | None]:
    """One view's ordering, its prepared mask, and the walk through a hook it started with
    (None: none)."""
    started = time.perf_counter()
    if tip is not None:  # reject a bad hint before spending time on the mask
        shape = np.shape(mask)
        if len(shape) == 2:
            check_hint(tip, shape[1], shape[0], view)
    prepared = _prepare(mask, params, view)
    clean, scaled = prepared.clean.mask, prepared.scaled
    if tip is None:
        start = automatic_tip(clean, scaled.tip_radius, view)
        return _search(prepared, start, "automatic", started), prepared, None
    # A cut tip inside a hook (no free end there, or the free end is the hook's bend).
    try:
        start = tip_from_hint(clean, tip, scaled.tip_radius, view)
    except NoFreeEndError:
        hook = hook_start(clean, tip, scaled)
        if hook is None:
            raise
        return _search(prepared, tip, "hint", started, hook), prepared, hook
    except TipNotOnThreadError:
        end = None
        if scaled.tip_gap_max > 0:
            end = tip_across_gap(clean, tip, scaled.tip_radius, scaled.tip_gap_max, params.tip_gap_max_angle)
        if end is None:
            raise
        return _with_tip_gap(_search(prepared, end, "hint", started), tip), prepared, None
    result = _search(prepared, start, "hint", started)
    hook = hook_after_search(clean, prepared.searcher.context.reader, tip, start, result.points, scaled)
    if hook is None:
        return result, prepared, None
    return _search(prepared, tip, "hint", started, hook), prepared, hook


def _with_tip_gap(result: OrderingResult, tip: np.ndarray) -> OrderingResult:
    """``result`` with a straight stretch from ``tip`` to its first point put in front, 1 px
    apart and flagged bridged: the cut end the mask lost (:func:`suture_ordering.tip.tip_across_gap`)."""
    tip = np.asarray(tip, dtype=np.float64)
    first = result.points[0]
    count = max(1, int(np.ceil(np.hypot(*(first - tip)))))
    stretch = tip + (first - tip) * (np.arange(count) / count)[:, None]
    return dataclasses.replace(
        result,
        points=np.vstack([stretch, result.points]),
        bridged=np.concatenate([np.ones(count, dtype=bool), result.bridged]),
        tip=tip,
        bridges=result.bridges + 1,
    )


def _tip_gap(result: OrderingResult) -> int:
    """How many points at the start of ``result`` bridge a cut end the mask lost."""
    if len(result.bridged) == 0 or not result.bridged[0]:
        return 0
    seen = np.flatnonzero(~result.bridged)
    return int(seen[0]) if seen.size else len(result.bridged)


def order_stereo(
    left_mask: np.ndarray,
    right_mask: np.ndarray,
    tip_hint: np.ndarray | None,
    camera: StereoCamera,
    params: OrderingParams | None = None,
    low_masks: tuple[np.ndarray, np.ndarray] | None = None,
) -> StereoOrdering:
    """Order the target thread in both views of a rectified stereo pair.

    Parameters
    ----------
    left_mask, right_mask : (H, W) uint8 (0/255) or bool
        Thread masks of the left and right views, of the camera's size.
    tip_hint : (2,) float (u, v) or None
        Pixel near the cut tip in the **left** image (``/suture/tip_hint``); None: automatic.
    camera : suture_common.camera.StereoCamera
        The rectified pair; bounds the right tip's disparity to
        ``[camera.disparity(max_depth_m), camera.disparity(min_depth_m)]``.
    params : OrderingParams, optional
    low_masks : (left, right) (H, W) uint8 (0/255) or bool, optional
        The views' *low masks* (the masks plus the fainter pixels connected to them,
        ``/suture/{left,right}/mask_low``). Both pairs are ordered and the low masks' sequences
        are taken when they reach farther: one view longer by more than ``low_mask_min_gain``
        and neither shorter by more than ``low_mask_max_loss`` (relative); when they hold more
        of the thread near the cut tip (``low_mask_tip_gain_px``, :func:`_holds_more_of_the_tip`);
        or when the masks themselves give no sequence. A faint stretch where the masks break
        then no longer ends the thread, while where both agree the masks' narrower centrelines
        are kept; a stretch that the masks' search bridged and that the low mask covers is
        published as seen.

    Returns
    -------
    StereoOrdering
        ``left`` (N, 2) and ``right`` (M, 2) float64 (u, v) from the cut tip, and per-view results.
        A view whose search stopped where the other's went on is continued along the other
        view, and one that cut across a loop the other went round gets the loop back, on its
        own mask only (:mod:`suture_ordering.stereo_fill`; ``filled`` counts those points).
        A view whose sequence turned onto a crossing strand, or passed by a loop that its mask
        (low mask where given) shows beside it, is cut there (``cut``;
        :mod:`suture_ordering.strand_switch`, :mod:`suture_ordering.skipped_loop`).

    Raises
    ------
    OrderingError
        A subclass naming the view and the problem (see :func:`order_sequence`); also
        :class:`InvalidInputError` when a mask's size differs from the camera's. With low masks,
        the masks' error when neither pair gives a sequence.

    Examples
    --------
    A curved thread 3 px wide, 100 mm in front of the camera (26 px of disparity), its cut tip
    at the left end:

    >>> import cv2
    >>> import numpy as np
    >>> from suture_common.camera import StereoCamera
    >>> from suture_ordering import order_stereo
    >>> camera = StereoCamera.default(640, 480)
    >>> u = np.arange(120, 521)
    >>> v = 240 + 60 * np.sin((u - 120) / 80)
    >>> left = np.zeros((480, 640), np.uint8)
    >>> _ = cv2.polylines(left, [np.column_stack([u, v]).round().astype(np.int32)], False, 255, 3)
    >>> right = np.roll(left, -26, axis=1)
    >>> ordering = order_stereo(left, right, np.array([120.0, 240.0]), camera)
    >>> ordering.left.shape, ordering.left.dtype
    ((480, 2), dtype('float64'))
    >>> print(ordering.left[0].round(), ordering.right[0].round(), ordering.left[-1].round())
    [119. 241.] [ 93. 241.] [520. 182.]
    >>> ordering.left_result.status, ordering.right_result.tip_source
    ('free_end', 'epipolar')
    """
    params = OrderingParams() if params is None else params
    views = {"left": left_mask, "right": right_mask}
    if low_masks is not None:
        views.update({"left low": low_masks[0], "right low": low_masks[1]})
    for view, mask in views.items():
        shape = np.shape(mask)
        if shape[:2] != (camera.height, camera.width) or len(shape) != 2:
            raise InvalidInputError(
                f"mask shape {shape} does not match the camera: expected (H, W) = "
                f"({camera.height}, {camera.width}) from camera_info",
                view,
            )
    ordering = _masks_or_low_masks(left_mask, right_mask, tip_hint, camera, params, low_masks)
    explained = low_masks if low_masks is not None else (left_mask, right_mask)
    if params.skipped_loop_cut:
        ordering = _cut_at_skipped_loops(ordering, explained, params.scale_for(camera.width))
    radius = params.tip_unexplained_radius_px * params.scale_for(camera.width)
    if radius > 0:
        max_pixels = params.tip_unexplained_max_px * params.scale_for(camera.width) ** 2
        scaled = _scaled_params(params, camera.width)
        sequences = (ordering.left, ordering.right)
        check_tip_explained(
            explained, sequences, radius, max_pixels, scaled.max_hole_area, scaled.min_eye_width
        )
    return ordering


def _cut_at_skipped_loops(
    ordering: StereoOrdering, masks: tuple[np.ndarray, np.ndarray], scale: float
) -> StereoOrdering:
    """``ordering`` with each view's sequence cut where it first passes by a loop or detour of
    its mask (:func:`suture_ordering.skipped_loop.skipped_loop_index`), the points cut counted in
    ``cut``."""
    views = {
        "left": (ordering.left, ordering.left_sequence),
        "right": (ordering.right, ordering.right_sequence),
    }
    changes, cut = {}, list(ordering.cut)
    for index, (mask, (view, (visible, published))) in enumerate(zip(masks, views.items(), strict=True)):
        at = skipped_loop_index(mask, published[:, :2], scale, published[:, 2] > 0)
        if at is None:
            continue
        removed = {tuple(point) for point in published[at + 1 :, :2].tolist()}
        kept = len(visible) - sum(tuple(point) in removed for point in visible.tolist())
        changes[view] = visible[:kept]
        changes[f"{view}_sequence"] = published[: at + 1]
        cut[index] += len(visible) - kept
    if not changes:
        return ordering
    return dataclasses.replace(ordering, cut=(cut[0], cut[1]), **changes)


def _masks_or_low_masks(
    left_mask: np.ndarray,
    right_mask: np.ndarray,
    tip_hint: np.ndarray | None,
    camera: StereoCamera,
    params: OrderingParams,
    low_masks: tuple[np.ndarray, np.ndarray] | None,
) -> StereoOrdering:
    """The ordering of the masks, or of the low masks where they reach farther (:func:`order_stereo`)."""
    try:
        ordering = _order_pair(left_mask, right_mask, tip_hint, camera, params)
    except InvalidInputError:
        raise
    except OrderingError as error:
        if low_masks is None:
            raise
        try:
            return dataclasses.replace(_order_pair(*low_masks, tip_hint, camera, params), low_masks_used=True)
        except OrderingError:
            raise error from None
    if low_masks is None:
        return ordering
    try:
        low = _order_pair(*low_masks, tip_hint, camera, params)
    except OrderingError:
        return _gaps_read_on(ordering, low_masks)
    gains = [_length(low.left) / _length(ordering.left), _length(low.right) / _length(ordering.right)]
    # Seeing the cut end beats bridging it from the hint.
    sees_tip = _tip_gap(low.left_result) < _tip_gap(ordering.left_result)
    keeps_length = min(gains) >= 1 - params.low_mask_max_loss
    reaches_farther = max(gains) > 1 + params.low_mask_min_gain
    if sees_tip or (keeps_length and reaches_farther):
        return dataclasses.replace(low, low_masks_used=True)
    if keeps_length and _holds_more_of_the_tip(ordering, low, _scaled_params(params, camera.width), params):
        return dataclasses.replace(low, low_masks_used=True)
    return _gaps_read_on(ordering, low_masks)


def _holds_more_of_the_tip(
    ordering: StereoOrdering, low: StereoOrdering, scaled: ScaledParams, params: OrderingParams
) -> bool:
    """Whether the low masks' sequences hold more of the thread near the cut tip than the masks':
    between the tip and where the masks' sequence leaves the hook window, one view's low
    sequence runs more than ``low_mask_tip_gain_px`` along thread that the masks' sequence does
    not pass (a hairpin's bend or a loop that the mask lost and the low mask kept; not a second
    lap of the same loop), and neither view's is shorter there by more than ``TIP_ARC_SLACK_PX``."""
    if params.low_mask_tip_gain_px <= 0:
        return False
    window, slack = HOOK_WINDOW * scaled.roi_radius, TIP_ARC_SLACK_PX * scaled.scale
    arcs = [
        _tip_arcs(ordering.left, low.left, window, slack),
        _tip_arcs(ordering.right, low.right, window, slack),
    ]
    if arcs[0] is None or arcs[1] is None:
        return False
    longer, unexplained = zip(*arcs, strict=True)
    return min(longer) >= -slack and max(unexplained) > params.low_mask_tip_gain_px * scaled.scale


def _tip_arcs(
    sequence: np.ndarray, other: np.ndarray, window: float, slack: float
) -> tuple[float, float] | None:
    """How ``other`` (M, 2) differs from ``sequence`` (N, 2), both from the cut tip, up to the point
    where ``sequence`` first lies farther than ``window`` px from its tip: the arc (px) by which
    ``other`` is longer to reach that point, and the arc of ``other`` there that lies farther
    than ``slack`` px from ``sequence``. None where ``sequence`` stays within the window or
    ``other`` does not pass within ``slack`` of that point."""
    sequence, other = np.asarray(sequence)[:, :2], np.asarray(other)[:, :2]
    outside = np.flatnonzero(np.hypot(*(sequence - sequence[0]).T) > window)
    if len(outside) == 0 or len(other) < 2:
        return None
    leaving = sequence[outside[0]]
    distance = np.hypot(*(other - leaving).T)
    reach = int(np.argmin(distance))
    if distance[reach] > slack:
        return None
    other_arc = arc_length(other[: reach + 1])
    away, _ = cKDTree(sequence[: outside[0] + 1]).query(other[: reach + 1])
    unexplained = float(np.gradient(other_arc)[away > slack].sum()) if reach > 0 else 0.0
    return float(other_arc[-1]) - _length(sequence[: outside[0] + 1]), unexplained


def _gaps_read_on(ordering: StereoOrdering, low_masks: tuple[np.ndarray, np.ndarray]) -> StereoOrdering:
    """``ordering`` of the masks with the stretches it bridged re-read on the low masks: a
    stretch the low mask covers was faint, not hidden, and is published as seen."""
    return dataclasses.replace(
        ordering,
        left_sequence=seen_in_low_mask(ordering.left_sequence, low_masks[0]),
        right_sequence=seen_in_low_mask(ordering.right_sequence, low_masks[1]),
    )


def _right_view(
    prepared: _Prepared,
    left_prepared: _Prepared,
    left: OrderingResult,
    left_hook: HookStart | None,
    disparity_range: tuple[float, float],
    started: float,
    tip_gap_max_angle: float,
) -> tuple[OrderingResult, int | None]:
    """The right view's ordering from the left tip: the free end on its epipolar band, or,
    when the band has no thread at all (the mask lost the cut end), the thread end that points
    back at it across the gap (:func:`suture_ordering.tip.right_tip_across_gap`), the stretch
    bridged; when the left tip lies in a hook or the band has no free end, through the hook at the
    pixel that the left tip's neighbourhood matches (:func:`suture_ordering.hooks.stereo_tip`).
    A search from the band's free end is checked for a hook only where the left view had one:
    another strand near the right tip is not read as a hook the left view did not see. Through
    a hook the left view started in, the walk follows ``left``'s sequence shifted by that
    disparity (the guide of :func:`suture_ordering.hooks.hook_walk`): both views go round a
    loop of merged arms the same way; where the right view's own rule would go round the other
    way, both views' evidence chooses the way (``other``, ``other_choice`` of
    :func:`suture_ordering.hooks.hook_walk`). Also the index of the left view's walk that the
    right view's was paired with there (the left view must take it), else None."""
    clean, scaled = prepared.clean.mask, prepared.scaled
    left_tip, guide, other = left.tip, None, None
    left_hooked = left_hook is not None
    try:
        start = right_tip(clean, left_tip, disparity_range, scaled.row_tolerance, scaled.tip_radius)
        missing = None
    except NoFreeEndError as error:
        start, missing = None, error
    except TipNotOnThreadError:
        found = None
        if scaled.tip_gap_max > 0 and not left.bridged[0]:
            found = right_tip_across_gap(
                clean, left.points, disparity_range, scaled.tip_radius, scaled.tip_gap_max, tip_gap_max_angle
            )
        if found is None:
            raise
        return _with_tip_gap(_search(prepared, found[0], "epipolar", started), found[1]), None
    if start is None or left_hooked:
        guess = stereo_tip(
            left_prepared.clean.mask, clean, left_tip, disparity_range, scaled.row_tolerance, scaled
        )
        if start is None and guess is not None and not on_mask(clean, guess):
            guess = None  # the tip is missing from this mask, not inside a stroke
        if guess is not None and left_hook is not None:
            shift = guess - np.asarray(left_tip, dtype=np.float64)
            guide = left.points + shift
            if left_hook.alternatives is not None:
                other = left_hook.alternatives.shifted(shift)
        # Without a free end on the band, any walk from the matched pixel out of the window.
        hook = (
            None
            if guess is None
            else hook_start(clean, guess, scaled, require_return=start is not None, guide=guide, other=other)
        )
        if hook is not None:
            return _search(prepared, hook.points[0], "epipolar", started, hook), hook.other_choice
        if start is None:
            raise missing  # type: ignore[misc]
    result = _search(prepared, start, "epipolar", started)
    if not left_hooked:  # the same thread: no hook at the left tip, none at the right one
        return result, None
    hook = hook_after_search(
        clean, prepared.searcher.context.reader, start, start, result.points, scaled, guide, other
    )
    if hook is None:
        return result, None
    return _search(prepared, start, "epipolar", started, hook), hook.other_choice


def _rewalk(
    prepared: _Prepared, left: OrderingResult, hook: HookStart, choice: int, tip: np.ndarray
) -> OrderingResult:
    """The left view's ordering through its hook at ``tip`` along walk ``choice`` of its
    alternatives, where both views' evidence chose that walk (:func:`_right_view`); ``left``
    where it is the walk taken already."""
    if hook.alternatives is None or hook.alternatives.chosen == choice:
        return left
    walk = hook_start(prepared.clean.mask, tip, prepared.scaled, require_return=False, choice=choice)
    if walk is None:
        return left
    started = time.perf_counter() - left.elapsed_ms / 1e3
    return _search(prepared, tip, left.tip_source, started, walk)


def _length(sequence: np.ndarray) -> float:
    return max(float(arc_length(sequence)[-1]), 1e-9)


def _order_pair(
    left_mask: np.ndarray,
    right_mask: np.ndarray,
    tip_hint: np.ndarray | None,
    camera: StereoCamera,
    params: OrderingParams,
) -> StereoOrdering:
    """:func:`order_stereo` of one pair of masks (of the camera's size)."""
    left, left_prepared, left_hook = _order_view(left_mask, tip_hint, params, "left")
    started = time.perf_counter()
    right_prepared = _prepare(right_mask, params, "right")
    d_min = float(camera.disparity(params.max_depth_m))
    d_max = float(camera.disparity(params.min_depth_m))
    gap, angle = _tip_gap(left), params.tip_gap_max_angle
    if gap == 0:
        right, pair = _right_view(
            right_prepared, left_prepared, left, left_hook, (d_min, d_max), started, angle
        )
        if pair is not None and left_hook is not None and tip_hint is not None:
            left = _rewalk(left_prepared, left, left_hook, pair, tip_hint)
    else:  # the right view starts where the left one's mask does, and gets the same gap
        seen = dataclasses.replace(
            left, points=left.points[gap:], bridged=left.bridged[gap:], tip=left.points[gap]
        )
        right, _ = _right_view(right_prepared, left_prepared, seen, left_hook, (d_min, d_max), started, angle)
        right = _with_tip_gap(right, left.tip + (right.points[0] - left.points[gap]))
    # Where one view's search stopped at a gap and the other's went on, follow the other view.
    views = ((left, left_prepared, right, -1.0), (right, right_prepared, left, 1.0))
    sequences, filled = [], []
    for own, prepared, guide, sign in views:
        sequence, added = own.visible, 0
        if params.stereo_fill_max_gap_px > 0 and own.status == "free_end":
            sequence, added = continue_from_other_view(
                own.visible,
                prepared.clean.mask,
                guide.points,
                sign,
                (d_min, d_max),
                max_gap=params.stereo_fill_max_gap_px * prepared.scaled.scale,
                guide_not_seen=guide.bridged,
            )
        sequences.append(sequence)
        filled.append(added)
    # Where one view went round its loop and the other cut across, put the loop back.
    if params.stereo_fill_max_gap_px > 0:
        for index, (_, prepared, _, sign) in enumerate(views):
            other = sequences[1 - index]
            sequences[index], spliced = splice_skipped_stretch(
                sequences[index], prepared.clean.mask, other, sign, (d_min, d_max)
            )
            filled[index] += spliced
    cut = [0, 0]
    for index, (_, prepared, _, _) in enumerate(views):
        switch = strand_switch_index(
            prepared.clean.mask,
            sequences[index],
            prepared.scaled.roi_radius,
            params.strand_switch_turn,
            HOOK_WINDOW * prepared.scaled.roi_radius,
            prepared.scaled.scale,
        )
        if switch is not None:
            cut[index] = len(sequences[index]) - switch - 1
            sequences[index] = sequences[index][: switch + 1]
    return StereoOrdering(
        left=sequences[0],
        right=sequences[1],
        left_result=left,
        right_result=right,
        left_sequence=flagged_sequence(sequences[0], left.points, left.bridged, left_prepared.clean.mask),
        right_sequence=flagged_sequence(sequences[1], right.points, right.bridged, right_prepared.clean.mask),
        filled=(filled[0], filled[1]),
        cut=(cut[0], cut[1]),
    )
