# SPDX-License-Identifier: Apache-2.0
"""ordering_node over rclpy: masks, tip hint and camera_info in, both sequences out; bad input dropped.

Each test uses its own rclpy Context on a DDS domain derived from the process id, so
parallel test processes do not hear each other.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import rclpy
from geometry_msgs.msg import PolygonStamped
from rclpy.executors import SingleThreadedExecutor
from scipy.spatial import cKDTree

from suture_common import topics
from suture_common.camera import StereoCamera
from suture_common.messages import camera_info_message, image_message, point_message, polygon_to_array
from suture_common.ros import RELIABLE_QOS, SENSOR_DATA_QOS, spin_until, to_rclpy
from suture_ordering.ordering_node import OrderingNode

W, H = 640, 480
STAMP = 1_700_000_000_000_000_000


def _scene(disparity: int = 30) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    s = np.linspace(0, 1, 1500)
    truth = np.column_stack([150 + 380 * s, 120 + 250 * s + 60 * np.sin(3 * s)])
    left = np.zeros((H, W), np.uint8)
    cv2.polylines(left, [np.rint(truth).astype(np.int32)], False, 255, 3)
    right = np.zeros_like(left)
    right[:, : W - disparity] = left[:, disparity:]
    return left, right, truth


@pytest.fixture
def ros(ros_domain_id):
    """(context, executor, node under test, helper node, received sequences by topic)."""
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=ros_domain_id)
    node = OrderingNode(context=context)
    helper = rclpy.create_node("ordering_test_helper", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    executor.add_node(helper)
    received: dict[str, list[PolygonStamped]] = {topics.LEFT_SEQUENCE: [], topics.RIGHT_SEQUENCE: []}
    for topic, store in received.items():
        helper.create_subscription(PolygonStamped, topic, store.append, RELIABLE_QOS)
    publishers = {
        topic: helper.create_publisher(kind, topic, SENSOR_DATA_QOS)
        for topic, kind in (
            (topics.LEFT_MASK, node_types()["Image"]),
            (topics.RIGHT_MASK, node_types()["Image"]),
            (topics.LEFT_MASK_LOW, node_types()["Image"]),
            (topics.RIGHT_MASK_LOW, node_types()["Image"]),
            (topics.TIP_HINT, node_types()["PointStamped"]),
            (topics.LEFT_CAMERA_INFO, node_types()["CameraInfo"]),
            (topics.RIGHT_CAMERA_INFO, node_types()["CameraInfo"]),
        )
    }
    try:
        yield executor, node, publishers, received
    finally:
        executor.shutdown()
        node.destroy_node()
        helper.destroy_node()
        rclpy.shutdown(context=context)


def node_types() -> dict[str, type]:
    from geometry_msgs.msg import PointStamped
    from sensor_msgs.msg import CameraInfo, Image

    return {"Image": Image, "PointStamped": PointStamped, "CameraInfo": CameraInfo}


def _wait_for_subscribers(executor, publishers) -> None:
    assert spin_until(
        executor, lambda: all(p.get_subscription_count() > 0 for p in publishers.values()), 10.0
    )


def _send_frame(publishers, stamp, left, right, hint, camera, encoding="mono8", executor=None) -> None:
    """camera_info and tip hint, then (after spinning ``executor`` briefly so they arrive first) masks."""
    frame_left, frame_right = topics.LEFT_FRAME, topics.RIGHT_FRAME
    publishers[topics.LEFT_CAMERA_INFO].publish(
        to_rclpy(camera_info_message(camera, "left", stamp, frame_left))
    )
    publishers[topics.RIGHT_CAMERA_INFO].publish(
        to_rclpy(camera_info_message(camera, "right", stamp, frame_right))
    )
    if hint is not None:
        message = to_rclpy(point_message(np.zeros(3), stamp, frame_left))
        message.point.x, message.point.y = float(hint[0]), float(hint[1])  # may be NaN on purpose
        publishers[topics.TIP_HINT].publish(message)
    if executor is not None:
        spin_until(executor, lambda: False, 0.05)
    if encoding == "mono8":
        left_msg = image_message(left, "mono8", stamp, frame_left)
    else:
        left_msg = image_message(np.dstack([left] * 3), encoding, stamp, frame_left)
    publishers[topics.LEFT_MASK].publish(to_rclpy(left_msg))
    publishers[topics.RIGHT_MASK].publish(to_rclpy(image_message(right, "mono8", stamp, frame_right)))


def _send_until_heard(executor, publishers, received, stamp, left, right, hint, camera) -> bool:
    """Send the frame (sensor-data QoS is best effort) until every topic in ``received`` got a
    message, at most 20 times; whether they all did."""
    for _ in range(20):
        _send_frame(publishers, stamp, left, right, hint, camera, executor=executor)
        if spin_until(executor, lambda: all(received.values()), 0.5):
            return True
    return False


def test_node_publishes_both_sequences_with_the_pair_stamp(ros):
    executor, _node, publishers, received = ros
    camera = StereoCamera.default(W, H)
    left, right, truth = _scene()
    _wait_for_subscribers(executor, publishers)
    # The hint and camera_info first, then the masks (resent until heard).
    heard = _send_until_heard(executor, publishers, received, STAMP, left, right, truth[0] + 1.0, camera)
    assert heard, "no sequences after 20 frames"
    left_seq, right_seq = received[topics.LEFT_SEQUENCE][0], received[topics.RIGHT_SEQUENCE][0]
    for message, frame in ((left_seq, topics.LEFT_FRAME), (right_seq, topics.RIGHT_FRAME)):
        assert message.header.stamp.sec * 10**9 + message.header.stamp.nanosec == STAMP
        assert message.header.frame_id == frame
    for message, shift in ((left_seq, 0), (right_seq, 30)):
        points = polygon_to_array(message)
        assert np.all(points[:, 2] == 0.0)
        distance, index = cKDTree(truth - [shift, 0]).query(points[:, :2])
        assert np.hypot(*(points[0, :2] - truth[0] + [shift, 0])) < 3.0
        assert distance.max() < 2.0 and index[-1] > 0.95 * len(truth)


def test_masks_before_camera_info_are_held_and_ordered_when_it_arrives(ros):
    executor, node, publishers, received = ros
    camera = StereoCamera.default(W, H)
    left, right, truth = _scene()
    _wait_for_subscribers(executor, publishers)
    for _ in range(20):  # masks and hint only: no camera driver yet
        message = to_rclpy(point_message(np.zeros(3), STAMP, topics.LEFT_FRAME))
        message.point.x, message.point.y = float(truth[0][0] + 1.0), float(truth[0][1] + 1.0)
        publishers[topics.TIP_HINT].publish(message)
        spin_until(executor, lambda: False, 0.05)
        for topic, mask, frame in (
            (topics.LEFT_MASK, left, topics.LEFT_FRAME),
            (topics.RIGHT_MASK, right, topics.RIGHT_FRAME),
        ):
            publishers[topic].publish(to_rclpy(image_message(mask, "mono8", STAMP, frame)))
        if spin_until(executor, lambda: node.dropped.get("camera_info", 0) > 0, 0.5):
            break
    assert node.dropped.get("camera_info", 0) > 0 and not any(received.values())
    for _ in range(20):  # the camera driver starts: the held pair comes out with its own stamp
        for side, topic in (("left", topics.LEFT_CAMERA_INFO), ("right", topics.RIGHT_CAMERA_INFO)):
            frame = topics.LEFT_FRAME if side == "left" else topics.RIGHT_FRAME
            publishers[topic].publish(to_rclpy(camera_info_message(camera, side, STAMP + 1, frame)))
        if spin_until(executor, lambda: all(received.values()), 0.5):
            break
    stamps = {m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in received[topics.LEFT_SEQUENCE]}
    assert stamps == {STAMP}


def test_node_drops_bad_input_and_keeps_serving(ros, caplog):
    executor, node, publishers, received = ros
    camera = StereoCamera.default(W, H)
    left, right, truth = _scene()
    _wait_for_subscribers(executor, publishers)
    bad_frames = [
        dict(encoding="rgb8"),  # wrong encoding for a mask
        dict(hint=np.array([np.nan, 10.0])),  # NaN hint
        dict(hint=np.array([900.0, 10.0])),  # hint outside the image
        dict(left=np.zeros((H, W), np.uint8)),  # empty mask
        dict(right=right[:, :600].copy()),  # size mismatch
    ]
    for k, bad in enumerate(bad_frames):
        args = dict(left=left, right=right, hint=truth[0], encoding="mono8") | bad
        for _ in range(3):
            _send_frame(
                publishers,
                STAMP + k,
                args["left"],
                args["right"],
                args["hint"],
                camera,
                args["encoding"],
                executor,
            )
            spin_until(executor, lambda: False, 0.1)
    assert not any(received.values()) and node.frames_published == 0
    good = STAMP + 100
    heard = _send_until_heard(executor, publishers, received, good, left, right, truth[0], camera)
    assert heard, "the node stopped serving after bad input"
    stamp = received[topics.LEFT_SEQUENCE][0].header.stamp
    assert stamp.sec * 10**9 + stamp.nanosec == good
    assert len(node.dropped) >= 4  # each problem was reported (throttled, once per kind)


def test_masks_use_the_tip_hint_of_their_own_stamp_not_the_latest(ros):
    """A stream where segmentation lags: hints of newer frames must not steer older masks."""
    _executor, node, _publishers, _received = ros

    def hint(stamp: int, x: float) -> None:
        message = to_rclpy(point_message(np.array([x, 10.0, 0.0]), stamp, topics.LEFT_FRAME))
        node._on_hint(message)

    hint(STAMP, 100.0)
    hint(STAMP + 200, 300.0)  # the hint of a later frame, arrived before the masks of STAMP
    assert node._tip_hint(STAMP)[0] == 100.0
    assert node._tip_hint(STAMP + 100)[0] == 100.0  # no hint of its own: the newest earlier one
    assert node._tip_hint(STAMP + 200)[0] == 300.0
    assert node._tip_hint(STAMP - 1) is None  # every hint is newer than these masks


def test_low_masks_of_the_stamp_carry_the_sequences_across_a_faint_stretch(ros):
    """Masks broken for 200 px in both views (a faint stretch, farther than the ordering bridges
    an occluder: occluder_reach_px) end the sequences there; the low
    masks of the same stamp, published just before them as segmentation_node does, are whole and
    give the sequences to the end. A later pair whose low masks never come is ordered from its
    masks alone once it has waited low_mask_wait, and counted."""
    executor, node, publishers, received = ros
    camera = StereoCamera.default(W, H)
    low_left, low_right, truth = _scene()
    faint = slice(450, 1100)  # samples of the 1500 along the thread: a 200 px stretch
    left, right = low_left.copy(), low_right.copy()
    box = np.rint(truth[faint]).astype(int)
    for mask, shift in ((left, 0), (right, 30)):
        mask[box[:, 1].min() - 4 : box[:, 1].max() + 5, box[:, 0].min() - shift : box[:, 0].max() - shift] = 0
    _wait_for_subscribers(executor, publishers)

    def reach(message: PolygonStamped) -> float:
        return cKDTree(truth).query(polygon_to_array(message)[-1, :2])[1] / len(truth)

    def answered(stamp: int) -> bool:
        return any(m.header.stamp.nanosec == stamp % 10**9 for m in received[topics.LEFT_SEQUENCE])

    for stamp, with_low in ((STAMP, True), (STAMP + 1, False)):
        for _ in range(20):
            if with_low:
                for topic, mask, frame in (
                    (topics.LEFT_MASK_LOW, low_left, topics.LEFT_FRAME),
                    (topics.RIGHT_MASK_LOW, low_right, topics.RIGHT_FRAME),
                ):
                    publishers[topic].publish(to_rclpy(image_message(mask, "mono8", stamp, frame)))
            _send_frame(publishers, stamp, left, right, truth[0] + 1.0, camera, executor=executor)
            if spin_until(executor, lambda s=stamp: answered(s), 0.5):
                break
        assert answered(stamp), f"no sequences for the pair {'with' if with_low else 'without'} low masks"
    whole, broken = received[topics.LEFT_SEQUENCE][0], received[topics.LEFT_SEQUENCE][-1]
    assert reach(whole) > 0.95 and reach(broken) < 0.5
    assert node.low_masks_seen and node.without_low_masks >= 1


def test_points_bridged_under_a_wide_occluder_are_published_with_z_one(ros):
    executor, _node, publishers, received = ros
    camera = StereoCamera.default(W, H)
    left, right, truth = _scene()
    # An instrument shaft 90 px wide lies across the thread in both views (same rows).
    shaft = np.array([[300, 0], [390, 0], [390, H], [300, H]], np.int32)
    cv2.fillConvexPoly(left, shaft, 0)
    cv2.fillConvexPoly(right, shaft - [30, 0], 0)
    _wait_for_subscribers(executor, publishers)
    heard = _send_until_heard(executor, publishers, received, STAMP, left, right, truth[0] + 1.0, camera)
    assert heard, "no sequences after 20 frames"
    for topic, shift in ((topics.LEFT_SEQUENCE, 0), (topics.RIGHT_SEQUENCE, 30)):
        points = polygon_to_array(received[topic][0])
        assert set(np.unique(points[:, 2])) == {0.0, 1.0}
        not_seen = points[:, 2] == 1.0
        # z = 1 on every point under the shaft (and on at most a step, r_s = 8 px, of seen thread
        # before it, where the bridge leaves the last vertex); they lie on the hidden centreline.
        under = (points[:, 0] > 300 - shift + 1) & (points[:, 0] < 390 - shift - 1)
        assert not_seen[under].all() and (not_seen & ~under).sum() <= 16
        distance, index = cKDTree(truth - [shift, 0]).query(points[:, :2])
        assert distance[not_seen].max() < 3.0 and index[-1] > 0.95 * len(truth)


def test_a_sequence_that_took_the_crossing_strand_is_published_cut_and_counted(ros):
    """Our thread's mask lost 30 px just past a 45 degree crossing, where the search takes the
    other strand: the node publishes both sequences cut at the crossing and counts the frame."""
    executor, node, publishers, received = ros
    camera = StereoCamera.default(W, H)
    left = np.zeros((H, W), np.uint8)
    cv2.line(left, (100, 240), (560, 240), 255, 3)
    left[235:246, 300:330] = 0
    cv2.line(left, (159, 381), (441, 99), 255, 3)  # through (300, 240) at 45 degrees
    right = np.roll(left, -26, axis=1)
    _wait_for_subscribers(executor, publishers)
    heard = _send_until_heard(executor, publishers, received, STAMP, left, right, (100.0, 240.0), camera)
    assert heard, "no sequences after 20 frames"
    for topic, crossing in ((topics.LEFT_SEQUENCE, 300), (topics.RIGHT_SEQUENCE, 274)):
        points = polygon_to_array(received[topic][0])
        assert np.all(np.abs(points[:, 1] - 240) <= 2) and abs(points[-1, 0] - crossing) <= 12
    assert node.frames_cut >= 1 and not node.dropped
