# SPDX-License-Identifier: Apache-2.0
"""The simulator's ground truth is exact, read back from a bag as any user would read it."""

from __future__ import annotations

import numpy as np
import pytest

from suture_common import messages, topics
from suture_common.bag_io import BagWriter, read_messages
from suture_common.camera import StereoCamera
from suture_common.grasp import quaternion_to_rotation
from suture_sim.output import write_frame
from suture_sim.scene import HARD_TOPOLOGIES, MIXTURES, TOPOLOGIES, SimConfig, generate_frame


def _read_frames(bag) -> list[dict]:
    frames: dict[int, dict] = {}
    for record in read_messages(bag):
        frames.setdefault(record.timestamp_ns, {})[record.topic] = record.message
    return [frames[stamp] for stamp in sorted(frames)]


@pytest.fixture(
    scope="module",
    params=[
        ("mixed", 640, 480, "raster"),
        ("mixed", 1280, 1024, "raster"),
        ("hard", 640, 480, "raster"),
        ("hard", 1280, 1024, "raster"),
        ("mixed", 640, 480, "cycles"),
    ],
    ids=["mixed-640x480", "mixed-1280x1024", "hard-640x480", "hard-1280x1024", "cycles-640x480"],
)
def bag_frames(request, tmp_path_factory):
    """Frames of every topology of a mixture written to a bag and read back with rosbags: two each
    from the raster renderer at 640x480, one each otherwise. The Cycles frames take one sample per
    pixel: their ground truth comes from a render of its own, whatever the image's samples."""
    mixture, width, height, renderer = request.param
    if renderer == "cycles":
        request.getfixturevalue("blender")
    cycle = MIXTURES[mixture]
    bag = tmp_path_factory.mktemp("gt") / "bag"
    config = SimConfig(
        topology=mixture, camera=StereoCamera.default(width, height), seed=11, renderer=renderer, samples=1
    )
    with BagWriter(bag) as writer:
        for index in range(2 * len(cycle) if (width, renderer) == (640, "raster") else len(cycle)):
            write_frame(writer, generate_frame(config, index))
    return _read_frames(bag)


def _camera(frame: dict) -> StereoCamera:
    return StereoCamera.from_camera_info(frame[topics.LEFT_CAMERA_INFO], frame[topics.RIGHT_CAMERA_INFO])


