# SPDX-License-Identifier: Apache-2.0
"""The thread's ends in the images, as the witness of a depth that rests on them alone.

Rectified stereo measures a thread's depth only where it crosses the image rows. A thread that
nowhere crosses them steeply (no stretch of :data:`ANCHOR_ARC_M` at :data:`ANCHOR_ROW_DEG` or
more) gets its depth from where its two ends lie in each view: the disparity of the cut tip and of
the far end, carried between them under the shape prior. Predicted masks disturb both: an end cut
short in one view by a few pixels, and the two views' masks a fraction of a pixel apart in rows,
which along a thread at angle a to the rows changes every pair's disparity by that offset / tan(a)
(0.3 px at 3 degrees: 6 px) while the views still agree. With an endoscope's 5 mm baseline each
pixel of disparity is 3-9 mm of depth, which tilts the thread and moves the grasp point, placed by
arc length from the tip, along it.

An end of a thread is a feature in both directions, so the images measure its disparity where the
masks do not: :func:`end_disparity_gaps_px` matches a window around each end of the left sequence
(centred on its first and last :data:`END_SAMPLES` seen samples, :data:`END_RADIUS_PX` along the
thread so that it holds the termination, and away from the image border, where a view's sequence
stops because the image does) along the same row of the right image, within
:data:`END_SEARCH_PX` of the reconstruction's disparity
(:func:`~suture_reconstruction.photometric.match_along_rows`), and returns the median difference
at each end. A window along the thread alone would not do: shifted along a thread parallel to
the rows, it matches itself. :func:`refuse_contradicted_ends` raises
:class:`~suture_reconstruction.errors.EndDisparityError` when the thread has no steep stretch
and the images put an end more than ``max_end_disparity_gap_px`` from where the reconstruction has
it. The steepest stretch is read on the 3D curve (:func:`anchor_row_angle_deg`) and on the left
sequence (:func:`sequence_anchor_deg`, the refinement's reading), and the smaller counts: the curve
smooths the sequence, so near :data:`ANCHOR_ROW_DEG` the two can fall either side of it, and a
thread the refinement took for nowhere steep must not escape the check. A thread that crosses
the rows somewhere is not checked: its depth is measured there, and the end matches, which are
weak on a faint thread on blurred tissue, would only add false refusals.

Such a thread can still run along the rows for most of its length from an end, so that the end's
depth rests on that end's pair, carried over tens of millimetres to the nearest steep stretch: a
mask cut 3 px short at the tip in one view is 3 px of disparity there, and the grasp point 50 mm
along moves with it. :func:`match_unanchored_ends` matches the same window round each end whose
nearest steep stretch lies at least :data:`END_LEVER_M` of arc away, and the refinement
(:func:`~suture_reconstruction.photometric.refine_disparity`) fuses those matches in place of the
end's pair, with the weight of its most confident match: there the images, not the masks, say
where the end is. That holds for an end where the thread stops, not for one where an instrument
lies over it: the window then holds the instrument's edge, at the instrument's depth, and matches
that (a shaft a few millimetres above the thread is several px of disparity nearer, and the fused
end follows it by as much). Past an end where the thread stops lies the tissue it rests on, at
about its depth; past one under an instrument lies the instrument, nearer the camera.
:func:`at_occluder` matches a window just past the end
(:func:`~suture_reconstruction.surface.window_disparity`); where it holds a clear structure
(:data:`MIN_STRUCTURE`) that the right view puts more than :data:`NEARER_PX` nearer than the
thread's end, the end is not matched, as an end at the image border is not. The check of a
thread with no steep stretch (:func:`end_disparity_gaps_px`) still reads such an end: the gap it
finds there is the instrument's, and a refusal is the safe side.

A thread with no steep stretch at all has its depth from its two ends' pairs, and a mask a pixel
wider on one side or cut short in one view moves them, and the whole thread's depth with them,
while the views still agree. :func:`match_unanchored_ends` matches its ends too, and the
refinement fuses an end's matches where the images put it :data:`UNANCHORED_MIN_GAP_PX` to
``max_end_disparity_gap_px`` from the pairs (nearer, the two agree within the match's own noise and
the pairs are kept; farther, the check above refuses the thread) and where the thread stands out
from the tissue round the end (:func:`end_contrast` at least :data:`MIN_END_CONTRAST`): a thread
of the tissue's colour leaves the window only the tissue's texture to match, which a shift along
the rows matches about as well.

Units: metres for 3D points, pixels in the images, degrees for angles.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import minimum_filter1d
from scipy.spatial import cKDTree

from suture_common.camera import StereoCamera
from suture_reconstruction.curve import ArcLengthCurve
from suture_reconstruction.errors import EndDisparityError, GraspNotSeenError
from suture_reconstruction.pairing import Disparity
from suture_reconstruction.photometric import PhotometricParams, match_along_rows, prepare_images
from suture_reconstruction.sequences import Resampled
from suture_reconstruction.surface import PATCH_HALF_PX, window_disparity
from suture_reconstruction.uncertainty import SAMPLE_STEP_M, row_sines

#: A stretch of thread at least this steep (deg to the image rows) over ANCHOR_ARC_M measures depth.
ANCHOR_ROW_DEG = 10.0
#: Arc (m) a stretch must hold ANCHOR_ROW_DEG over to anchor the thread's depth.
ANCHOR_ARC_M = 0.005
#: Outermost seen samples (1 px apart) of the left sequence matched at each end.
END_SAMPLES = 5
#: Half-length (px, along the thread) of each end's window: it reaches past the end, so that the
#: termination, which fixes the shift along a thread parallel to the rows, lies inside it.
END_RADIUS_PX = 10
#: Half-width (px, across the thread) of each end's window.
END_HALF_WIDTH_PX = 5.0
#: Disparities (px) searched either side of the reconstruction's at the ends.
END_SEARCH_PX = 10
#: Fewest matched samples for an end to count as evidence.
MIN_END_MATCHES = 3
#: Ends closer than this (px) to the image border are where the image, not the thread, stops.
BORDER_PX = 12.0
#: An end whose nearest stretch steeper than ANCHOR_ROW_DEG lies at least this far (m of arc)
#: along the thread rests its depth on the end's pair, and is matched in the images.
END_LEVER_M = 0.012
#: Something past an end nearer the camera than the thread's end by more than this (px of
#: disparity: 5 mm at 95 mm) lies over the thread: the thread runs on under it.
NEARER_PX = 1.5
#: A window past an end is matched only where its grey levels vary by at least this much
#: (standard deviation, 8-bit scale): an instrument's edge and shading do, and a faint texture's
#: match along the rows is ambiguous.
MIN_STRUCTURE = 8.0
#: The window past an end starts this far (px) beyond it.
BEYOND_GAP_PX = 2.0
#: Samples (1 px apart) before an end that give the way the thread leaves it.
END_DIRECTION_SAMPLES = 12
#: On a thread with no steep stretch, an end's match is fused only where it lies at least this far
#: (px of disparity) from the masks' pairs: nearer, both agree within the match's own noise.
UNANCHORED_MIN_GAP_PX = 1.0
#: ... and only where the thread differs from the tissue beside it by at least this many times the
#: tissue's own variation there (:func:`end_contrast`): the thread, not the texture, is then what
#: the window matches.
MIN_END_CONTRAST = 1.0
#: Pixels within this distance (px) of the sequence are the thread's in :func:`end_contrast`, ...
END_CORE_PX = 1.0
#: ... and those from END_CORE_PX + 2 px out to this distance the tissue's beside it.
END_TISSUE_PX = 7.0
#: The matching of an end's window: it holds the termination, searched about the given disparity.
END_WINDOW = PhotometricParams(
    search_px=END_SEARCH_PX, radius_px=END_RADIUS_PX, half_width_px=END_HALF_WIDTH_PX
)


def anchor_row_angle_deg(curve: ArcLengthCurve, camera: StereoCamera) -> float:
    """The largest angle (deg) to the image rows that the thread's left image holds over
    :data:`ANCHOR_ARC_M` of arc anywhere along it (0.0 for a thread shorter than that)."""
    s = np.arange(0.0, curve.length + 1e-12, SAMPLE_STEP_M)
    window = max(round(ANCHOR_ARC_M / SAMPLE_STEP_M), 1)
    if s.size < window:
        return 0.0
    held = _held_row_sines(camera.project(curve.at(s), "left"), window)
    return float(np.degrees(np.arcsin(min(float(held.max()), 1.0))))


def sequence_anchor_deg(left: Resampled, disparity: Disparity, camera: StereoCamera) -> float:
    """The largest angle (deg) to the image rows that the left sequence holds over
    :data:`ANCHOR_ARC_M` of arc at its observed samples (arc read in pixels at the thread's median
    disparity), as :func:`match_unanchored_ends` reads it; 0.0 with fewer than two supported samples.

    ``left``: the left sequence resampled every 1 px with its ``observed`` flags; ``disparity``: the
    fused disparity along it. The 3D curve smooths the sequence, so near :data:`ANCHOR_ROW_DEG` the
    two readings (this and :func:`anchor_row_angle_deg`) can fall either side of it.
    """
    if np.count_nonzero(left.observed & disparity.supported) < 2:
        return 0.0
    held, _ = _sequence_steepness(left, disparity, camera)
    return float(np.degrees(np.arcsin(min(float(held[left.observed].max()), 1.0))))


def _sequence_steepness(
    left: Resampled, disparity: Disparity, camera: StereoCamera
) -> tuple[np.ndarray, float]:
    """(K,) :func:`_held_row_sines` of the left sequence over :data:`ANCHOR_ARC_M`, and the pixels
    per metre of arc at the thread's median disparity (over its observed, supported samples)."""
    supported = left.observed & disparity.supported
    px_per_m = float(np.median(disparity.value[supported])) / camera.baseline
    window = max(round(ANCHOR_ARC_M * px_per_m), 1)
    return _held_row_sines(left.points[:, :2], window), px_per_m


