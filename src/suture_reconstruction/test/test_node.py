# SPDX-License-Identifier: Apache-2.0
"""reconstruction_node over real rclpy topics: sequences and camera_info in, path and grasp pose out.

Each test runs its own rclpy Context on a DDS domain derived from the process id;
the node under test and a test node share one executor spun here.
"""

from __future__ import annotations

import copy
import os
import signal
import subprocess
import sys
from collections.abc import Iterator

import numpy as np
import pytest
import rclpy
from geometry_msgs.msg import PolygonStamped, PoseStamped
from nav_msgs.msg import Path
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from visualization_msgs.msg import Marker, MarkerArray

from suture_common import topics
from suture_common.camera import CameraInfoCache
from suture_common.messages import (
    image_message,
    ns_from_stamp,
    path_to_array,
    polygon_message,
    pose_to_arrays,
)
from suture_common.ros import RELIABLE_QOS, spin_until, to_rclpy
from suture_reconstruction.reconstruction_node import PARAMETERS, ReconstructionNode, point_cloud_to_array

TIMEOUT = 20.0


class Harness:
    """The node under test, a test node publishing its inputs and collecting its outputs, one executor."""

    def __init__(self, context: rclpy.Context, **overrides: object) -> None:
        parameters = [Parameter(name, value=value) for name, value in overrides.items()]
        self.node = ReconstructionNode(context=context, parameter_overrides=parameters)
        self.peer = rclpy.create_node("reconstruction_test_peer", context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.peer)
        self.publishers = {
            "left": self.peer.create_publisher(PolygonStamped, topics.LEFT_SEQUENCE, RELIABLE_QOS),
            "right": self.peer.create_publisher(PolygonStamped, topics.RIGHT_SEQUENCE, RELIABLE_QOS),
            "left_info": self.peer.create_publisher(CameraInfo, topics.LEFT_CAMERA_INFO, RELIABLE_QOS),
            "right_info": self.peer.create_publisher(CameraInfo, topics.RIGHT_CAMERA_INFO, RELIABLE_QOS),
        }
        self.image_publishers = {
            side: self.peer.create_publisher(Image, topic, RELIABLE_QOS)
            for side, topic in (("left", topics.LEFT_IMAGE), ("right", topics.RIGHT_IMAGE))
        }
        self.received: dict[str, list] = {"points": [], "path": [], "pose": [], "markers": []}
        for key, cls, topic in (
            ("points", PointCloud2, topics.POINTS),
            ("path", Path, topics.PATH),
            ("pose", PoseStamped, topics.GRASP_POSE),
            ("markers", MarkerArray, topics.MARKERS),
        ):
            self.peer.create_subscription(cls, topic, self.received[key].append, RELIABLE_QOS)
        assert spin_until(self.executor, self._matched, TIMEOUT), "publishers and subscriptions did not match"

    def _matched(self) -> bool:
        return all(p.get_subscription_count() >= 1 for p in self.publishers.values()) and all(
            self.peer.count_publishers(t) >= 1
            for t in (topics.POINTS, topics.PATH, topics.GRASP_POSE, topics.MARKERS)
        )

    def send_camera_info(self, left: object, right: object) -> None:
        self.publishers["left_info"].publish(to_rclpy(left))
        self.publishers["right_info"].publish(to_rclpy(right))
        # camera_info is heard with sensor-data QoS: give it time to arrive before the sequences
        spin_until(self.executor, lambda: False, 0.3)

    def send_sequences(self, stamp_ns: int, left: np.ndarray, right: np.ndarray) -> None:
        self.publishers["right"].publish(to_rclpy(polygon_message(right, stamp_ns, topics.LEFT_FRAME)))
        self.publishers["left"].publish(to_rclpy(polygon_message(left, stamp_ns, topics.LEFT_FRAME)))

    def send_images(self, stamp_ns: int, left: np.ndarray, right: np.ndarray, encoding: str = "rgb8") -> None:
        for side, image in (("left", left), ("right", right)):
            message = image_message(image, encoding, stamp_ns, topics.LEFT_FRAME)
            self.image_publishers[side].publish(to_rclpy(message))

    def wait_outputs(self, count: int) -> bool:
        return spin_until(
            self.executor, lambda: all(len(v) >= count for v in self.received.values()), TIMEOUT
        )

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.peer.destroy_node()


@pytest.fixture
def context(ros_domain_id: int) -> Iterator[rclpy.Context]:
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=ros_domain_id)
    try:
        yield context
    finally:
        context.try_shutdown()


@pytest.fixture
def harness(context) -> Iterator[Harness]:
    h = Harness(context)
    try:
        yield h
    finally:
        h.close()


