# SPDX-License-Identifier: Apache-2.0
"""One fork of the ordering search: the path it has traversed, the thread's width and the
direction its curvature predicts, and how a step extends it.

Turning angle δ.
    Eq. (4) measures δ from the last chord ``V^t - V^{t-1}``; on a curved thread
    that makes every step look like a turn, and a crossing strand can look
    straighter than the thread's own curling continuation. δ is therefore
    measured from the direction the thread's curvature predicts: the last chord
    turned by the last turn (the angle between the two previous chords), i.e. the
    next chord of the circle through the last three vertices; for a straight
    thread this is the paper's δ (``curvature_prediction=False`` gives Eq. 4 as
    written). Steps through merged cross-sections (a crossing) do not update the
    prediction for up to Υ; longer merged stretches (threads side by side) do.
    δ = 0 for the first step (t = 1), which has no previous vertex.

Detected nodes.
    Each branch draws its path, ``thickness`` px wide, into its own ``consumed`` raster
    (the padded mask's shape): nodes on it are *detected*, i.e. within ``detect_radius``
    of the path traversed so far.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import cv2
import numpy as np

from suture_ordering.compiled import chord_points
from suture_ordering.context import SearchContext
from suture_ordering.geometry import LINE_SHIFT, fixed_point, hermite, rotate, signed_angle


@dataclass
class Branch:
    """One fork of the search: the parameter sets (rows of the grid) that agreed so far."""

    rows: np.ndarray
    consumed: np.ndarray
    vertices: list[np.ndarray]
    segments: list[np.ndarray] = field(default_factory=list)
    segment_bridged: list[bool] = field(default_factory=list)
    widths: list[float] = field(default_factory=list)
    track: np.ndarray | None = None
    turn: float = 0.0
    clean_steps: int = 0
    merged_steps: int = 0
    steps: int = 0
    bridges: int = 0
    status: str = ""

    def fork(self, rows: np.ndarray) -> Branch:
        return Branch(
            rows=rows,
            consumed=self.consumed.copy(),
            vertices=list(self.vertices),
            segments=list(self.segments),
            segment_bridged=list(self.segment_bridged),
            widths=list(self.widths),
            track=None if self.track is None else self.track.copy(),
            turn=self.turn,
            clean_steps=self.clean_steps,
            merged_steps=self.merged_steps,
            steps=self.steps,
            bridges=self.bridges,
        )

    @property
    def length(self) -> int:
        return 1 + sum(len(s) for s in self.segments)


@functools.lru_cache(maxsize=256)
def chord_steps(n: int) -> np.ndarray:
    """(n, 1) fractions 1/n .. n/n: the points of a chord n px long, 1 px apart, after its start."""
    return (np.arange(1, n + 1) / n)[:, None]


def thread_width(branch: Branch) -> float | None:
    """The median of the last nine clean cross-sections' widths (px); None before the first."""
    if not branch.widths:
        return None
    recent = sorted(branch.widths[-9:])
    return recent[len(recent) // 2]


def predicted_heading(branch: Branch) -> np.ndarray | None:
    """Direction δ is measured from: the thread's track turned by its last turn."""
    if branch.track is None or branch.turn == 0.0:
        return branch.track
    return rotate(branch.track, branch.turn)


def tangent_at_vertex(branch: Branch) -> np.ndarray | None:
    """The thread's tangent at the current vertex: the track turned by half the last turn."""
    if branch.track is None or branch.turn == 0.0:
        return branch.track
    return rotate(branch.track, branch.turn / 2)


def entry_point(branch: Branch, radius: float) -> np.ndarray | None:
    """Where the path traversed so far last enters the circle of ``radius`` around the vertex."""
    vertex = branch.vertices[-1]
    for segment in reversed(branch.segments):
        outside = np.flatnonzero(np.hypot(*(segment - vertex).T) >= radius)
        if outside.size:
            return segment[outside[-1]]
    return None


def advance(
    context: SearchContext,
    branch: Branch,
    target: np.ndarray,
    width: float,
    continuation: np.ndarray | None = None,
    bridge: bool = False,
) -> None:
    """Append the step V^t -> target to ``branch``: a chord, or a cubic Hermite curve ending
    along ``continuation`` (across a gap when ``bridge``, else across a junction)."""
    pad = context.reader.pad
    start = branch.vertices[-1]
    if continuation is None:
        chord, length, segment = chord_points(
            float(start[0]), float(start[1]), float(target[0]), float(target[1])
        )
        cv2.line(
            branch.consumed,
            fixed_point((float(start[0]) + pad, float(start[1]) + pad)),
            fixed_point((float(target[0]) + pad, float(target[1]) + pad)),
            1,
            context.thickness,
            cv2.LINE_8,
            LINE_SHIFT,
        )
    else:
        chord = target - start
        length = float(np.hypot(chord[0], chord[1]))
        before = tangent_at_vertex(branch)
        before = chord if before is None else before
        segment = hermite(start, target, before / np.linalg.norm(before) * length, continuation * length)
        pts = np.rint((np.vstack((start, segment)) + pad) * (1 << LINE_SHIFT)).astype(np.int32)
        cv2.polylines(branch.consumed, [pts], False, 1, context.thickness, cv2.LINE_8, LINE_SHIFT)
        if bridge:
            branch.bridges += 1
    _record(context, branch, target, segment, chord, length, width, continuation, bridge)


def advance_along(context: SearchContext, branch: Branch, targets: np.ndarray, width: float) -> None:
    """:func:`advance` to each of ``targets`` ((m, 2) float64 (u, v)) in turn along chords, all
    ``width`` px wide: the same steps, with the chords' points computed and the path drawn
    (one polyline paints the pixels its segments' lines paint) for all of them at once."""
    if not len(targets):
        return
    pad = context.reader.pad
    starts = np.vstack((branch.vertices[-1], targets[:-1]))
    chords = targets - starts
    counts = np.maximum(1, np.ceil(np.hypot(chords[:, 0], chords[:, 1]))).astype(int)
    segments: list[np.ndarray] = [np.empty(0)] * len(targets)
    for n in np.unique(counts).tolist():
        chosen = np.flatnonzero(counts == n)
        points = starts[chosen][:, None, :] + chord_steps(n)[None, :, :] * chords[chosen][:, None, :]
        for k, segment in zip(chosen.tolist(), points, strict=True):
            segments[k] = segment
    path = np.rint((np.vstack((starts[:1], targets)) + pad) * (1 << LINE_SHIFT)).astype(np.int32)
    cv2.polylines(branch.consumed, [path], False, 1, context.thickness, cv2.LINE_8, LINE_SHIFT)
    for target, segment, chord in zip(targets, segments, chords, strict=True):
        _record(context, branch, target, segment, chord, 0.0, width, None, False)


def _record(
    context: SearchContext,
    branch: Branch,
    target: np.ndarray,
    segment: np.ndarray,
    chord: np.ndarray,
    length: float,
    width: float,
    continuation: np.ndarray | None,
    bridge: bool,
) -> None:
    """The bookkeeping of a step of :func:`advance` (drawn already): the segment and vertex, the
    thread's width, track and turn, and the step counts. ``length``: the chord's length (px),
    needed only with a ``continuation``."""
    params, scaled = context.params, context.scaled
    branch.segments.append(segment)
    branch.segment_bridged.append(bridge)
    branch.vertices.append(target)
    expected = thread_width(branch)
    clean = continuation is None and (expected is None or width <= params.wide_arc_factor * expected)
    if clean:
        branch.widths.append(width)
    if continuation is not None:  # after a gap or junction: go on along the thread's tangent there
        branch.track, branch.turn, branch.clean_steps = continuation * length, 0.0, 0
    elif not clean:  # a merged cross-section (a crossing, touching threads)
        branch.merged_steps += 1
        if branch.merged_steps * scaled.step_radius <= scaled.roi_radius or branch.track is None:
            # keep the track through a junction (up to Υ) ...
            branch.track = chord if branch.track is None else rotate(branch.track, branch.turn)
        else:  # ... but follow a longer merged stretch (two threads side by side)
            branch.track, branch.turn = chord, 0.0
        branch.clean_steps = 0
    else:
        if branch.track is not None and branch.clean_steps > 0 and params.curvature_prediction:
            branch.turn = signed_angle(branch.track, chord)
        branch.track = chord
        branch.clean_steps += 1
        branch.merged_steps = 0
    branch.steps += 1
