# SPDX-License-Identifier: Apache-2.0
"""segmentation_node over rclpy: stereo images in, both masks out; bad input dropped; bad weights refused.

Each test uses its own rclpy Context on a DDS domain derived from the process id, so parallel
test processes do not hear each other; the node under test and a peer node that publishes its
inputs and collects its outputs share one executor spun here.

The sample bag is in the simulator's ``legacy`` domain, so its test runs the shipped M-oST weights
(``weights:=m_ost``, the model for that domain; the node's default is the on-site m_onsite); the
other tests use a small random checkpoint written to a temporary folder.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import rclpy
import torch
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from sensor_msgs.msg import Image

from suture_common import topics
from suture_common.bag_io import read_messages
from suture_common.messages import image_message, image_to_array, ns_from_stamp
from suture_common.ros import SENSOR_DATA_QOS, spin_until, to_rclpy
from suture_segmentation.checkpoint import save_checkpoint
from suture_segmentation.model import SutureUNet
from suture_segmentation.segmentation_node import PARAMETERS, SegmentationNode, main

SAMPLE_BAG = Path(__file__).resolve().parents[3] / "bags" / "sample"
MIN_IOU = 0.5
"""Lowest IoU of a predicted mask with the ground truth, per frame and view, on bags/sample."""
MIN_MEAN_IOU = 0.7
"""Lowest IoU averaged over the frames and views of bags/sample."""
TIMEOUT = 10.0
W, H = 64, 48
STAMP = 1_700_000_000_000_000_000


@dataclass
class SampleFrame:
    stamp_ns: int
    left: object  # rosbags sensor_msgs/Image, rgb8
    right: object
    left_truth: np.ndarray  # (H, W) bool
    right_truth: np.ndarray


@pytest.fixture(scope="module")
def sample_frames() -> list[SampleFrame]:
    wanted = {
        topics.LEFT_IMAGE: "left",
        topics.RIGHT_IMAGE: "right",
        topics.GT_LEFT_MASK: "left_truth",
        topics.GT_RIGHT_MASK: "right_truth",
    }
    by_stamp: dict[int, dict[str, object]] = {}
    for item in read_messages(SAMPLE_BAG, list(wanted)):
        value = item.message if "truth" not in wanted[item.topic] else image_to_array(item.message) > 0
        by_stamp.setdefault(ns_from_stamp(item.message.header.stamp), {})[wanted[item.topic]] = value
    return [SampleFrame(stamp, **fields) for stamp, fields in sorted(by_stamp.items())]


@pytest.fixture(scope="module")
def random_weights(tmp_path_factory) -> Path:
    torch.manual_seed(0)
    return save_checkpoint(SutureUNet(), tmp_path_factory.mktemp("weights") / "random.pt")


class Harness:
    """The node under test, a peer publishing stereo images and collecting masks, one executor."""

    def __init__(self, context: rclpy.Context, **overrides: object) -> None:
        parameters = [Parameter(name, value=value) for name, value in overrides.items()]
        self.node = SegmentationNode(context=context, parameter_overrides=parameters)
        self.peer = rclpy.create_node("segmentation_test_peer", context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.peer)
        self.publishers = {
            "left": self.peer.create_publisher(Image, topics.LEFT_IMAGE, SENSOR_DATA_QOS),
            "right": self.peer.create_publisher(Image, topics.RIGHT_IMAGE, SENSOR_DATA_QOS),
        }
        self.masks: dict[str, dict[int, Image]] = {"left": {}, "right": {}}
        self.low_masks: dict[str, dict[int, Image]] = {"left": {}, "right": {}}
        for store, side, topic in (
            (self.masks, "left", topics.LEFT_MASK),
            (self.masks, "right", topics.RIGHT_MASK),
            (self.low_masks, "left", topics.LEFT_MASK_LOW),
            (self.low_masks, "right", topics.RIGHT_MASK_LOW),
        ):
            self.peer.create_subscription(
                Image,
                topic,
                lambda m, s=side, store=store: store[s].setdefault(ns_from_stamp(m.header.stamp), m),
                SENSOR_DATA_QOS,
            )
        assert spin_until(self.executor, self._matched, TIMEOUT), "publishers and subscriptions did not match"

    def _matched(self) -> bool:
        return all(p.get_subscription_count() >= 1 for p in self.publishers.values()) and all(
            self.peer.count_publishers(t) >= 1 for t in (topics.LEFT_MASK, topics.RIGHT_MASK)
        )

    def send(self, left: object, right: object) -> None:
        """Publish a stereo pair (rosbags or rclpy Image messages)."""
        for side, message in (("left", left), ("right", right)):
            self.publishers[side].publish(message if isinstance(message, Image) else to_rclpy(message))

    def has_masks(self, stamp_ns: int) -> bool:
        """Both masks of the stamp came, and both low masks if the node publishes them."""
        low = self.low_masks.values() if self.node.segmenter.low_threshold is not None else ()
        return all(stamp_ns in received for received in (*self.masks.values(), *low))

    def segment(self, left: object, right: object) -> tuple[Image, Image]:
        """Send a pair until both of its masks come back (sensor-data QoS is best effort)."""
        stamp_ns = ns_from_stamp(left.header.stamp)
        for _ in range(5):
            self.send(left, right)
            if spin_until(self.executor, lambda: self.has_masks(stamp_ns), 3.0):
                return self.masks["left"][stamp_ns], self.masks["right"][stamp_ns]
        raise AssertionError(f"no masks for the pair at {stamp_ns} ns; dropped: {self.node.dropped}")

    def drop(self, left: object, right: object, reason: str) -> None:
        """Send a bad pair until the node has dropped it for ``reason``."""
        before = self.node.dropped.get(reason, 0)
        for _ in range(5):
            self.send(left, right)
            if spin_until(self.executor, lambda: self.node.dropped.get(reason, 0) > before, 1.0):
                return
        raise AssertionError(f"the pair was not dropped for {reason}: {self.node.dropped}")

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


def iou(mask: np.ndarray, truth: np.ndarray) -> float:
    predicted = mask > 0
    return float((predicted & truth).sum() / max((predicted | truth).sum(), 1))


def test_sample_bag_masks_match_the_ground_truth(context, sample_frames):
    harness = Harness(context, weights="m_ost")  # the legacy-domain model, ONNX on the CPU
    try:
        scores = []
        for frame in sample_frames:
            left_mask, right_mask = harness.segment(frame.left, frame.right)
            for mask, image, truth in (
                (left_mask, frame.left, frame.left_truth),
                (right_mask, frame.right, frame.right_truth),
            ):
                assert ns_from_stamp(mask.header.stamp) == frame.stamp_ns
                assert mask.header.frame_id == image.header.frame_id
                assert mask.encoding == "mono8" and (mask.width, mask.height) == (image.width, image.height)
                pixels = image_to_array(mask)
                assert set(np.unique(pixels)) <= {0, 255}
                scores.append(iou(pixels, truth))
        per_frame = np.round(scores, 3).reshape(-1, 2).tolist()
        print("per-frame IoU (left, right):", per_frame)
        # the low masks of each pair, published just before its masks: the masks and more
        for side in ("left", "right"):
            for stamp_ns, mask in harness.masks[side].items():
                low = image_to_array(harness.low_masks[side][stamp_ns])
                assert low.shape == image_to_array(mask).shape and set(np.unique(low)) <= {0, 255}
                assert np.all(low[image_to_array(mask) > 0] == 255)
                assert harness.low_masks[side][stamp_ns].header.frame_id == mask.header.frame_id
        assert min(scores) >= MIN_IOU, f"IoU (left, right) per frame below {MIN_IOU}: {per_frame}"
        assert np.mean(scores) >= MIN_MEAN_IOU, f"mean IoU below {MIN_MEAN_IOU}: {per_frame}"

        # bgr8 is reordered to RGB: the same pixels give the same masks
        frame = sample_frames[0]
        stamp = frame.stamp_ns + 1
        bgr_pair = [
            image_message(image_to_array(m)[..., ::-1], "bgr8", stamp, m.header.frame_id)
            for m in (frame.left, frame.right)
        ]
        left_mask, _ = harness.segment(*bgr_pair)
        np.testing.assert_array_equal(
            image_to_array(left_mask), image_to_array(harness.masks["left"][frame.stamp_ns])
        )
        assert not harness.node.dropped
    finally:
        harness.close()


def _image(stamp_ns: int, frame_id: str, width: int = W, height: int = H, encoding: str = "rgb8") -> Image:
    rng = np.random.default_rng(stamp_ns % 1000)
    shape = (height, width) if encoding == "mono8" else (height, width, 3)
    return to_rclpy(image_message(rng.integers(0, 256, shape, dtype=np.uint8), encoding, stamp_ns, frame_id))


def test_bad_input_is_dropped_and_the_node_keeps_serving(context, random_weights, capfd):
    harness = Harness(context, weights=str(random_weights))
    try:
        assert all(harness.node.has_parameter(name) for name in PARAMETERS)
        assert harness.node.get_parameter("backend").value == "onnx"
        left_frame, right_frame = topics.LEFT_FRAME, topics.RIGHT_FRAME

        float_image = _image(STAMP + 1, left_frame)
        float_image.encoding, float_image.step = "32FC1", 4 * W
        float_image.data = bytes(4 * W * H)
        empty = _image(STAMP + 3, left_frame)
        empty.width = empty.height = empty.step = 0
        empty.data = b""
        short = _image(STAMP + 4, left_frame)
        short.data = bytes(short.data)[: -3 * W]  # one row missing
        bad_pairs = [
            (float_image, _image(STAMP + 1, right_frame), "encoding", "'32FC1'"),
            (
                _image(STAMP + 2, left_frame),
                _image(STAMP + 2, right_frame, width=48),
                "size_mismatch",
                "64x48",
            ),
            (empty, _image(STAMP + 3, right_frame), "empty_image", "zero size"),
            (short, _image(STAMP + 4, right_frame), "malformed_image", "bytes"),
        ]
        for left, right, reason, named in bad_pairs:
            harness.drop(left, right, reason)
            stamp = ns_from_stamp(left.header.stamp)
            err = capfd.readouterr().err
            assert f"dropped stereo pair at {stamp} ns" in err and named in err, err
        spin_until(harness.executor, lambda: False, 0.2)
        assert not any(harness.masks.values()) and harness.node.frames == 0

        # ...and the next good pair (grey this time) is segmented
        left_mask, right_mask = harness.segment(
            _image(STAMP + 5, left_frame, encoding="mono8"), _image(STAMP + 5, right_frame, encoding="mono8")
        )
        assert ns_from_stamp(left_mask.header.stamp) == STAMP + 5
        assert (left_mask.header.frame_id, right_mask.header.frame_id) == (left_frame, right_frame)
        assert (left_mask.encoding, left_mask.width, left_mask.height) == ("mono8", W, H)
        assert harness.node.frames == 1
    finally:
        harness.close()


@pytest.mark.parametrize("problem", ["missing", "corrupt"])
def test_unloadable_weights_stop_the_node_with_one_line(problem, tmp_path, monkeypatch, capfd, ros_domain_id):
    weights = tmp_path / "weights.pt"
    if problem == "corrupt":
        weights.write_bytes(b"\x00garbage, not a checkpoint\xff" * 100)
    monkeypatch.setenv("ROS_DOMAIN_ID", str(ros_domain_id))
    status = main(["segmentation_node", "--ros-args", "-p", f"weights:={weights}"])
    lines = [line for line in capfd.readouterr().err.splitlines() if line.strip()]
    assert status == 1
    assert len(lines) == 1, lines
    assert lines[0].startswith("segmentation_node: cannot load weights") and str(weights) in lines[0]
    assert ("does not exist" if problem == "missing" else "not a readable checkpoint") in lines[0]


@pytest.mark.parametrize(("queue_depth", "expected"), [(1, 1), (4, 4)])
def test_queue_depth_bounds_the_images_waiting(context, random_weights, queue_depth, expected):
    # Four pairs arrive while the node is busy (not spinning): by default it then segments only
    # the newest, so a node slower than the camera works on the current frame.
    harness = Harness(context, weights=str(random_weights), queue_depth=queue_depth)
    try:
        stamps = [STAMP + k * 100_000_000 for k in range(4)]
        for stamp in stamps:
            harness.send(_image(stamp, topics.LEFT_FRAME), _image(stamp, topics.RIGHT_FRAME))
        time.sleep(0.5)  # delivered into the subscriptions' queues, not yet taken
        assert spin_until(harness.executor, lambda: harness.has_masks(stamps[-1]), TIMEOUT)
        spin_until(harness.executor, lambda: False, 0.5)
        assert sorted(harness.masks["left"]) == stamps[-expected:]
    finally:
        harness.close()


@pytest.mark.parametrize(
    ("overrides", "match"),
    [
        ({"queue_depth": 0}, "queue_depth"),
        ({"input_width": 320}, "input_width and input_height"),
        ({"threads": -1}, "threads"),
        ({"threshold": 1.5}, "threshold"),
        ({"low_threshold": 0.7}, "low_threshold"),
        ({"backend": "tensorrt"}, "backend"),
    ],
)
def test_bad_parameters_refuse_to_start(context, random_weights, overrides, match):
    parameters = [Parameter(n, value=v) for n, v in {"weights": str(random_weights), **overrides}.items()]
    with pytest.raises(ValueError, match=match):
        SegmentationNode(context=context, parameter_overrides=parameters)


def test_low_threshold_zero_publishes_no_low_masks(context, random_weights):
    harness = Harness(context, weights=str(random_weights), low_threshold=0.0)
    try:
        stamp = 1_700_000_000_000_000_000
        harness.segment(_image(stamp, topics.LEFT_FRAME), _image(stamp, topics.RIGHT_FRAME))
        assert harness.peer.count_publishers(topics.LEFT_MASK_LOW) == 0
        assert not any(harness.low_masks.values())
    finally:
        harness.close()