def noisy(sequence: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    return sequence + rng.normal(0.0, 0.3, sequence.shape)


def test_reconstructs_sample_frames_and_publishes_everything(harness, sample_frames):
    rng = np.random.default_rng(1)
    frames = sample_frames[:4]
    harness.send_camera_info(frames[0].left_info, frames[0].right_info)
    for frame in frames:
        harness.send_sequences(frame.stamp_ns, noisy(frame.left, rng), noisy(frame.right, rng))
    assert harness.wait_outputs(len(frames)), {k: len(v) for k, v in harness.received.items()}
    assert harness.node.frames == len(frames) and not harness.node.dropped

    for frame, path, pose, cloud, markers in zip(
        frames, *(harness.received[k] for k in ("path", "pose", "points", "markers")), strict=True
    ):
        for header in (path.header, pose.header, cloud.header, markers.markers[0].header):
            assert ns_from_stamp(header.stamp) == frame.stamp_ns
            assert header.frame_id == "left_camera_optical_frame"
        points = path_to_array(path)
        distance = np.min(np.linalg.norm(points[:, None] - frame.path[None], axis=2), axis=1)
        assert distance.mean() < 1.0e-3, frame.topology
        position, quaternion = pose_to_arrays(pose)
        assert np.linalg.norm(position - frame.grasp) < 2.5e-3, frame.topology
        assert np.linalg.norm(quaternion) == pytest.approx(1.0)
        assert [f.name for f in cloud.fields] == ["x", "y", "z"] and cloud.point_step == 12
        dense = point_cloud_to_array(cloud)
        assert len(dense) == cloud.width > 100
        assert np.linalg.norm(dense[0] - frame.path[0]) < 3e-3  # sequence order: from the cut tip
        line, sphere = markers.markers
        assert (line.type, sphere.type) == (Marker.LINE_STRIP, Marker.SPHERE)
        assert len(line.points) == len(points)
        assert sphere.pose.position.x == pytest.approx(position[0])


def test_images_of_the_same_stamp_refine_the_disparity(harness, sample_frames):
    """Sequences 0.8 px of disparity off (a mask edge a pixel off in one view: ~3.5 mm of depth) are
    put right by the images of their stamp; without images, or with unusable ones, the frame is
    still reconstructed, from the sequences alone."""
    frames = sample_frames[:4]
    bias = np.array([0.8, 0.0])
    harness.send_camera_info(frames[0].left_info, frames[0].right_info)
    assert spin_until(
        harness.executor,
        lambda: all(p.get_subscription_count() for p in harness.image_publishers.values()),
        5,
    )
    for frame in frames[:2]:
        harness.send_images(frame.stamp_ns, frame.left_image, frame.right_image)
    harness.send_images(frames[2].stamp_ns, frames[2].left_image, frames[2].right_image[:200])  # wrong size
    assert spin_until(harness.executor, lambda: len(harness.node._images) == 3, TIMEOUT)
    for frame in frames:
        harness.send_sequences(frame.stamp_ns, frame.left, frame.right + bias)
    assert harness.wait_outputs(len(frames)), harness.node.dropped
    assert harness.node.refined == 2 and not harness.node.dropped
    assert harness.node.without_images == {"bad_image": 1, "no_images": 1}
    errors = [
        np.linalg.norm(pose_to_arrays(pose)[0] - frame.grasp)
        for frame, pose in zip(frames, harness.received["pose"], strict=True)
    ]
    assert max(errors[:2]) < 1.5e-3 and min(errors[2:]) > 2.0e-3, errors


def test_images_can_be_turned_off(context, sample_frames):
    h = Harness(context, use_images=False)
    try:
        frame = sample_frames[0]
        assert h.image_publishers["left"].get_subscription_count() == 0
        h.send_camera_info(frame.left_info, frame.right_info)
        h.send_sequences(frame.stamp_ns, frame.left, frame.right)
        assert h.wait_outputs(1)
        assert h.node.refined == 0 and not h.node.without_images and not h.node.dropped
    finally:
        h.close()


def test_bad_input_is_dropped_and_the_node_keeps_serving(harness, sample_frames):
    rng = np.random.default_rng(2)
    good = sample_frames[1]
    stamp = good.stamp_ns

    # no camera_info yet
    harness.send_sequences(stamp + 1, noisy(good.left, rng), noisy(good.right, rng))
    assert spin_until(harness.executor, lambda: "no_camera_info" in harness.node.dropped, TIMEOUT)

    # not rectified: the right camera has another focal length
    skewed = copy.deepcopy(good.right_info)
    skewed.p = np.array(skewed.p, dtype=float)
    skewed.p[0] *= 1.2
    harness.send_camera_info(good.left_info, skewed)
    harness.send_sequences(stamp + 2, noisy(good.left, rng), noisy(good.right, rng))
    assert spin_until(harness.executor, lambda: harness.node.dropped.get("camera_info") == 1, TIMEOUT)

    # zero baseline
    flat = copy.deepcopy(good.right_info)
    flat.p = np.array(flat.p, dtype=float)
    flat.p[3] = 0.0
    harness.send_camera_info(good.left_info, flat)
    harness.send_sequences(stamp + 3, noisy(good.left, rng), noisy(good.right, rng))
    assert spin_until(harness.executor, lambda: harness.node.dropped.get("camera_info") == 2, TIMEOUT)

    harness.send_camera_info(good.left_info, good.right_info)
    # too few points, right points below the image, NaN
    harness.send_sequences(stamp + 4, good.left[:4], good.right)
    harness.send_sequences(stamp + 5, good.left, good.right + np.array([0.0, 300.0]))
    harness.publishers["right"].publish(to_rclpy(polygon_message(good.right, stamp + 6, topics.LEFT_FRAME)))
    with_nan = to_rclpy(polygon_message(good.left, stamp + 6, topics.LEFT_FRAME))
    with_nan.polygon.points[7].x = float("nan")
    harness.publishers["left"].publish(with_nan)
    expected = {"TooFewPointsError": 1, "InvalidSequenceError": 1, "bad_sequence": 1}
    assert spin_until(
        harness.executor, lambda: all(harness.node.dropped.get(k) == v for k, v in expected.items()), TIMEOUT
    ), harness.node.dropped
    assert not any(harness.received.values())

    # ...and the next good pair is reconstructed
    harness.send_sequences(stamp + 7, noisy(good.left, rng), noisy(good.right, rng))
    assert harness.wait_outputs(1)
    assert ns_from_stamp(harness.received["path"][0].header.stamp) == stamp + 7


def test_a_refused_grasp_is_logged_by_reason_and_nothing_is_published(context, sample_frames):
    """A grasp point the views do not see (flagged z = 1 around it) and one more uncertain than
    max_grasp_uncertainty_mm are dropped by reason; the next frame is served."""
    frame = sample_frames[1]
    h = Harness(context, max_grasp_uncertainty_mm=0.01)
    try:
        h.send_camera_info(frame.left_info, frame.right_info)
        cache = CameraInfoCache()
        cache.update("left", frame.left_info)
        cache.update("right", frame.right_info)
        samples = cache.camera().triangulate(frame.left, frame.right[:, 0])  # same 3D sample per row
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(samples, axis=0), axis=1))])
        hidden = ((arc > 0.045) & (arc < 0.056)).astype(float)
        left, right = np.column_stack([frame.left, hidden]), np.column_stack([frame.right, hidden])
        h.send_sequences(frame.stamp_ns, left, right)
        assert spin_until(h.executor, lambda: h.node.dropped.get("GraspNotSeenError") == 1, TIMEOUT)
        h.send_sequences(frame.stamp_ns + 1, frame.left, frame.right)
        assert spin_until(h.executor, lambda: h.node.dropped.get("UncertainGraspError") == 1, TIMEOUT)
        assert not any(h.received.values()) and h.node.frames == 0
    finally:
        h.close()


