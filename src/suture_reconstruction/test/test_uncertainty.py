# SPDX-License-Identifier: Apache-2.0
"""The grasp point's uncertainty and the refusals it grounds (suture_reconstruction.uncertainty)."""

from __future__ import annotations

import numpy as np
import pytest

from suture_common.camera import StereoCamera
from suture_reconstruction import (
    ArcAlongViewError,
    GraspNotSeenError,
    ReconstructionParams,
    TipNotReconstructedError,
    UncertainGraspError,
    UnexplainedArcError,
    reconstruct,
)


def arc_of_points(sequence: np.ndarray, camera, curve: np.ndarray, view: str) -> np.ndarray:
    """(N,) 3D arc length (m) from the tip of the curve sample each sequence point shows."""
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(curve, axis=0), axis=1))])
    uv = camera.project(curve, view)
    nearest = np.argmin(np.linalg.norm(sequence[:, None, :2] - uv[None, ::4], axis=2), axis=1) * 4
    return arc[nearest]


def thread_at(heading_deg: float, depth_slope: float = 0.1) -> np.ndarray:
    """A gently bent 90 mm thread ``heading_deg`` off the image rows, its depth 95 mm at its middle
    and changing by ``depth_slope`` m per m along x (m, every 0.05 mm)."""
    s = np.arange(0.0, 0.09, 5e-5)
    heading = np.radians(heading_deg) + 0.05 * np.sin(2 * np.pi * s / 0.09)
    xy = np.cumsum(np.column_stack([np.cos(heading), np.sin(heading)]) * 5e-5, axis=0)
    xy -= xy.mean(axis=0)
    return np.column_stack([xy, 0.095 + depth_slope * xy[:, 0]])


def sequence_of(camera, curve: np.ndarray, view: str, rng: np.random.Generator) -> np.ndarray:
    """The view's sequence of ``curve``: every 1 px from the tip, 0.3 px of noise."""
    uv = camera.project(curve, view)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(uv, axis=0), axis=1))])
    s = np.arange(0.0, arc[-1], 1.0)
    sequence = np.column_stack([np.interp(s, arc, uv[:, 0]), np.interp(s, arc, uv[:, 1])])
    return sequence + rng.normal(0.0, 0.3, sequence.shape)


def test_a_good_grasp_is_published_with_a_small_uncertainty(make_scene):
    scene = make_scene("curved", seed=3)
    result = reconstruct(scene.left, scene.right, scene.camera)
    assert np.linalg.norm(result.grasp_position - scene.grasp) < 0.002
    assert 0 < result.grasp_uncertainty_mm < 2.0
    assert result.uncertainty.grasp_not_seen == ()
    assert result.path_not_seen.shape == (len(result.path),) and not result.path_not_seen.any()


def test_a_thread_along_the_image_rows_is_less_certain_and_refused_below_its_uncertainty(make_scene):
    rows = make_scene("rows", seed=1)
    steep = make_scene("curved", seed=3)
    rows_mm = reconstruct(rows.left, rows.right, rows.camera).uncertainty
    steep_mm = reconstruct(steep.left, steep.right, steep.camera).uncertainty
    assert rows_mm.row_angle_deg < 3 and steep_mm.row_angle_deg > 20
    assert rows_mm.conditioning_mm > 5 * steep_mm.conditioning_mm
    strict = ReconstructionParams(max_grasp_uncertainty_mm=0.5 * (rows_mm.total_mm + steep_mm.total_mm))
    with pytest.raises(UncertainGraspError, match="image rows") as refused:
        reconstruct(rows.left, rows.right, rows.camera, strict)
    assert refused.value.uncertainty.total_mm == pytest.approx(rows_mm.total_mm)
    reconstruct(steep.left, steep.right, steep.camera, strict)  # not refused