def _held_row_sines(uv: np.ndarray, window: int) -> np.ndarray:
    """(K,) the smallest sine of the angle to the image rows of the polyline ``uv`` (K, 2) px over
    the ``window`` points round each point: the steepness a stretch holds there. A point nearer an
    end than half the window holds none (0): past the end there is no thread, and a curl of the
    last few points would otherwise pass for a steep stretch over half the window."""
    return minimum_filter1d(row_sines(uv), window, mode="constant", cval=0.0)


def match_unanchored_ends(
    prepared: tuple[np.ndarray, np.ndarray],
    left: Resampled,
    disparity: Disparity,
    camera: StereoCamera,
    images: tuple[np.ndarray, np.ndarray],
    max_gap_px: float,
) -> tuple[np.ndarray, np.ndarray] | None:
    """The images' disparity at each end of a thread whose depth there rests on the end's pair.

    ``prepared``: the rectified (left, right) views as
    :func:`~suture_reconstruction.photometric.prepare_images` blurs them (the refinement's own);
    ``left``: the left sequence resampled every 1 px with its ``observed`` flags; ``disparity``:
    the fused disparity along it; ``images``: the rectified views, unblurred. An end qualifies
    when the thread crosses the image rows at :data:`ANCHOR_ROW_DEG` or more over
    :data:`ANCHOR_ARC_M` somewhere, but not within :data:`END_LEVER_M` of arc from that end (arc
    read in pixels at the thread's median disparity), or nowhere at all; it lies away from the
    image border, and it does not run under something nearer the camera (:func:`at_occluder`).
    Its :data:`END_SAMPLES` outermost supported samples are matched along the rows with the window
    that holds the termination (:func:`end_disparity_gaps_px`' window), within
    :data:`END_SEARCH_PX` of ``disparity``. On a thread with no steep stretch an end's matches
    count only where their median lies :data:`UNANCHORED_MIN_GAP_PX` to ``max_gap_px``
    (``ReconstructionParams.max_end_disparity_gap_px``) from ``disparity`` and the thread stands
    out there (:func:`end_contrast` at least :data:`MIN_END_CONTRAST`).
    Returns (rows (E,) int, disparities (E,) px) of the matched samples, or None where no end
    qualifies or none matched :data:`MIN_END_MATCHES` samples.
    """
    points = left.points[:, :2]
    supported = np.flatnonzero(left.observed & disparity.supported)
    if supported.size < 2:
        return None
    held, px_per_m = _sequence_steepness(left, disparity, camera)
    anchored = np.flatnonzero((held >= np.sin(np.radians(ANCHOR_ROW_DEG))) & left.observed)
    nowhere_steep = anchored.size == 0
    lever = END_LEVER_M * px_per_m
    unanchored = []
    if nowhere_steep or anchored[0] - supported[0] >= lever:
        unanchored.append((supported[:END_SAMPLES], supported[0], 1))
    if nowhere_steep or supported[-1] - anchored[-1] >= lever:
        unanchored.append((supported[-END_SAMPLES:], supported[-1], -1))
    windows = [
        index
        for index, outermost, inward in unanchored
        if not _at_border(points[outermost], camera)
        and not at_occluder(images, points, outermost, inward, float(disparity.value[outermost]))
    ]
    tangents = np.gradient(points, axis=0)
    rows, values = [], []
    for index in windows:
        matches = match_along_rows(
            *prepared, points[index], tangents[index], disparity.value[index], END_WINDOW
        )
        if matches.matched.sum() < MIN_END_MATCHES:
            continue
        found = matches.disparity[matches.matched]
        if nowhere_steep:
            gap = abs(float(np.median(found - disparity.value[index][matches.matched])))
            if not UNANCHORED_MIN_GAP_PX <= gap <= max_gap_px:
                continue
            if end_contrast(images[0], points[left.observed], points[index]) < MIN_END_CONTRAST:
                continue
        rows.append(index[matches.matched])
        values.append(found)
    if not rows:
        return None
    return np.concatenate(rows), np.concatenate(values)