def test_parameters_reach_the_core(context, sample_frames):
    h = Harness(context, grasp_arc_length=0.03, tau_l=0.002, frame_id="camera")
    try:
        assert h.node.params.grasp_arc_length == 0.03 and h.node.params.shape.tau_l == 0.002
        assert all(h.node.has_parameter(name) for name in PARAMETERS)
        frame = sample_frames[2]
        h.send_camera_info(frame.left_info, frame.right_info)
        h.send_sequences(frame.stamp_ns, frame.left, frame.right)
        assert h.wait_outputs(1)
        assert h.received["pose"][0].header.frame_id == "camera"
        position, _ = pose_to_arrays(h.received["pose"][0])
        path = path_to_array(h.received["path"][0])
        arc = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
        assert arc[np.argmin(np.linalg.norm(path - position, axis=1))] == pytest.approx(0.03, abs=5e-4)
    finally:
        h.close()


def test_bad_parameters_refuse_to_start(context):
    with pytest.raises(ValueError, match="min_depth"):
        ReconstructionNode(context=context, parameter_overrides=[Parameter("min_depth", value=0.5)])


def test_main_shuts_down_cleanly_on_ctrl_c(ros_domain_id):
    env = dict(os.environ, ROS_DOMAIN_ID=str(ros_domain_id))
    process = subprocess.Popen(
        [sys.executable, "-m", "suture_reconstruction.reconstruction_node"],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        # interrupt once the node is up (its start-up line), however long the imports take
        started = process.stderr.readline()
        assert "reconstructing" in started, started + process.communicate()[1]
        process.send_signal(signal.SIGINT)
        _, err = process.communicate(timeout=15)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 0, err
    assert "Traceback" not in err