def _distance_to_polyline(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """Distance of each of (N, D) points to an (M, D) polyline."""
    a, b = polyline[:-1], polyline[1:]
    d = b - a
    t = np.clip(np.einsum("nmd,md->nm", points[:, None, :] - a[None], d) / np.sum(d * d, axis=1), 0, 1)
    nearest = a[None] + t[..., None] * d[None]
    return np.min(np.linalg.norm(points[:, None, :] - nearest, axis=2), axis=1)


def test_projected_centreline_lies_in_the_mask_and_on_the_sequence(bag_frames):
    for frame in bag_frames:
        camera = _camera(frame)
        path = messages.path_to_array(frame[topics.GT_PATH])
        for view, mask_topic, sequence_topic in (
            ("left", topics.GT_LEFT_MASK, topics.GT_LEFT_SEQUENCE),
            ("right", topics.GT_RIGHT_MASK, topics.GT_RIGHT_SEQUENCE),
        ):
            mask = messages.image_to_array(frame[mask_topic], expect="mono8")
            sequence = messages.polygon_to_array(frame[sequence_topic])
            projected = camera.project(path, view)
            # Sub-pixel: the projected 3D centreline runs along the 2D ground truth. A hook's
            # bend can be ~1 px in radius, and 1 px chords cut it by up to 1 / (8 R) px.
            tolerance = 0.15 if frame[topics.GT_TOPOLOGY].data == "hooked" else 0.05
            assert _distance_to_polyline(projected, sequence[:, :2]).max() < tolerance
            # Wherever the target is visible, its centreline pixel is in the mask.
            visible = sequence[:, 2] == 1.0
            pixels = np.rint(sequence[visible, :2]).astype(int)
            assert np.all(mask[pixels[:, 1], pixels[:, 0]] == 255), view
            # Wide shafts and a buried end may hide ~40 % of a short hard thread.
            assert visible.mean() > (0.5 if frame[topics.GT_TOPOLOGY].data in HARD_TOPOLOGIES else 0.7)


def test_left_and_right_sequences_share_rows_with_positive_disparity(bag_frames):
    for frame in bag_frames:
        camera = _camera(frame)
        left = messages.polygon_to_array(frame[topics.GT_LEFT_SEQUENCE])
        right = messages.polygon_to_array(frame[topics.GT_RIGHT_SEQUENCE])
        assert left.shape == right.shape
        np.testing.assert_allclose(left[:, 1], right[:, 1], atol=1e-3)
        disparity = left[:, 0] - right[:, 0]
        # Depth 50..150 mm, so disparity = fx * b / z lies in this range.
        assert np.all(disparity > camera.disparity(0.150) - 0.01)
        assert np.all(disparity < camera.disparity(0.050) + 0.01)
        # Consecutive samples are about a pixel apart in the left view.
        steps = np.linalg.norm(np.diff(left[:, :2], axis=0), axis=1)
        assert steps.max() < 2.5 and np.median(steps) > 0.8


def test_grasp_pose_is_on_the_centreline_at_50_mm(bag_frames):
    for frame in bag_frames:
        path = messages.path_to_array(frame[topics.GT_PATH])
        position, quaternion = messages.pose_to_arrays(frame[topics.GT_GRASP_POSE])
        distance = _distance_to_polyline(position[None], path)[0]
        assert distance < 2e-6
        # Arc length from the tip to the grasp point along the path.
        steps = np.linalg.norm(np.diff(path, axis=0), axis=1)
        cumulative = np.r_[0.0, np.cumsum(steps)]
        nearest = np.argmin(np.linalg.norm(path - position, axis=1))
        arc = cumulative[nearest] + np.dot(
            position - path[nearest], path[min(nearest + 1, len(path) - 1)] - path[nearest]
        ) / max(steps[min(nearest, len(steps) - 1)], 1e-12)
        assert abs(arc - 0.05) < 1e-4
        rotation = quaternion_to_rotation(quaternion)
        tangent = path[nearest + 1] - path[nearest - 1]
        tangent /= np.linalg.norm(tangent)
        # The path tangent is a 1 mm central difference, so allow its own error.
        assert np.dot(rotation[:, 0], tangent) > 0.99  # x along the thread, away from the tip
        assert abs(np.dot(rotation[:, 2], tangent)) < 0.02  # z orthogonal to it
        np.testing.assert_allclose(rotation.T @ rotation, np.eye(3), atol=1e-9)
        assert np.dot(rotation[:, 2], position / np.linalg.norm(position)) > 0.5  # away from the camera


def test_physical_sizes_and_labels(bag_frames):
    seen = []
    for frame in bag_frames:
        path = messages.path_to_array(frame[topics.GT_PATH])
        length = np.linalg.norm(np.diff(path, axis=0), axis=1).sum()
        assert 0.060 <= length <= 0.1501
        assert np.all((path[:, 2] >= 0.050) & (path[:, 2] <= 0.150))
        seen.append(frame[topics.GT_TOPOLOGY].data)
        tip = messages.point_to_array(frame[topics.TIP_HINT])
        first = messages.polygon_to_array(frame[topics.GT_LEFT_SEQUENCE])[0, :2]
        assert np.linalg.norm(tip[:2] - first) <= 3.0 + 1e-4
    assert set(seen) in (set(TOPOLOGIES), set(HARD_TOPOLOGIES))


def test_occlusion_agrees_between_views(bag_frames):
    """Crossings, loops, instruments and the tissue hide the same stretch of the target in both
    views."""
    for frame in bag_frames:
        topology = frame[topics.GT_TOPOLOGY].data
        left = messages.polygon_to_array(frame[topics.GT_LEFT_SEQUENCE])[:, 2] == 0
        right = messages.polygon_to_array(frame[topics.GT_RIGHT_SEQUENCE])[:, 2] == 0
        if topology in ("self_intersected", "occluded", "wide_occlusion"):
            assert left.any() and right.any(), topology
        if topology == "wide_occlusion":
            # Shafts hover 2-10 mm above the thread (their hidden arc: test_hard_topologies).
            assert np.sum(left & right) / np.sum(left | right) > 0.5
        elif topology == "occluded":
            # The instrument floats 4-12 mm above the thread: parallax shifts its shadow a little.
            assert np.sum(left & right) / np.sum(left | right) > 0.5
            # It crosses the thread rather than lying along it: at most ~10 mm of thread hidden
            # (samples are ~1 px apart; a pixel spans at most z_max / fx metres).
            camera = _camera(frame)
            metres_per_px = messages.path_to_array(frame[topics.GT_PATH])[:, 2].max() / camera.fx
            runs = np.split(np.flatnonzero(left), np.flatnonzero(np.diff(np.flatnonzero(left)) > 1) + 1)
            assert max(len(run) for run in runs) * metres_per_px < 0.0105
        else:
            # Threads rest on each other: every hidden sample in one view has a hidden sample
            # within 3 px of arc in the other.
            hidden_left, hidden_right = np.flatnonzero(left), np.flatnonzero(right)
            for one, other in ((hidden_left, hidden_right), (hidden_right, hidden_left)):
                if one.size:
                    assert other.size and np.abs(one[:, None] - other[None, :]).min(axis=1).max() <= 3, (
                        topology
                    )
        if topology in ("straight", "curved"):
            assert not left.any() and not right.any(), topology


def test_crossed_frames_show_a_second_thread_in_the_mask(bag_frames):
    for frame in bag_frames:
        if frame[topics.GT_TOPOLOGY].data != "crossed":
            continue
        camera = _camera(frame)
        mask = messages.image_to_array(frame[topics.GT_LEFT_MASK]) > 0
        sequence = messages.polygon_to_array(frame[topics.GT_LEFT_SEQUENCE])
        near_target = np.zeros_like(mask)
        pixels = np.rint(sequence[:, :2]).astype(int)
        radius = int(np.ceil(0.0003 * camera.fx / 0.05)) + 1
        for dy in range(-radius, radius + 1):
            for dx in range(-radius, radius + 1):
                near_target[
                    np.clip(pixels[:, 1] + dy, 0, mask.shape[0] - 1),
                    np.clip(pixels[:, 0] + dx, 0, mask.shape[1] - 1),
                ] = True
        assert np.sum(mask & ~near_target) > 50  # the other thread's pixels


def test_same_seed_same_frame_other_seed_other_frame():
    camera = StereoCamera.default(640, 480)
    a = generate_frame(SimConfig("curved", camera, seed=5), 3)
    b = generate_frame(SimConfig("curved", camera, seed=5), 3)
    c = generate_frame(SimConfig("curved", camera, seed=6), 3)
    np.testing.assert_array_equal(a.left_image, b.left_image)
    np.testing.assert_array_equal(a.right_mask, b.right_mask)
    np.testing.assert_array_equal(a.path, b.path)
    assert not np.array_equal(a.left_image, c.left_image)


def test_domains_look_different():
    camera = StereoCamera.default(640, 480)
    legacy = generate_frame(SimConfig("curved", camera, domain="legacy", seed=2), 0)
    onsite = generate_frame(SimConfig("curved", camera, domain="on-site", seed=2), 0)
    assert legacy.background == "tissue" and onsite.background in ("phantom", "printed")
    assert np.abs(legacy.left_image.mean(axis=(0, 1)) - onsite.left_image.mean(axis=(0, 1))).max() > 5