def end_contrast(image: np.ndarray, sequence: np.ndarray, end: np.ndarray) -> float:
    """How far the thread stands out from the tissue beside it round an end, in units of the
    tissue's own variation.

    ``image``: the left view (H, W) or (H, W, C), grey levels; ``sequence`` (K, 2) px: the seen
    samples of the left sequence; ``end`` (E, 2) px: the end's outermost samples. Within
    :data:`END_RADIUS_PX` of the end's centre, the pixels within :data:`END_CORE_PX` of the
    sequence are the thread's, those from ``END_CORE_PX + 2`` to :data:`END_TISSUE_PX` the
    tissue's (beside the thread and past its end). Returns the difference of their median grey
    levels (the mean over channels) over the tissue's robust standard deviation (1.4826 median
    absolute deviation) plus one grey level; 0.0 where either holds fewer than
    :data:`MIN_END_MATCHES` pixels.
    """
    centre = np.rint(end.mean(axis=0)).astype(np.int64)
    low = np.maximum(centre - END_RADIUS_PX, 0)
    high = np.minimum(centre + END_RADIUS_PX + 1, [image.shape[1], image.shape[0]])
    window = image[low[1] : high[1], low[0] : high[0]].astype(np.float64)
    levels = (window.mean(axis=2) if window.ndim == 3 else window).ravel()
    rows, cols = np.mgrid[low[1] : high[1], low[0] : high[0]]
    near = sequence[np.linalg.norm(sequence - centre, axis=1) <= END_RADIUS_PX + END_TISSUE_PX]
    if near.size == 0:
        return 0.0
    distance = cKDTree(near).query(np.column_stack([cols.ravel(), rows.ravel()]))[0]
    thread = levels[distance <= END_CORE_PX]
    tissue = levels[(distance >= END_CORE_PX + 2.0) & (distance <= END_TISSUE_PX)]
    if thread.size < MIN_END_MATCHES or tissue.size < MIN_END_MATCHES:
        return 0.0
    spread = 1.4826 * float(np.median(np.abs(tissue - np.median(tissue))))
    return abs(float(np.median(thread) - np.median(tissue))) / (spread + 1.0)


