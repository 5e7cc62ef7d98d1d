# SPDX-License-Identifier: Apache-2.0
"""Replay a bag through rclpy (read_raw + from_cdr -> publish -> subscribe) and compare the messages.

:func:`replay_and_receive` takes any bag path, so the same check can later be run
on ``bags/sample``. Each run uses its own rclpy Context on a DDS domain derived
from the process id, so parallel test processes do not hear each other.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosbags.rosbag2 import Reader

from suture_common.bag_io import BagWriter, bag_summary, read_raw
from suture_common.camera import StereoCamera
from suture_common.messages import TYPESTORE, camera_info_message, image_message, image_to_array
from suture_common.ros import (
    RELIABLE_QOS,
    SENSOR_DATA_QOS,
    ThrottledWarnings,
    from_cdr,
    message_class,
    serialized,
    spin_until,
    to_cdr,
    to_rclpy,
)

FRAME_TOPICS = (
    "/stereo/left/image_rect",
    "/stereo/right/image_rect",
    "/stereo/left/camera_info",
    "/stereo/right/camera_info",
    "/suture/left/mask",
)
FRAMES = 4


def write_frames_bag(path: Path, frames: int = FRAMES, width: int = 64, height: int = 48) -> Path:
    """Write ``frames`` stereo frames: rgb8/bgr8 images, camera_info pair and a mono8 mask."""
    camera = StereoCamera.default(width, height)
    rng = np.random.default_rng(3)
    with BagWriter(path) as bag:
        for index in range(frames):
            stamp = 1_700_000_000_000_000_000 + index * 50_000_000
            left, right = "left_camera_optical_frame", "right_camera_optical_frame"
            messages = {
                FRAME_TOPICS[0]: image_message(
                    rng.integers(0, 256, (height, width, 3), np.uint8), "rgb8", stamp, left
                ),
                FRAME_TOPICS[1]: image_message(
                    rng.integers(0, 256, (height, width, 3), np.uint8), "bgr8", stamp, right
                ),
                FRAME_TOPICS[2]: camera_info_message(camera, "left", stamp, left),
                FRAME_TOPICS[3]: camera_info_message(camera, "right", stamp, right),
                FRAME_TOPICS[4]: image_message(
                    (rng.random((height, width)) > 0.7).astype(np.uint8) * 255, "mono8", stamp, left
                ),
            }
            for topic, message in messages.items():
                bag.write(topic, message, stamp)
    return path


@dataclass
class Replayed:
    """One bag message and what the subscriber received for it."""

    topic: str
    msgtype: str
    timestamp_ns: int
    cdr: bytes
    received: Any


def replay_and_receive(
    bag_path: Path, topics: Collection[str], domain_id: int, timeout_s: float = 10.0
) -> list[Replayed]:
    """Publish the bag's messages on ``topics`` from node A and receive them on node B.

    Returns one :class:`Replayed` per bag message, in bag order, paired with the
    subscriber's message at the same position on its topic. Raises AssertionError
    if the endpoints do not match or not every message arrives within ``timeout_s``.
    Also checks that the type hash in the bag equals the one rclpy advertises.
    """
    raw = list(read_raw(bag_path, topics))
    assert raw, f"{bag_path} has no messages on {sorted(topics)}"
    msgtypes = {topic: msgtype for topic, msgtype, _, _ in raw}
    counts: dict[str, int] = defaultdict(int)
    for topic, _, _, _ in raw:
        counts[topic] += 1

    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    executor = None
    nodes = []
    try:
        talker = rclpy.create_node("bag_replayer", context=context)
        listener = rclpy.create_node("bag_listener", context=context)
        nodes = [talker, listener]
        executor = SingleThreadedExecutor(context=context)
        for node in nodes:
            executor.add_node(node)
        received: dict[str, list[Any]] = defaultdict(list)
        publishers, subscriptions = {}, {}
        for topic, msgtype in msgtypes.items():
            qos = QoSProfile(
                depth=counts[topic],
                history=HistoryPolicy.KEEP_LAST,
                reliability=ReliabilityPolicy.RELIABLE,
                durability=DurabilityPolicy.VOLATILE,
            )
            cls = message_class(msgtype)
            publishers[topic] = talker.create_publisher(cls, topic, qos)
            subscriptions[topic] = listener.create_subscription(cls, topic, received[topic].append, qos)

        def matched() -> bool:
            return all(p.get_subscription_count() >= 1 for p in publishers.values()) and all(
                s.get_publisher_count() >= 1 for s in subscriptions.values()
            )

        assert spin_until(executor, matched, timeout_s), "publishers and subscriptions did not match"
        _check_type_hashes(bag_path, talker, msgtypes)

        for topic, msgtype, _, data in raw:
            publishers[topic].publish(from_cdr(data, msgtype))
            executor.spin_once(timeout_sec=0)

        def all_arrived() -> bool:
            return all(len(received[topic]) >= count for topic, count in counts.items())

        arrived = spin_until(executor, all_arrived, timeout_s)
        got = {topic: len(received[topic]) for topic in counts}
        assert arrived, f"not every message arrived within {timeout_s} s: got {got}, sent {dict(counts)}"
        assert got == dict(counts), f"more messages than sent arrived: got {got}, sent {dict(counts)}"

        position: dict[str, int] = defaultdict(int)
        result = []
        for topic, msgtype, stamp, data in raw:
            result.append(Replayed(topic, msgtype, stamp, data, received[topic][position[topic]]))
            position[topic] += 1
        return result
    finally:
        if executor is not None:
            executor.shutdown()
        for node in nodes:
            node.destroy_node()
        context.try_shutdown()


def _check_type_hashes(bag_path: Path, node: Any, msgtypes: dict[str, str]) -> None:
    """Check that the bag's RIHS01 type hashes are those that ROS 2 Jazzy advertises."""
    with Reader(bag_path) as reader:
        recorded = {c.topic: c.digest for c in reader.connections if c.topic in msgtypes and c.digest}
    for topic, digest in recorded.items():
        (info,) = [i for i in node.get_publishers_info_by_topic(topic) if i.node_name == node.get_name()]
        assert str(info.topic_type_hash) == digest, (
            f"{topic}: bag hash {digest} != rclpy {info.topic_type_hash}"
        )


