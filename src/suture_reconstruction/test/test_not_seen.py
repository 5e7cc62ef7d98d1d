# SPDX-License-Identifier: Apache-2.0
"""The 3D stage across a stretch not seen in the views (suture_reconstruction.not_seen): the
sequences' third column is the not-seen flag; the flagged pixels are not matched, their depth
comes from the seen thread on either side, and the path points there are flagged."""

from __future__ import annotations

import numpy as np
import pytest

from suture_common.camera import StereoCamera
from suture_reconstruction import reconstruct
from suture_reconstruction.errors import InvalidSequenceError

CAMERA = StereoCamera.default(640, 480)
#: The hidden stretch, in m of arc from the cut tip (an instrument shaft across the thread).
HIDDEN = (0.025, 0.045)


def _thread() -> tuple[np.ndarray, np.ndarray]:
    """A curved thread ~90 mm long, 100-120 mm from the camera, and the arc length of its samples."""
    s = np.linspace(0.0, 1.0, 4000)
    thread = np.column_stack(
        [0.075 * s - 0.04, 0.012 * np.sin(3.0 * s) - 0.01, 0.1 + 0.012 * s + 0.006 * np.sin(4.0 * s)]
    )
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(thread, axis=0), axis=1))])
    return thread, arc


def _hermite(start: np.ndarray, end: np.ndarray, t0: np.ndarray, t1: np.ndarray, n: int) -> np.ndarray:
    t = np.linspace(0.0, 1.0, n)[1:-1, None]
    return (
        (2 * t**3 - 3 * t**2 + 1) * start
        + (t**3 - 2 * t**2 + t) * t0
        + (-2 * t**3 + 3 * t**2) * end
        + (t**3 - t**2) * t1
    )


def _flagged_view(thread: np.ndarray, arc: np.ndarray, view: str) -> np.ndarray:
    """(N, 3) sequence of ``view``: the projection ~1 px apart, the hidden stretch replaced by a
    Hermite curve between its seen ends along the thread's image direction there (as the ordering
    stage bridges it), flagged 1.0."""
    pixels = CAMERA.project(thread, view)
    step = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pixels, axis=0).T))])
    keep = np.searchsorted(step, np.arange(0.0, step[-1], 1.0))
    pixels, arc = pixels[keep], arc[keep]
    first, last = np.searchsorted(arc, HIDDEN[0]), np.searchsorted(arc, HIDDEN[1])
    a, b = pixels[first - 1], pixels[last]
    chord = float(np.hypot(*(b - a)))
    t0 = pixels[first - 1] - pixels[first - 6]
    t1 = pixels[last + 5] - pixels[last]
    bridge = _hermite(a, b, t0 / np.hypot(*t0) * chord, t1 / np.hypot(*t1) * chord, last - first + 2)
    seen = lambda p: np.column_stack([p, np.zeros(len(p))])  # noqa: E731
    return np.vstack(
        [seen(pixels[:first]), np.column_stack([bridge, np.ones(len(bridge))]), seen(pixels[last:])]
    )


def test_the_grasp_beyond_a_stretch_not_seen_lands_within_a_few_mm_of_truth():
    thread, arc = _thread()
    left, right = _flagged_view(thread, arc, "left"), _flagged_view(thread, arc, "right")
    result = reconstruct(left, right, CAMERA)
    true_grasp = thread[np.searchsorted(arc, 0.05)]
    assert np.linalg.norm(result.grasp_position - true_grasp) < 0.002
    assert abs(result.length - arc[-1]) < 0.002
    # The path points on the hidden stretch, and only those, are flagged not seen.
    path_arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(result.path, axis=0), axis=1))])
    assert result.path_not_seen.shape == (len(result.path),)
    inside = (path_arc > HIDDEN[0] + 0.002) & (path_arc < HIDDEN[1] - 0.002)
    outside = (path_arc < HIDDEN[0] - 0.002) | (path_arc > HIDDEN[1] + 0.002)
    assert result.path_not_seen[inside].all()
    assert not result.path_not_seen[outside].any()
    # The 3D path across the stretch follows the thread (its depth from both sides).
    hidden = (arc > HIDDEN[0]) & (arc < HIDDEN[1])
    distance = np.linalg.norm(result.path[inside][:, None, :] - thread[hidden][None, :, :], axis=2).min(
        axis=1
    )
    assert distance.max() < 0.002
    # Flagged pixels are never matched: only seen left samples have dense vertices.
    seen_u = left[left[:, 2] == 0, 0]
    assert result.left_uv[:, 0].min() >= seen_u.min() - 1 and len(result.points) < (left[:, 2] == 0).sum() + 5


def test_a_zero_flag_column_means_all_seen():
    thread, _arc = _thread()
    left, right = CAMERA.project(thread, "left"), CAMERA.project(thread, "right")
    plain = reconstruct(left, right, CAMERA)
    zeros = reconstruct(np.column_stack([left, np.zeros(len(left))]), right, CAMERA)
    np.testing.assert_allclose(zeros.grasp_position, plain.grasp_position)
    assert not zeros.path_not_seen.any() and len(zeros.path_not_seen) == len(zeros.path)


def test_a_nan_flag_is_refused_with_a_clear_message():
    thread, arc = _thread()
    left = _flagged_view(thread, arc, "left")
    left[5, 2] = np.nan
    with pytest.raises(InvalidSequenceError, match="not-seen flag"):
        reconstruct(left, _flagged_view(thread, arc, "right"), CAMERA)


def test_a_cut_end_not_seen_counts_in_the_arc_to_the_grasp():
    # The first 8 mm of arc from the tip lost by the segmenter: the ordering bridges it straight
    # from the tip hint and flags it. Its depth is the first seen vertex's, its arc counts.
    thread, arc = _thread()
    views = []
    for view in ("left", "right"):
        pixels = CAMERA.project(thread, view)
        step = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pixels, axis=0).T))])
        keep = np.searchsorted(step, np.arange(0.0, step[-1], 1.0))
        pixels, kept_arc = pixels[keep], arc[keep]
        seen_from = int(np.searchsorted(kept_arc, 0.008))
        count = int(np.ceil(np.hypot(*(pixels[seen_from] - pixels[0]))))
        chord = pixels[0] + (pixels[seen_from] - pixels[0]) * (np.arange(count) / count)[:, None]
        views.append(
            np.vstack(
                [
                    np.column_stack([chord, np.ones(count)]),
                    np.column_stack([pixels[seen_from:], np.zeros(len(pixels) - seen_from)]),
                ]
            )
        )
    result = reconstruct(views[0], views[1], CAMERA)
    true_grasp = thread[np.searchsorted(arc, 0.05)]
    assert np.linalg.norm(result.grasp_position - true_grasp) < 0.002
    assert np.linalg.norm(result.path[0] - thread[0]) < 0.004  # at the first seen depth: 3 mm nearer
    path_arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(result.path, axis=0), axis=1))])
    assert result.path_not_seen[path_arc < 0.006].all()
    assert not result.path_not_seen[path_arc > 0.010].any()
    assert result.uncertainty.not_seen_arc_mm > 6.0
