# SPDX-License-Identifier: Apache-2.0
"""reconstruct(): accuracy on synthetic threads and on the sample bag, and every bad input's error."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from suture_common.camera import CameraModelError, StereoCamera
from suture_common.grasp import grasp_rotation, quaternion_to_rotation
from suture_reconstruction import (
    InvalidSequenceError,
    NoStereoOverlapError,
    ReconstructionError,
    ReconstructionParams,
    ThreadTooShortError,
    TooFewPointsError,
    reconstruct,
)


def distances_to(points: np.ndarray, curve: np.ndarray) -> np.ndarray:
    """Distance from each point to the nearest sample of a dense curve (0.05 mm apart)."""
    return np.min(np.linalg.norm(points[:, None, :] - curve[None, ::2, :], axis=2), axis=1)


@pytest.mark.parametrize("kind", ["curved", "loop"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_reconstructs_a_noisy_thread(make_scene, kind, seed):
    scene = make_scene(kind, seed)
    result = reconstruct(scene.left, scene.right, scene.camera)
    errors = distances_to(result.path, scene.path)
    assert errors.mean() < 0.6e-3
    assert np.linalg.norm(result.grasp_position - scene.grasp) < 1.5e-3
    true_length = np.linalg.norm(np.diff(scene.path, axis=0), axis=1).sum()
    assert result.length == pytest.approx(true_length, abs=1.5e-3)
    # path: from the cut tip, every 0.5 mm of arc
    assert np.linalg.norm(result.path[0] - scene.path[0]) < 2e-3
    steps = np.linalg.norm(np.diff(result.path, axis=0), axis=1)
    assert np.allclose(steps[:-1], 5e-4, rtol=0.02) and steps[-1] <= 5e-4 + 1e-6
    # dense vertices in sequence order
    assert result.points.shape[1] == 3 and len(result.points) > 0.9 * len(scene.left)
    order = np.argmin(np.linalg.norm(result.points[:, None] - scene.path[None, ::10], axis=2), axis=1)
    assert np.mean(np.diff(order) >= 0) > 0.95
    assert result.rejected.keys() >= {"off_epipolar", "disparity_range", "ill_conditioned", "outlier"}


def test_noise_free_sequences_are_reconstructed_almost_exactly(make_scene):
    scene = make_scene("loop", 4, noise=0.0)
    result = reconstruct(scene.left, scene.right, scene.camera)
    assert distances_to(result.path, scene.path).mean() < 0.06e-3
    assert np.linalg.norm(result.grasp_position - scene.grasp) < 0.3e-3


def test_grasp_frame_follows_the_shared_convention(make_scene):
    scene = make_scene("curved", 5, noise=0.0)
    result = reconstruct(scene.left, scene.right, scene.camera)
    rotation = quaternion_to_rotation(result.grasp_quaternion)
    k = int(np.argmin(np.linalg.norm(scene.path - scene.grasp, axis=1)))
    tangent = scene.path[k + 1] - scene.path[k - 1]
    expected = grasp_rotation(scene.grasp, tangent)
    assert np.linalg.norm(result.grasp_quaternion) == pytest.approx(1.0)
    # x along the thread away from the tip, z the approach (away from the camera)
    assert np.degrees(np.arccos(np.clip(rotation[:, 0] @ expected[:, 0], -1, 1))) < 5
    assert np.degrees(np.arccos(np.clip(rotation[:, 2] @ expected[:, 2], -1, 1))) < 5
    assert rotation[:, 2] @ result.grasp_position > 0


def test_a_thread_along_the_image_rows_is_fixed_by_its_ends(make_scene):
    """1 degree off the epipolar lines no row pairs it; the tip and end pairs still give its depth."""
    scene = make_scene("rows", 0)
    result = reconstruct(scene.left, scene.right, scene.camera)
    assert result.rejected["ill_conditioned"] > 0.8 * len(result.points)
    assert distances_to(result.path, scene.path).mean() < 2.5e-3


@pytest.mark.parametrize("kind", ["lifted", "lifted_steep"])
def test_a_lift_over_a_crossing_keeps_its_arc_length(make_scene, kind):
    """A lifted crossing: exact sequences of a thread lifted 6 mm where it passes over the
    other strand. The lift is a 2-4 px disparity bump (1 px is 3 mm of depth there); the
    regulariser used to reject its exact pairs as outliers, smooth it over 30-50 px and step
    between scales, which flattened the lift: 4.5 mm of arc length lost before the grasp point
    and a grasp 4 mm off along the thread."""
    scene = make_scene(kind, 0, noise=0.0)
    result = reconstruct(scene.left, scene.right, scene.camera)
    assert result.rejected["outlier"] <= 2
    true_length = np.linalg.norm(np.diff(scene.path, axis=0), axis=1).sum()
    assert result.length == pytest.approx(true_length, abs=1.5e-3)
    assert np.linalg.norm(result.grasp_position - scene.grasp) < 1.0e-3
    assert distances_to(result.path, scene.path).mean() < 0.3e-3


def test_sequence_order_and_lengths_may_differ(make_scene):
    scene = make_scene("curved", 1)
    right = scene.right[: len(scene.right) - 15]  # the right view stops 15 px earlier
    result = reconstruct(scene.left, right, scene.camera)
    assert distances_to(result.path, scene.path).mean() < 0.8e-3


def test_sample_bag_ground_truth(sample_frames):
    """All ten sample frames (every topology) from their ground-truth sequences, with 0.3 px noise."""
    rng = np.random.default_rng(0)
    errors = []
    for frame in sample_frames:
        camera = StereoCamera.from_camera_info(frame.left_info, frame.right_info)
        left = frame.left + rng.normal(0, 0.3, frame.left.shape)
        right = frame.right + rng.normal(0, 0.3, frame.right.shape)
        result = reconstruct(left, right, camera)
        errors.append(distances_to(result.path, frame.path).mean())
        assert np.linalg.norm(result.grasp_position - frame.grasp) < 2.5e-3, frame.topology
    assert np.mean(errors) < 0.6e-3 and max(errors) < 1.5e-3


# ------------------------------------------------------------------ bad input


def test_too_few_points(make_scene):
    scene = make_scene()
    with pytest.raises(TooFewPointsError, match="at least 8"):
        reconstruct(scene.left[:4], scene.right, scene.camera)
    with pytest.raises(TooFewPointsError):
        reconstruct(scene.left, np.zeros((0, 2)), scene.camera)


def test_nan_and_bad_shapes(make_scene):
    scene = make_scene()
    left = scene.left.copy()
    left[10, 1] = np.nan
    with pytest.raises(InvalidSequenceError, match="NaN"):
        reconstruct(left, scene.right, scene.camera)
    right = scene.right.copy()
    right[3, 0] = np.inf
    with pytest.raises(InvalidSequenceError, match="right sequence contains NaN or inf"):
        reconstruct(scene.left, right, scene.camera)
    with pytest.raises(InvalidSequenceError, match="shape"):
        reconstruct(scene.left[:, :1], scene.right, scene.camera)
    # (N, 3) arrays, as PolygonStamped gives them, are fine
    reconstruct(np.column_stack([scene.left, np.zeros(len(scene.left))]), scene.right, scene.camera)


def test_no_overlap_between_the_views(make_scene):
    scene = make_scene()
    # the upper half of the thread on the left, the lower half on the right: no common rows
    middle = np.median(scene.left[:, 1])
    upper, lower = scene.left[scene.left[:, 1] < middle - 5], scene.right[scene.right[:, 1] > middle + 5]
    with pytest.raises(NoStereoOverlapError, match="epipolar"):
        reconstruct(upper, lower, scene.camera)
    with pytest.raises(InvalidSequenceError, match="outside"):
        reconstruct(scene.left, scene.right + np.array([0.0, 400.0]), scene.camera)
    swapped = scene.right + np.array([200.0, 0.0])  # disparities far outside 45-165 mm
    with pytest.raises(NoStereoOverlapError):
        reconstruct(scene.left, swapped, scene.camera)
    with pytest.raises(ReconstructionError):  # the views swapped: negative disparities
        reconstruct(scene.right, scene.left, scene.camera)


def test_thread_shorter_than_the_reserve(make_scene):
    scene = make_scene("short")
    with pytest.raises(ThreadTooShortError, match="shorter than the reserved 50.0 mm"):
        reconstruct(scene.left, scene.right, scene.camera)
    result = reconstruct(scene.left, scene.right, scene.camera, ReconstructionParams(grasp_arc_length=0.01))
    assert result.length == pytest.approx(0.02, abs=1.5e-3)


def test_camera_info_that_is_not_rectified_or_has_no_baseline(sample_frames):
    frame = sample_frames[0]
    skewed = copy.deepcopy(frame.right_info)
    skewed.p = np.array(skewed.p, dtype=float)
    skewed.p[0] *= 1.1  # another fx: not a rectified pair
    with pytest.raises(CameraModelError, match="not rectified"):
        StereoCamera.from_camera_info(frame.left_info, skewed)
    flat = copy.deepcopy(frame.right_info)
    flat.p = np.array(flat.p, dtype=float)
    flat.p[3] = 0.0  # Tx = 0: zero baseline
    with pytest.raises(CameraModelError, match="baseline"):
        StereoCamera.from_camera_info(frame.left_info, flat)
    with pytest.raises(CameraModelError):
        reconstruct(frame.left, frame.right, camera=None)  # type: ignore[arg-type]


def test_parameters():
    params = ReconstructionParams().replace(
        tau_l=0.002, min_depth=0.04, threshold=2.0, skip_cost=2.0, grasp_arc_length=0.03
    )
    assert params.shape.tau_l == 0.002 and params.pairing.min_depth == 0.04
    assert params.disparity.threshold == 2.0 and params.pairing.selection.skip_cost == 2.0
    assert params.grasp_arc_length == 0.03
    with pytest.raises(TypeError, match="unknown"):
        ReconstructionParams().replace(tau=1.0)
    with pytest.raises(ValueError):
        ReconstructionParams().replace(tau_l=-1.0)
    with pytest.raises(ValueError):
        ReconstructionParams().replace(min_depth=0.2, max_depth=0.1)


@pytest.mark.parametrize(
    ("what", "make"),
    [
        # 3000 points scattered over the image: Algorithm 1 would work for minutes on it
        ("px long", lambda rng: np.column_stack([rng.uniform(0, 640, 3000), rng.uniform(0, 480, 3000)])),
        # astronomically far points: resampling them every pixel would need petabytes
        ("outside the 640x480 image", lambda rng: np.full((50, 2), 1e30)),
    ],
)
def test_garbage_sequences_are_refused_at_once(what, make):
    rng = np.random.default_rng(4)
    camera = StereoCamera.default(640, 480)
    left = make(rng)
    with pytest.raises(InvalidSequenceError, match=what):
        reconstruct(left, left - [20.0, 0.0], camera)