def canonical_cdr(data: bytes, msgtype: str) -> bytes:
    """CDR bytes with zeroed alignment padding.

    rclpy (Fast CDR) leaves the padding bytes between fields uninitialised, so two
    serialisations of one message can differ there; rosbags writes zeros. A round
    trip through rosbags keeps every field byte and zeroes the padding.
    """
    return bytes(TYPESTORE.serialize_cdr(TYPESTORE.deserialize_cdr(data, msgtype), msgtype))


def assert_replay_faithful(replayed: list[Replayed]) -> None:
    """Every received message re-serialises to the bag's CDR bytes; images also compare as arrays."""
    for item in replayed:
        assert type(item.received) is message_class(item.msgtype)
        cdr = to_cdr(item.received)
        assert len(cdr) == len(item.cdr), f"{item.topic} at {item.timestamp_ns}: CDR length differs"
        assert canonical_cdr(cdr, item.msgtype) == canonical_cdr(item.cdr, item.msgtype), (
            f"{item.topic} at {item.timestamp_ns}: CDR differs"
        )
        if item.msgtype == "sensor_msgs/msg/Image":
            original = TYPESTORE.deserialize_cdr(item.cdr, item.msgtype)
            np.testing.assert_array_equal(image_to_array(item.received), image_to_array(original))
            assert item.received.encoding == original.encoding
        stamp = getattr(getattr(item.received, "header", None), "stamp", None)
        if stamp is not None:
            assert stamp.sec * 10**9 + stamp.nanosec == item.timestamp_ns


@pytest.fixture(scope="module")
def frames_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_frames_bag(tmp_path_factory.mktemp("replay") / "frames")