def test_views_that_disagree_make_the_grasp_uncertain():
    """A stretch of the right sequence 8 px off its epipolar rows (no partner in the left view):
    the grasp lands 15-20 mm off, and the path's distance from the right sequence says so."""
    camera = StereoCamera.default(640, 480)
    rng = np.random.default_rng(3)
    curve = thread_at(30.0)
    left, right = (sequence_of(camera, curve, view, rng) for view in ("left", "right"))
    assert reconstruct(left, right, camera).grasp_uncertainty_mm < 3.0
    arc = arc_of_points(right, camera, curve, "right")
    right[(arc > 0.03) & (arc < 0.045), 1] += 8.0
    with pytest.raises(UncertainGraspError, match="views disagree") as refused:
        reconstruct(left, right, camera)
    assert refused.value.uncertainty.residual_px > 4.0


def test_a_blip_of_one_views_sequence_is_not_taken_for_views_that_disagree():
    """A blob on one view's mask moves its centreline over a few pixels only: 4 px off over 1 mm
    of arc (about 5 px) moves the grasp by little, and is not read as a disagreement."""
    camera = StereoCamera.default(640, 480)
    rng = np.random.default_rng(3)
    curve = thread_at(30.0)
    left, right = (sequence_of(camera, curve, view, rng) for view in ("left", "right"))
    clean = reconstruct(left, right, camera)
    arc = arc_of_points(right, camera, curve, "right")
    right[(arc > 0.030) & (arc < 0.031), 1] += 4.0
    blip = reconstruct(left, right, camera)
    assert blip.uncertainty.residual_px < 1.0 and blip.grasp_uncertainty_mm < 5.0
    assert np.linalg.norm(blip.grasp_position - clean.grasp_position) < 0.001


def hook_at_the_tip(radius: float, tip_arm: float, step: float = 5e-5) -> np.ndarray:
    """A cut end bent into a hairpin of ``radius`` after a ``tip_arm`` (m), then 60 mm back past
    the tip, 60 deg to the image rows, 100 mm away (m, every ``step``)."""
    arm = np.column_stack([np.arange(0.0, tip_arm, step), np.zeros(round(tip_arm / step))])
    angle = np.arange(0.0, np.pi, step / radius)[:, None]
    bend = np.hstack([tip_arm + radius * np.sin(angle), radius - radius * np.cos(angle)])
    back_x = np.arange(tip_arm, -0.06, -step)
    back = np.column_stack([back_x, np.full(len(back_x), 2 * radius)])
    turn = np.radians(60.0)
    rotation = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
    xy = np.vstack([arm, bend, back]) @ rotation.T + [0.01, 0.025]
    return np.column_stack([xy, 0.1 + 0.1 * xy[:, 0]])


def test_a_hook_one_view_cut_across_at_the_tip_is_not_read_as_depth_at_the_grasp_point(exact_views):
    """The right view's sequence cuts across a hairpin's bend at the cut tip, as a mask whose arms
    merge there makes it do; the 3D thread follows the left view, which goes round it. The views
    disagree by several pixels at the tip but not at the grasp point 50 mm on, whose depth and arc
    are right: it is published."""
    camera = StereoCamera.default(640, 480)
    radius, tip_arm = 0.0005, 0.006
    curve = hook_at_the_tip(radius, tip_arm)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(curve, axis=0), axis=1))])
    true_grasp = curve[np.argmin(np.abs(arc - 0.05))]
    left, right = exact_views(camera, curve)
    shown = arc_of_points(right, camera, curve, "right")
    cut = np.flatnonzero((shown > tip_arm - 0.001) & (shown < tip_arm + np.pi * radius + 0.001))
    first, last = cut[0] - 1, cut[-1] + 1
    chord = np.linspace(0.0, 1.0, last - first + 1)[:, None]
    right[first : last + 1] = (1 - chord) * right[first] + chord * right[last]
    result = reconstruct(left, right, camera)
    assert np.linalg.norm(result.grasp_position - true_grasp) < 0.001
    assert result.uncertainty.residual_px < 0.5 and result.grasp_uncertainty_mm < 2.0