def end_disparity_gaps_px(
    images: tuple[np.ndarray, np.ndarray],
    left: Resampled,
    curve: ArcLengthCurve,
    camera: StereoCamera,
) -> tuple[float | None, float | None]:
    """The images' disparity less the reconstruction's (px) at the cut tip and at the far end.

    ``images``: the rectified (left, right) views; ``left``: the left sequence smoothed and
    resampled every 1 px with its ``observed`` flags; ``curve``: the reconstructed thread. Each
    value is the median over the end's matched samples; None where the end lies within
    :data:`BORDER_PX` of the image border or fewer than :data:`MIN_END_MATCHES` samples matched.
    """
    prepared = prepare_images(*images)
    points = left.points[:, :2]
    seen = np.flatnonzero(left.observed)
    path = curve.resample(SAMPLE_STEP_M)
    path_uv = camera.project(path, "left")
    tangents = np.gradient(points, axis=0)
    gaps: list[float | None] = []
    for index, outermost in ((seen[:END_SAMPLES], 0), (seen[-END_SAMPLES:], -1)):
        if index.size == 0 or _at_border(points[index[outermost]], camera):
            gaps.append(None)
            continue
        nearest = np.argmin(np.linalg.norm(path_uv[None] - points[index][:, None], axis=2), axis=1)
        reconstructed = camera.disparity(path[nearest, 2])
        matches = match_along_rows(*prepared, points[index], tangents[index], reconstructed, END_WINDOW)
        if matches.matched.sum() < MIN_END_MATCHES:
            gaps.append(None)
            continue
        gaps.append(float(np.median(matches.disparity[matches.matched] - reconstructed[matches.matched])))
    return gaps[0], gaps[1]