def test_replay_frames(frames_bag, ros_domain_id):
    replayed = replay_and_receive(frames_bag, FRAME_TOPICS, ros_domain_id)
    assert len(replayed) == FRAMES * len(FRAME_TOPICS)
    assert {r.topic for r in replayed} == set(FRAME_TOPICS)
    assert_replay_faithful(replayed)


def test_replay_subset_of_topics(frames_bag, ros_domain_id):
    replayed = replay_and_receive(frames_bag, ["/stereo/left/image_rect"], ros_domain_id)
    assert [r.topic for r in replayed] == ["/stereo/left/image_rect"] * FRAMES
    assert_replay_faithful(replayed)


def test_replay_detects_a_corrupted_message(frames_bag, ros_domain_id):
    """The comparison would notice if the transport changed a message."""
    replayed = replay_and_receive(frames_bag, ["/suture/left/mask"], ros_domain_id)
    replayed[1].received.data[5] ^= 0xFF
    with pytest.raises(AssertionError):
        assert_replay_faithful(replayed)


# --------------------------------------------------------------------------- ros.py helpers


def test_message_class():
    from geometry_msgs.msg import PoseStamped
    from sensor_msgs.msg import Image

    assert message_class("sensor_msgs/msg/Image") is Image
    assert message_class("geometry_msgs/PoseStamped") is PoseStamped
    with pytest.raises(ValueError, match="package/msg/Name"):
        message_class("Image")
    with pytest.raises(ValueError, match="no Python module"):
        message_class("no_such_msgs/msg/Thing")
    with pytest.raises(ValueError, match="has no msg type 'NoSuchImage'"):
        message_class("sensor_msgs/msg/NoSuchImage")


def test_to_rclpy_and_cdr_agree(frames_bag):
    for topic, msgtype, _, data in read_raw(frames_bag, [FRAME_TOPICS[0], FRAME_TOPICS[3]]):
        message = TYPESTORE.deserialize_cdr(data, msgtype)
        converted = to_rclpy(message)
        assert converted == from_cdr(data, msgtype), topic
        assert canonical_cdr(to_cdr(converted), msgtype) == data  # rosbags writes zero padding
        # what the nodes publish: bytes that rclpy reads back as the same message
        assert from_cdr(serialized(message), msgtype) == converted, topic


def test_qos_profiles():
    assert SENSOR_DATA_QOS.reliability == ReliabilityPolicy.BEST_EFFORT
    assert RELIABLE_QOS.reliability == ReliabilityPolicy.RELIABLE
    assert RELIABLE_QOS.depth == 10 and RELIABLE_QOS.history == HistoryPolicy.KEEP_LAST


def test_throttled_warnings_log_each_reason_once_per_period():
    class Logger:
        def __init__(self) -> None:
            self.lines: list[str] = []

        def warning(self, text: str) -> None:
            self.lines.append(text)

    now = [100.0]
    logger = Logger()
    warnings = ThrottledWarnings(logger, 2.0, clock=lambda: now[0])
    assert warnings.warn("encoding", "bad encoding 1")
    assert not warnings.warn("encoding", "bad encoding 2")  # same reason within the period
    assert warnings.warn("size", "size mismatch")  # a new reason is logged at once
    now[0] += 1.9
    assert not warnings.warn("encoding", "bad encoding 3")
    now[0] += 0.1
    assert warnings.warn("encoding", "bad encoding 4")
    assert logger.lines == ["bad encoding 1", "size mismatch", "bad encoding 4"]
    assert warnings.counts == {"encoding": 4, "size": 1}


SAMPLE_BAG = Path(__file__).resolve().parents[3] / "bags" / "sample"


def test_replay_sample_bag_frames_unchanged(ros_domain_id):
    """The committed sample bag: every topic of every frame crosses rclpy unchanged."""
    replayed = replay_and_receive(SAMPLE_BAG, list(bag_summary(SAMPLE_BAG)), ros_domain_id)
    assert len(replayed) == sum(count for _, count in bag_summary(SAMPLE_BAG).values())
    assert_replay_faithful(replayed)