def flagged_gap(scene, start: float, end: float) -> tuple[np.ndarray, np.ndarray]:
    """Both sequences as (N, 3) with the points showing arc ``start``-``end`` (m) flagged not seen."""
    out = []
    for view, sequence in (("left", scene.left), ("right", scene.right)):
        arc = arc_of_points(sequence, scene.camera, scene.path, view)
        out.append(np.column_stack([sequence, ((arc > start) & (arc < end)).astype(float)]))
    return out[0], out[1]


def test_a_grasp_point_on_a_stretch_not_seen_is_refused(make_scene):
    scene = make_scene("curved", seed=3)
    left, right = flagged_gap(scene, 0.045, 0.056)
    with pytest.raises(GraspNotSeenError, match="left and right views do not see"):
        reconstruct(left, right, scene.camera)
    # Removed instead of flagged: a jump across the gap, the same refusal.
    with pytest.raises(GraspNotSeenError):
        reconstruct(left[left[:, 2] == 0, :2], right[right[:, 2] == 0, :2], scene.camera)
    # Not refused on request; the path says where it is not seen, the uncertainty counts the arc.
    result = reconstruct(left, right, scene.camera, ReconstructionParams(refuse_unseen_grasp=False))
    assert result.uncertainty.grasp_not_seen == ("left", "right")
    arc = np.linspace(0.0, result.length, len(result.path))
    assert result.path_not_seen[(arc > 0.047) & (arc < 0.054)].all()
    assert not result.path_not_seen[(arc < 0.04) | (arc > 0.062)].any()
    assert result.uncertainty.not_seen_arc_mm == pytest.approx(5.0, abs=1.5)


def test_a_gap_before_the_grasp_point_is_not_a_refusal(make_scene):
    scene = make_scene("curved", seed=3)
    left, right = flagged_gap(scene, 0.02, 0.03)
    result = reconstruct(left, right, scene.camera)
    assert result.uncertainty.grasp_not_seen == ()
    assert result.uncertainty.not_seen_arc_mm == pytest.approx(10.0, abs=2.0)
    assert result.uncertainty.not_seen_mm > 1.0


def test_the_threshold_is_checked():
    with pytest.raises(ValueError, match="max_grasp_uncertainty_mm"):
        ReconstructionParams(max_grasp_uncertainty_mm=0.0)
    with pytest.raises(ValueError, match="max_tip_gap_mm"):
        ReconstructionParams(max_tip_gap_mm=0.0)