def at_occluder(
    images: tuple[np.ndarray, np.ndarray], points: np.ndarray, end: int, inward: int, end_disparity: float
) -> bool:
    """Whether the thread's end at sample ``end`` of the left sequence ``points`` ((K, 2) px,
    resampled every 1 px; ``inward``: 1 where the thread lies at higher indices, as at the cut tip,
    -1 at the far end) runs under something nearer the camera: whether the window just past the
    end (:data:`BEYOND_GAP_PX` beyond it, along the way the thread leaves it) holds a structure
    (:data:`MIN_STRUCTURE`) that ``images`` (the rectified left and right views) put more than
    :data:`NEARER_PX` of disparity nearer than ``end_disparity``, the thread's at the end."""
    last = points[np.clip(end + inward * np.arange(END_DIRECTION_SAMPLES), 0, len(points) - 1)]
    outward = last[0] - last[-1]
    length = float(np.linalg.norm(outward))
    if length == 0.0:
        return False
    centre = last[0] + (PATCH_HALF_PX + BEYOND_GAP_PX) * outward / length
    beyond = window_disparity(images, centre, end_disparity, min_texture=MIN_STRUCTURE)
    return beyond is not None and beyond - end_disparity > NEARER_PX


def refuse_grasp_under_occluder(
    images: tuple[np.ndarray, np.ndarray],
    left: Resampled,
    disparity: Disparity,
    camera: StereoCamera,
    length_m: float,
    grasp_arc_length_m: float,
) -> None:
    """Raise :class:`~suture_reconstruction.errors.GraspNotSeenError` when the thread, reconstructed
    ``length_m`` long (shorter than ``grasp_arc_length_m``), ends where it runs under something
    nearer the camera: the far end of ``left`` (the left sequence resampled every 1 px, its last
    sample that ``disparity`` supports) lies away from the image border and :func:`at_occluder`
    holds there. ``images``: the rectified (left, right) views."""
    supported = np.flatnonzero(left.observed & disparity.supported)
    if supported.size < 2:
        return
    points = left.points[:, :2]
    end = supported[-1]
    if _at_border(points[end], camera):
        return
    if at_occluder(images, points, end, -1, float(disparity.value[end])):
        raise GraspNotSeenError(
            "the thread runs under something nearer the camera (an instrument) "
            f"{length_m * 1000:.1f} mm from the cut tip, short of the grasp point "
            f"{grasp_arc_length_m * 1000:.1f} mm along it, which lies on thread the views do not "
            "see there (hidden, or beyond the instrument where the ordering did not bridge it); "
            "move the occluder or the camera, or lower grasp_arc_length",
            None,
        )


def _at_border(uv: np.ndarray, camera: StereoCamera) -> bool:
    """Whether the left pixel ``uv`` (2,) lies within :data:`BORDER_PX` of the image border."""
    u, v = float(uv[0]), float(uv[1])
    return min(u, v, camera.width - 1 - u, camera.height - 1 - v) < BORDER_PX


def refuse_contradicted_ends(
    gaps_px: tuple[float | None, float | None], anchor_deg: float, max_gap_px: float
) -> None:
    """Raise EndDisparityError when the thread has no stretch steeper than :data:`ANCHOR_ROW_DEG`
    (``anchor_deg``: the smaller of :func:`anchor_row_angle_deg` and :func:`sequence_anchor_deg`)
    and an end's gap (``gaps_px``, tip and far end, from :func:`end_disparity_gaps_px`; None: no
    evidence) exceeds ``max_gap_px``."""
    if anchor_deg >= ANCHOR_ROW_DEG:
        return
    for end, gap in zip(("cut tip", "far end"), gaps_px, strict=True):
        if gap is not None and abs(gap) > max_gap_px:
            raise EndDisparityError(
                f"no stretch of the thread crosses the image rows at {ANCHOR_ROW_DEG:g} deg or more "
                f"(the steepest: {anchor_deg:.1f} deg), so its depth rests on where its ends lie in the "
                f"two views, and the images put its {end} {gap:+.1f} px of disparity from where the "
                f"masks' sequences do (more than max_end_disparity_gap_px {max_gap_px:g}): the views' "
                "masks disagree at the ends or sit apart in rows, which tilts the thread's depth and "
                "moves the grasp point along it; turn the camera or the thread so that part of it "
                "crosses the image rows, or check both views' masks"
            )