def tip_along_the_rows(camera, exact_views) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 90 mm thread 100 mm away whose first 30 mm run exactly along an image row, then bend
    to 60 deg from the rows (m, every 0.05 mm), and its left and right sequences (every 1 px)."""
    s = np.arange(0.0, 0.09, 5e-5)
    heading = np.radians(60.0) * np.clip((s - 0.03) / 0.01, 0.0, 1.0)
    xy = np.cumsum(np.column_stack([np.cos(heading), np.sin(heading)]) * 5e-5, axis=0) - [0.04, 0.02]
    curve = np.column_stack([xy, np.full(len(s), 0.1)])
    return (curve, *exact_views(camera, curve))


def test_a_thread_whose_tip_stretch_has_no_stereo_support_is_refused(exact_views):
    camera = StereoCamera.default(640, 480)
    curve, left, right = tip_along_the_rows(camera, exact_views)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(curve, axis=0), axis=1))])
    true_grasp = curve[np.argmin(np.abs(arc - 0.05))]
    # Both views' tips on one row: the tip pair carries the depth along the rows to the bend.
    good = reconstruct(left, right, camera)
    assert np.linalg.norm(good.grasp_position - true_grasp) < 0.001
    # The right view's tip curls 4 px off the row (a small hook in its mask): no tip pair, and the
    # 30 mm along the rows have no crossing to pair, so the 3D thread starts at the bend. Counted
    # from there, the grasp point would lie about 20 mm too far along the thread.
    right[:6, 1] -= 4.0
    lenient_params = ReconstructionParams(max_tip_gap_mm=1000.0, max_unexplained_arc_mm=1000.0)
    lenient = reconstruct(left, right, camera, lenient_params)
    assert np.linalg.norm(lenient.grasp_position - true_grasp) > 0.01
    with pytest.raises(TipNotReconstructedError, match=r"starts 2\d\.\d mm of arc after the cut tip"):
        reconstruct(left, right, camera)


def test_a_depth_change_along_the_image_rows_counts_as_unsupported():
    from suture_reconstruction.uncertainty import _unsupported_depth_mm

    # 40 mm of thread, its depth rising by 12 mm: along the rows the pair measured none of it.
    s = np.linspace(0.0, 0.04, 81)
    points = np.column_stack([s, np.zeros_like(s), 0.1 + 0.3 * s])
    along_rows = np.full(len(s), np.sin(np.radians(1.0)))
    across_rows = np.full(len(s), np.sin(np.radians(40.0)))
    assert _unsupported_depth_mm(points, along_rows) == pytest.approx(12.0)
    assert _unsupported_depth_mm(points, across_rows) == 0.0
    half = along_rows.copy()
    half[40:] = across_rows[40:]
    assert _unsupported_depth_mm(points, half) == pytest.approx(6.0, abs=0.2)


def test_an_unsupported_depth_change_before_the_grasp_point_refuses_it(make_scene):
    steep = make_scene("curved", seed=3)
    assert reconstruct(steep.left, steep.right, steep.camera).uncertainty.unsupported_depth_mm < 1.0
    camera = StereoCamera.default(640, 480)
    rng = np.random.default_rng(5)
    curve = thread_at(1.0)
    left, right = (sequence_of(camera, curve, view, rng) for view in ("left", "right"))
    lenient = ReconstructionParams(max_grasp_uncertainty_mm=1e6)
    assessed = reconstruct(left, right, camera, lenient).uncertainty
    assert "depth change along the rows" in assessed.describe()
    # The thread at 1 deg to the rows rises 5 mm in depth over its first 50 mm: none of it measured.
    assert assessed.unsupported_depth_mm > 3.0
    strict = ReconstructionParams(max_grasp_uncertainty_mm=0.9 * assessed.unsupported_depth_mm)
    with pytest.raises(UncertainGraspError, match="depth changes along a stretch parallel"):
        reconstruct(left, right, camera, strict)


def test_the_default_refuses_a_grasp_whose_depth_along_the_rows_rests_on_no_measurement():
    """A thread at 1 degree to the rows whose depth changes by 12 mm before the grasp point: the
    default threshold refuses it (on a fresh simulated set such a grasp, its uncertainty 14.7 mm,
    came out 16.8 mm off), while the same thread at 30 degrees, whose depth the pair measures, is
    published."""
    camera = StereoCamera.default(640, 480)
    rng = np.random.default_rng(5)
    along_rows, steep = thread_at(1.0, depth_slope=0.25), thread_at(30.0, depth_slope=0.25)
    lenient = ReconstructionParams(max_grasp_uncertainty_mm=1e6)
    sequences = {
        name: [sequence_of(camera, curve, view, rng) for view in ("left", "right")]
        for name, curve in (("rows", along_rows), ("steep", steep))
    }
    assessed = reconstruct(*sequences["rows"], camera, lenient).uncertainty
    assert 11.0 < assessed.total_mm < 15.0 and assessed.unsupported_depth_mm > 10.0
    with pytest.raises(UncertainGraspError, match="depth changes along a stretch parallel"):
        reconstruct(*sequences["rows"], camera)
    assert reconstruct(*sequences["steep"], camera).grasp_uncertainty_mm < 5.0


def test_the_tip_gap_counts_from_the_earliest_pass_near_the_start():
    from types import SimpleNamespace

    from suture_reconstruction.sequences import Resampled
    from suture_reconstruction.uncertainty import tip_gap_mm

    camera = StereoCamera.default(640, 480)
    # A hairpin at the tip: 40 px to the right along row 200, back along row 202 past the tip.
    out = np.column_stack([np.arange(100.0, 140.0), np.full(40, 200.0)])
    back = np.column_stack([np.arange(140.0, 60.0, -1.0), np.full(80, 202.0)])
    points = np.vstack([out, back])
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    left = Resampled(points, arc, np.ones(len(points), dtype=bool))

    def curve_from(uv):
        """A stand-in for the 3D curve: its start 100 mm away on the left pixel ``uv``."""
        start = np.array([(uv[0] - camera.cx) * 0.1 / camera.fx, (uv[1] - camera.cy) * 0.1 / camera.fy, 0.1])
        return SimpleNamespace(at=lambda s: start)

    # The 3D start 1.8 px off the tip, nearer to the returning arm: no gap.
    assert tip_gap_mm(curve_from((100.5, 201.8)), left, camera) == 0.0
    # The 3D start 30 px along the first arm: 30 px at 100 mm is about 5.8 mm of arc missing.
    assert tip_gap_mm(curve_from((130.0, 200.0)), left, camera) == pytest.approx(
        30 * 100 / camera.fx, abs=0.7
    )


def tip_loop(with_loop: bool) -> np.ndarray:
    """A 90 mm thread 95-105 mm away at 60 deg to the image rows (m, every 0.05 mm) that curls once
    around a 1.5 mm radius loop 1 mm from the cut tip (about 9.4 mm of arc), or the same thread with
    the loop cut out (``with_loop`` False)."""
    step = 5e-5
    direction = np.array([np.cos(np.radians(60.0)), np.sin(np.radians(60.0))])
    normal = np.array([-direction[1], direction[0]])
    before = np.arange(0.0, 0.001, step)[:, None] * direction
    radius = 0.0015
    turn = np.arange(0.0, 2 * np.pi, step / radius)[:, None]
    loop = before[-1] + step * direction + radius * (np.sin(turn) * direction + (1 - np.cos(turn)) * normal)
    after = before[-1] + step * direction + np.arange(0.0, 0.08, step)[:, None] * direction
    xy = np.vstack([before, loop, after] if with_loop else [before, after]) - [0.02, 0.03]
    return np.column_stack([xy, 0.1 + 0.1 * xy[:, 0]])


def test_a_loop_at_the_tip_that_one_view_cut_across_is_refused(exact_views):
    camera = StereoCamera.default(640, 480)
    curve = tip_loop(with_loop=True)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(curve, axis=0), axis=1))])
    true_grasp = curve[np.argmin(np.abs(arc - 0.05))]
    exact_left, right = exact_views(camera, curve)
    both = reconstruct(exact_left, right, camera)
    assert np.linalg.norm(both.grasp_position - true_grasp) < 0.001
    # The left sequence cuts across the loop; the right one follows it. The 3D thread follows the
    # left view and lies on both sequences, so the views do not disagree, but it lacks the loop's
    # arc: counted from the tip, the grasp point lies that much too far along the thread.
    left = exact_views(camera, tip_loop(with_loop=False))[0]
    lenient = reconstruct(left, right, camera, ReconstructionParams(max_unexplained_arc_mm=1000.0))
    assert np.linalg.norm(lenient.grasp_position - true_grasp) > 0.005
    assert lenient.uncertainty.total_mm < 15.0
    with pytest.raises(UnexplainedArcError, match=r"[5-9]\.\d mm of the right view's sequence"):
        reconstruct(left, right, camera)
    with pytest.raises(ValueError, match="max_unexplained_arc_mm"):
        ReconstructionParams(max_unexplained_arc_mm=0.0)


# A thread's direction across the viewing rays, and one 67 degrees out of the image plane.
ACROSS = np.array([0.85, 0.25, 0.46]) / np.linalg.norm([0.85, 0.25, 0.46])
ALONG = np.array([0.33, 0.2, 0.92]) / np.linalg.norm([0.33, 0.2, 0.92])
LENIENT = dict(max_grasp_uncertainty_mm=1000.0, max_unexplained_arc_mm=1000.0)
STEP_M = 5e-5


def _bent_thread(
    start: list[float], first: np.ndarray, first_m: float, second: np.ndarray, second_m: float
) -> np.ndarray:
    """(N, 3) a thread sampled every STEP_M m: ``first_m`` along ``first`` from ``start``, then
    ``second_m`` along ``second``."""
    head = np.asarray(start) + np.arange(0.0, first_m, STEP_M)[:, None] * first
    return np.vstack([head, head[-1] + np.arange(STEP_M, second_m, STEP_M)[:, None] * second])


def _grasped_at_ratio_3_refused_at_2(exact_views, thread: np.ndarray, message: str) -> None:
    """``thread`` is grasped at its 50 mm point with ``max_arc_image_ratio`` 3 and refused with
    ``message`` at the default 2."""
    camera = StereoCamera.default(640, 480)
    left, right = exact_views(camera, thread)
    result = reconstruct(left, right, camera, ReconstructionParams(max_arc_image_ratio=3.0, **LENIENT))
    assert np.linalg.norm(result.grasp_position - thread[1000]) < 0.002
    with pytest.raises(ArcAlongViewError, match=message):
        reconstruct(left, right, camera, ReconstructionParams(**LENIENT))


def test_an_arc_along_the_viewing_rays_is_refused(exact_views):
    camera = StereoCamera.default(640, 480)
    s = np.arange(0.0, 0.07, STEP_M)[:, None]
    # A thread running across the viewing rays: its arc is about the length its image covers.
    flat = np.array([-0.03, -0.01, 0.09]) + s * ACROSS
    result = reconstruct(*exact_views(camera, flat), camera, ReconstructionParams(**LENIENT))
    assert np.linalg.norm(result.grasp_position - flat[1000]) < 0.002
    # One 67 degrees out of the image plane: 50 mm of arc cover 20 mm of image.
    steep = np.array([-0.01, -0.01, 0.07]) + s * ALONG
    _grasped_at_ratio_3_refused_at_2(exact_views, steep, r"2\.\d times the length its left image covers")
    with pytest.raises(ValueError, match="max_arc_image_ratio"):
        ReconstructionParams(max_arc_image_ratio=0.5)


def test_a_stretch_along_the_viewing_rays_before_the_grasp_point_is_refused(exact_views):
    # 20 mm from the cut tip 67 degrees out of the image plane, then across the viewing rays. Over
    # the whole 50 mm to the grasp point the 3D arc is only about 1.6 times its image, so the
    # diving stretch is seen only over a window of its own length.
    thread = _bent_thread([0.0, 0.0, 0.07], ALONG, 0.02, ACROSS, 0.06)
    _grasped_at_ratio_3_refused_at_2(exact_views, thread, r"20 mm of the 3D arc .* 2\.\d times the length")


def test_a_grasp_point_where_the_thread_dives_along_the_viewing_rays_is_refused(exact_views):
    # 40 mm across the viewing rays, then 20 mm 67 degrees out of the image plane: the grasp point
    # (50 mm) lies halfway down the dive. No stretch of 20 mm before it is twice its image (the one
    # ending there is half across, half diving); the one from 40 to 60 mm is.
    thread = _bent_thread([-0.03, -0.01, 0.09], ACROSS, 0.04, ALONG, 0.02)
    _grasped_at_ratio_3_refused_at_2(exact_views, thread, r"10 mm past the grasp point is 2\.\d times")
