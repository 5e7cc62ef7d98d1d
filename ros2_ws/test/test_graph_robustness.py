# SPDX-License-Identifier: Apache-2.0
"""The running system under bad input and crashes: the four pipeline nodes as separate processes.

docs/interfaces.md, "Bad input": a node never dies on a message; it drops a malformed input with a log
line naming the problem and keeps serving the next frame. Here the nodes are the installed
executables (segmentation_node, ordering_node, reconstruction_node, executor_node) with
``ros2_ws/params/pipeline.yaml``, each in its own process, and the test talks to them over the
real middleware from its own rclpy node (``node_processes.py``).

``test_nodes_survive_malformed_input_and_serve_the_next_frames`` sends more than a thousand
malformed messages, generated deterministically (seeded numpy RNG), on every input topic of
every node: wrong encodings and sizes, left/right mismatches, empty data and masks, NaN and
inf in polygons, poses and paths, zero quaternions, odd stamps, absurd camera_info, masks with
values other than 0/255, degenerate and huge sequences, tip hints outside the image, poses and
paths in the wrong frame. They go in bursts that fit the subscriptions' queues, each burst
followed by a well-formed "barrier" input whose output proves that the node worked through the
burst and still serves: nothing is lost unseen in a DDS queue, and a node that dies or stalls
is caught at the burst that did it (then restarted, so that one run reports every problem).
Afterwards every process is alive, three frames of ``bags/sample`` each give a grasp pose, the
dry-run executor (not armed) commanded no target for a malformed grasp pose and never ran, and
each node's log names dropped input.

``test_graph_recovers_when_each_node_is_killed_and_restarted`` plays ``bags/sample`` in a loop
with fresh stamps and SIGKILLs each node in turn: the other three keep running (those upstream
of the dead one keep publishing), and once it is restarted grasp and target poses arrive again
for new frames.
"""

from __future__ import annotations

import importlib.util
import math
import sys
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest
from geometry_msgs.msg import Point32, PointStamped, PolygonStamped, PoseStamped
from nav_msgs.msg import Path as PathMsg
from sensor_msgs.msg import CameraInfo, Image

from suture_common import topics
from suture_common.bag_io import read_raw
from suture_common.ros import from_cdr


def _load_harness() -> ModuleType:
    """ros2_ws/test/node_processes.py, imported by path (ros2_ws/test is no package)."""
    name = "ros2_ws_test_node_processes"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, Path(__file__).with_name("node_processes.py"))
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module  # dataclasses look their module up while it executes
        spec.loader.exec_module(module)
    return sys.modules[name]


harness = _load_harness()

SEGMENTATION, ORDERING, RECONSTRUCTION, EXECUTOR = harness.PIPELINE
LEFT_FRAME = topics.LEFT_FRAME
RIGHT_FRAME = topics.RIGHT_FRAME

START_TIMEOUT_S = 60.0
"""For the processes to start and be discovered (segmentation_node loads torch and ONNX Runtime)."""
SETTLE_S = 1.5
"""After our publishers see a subscriber, until that subscriber has matched them too."""
BURST_PER_TOPIC = 4
"""Most messages on one topic before a barrier: the barrier's one more fits the queues (5 and 10)."""
BARRIER_RESEND_S = 1.5
BARRIER_TIMEOUT_S = 12.0
"""A node that answers no barrier for this long after a burst has stopped serving."""
GRASP_TIMEOUT_S = 20.0
RECONNECT_TIMEOUT_S = 30.0
"""After a node is restarted, for a frame to go through the whole graph again (DDS discovery)."""
VALID_FRAMES = (2, 5, 8)
"""Indices of the bags/sample frames sent after the malformed input."""
REFERENCE_FRAME = 3
"""Index of the bags/sample frame whose messages and ground truth the cases and barriers reuse."""
MIN_MALFORMED = 1000
FORBIDDEN_STATES = ("executing", "done", "fault")
SEED = 20_240_611

FUZZ_BASE_NS = 1_600_000_000 * 10**9
"""Stamps of the malformed cases: 1 ms apart from here (bags/sample starts at 1.7e9 s)."""
BARRIER_BASE_NS = 1_650_000_000 * 10**9
UINT32_MAX = 2**32 - 1
INT32_MAX = 2**31 - 1
Stamp = int | tuple[int, int]
"""Integer nanoseconds, or a raw builtin_interfaces/Time (sec, nanosec) that may be malformed."""
STAMP_ZERO: Stamp = (0, 0)
FAR_FUTURE: Stamp = (INT32_MAX, 999_999_999)
"""The latest builtin_interfaces/Time there is."""
POSE_FAR_FUTURE: Stamp = (INT32_MAX, 999_999_998)
"""The far-future stamp of malformed grasp poses: no other case uses it."""
NEGATIVE: Stamp = (-1, 0)
"""sec < 0: a builtin_interfaces/Time (int32 sec) before the epoch."""
NANOSEC_OVERFLOW: Stamp = (INT32_MAX, UINT32_MAX)
"""nanosec >= 1e9: in nanoseconds, later than any builtin_interfaces/Time."""
BYTES_PER_PIXEL = {"mono8": 1, "rgb8": 3, "bgr8": 3, "32FC1": 4, "16UC1": 2, "yuv422": 2, "rgba16": 8}
BAD_ENCODINGS = ("32FC1", "16UC1", "yuv422", "rgba16", "", "RGB8", "bayer_rggb8", "8UC3", "mono16")


# --------------------------------------------------------------------------- bags/sample


@dataclass
class Sample:
    """bags/sample as rclpy messages: its frames and, of one frame, a well-formed input of each stage."""

    frames: list[Any]  # node_processes.Frame
    left_info: CameraInfo
    right_info: CameraInfo
    hint: PointStamped
    left_mask: Image  # ground truth: what segmentation_node would publish
    right_mask: Image
    left_sequence: PolygonStamped  # ground truth: what ordering_node would publish
    right_sequence: PolygonStamped
    grasp_pose: PoseStamped
    path: PathMsg

    @property
    def size(self) -> tuple[int, int]:
        return int(self.left_info.width), int(self.left_info.height)

    def mask_array(self, side: str) -> np.ndarray:
        message = self.left_mask if side == "left" else self.right_mask
        return np.frombuffer(bytes(message.data), np.uint8).reshape(message.height, message.width)


@pytest.fixture(scope="module")
def sample() -> Sample:
    frames = harness.load_frames(harness.SAMPLE_BAG)
    stamp = frames[REFERENCE_FRAME].stamp_ns
    wanted = {
        topics.LEFT_CAMERA_INFO: "left_info",
        topics.RIGHT_CAMERA_INFO: "right_info",
        topics.TIP_HINT: "hint",
        topics.GT_LEFT_MASK: "left_mask",
        topics.GT_RIGHT_MASK: "right_mask",
        topics.GT_LEFT_SEQUENCE: "left_sequence",
        topics.GT_RIGHT_SEQUENCE: "right_sequence",
        topics.GT_GRASP_POSE: "grasp_pose",
        topics.GT_PATH: "path",
    }
    found = {}
    for topic, msgtype, _, data in read_raw(harness.SAMPLE_BAG, list(wanted)):
        message = from_cdr(data, msgtype)
        if harness.raw_stamp_ns(message.header.stamp) == stamp:
            found[wanted[topic]] = message
    assert set(found) == set(wanted.values()), f"bags/sample lacks {set(wanted.values()) - set(found)}"
    # The true sequences' z is visibility (1 = visible); a published sequence's z is the
    # not-seen flag (docs/interfaces.md): sent as ordering_node would send them, all seen.
    for sequence in (found["left_sequence"], found["right_sequence"]):
        for point in sequence.polygon.points:
            point.z = 0.0
    return Sample(frames=frames, **found)


# --------------------------------------------------------------------------- raw messages (no checks)


def stamped(message: Any, stamp: Stamp, frame_id: str | None = None) -> Any:
    """``message`` with its header stamp (and frame_id) set; returns it."""
    sec, nanosec = divmod(stamp, 10**9) if isinstance(stamp, int) else stamp
    message.header.stamp.sec, message.header.stamp.nanosec = sec, nanosec
    if frame_id is not None:
        message.header.frame_id = frame_id
    return message


def copy_message(message: Any) -> Any:
    """A copy of an rclpy message, field by field (arrays are shared: edit by assignment only)."""
    fields = {}
    for name in message.get_fields_and_field_types():
        value = getattr(message, name)
        if hasattr(value, "get_fields_and_field_types"):
            value = copy_message(value)
        elif isinstance(value, list):
            value = [copy_message(v) if hasattr(v, "get_fields_and_field_types") else v for v in value]
        fields[name] = value
    return type(message)(**fields)


def restamped(message: Any, stamp: Stamp) -> Any:
    return stamped(copy_message(message), stamp)


def image(
    width: int, height: int, encoding: str, data: bytes, stamp: Stamp, step: int | None = None
) -> Image:
    """A sensor_msgs/Image with exactly these fields; ``step`` defaults to width * bytes per pixel."""
    step = width * BYTES_PER_PIXEL.get(encoding, 1) if step is None else step
    message = Image(height=height, width=width, encoding=encoding, step=step, data=data)
    return stamped(message, stamp, LEFT_FRAME)


def mono8(array: np.ndarray, stamp: Stamp) -> Image:
    array = np.ascontiguousarray(array, dtype=np.uint8)
    return image(array.shape[1], array.shape[0], "mono8", array.tobytes(), stamp)


def polygon(points: np.ndarray, stamp: Stamp) -> PolygonStamped:
    """geometry_msgs/PolygonStamped of (N, 2) or (N, 3) points (z = 0), NaN and inf kept."""
    points = np.asarray(points, dtype=np.float64)
    points = points.reshape(0, 3) if points.size == 0 else points
    if points.shape[1] == 2:
        points = np.column_stack([points, np.zeros(len(points))])
    message = PolygonStamped()
    message.polygon.points = [Point32(x=x, y=y, z=z) for x, y, z in points.tolist()]
    return stamped(message, stamp, LEFT_FRAME)


def polygon_points(message: PolygonStamped) -> np.ndarray:
    return np.array([(p.x, p.y, p.z) for p in message.polygon.points], dtype=np.float64).reshape(-1, 3)


def pose(position: Any, quaternion: Any, stamp: Stamp, frame_id: str = LEFT_FRAME) -> PoseStamped:
    message = PoseStamped()
    p, q = message.pose.position, message.pose.orientation
    p.x, p.y, p.z = map(float, position)
    q.x, q.y, q.z, q.w = map(float, quaternion)
    return stamped(message, stamp, frame_id)


def path(points: np.ndarray, stamp: Stamp, frame_id: str = LEFT_FRAME) -> PathMsg:
    message = PathMsg()
    message.poses = [pose(p, (0, 0, 0, 1), stamp, frame_id) for p in np.asarray(points).tolist()]
    return stamped(message, stamp, frame_id)


def point(u: float, v: float, stamp: Stamp, frame_id: str = LEFT_FRAME) -> PointStamped:
    message = PointStamped()
    message.point.x, message.point.y = float(u), float(v)
    return stamped(message, stamp, frame_id)


def _bytes(rng: np.random.Generator, size: int) -> bytes:
    return rng.integers(0, 256, max(size, 0), dtype=np.uint8).tobytes()


# --------------------------------------------------------------------------- malformed cases


@dataclass
class Send:
    topic: str
    message: Any
    malformed: bool = True
    """False for a well-formed message that only carries a case (the other view, a trigger)."""
    spin_after: float = 0.0
    """Seconds to spin before the next message (so that a camera_info or hint is taken first)."""


@dataclass
class Case:
    node: str
    """The executable whose input this exercises."""
    what: str
    sends: list[Send]


class Stamps:
    """Unique stamps, 1 ms apart after ``base``."""

    def __init__(self, base: int) -> None:
        self._last = base

    def __call__(self) -> int:
        self._last += 1_000_000
        return self._last


def pair(node: str, what: str, topic_pair: tuple[str, str], left: Send | Any, right: Send | Any) -> Case:
    """A case of a left and a right message (a Send, or a message that is malformed)."""
    sends = [
        item if isinstance(item, Send) else Send(topic, item)
        for topic, item in zip(topic_pair, (left, right), strict=True)
    ]
    return Case(node, what, sends)


def image_defects(
    rng: np.random.Generator, w: int, h: int, encoding: str
) -> list[tuple[str, Callable[[Stamp], Image]]]:
    """Malformed images of one view: (description, stamp -> image)."""
    c = BYTES_PER_PIXEL[encoding]
    size = w * h * c
    defects: list[tuple[str, Callable[[Stamp], Image]]] = [
        (
            f"encoding {other!r}",
            lambda s, o=other: image(w, h, o, _bytes(rng, w * h * BYTES_PER_PIXEL.get(o, c)), s),
        )
        for other in BAD_ENCODINGS
    ]
    defects += [
        ("data 1 byte short", lambda s: image(w, h, encoding, _bytes(rng, size - 1), s)),
        ("data half as long", lambda s: image(w, h, encoding, _bytes(rng, size // 2), s)),
        ("data 1 byte long", lambda s: image(w, h, encoding, _bytes(rng, size + 1), s)),
        ("data twice as long", lambda s: image(w, h, encoding, _bytes(rng, 2 * size), s)),
        (
            "step < width * channels",
            lambda s: image(w, h, encoding, _bytes(rng, (w * c - 1) * h), s, w * c - 1),
        ),
        ("step 0", lambda s: image(w, h, encoding, b"", s, 0)),
        ("width 0", lambda s: image(0, h, encoding, b"", s)),
        ("height 0", lambda s: image(w, 0, encoding, b"", s)),
        ("0x0 with data", lambda s: image(0, 0, encoding, _bytes(rng, 64), s, 0)),
        ("empty data", lambda s: image(w, h, encoding, b"", s)),
        ("huge width, tiny data", lambda s: image(2**30, 1, encoding, _bytes(rng, 3 * c), s)),
        ("huge height, tiny data", lambda s: image(1, UINT32_MAX, encoding, _bytes(rng, c), s)),
        (
            "step * height past 2**32",
            lambda s: image(UINT32_MAX // c, UINT32_MAX, encoding, _bytes(rng, 16), s),
        ),
    ]
    return defects


def random_image(rng: np.random.Generator, stamp: Stamp) -> Image:
    """Random declared size, encoding and step, and about (or exactly) as much data."""
    encoding = str(rng.choice(["mono8", "rgb8", "bgr8", "32FC1", "yuv422", "", "16UC1"]))
    width, height = int(rng.integers(0, 80)), int(rng.integers(0, 60))
    step = max(0, width * BYTES_PER_PIXEL.get(encoding, 1) + int(rng.integers(-3, 4)))
    length = step * height + int(rng.choice([0, 0, -1, 1, -step, int(rng.integers(-50, 50))]))
    return image(width, height, encoding, _bytes(rng, length), stamp, step)


def segmentation_cases(rng: np.random.Generator, stamps: Stamps) -> list[Case]:
    """Malformed stereo images for segmentation_node (64x48 where well-formed)."""
    images = (topics.LEFT_IMAGE, topics.RIGHT_IMAGE)

    def good(s: Stamp, w: int = 64, h: int = 48, encoding: str = "rgb8") -> Image:
        return image(w, h, encoding, _bytes(rng, w * h * BYTES_PER_PIXEL[encoding]), s)

    cases = []
    for what, bad in image_defects(rng, 64, 48, "rgb8"):
        s = stamps()
        cases.append(
            pair(SEGMENTATION, f"left image: {what}", images, bad(s), Send(images[1], good(s), False))
        )
        s = stamps()
        cases.append(
            pair(SEGMENTATION, f"right image: {what}", images, Send(images[0], good(s), False), bad(s))
        )
        s = stamps()
        cases.append(pair(SEGMENTATION, f"both images: {what}", images, bad(s), bad(s)))
    for a, b in [
        ((64, 48, "rgb8"), (32, 24, "rgb8")),
        ((64, 48, "rgb8"), (48, 64, "rgb8")),
        ((64, 48, "rgb8"), (64, 47, "rgb8")),
        ((1, 1, "rgb8"), (64, 48, "rgb8")),
        ((64, 48, "mono8"), (64, 48, "rgb8")),
        ((64, 48, "bgr8"), (32, 24, "mono8")),
    ]:
        for left, right in ((a, b), (b, a)):
            s = stamps()
            cases.append(
                pair(SEGMENTATION, f"left {left} and right {right}", images, good(s, *left), good(s, *right))
            )
    for size in [(1, 1, "rgb8"), (1, 1, "mono8"), (1, 1, "bgr8"), (1, 97, "rgb8"), (97, 1, "mono8")]:
        s = stamps()
        cases.append(pair(SEGMENTATION, f"{size} images", images, good(s, *size), good(s, *size)))
    for _ in range(5):
        cases.append(Case(SEGMENTATION, "left image only", [Send(images[0], good(stamps()))]))
        cases.append(Case(SEGMENTATION, "right image only", [Send(images[1], good(stamps()))]))
        s = stamps()
        cases.append(pair(SEGMENTATION, "left and right 1 ns apart", images, good(s), good(s + 1)))
    for stamp in (STAMP_ZERO, FAR_FUTURE, (1_600_000_000, 1_500_000_000)):
        cases.append(pair(SEGMENTATION, f"images stamped {stamp}", images, good(stamp), good(stamp)))
    for _ in range(100):
        s = stamps()
        cases.append(
            pair(SEGMENTATION, "random header and data", images, random_image(rng, s), random_image(rng, s))
        )
    return cases


# Absurd camera_info: (description, edits of the left info, edits of the right info). An edit
# "p3" sets element 3 of P; any other name sets that field.
CAMERA_INFO_DEFECTS: list[tuple[str, dict[str, Any], dict[str, Any]]] = [
    ("fx 0", {"p0": 0.0}, {"p0": 0.0, "p3": 0.0}),
    ("fx negative", {"p0": -520.0}, {"p0": -520.0}),
    ("fx NaN", {"p0": math.nan}, {"p0": math.nan}),
    ("fy inf", {"p5": math.inf}, {"p5": math.inf}),
    ("cx NaN on the right", {}, {"p2": math.nan}),
    ("P all zero", {"p": [0.0] * 12}, {"p": [0.0] * 12}),
    ("P all zero on the right", {}, {"p": [0.0] * 12}),
    ("right Tx positive", {}, {"p3": 2.6}),
    ("right Tx 0 (no baseline)", {}, {"p3": 0.0}),
    ("right Tx NaN", {}, {"p3": math.nan}),
    ("left Tx non-zero", {"p3": -2.6}, {}),
    ("right Ty non-zero", {}, {"p7": 1.0}),
    ("left and right fx differ", {}, {"p0": 530.0}),
    ("width 0", {"width": 0}, {"width": 0}),
    ("height 0", {"height": 0}, {"height": 0}),
    ("width 0 on the left", {"width": 0}, {}),
    ("left and right sizes differ", {}, {"width": 320, "height": 240}),
    ("huge width", {"width": UINT32_MAX}, {"width": UINT32_MAX}),
    ("distortion present", {"d": [0.1, -0.2, 0.001, 0.002, 0.05]}, {"d": [0.1, -0.2, 0.001, 0.002, 0.05]}),
    (
        "rational_polynomial, NaN",
        {"distortion_model": "rational_polynomial", "d": [math.nan] * 8},
        {"d": [math.nan]},
    ),
    ("K and R all zero", {"k": [0.0] * 9, "r": [0.0] * 9}, {"k": [0.0] * 9, "r": [0.0] * 9}),
]


def camera_info_pair(
    sample: Sample, left_edits: dict[str, Any], right_edits: dict[str, Any], stamp: Stamp
) -> list[Send]:
    """Copies of the sample's camera_info with these edits, and a spin for the nodes to take them."""
    sends = []
    for topic, info, edits in (
        (topics.LEFT_CAMERA_INFO, sample.left_info, left_edits),
        (topics.RIGHT_CAMERA_INFO, sample.right_info, right_edits),
    ):
        info = restamped(info, stamp)
        for name, value in edits.items():
            if name[0] == "p" and name[1:].isdigit():
                p = list(info.p)
                p[int(name[1:])] = value
                info.p = p
            else:
                setattr(info, name, value)
        sends.append(Send(topic, info, bool(edits)))
    sends[-1].spin_after = 0.05
    return sends


def good_camera_info(sample: Sample, stamp: Stamp) -> list[Send]:
    return camera_info_pair(sample, {}, {}, stamp)


def ordering_cases(rng: np.random.Generator, stamps: Stamps, sample: Sample) -> list[Case]:
    """Malformed masks, camera_info and tip hints for ordering_node."""
    masks = (topics.LEFT_MASK, topics.RIGHT_MASK)
    w, h = sample.size
    truth_left, truth_right = sample.mask_array("left"), sample.mask_array("right")
    empty = np.zeros((h, w), np.uint8)

    def hint(s: Stamp) -> Send:  # the well-formed hint of that stamp, taken before its masks
        return Send(topics.TIP_HINT, restamped(sample.hint, s), False, 0.05)

    cases = []
    for what, bad in image_defects(rng, 64, 48, "mono8"):  # small: these fail before their pixels count
        s = stamps()
        cases.append(pair(ORDERING, f"left mask: {what}; right mask empty", masks, bad(s), mono8(empty, s)))
        s = stamps()
        cases.append(pair(ORDERING, f"right mask: {what}; left mask empty", masks, mono8(empty, s), bad(s)))
        s = stamps()
        cases.append(pair(ORDERING, f"both masks: {what}", masks, bad(s), bad(s)))
    low = (topics.LEFT_MASK_LOW, topics.RIGHT_MASK_LOW)
    for what, bad in image_defects(rng, w, h, "mono8"):  # bad low masks of good masks: left out
        s = stamps()
        sends = [hint(s), Send(low[0], bad(s)), Send(low[1], bad(s))]
        sends += [Send(masks[0], mono8(truth_left, s), False), Send(masks[1], mono8(truth_right, s), False)]
        cases.append(Case(ORDERING, f"both low masks: {what}; true masks", sends))
    for what, left, right in [
        ("low masks half size", np.zeros((h // 2, w // 2)), np.zeros((h // 2, w // 2))),
        ("low masks of left and right sizes", np.zeros((h, w)), np.zeros((h, w - 1))),
        ("uniform noise low masks", rng.integers(0, 256, (h, w)), rng.integers(0, 256, (h, w))),
        ("full low masks", np.full((h, w), 255), np.full((h, w), 255)),
    ]:
        s = stamps()
        sends = [hint(s), Send(low[0], mono8(left, s)), Send(low[1], mono8(right, s))]
        sends += [Send(masks[0], mono8(truth_left, s), False), Send(masks[1], mono8(truth_right, s), False)]
        cases.append(Case(ORDERING, f"{what}; true masks", sends))
    for _ in range(10):
        s = stamps()
        cases.append(
            pair(ORDERING, "low masks only, random", low, random_image(rng, s), random_image(rng, s))
        )
        s = stamps()
        cases.append(
            pair(ORDERING, "low masks only, true", low, mono8(truth_left, s), mono8(truth_right, s + 1))
        )
    for encoding in ("rgb8", "bgr8"):
        s = stamps()
        rgb = np.repeat(truth_left[..., None], 3, axis=2).tobytes()
        cases.append(
            pair(
                ORDERING,
                f"masks in {encoding}",
                masks,
                image(w, h, encoding, rgb, s),
                image(w, h, encoding, rgb, s),
            )
        )
    for (lw, lh), (rw, rh) in [
        ((w, h), (w // 2, h // 2)),
        ((w // 2, h // 2), (w, h)),
        ((w // 2, h // 2), (w // 2, h // 2)),
        ((1, 1), (1, 1)),
        ((w, h - 1), (w, h)),
    ]:
        s = stamps()
        what = f"masks {lw}x{lh} and {rw}x{rh} (camera {w}x{h})"
        cases.append(pair(ORDERING, what, masks, mono8(np.zeros((lh, lw)), s), mono8(np.zeros((rh, rw)), s)))
    for what, left, right in [
        ("masks of 0 and 1", truth_left > 0, truth_right > 0),
        ("masks of 0 and 254", np.where(truth_left > 0, 254, 0), np.where(truth_right > 0, 254, 0)),
        ("thread at 128", np.where(truth_left > 0, 128, 0), np.where(truth_right > 0, 128, 0)),
        ("masks all 1", np.ones((h, w)), np.ones((h, w))),
        ("masks all 128", np.full((h, w), 128), np.full((h, w), 128)),
        ("uniform noise 0..255", rng.integers(0, 256, (h, w)), rng.integers(0, 256, (h, w))),
        ("empty masks", empty, empty),
        ("empty left mask", empty, truth_right),
        ("empty right mask", truth_left, empty),
        ("full masks", np.full((h, w), 255), np.full((h, w), 255)),
    ]:
        s = stamps()
        cases.append(
            Case(ORDERING, what, [hint(s), Send(masks[0], mono8(left, s)), Send(masks[1], mono8(right, s))])
        )
    for _ in range(3):
        s = stamps()
        cases.append(Case(ORDERING, "left mask only", [hint(s), Send(masks[0], mono8(truth_left, s))]))
        s = stamps()
        cases.append(Case(ORDERING, "right mask only", [hint(s), Send(masks[1], mono8(truth_right, s))]))
        s = stamps()
        cases.append(
            pair(ORDERING, "masks 1 ns apart", masks, mono8(truth_left, s), mono8(truth_right, s + 1))
        )
    for stamp in (STAMP_ZERO, FAR_FUTURE):
        cases.append(
            pair(ORDERING, f"empty masks stamped {stamp}", masks, mono8(empty, stamp), mono8(empty, stamp))
        )
    for _ in range(40):
        s = stamps()
        cases.append(
            pair(ORDERING, "random header and data", masks, random_image(rng, s), random_image(rng, s))
        )
    for what, left_edits, right_edits in CAMERA_INFO_DEFECTS:  # then empty masks: the camera is checked first
        s = stamps()
        sends = [
            *camera_info_pair(sample, left_edits, right_edits, s),
            Send(masks[0], mono8(empty, s)),
            Send(masks[1], mono8(empty, s)),
        ]
        cases.append(Case(ORDERING, f"camera_info: {what}", sends))
    nan, inf = math.nan, math.inf
    for u, v, frame in [
        (-1.0, 10.0, LEFT_FRAME), (w, 10.0, LEFT_FRAME), (w + 0.5, h - 1.0, LEFT_FRAME),
        (10.0, -0.5, LEFT_FRAME),
        (10.0, h, LEFT_FRAME), (1e9, 1e9, LEFT_FRAME), (-1e12, 5.0, LEFT_FRAME), (nan, 10.0, LEFT_FRAME),
        (10.0, nan, LEFT_FRAME), (nan, nan, LEFT_FRAME), (inf, 0.0, LEFT_FRAME), (-inf, 0.0, LEFT_FRAME),
        (0.0, inf, LEFT_FRAME), (-5.0, 5.0, RIGHT_FRAME),
    ]:  # fmt: skip
        s = stamps()
        sends = [
            *good_camera_info(sample, s),
            Send(topics.TIP_HINT, point(u, v, s, frame), True, 0.05),
            Send(masks[0], mono8(truth_left, s), False),
            Send(masks[1], mono8(truth_right, s), False),
        ]
        cases.append(Case(ORDERING, f"tip hint ({u}, {v}) in {frame}", sends))
    for stamp in (STAMP_ZERO, FAR_FUTURE):
        cases.append(
            Case(ORDERING, f"tip hint NaN stamped {stamp}", [Send(topics.TIP_HINT, point(nan, 1.0, stamp))])
        )
    return cases


def reconstruction_cases(rng: np.random.Generator, stamps: Stamps, sample: Sample) -> list[Case]:
    """Malformed sequences and camera_info for reconstruction_node."""
    sequences = (topics.LEFT_SEQUENCE, topics.RIGHT_SEQUENCE)
    left, right = polygon_points(sample.left_sequence), polygon_points(sample.right_sequence)
    w, h = sample.size
    cases = []

    def add(what: str, a: np.ndarray, b: np.ndarray, s: Stamp | None = None) -> None:
        s = stamps() if s is None else s
        cases.append(pair(RECONSTRUCTION, what, sequences, polygon(a, s), polygon(b, s)))

    for n in (0, 1, 2, 3, 7):
        add(f"{n} points", left[:n], right[:n])
    add("0 points on the left", left[:0], right)
    add("0 points on the right", left, right[:0])
    add("2 points on the left", left[:2], right)
    add("10 points on the right", left, right[:10])
    add("outside the image: u + 1000", left + np.array([1000, 0, 0]), right + np.array([1000, 0, 0]))
    add("outside the image: v - 1000", left - (0, 1000, 0), right - (0, 1000, 0))
    add("outside the image: every point at (-5, -5)", np.full_like(left, -5.0), np.full_like(right, -5.0))
    add("outside the image: every point at 1e30", np.full_like(left, 1e30), np.full_like(right, 1e30))
    add("one point 50 times", np.tile(left[:1], (50, 1)), np.tile(right[:1], (50, 1)))
    add("every point three times", np.repeat(left, 3, axis=0), np.repeat(right, 3, axis=0))
    add("left and right swapped", right, left)
    add("z = 5", left + np.array([0, 0, 5]), right + np.array([0, 0, 5]))
    for what, value in (("NaN", math.nan), ("inf", math.inf), ("-inf", -math.inf)):
        for axis in range(3):
            bad_left, bad_right = left.copy(), right.copy()
            bad_left[int(rng.integers(0, len(left))), axis] = value
            bad_right[int(rng.integers(0, len(right))), axis] = value
            add(f"{what} in {'xyz'[axis]} on the left", bad_left, right)
            add(f"{what} in {'xyz'[axis]} on the right", left, bad_right)
    add("all NaN", np.full_like(left, math.nan), np.full_like(right, math.nan))
    dense = np.linspace(0, 1, 100_000)
    add(
        "100k points along the thread",
        np.column_stack([np.interp(dense, np.linspace(0, 1, len(left)), left[:, i]) for i in range(3)]),
        np.column_stack([np.interp(dense, np.linspace(0, 1, len(right)), right[:, i]) for i in range(3)]),
    )
    for _ in range(3):
        cases.append(
            Case(RECONSTRUCTION, "left sequence only", [Send(sequences[0], polygon(left, stamps()))])
        )
        cases.append(
            Case(RECONSTRUCTION, "right sequence only", [Send(sequences[1], polygon(right, stamps()))])
        )
        s = stamps()
        cases.append(
            pair(RECONSTRUCTION, "sequences 1 ns apart", sequences, polygon(left, s), polygon(right, s + 1))
        )
    add("2 points stamped 0", left[:2], right[:2], STAMP_ZERO)
    add("0 points stamped far in the future", left[:0], right[:0], FAR_FUTURE)
    for _ in range(60):
        n = int(rng.integers(0, 40))
        walk = np.cumsum(rng.normal(0, 8, (n, 2)), axis=0) + rng.uniform((-50, -50), (w + 50, h + 50))
        add("random polyline", walk, walk + np.column_stack([rng.uniform(-80, 80, n), rng.normal(0, 2, n)]))
    for what, left_edits, right_edits in CAMERA_INFO_DEFECTS:  # then the true sequences
        s = stamps()
        sends = [
            *camera_info_pair(sample, left_edits, right_edits, s),
            Send(sequences[0], polygon(left, s), False),
            Send(sequences[1], polygon(right, s), False),
        ]
        cases.append(Case(RECONSTRUCTION, f"camera_info: {what}", sends))
    return cases


def executor_cases(rng: np.random.Generator, stamps: Stamps, sample: Sample) -> list[Case]:
    """Malformed grasp poses and paths for executor_node; it must refuse every one of these poses."""
    p = sample.grasp_pose.pose.position
    o = sample.grasp_pose.pose.orientation
    position, quaternion = (p.x, p.y, p.z), (o.x, o.y, o.z, o.w)
    nan, inf = math.nan, math.inf

    def at(index: int, value: float, values: tuple[float, ...]) -> tuple[float, ...]:
        return tuple(value if i == index else v for i, v in enumerate(values))

    pose_defects: list[tuple[str, tuple[float, ...], tuple[float, ...], str]] = [
        ("x NaN", at(0, nan, position), quaternion, LEFT_FRAME),
        ("y NaN", at(1, nan, position), quaternion, LEFT_FRAME),
        ("z NaN", at(2, nan, position), quaternion, LEFT_FRAME),
        ("z inf", at(2, inf, position), quaternion, LEFT_FRAME),
        ("x -inf", at(0, -inf, position), quaternion, LEFT_FRAME),
        ("quaternion NaN", position, at(0, nan, quaternion), LEFT_FRAME),
        ("quaternion inf", position, at(1, inf, quaternion), LEFT_FRAME),
        ("zero quaternion", position, (0.0, 0.0, 0.0, 0.0), LEFT_FRAME),
        ("quaternion of norm 2", position, tuple(2 * q for q in quaternion), LEFT_FRAME),
        ("quaternion (1, 1, 1, 1)", position, (1.0, 1.0, 1.0, 1.0), LEFT_FRAME),
        ("quaternion of norm 0.5", position, tuple(0.5 * q for q in quaternion), LEFT_FRAME),
        ("quaternion of norm 1e-12", position, (0.0, 0.0, 0.0, 1e-12), LEFT_FRAME),
        ("frame_id ''", position, quaternion, ""),
        ("frame_id 'base'", position, quaternion, "base"),
        ("frame_id 'world'", position, quaternion, "world"),
        ("frame_id of the right camera", position, quaternion, RIGHT_FRAME),
        ("frame_id with a trailing space", position, quaternion, LEFT_FRAME + " "),
        ("frame_id in capitals", position, quaternion, LEFT_FRAME.upper()),
    ]
    cases = []
    for what, xyz, xyzw, frame in pose_defects:
        for stamp in (stamps(), STAMP_ZERO, POSE_FAR_FUTURE):
            cases.append(
                Case(
                    EXECUTOR,
                    f"grasp pose: {what}, stamp {stamp}",
                    [Send(topics.GRASP_POSE, pose(xyz, xyzw, stamp, frame))],
                )
            )
    for _ in range(100):  # one to three defects in random fields
        xyz, xyzw, frame = list(position), list(quaternion), LEFT_FRAME
        for defect in rng.choice(["position", "quaternion", "frame", "zero"], size=int(rng.integers(1, 4))):
            if defect == "position":
                xyz[int(rng.integers(0, 3))] = float(rng.choice([nan, inf, -inf]))
            elif defect == "quaternion":
                xyzw[int(rng.integers(0, 4))] = float(rng.choice([nan, inf, 3.0, -7.5]))
            elif defect == "frame":
                frame = str(rng.choice(["", "base", "map", RIGHT_FRAME, "left_camera"]))
            else:
                xyzw = [0.0, 0.0, 0.0, 0.0]
        cases.append(
            Case(
                EXECUTOR,
                "grasp pose: random defects",
                [Send(topics.GRASP_POSE, pose(xyz, xyzw, stamps(), frame))],
            )
        )
    for stamp in (NEGATIVE, NANOSEC_OVERFLOW):
        cases.append(
            Case(
                EXECUTOR,
                f"grasp pose stamped {stamp}",
                [Send(topics.GRASP_POSE, pose(position, quaternion, stamp))],
            )
        )
    points = np.array([(q.pose.position.x, q.pose.position.y, q.pose.position.z) for q in sample.path.poses])
    path_defects: list[tuple[str, np.ndarray, str]] = [
        ("no poses", points[:0], LEFT_FRAME),
        ("one pose", points[:1], LEFT_FRAME),
        ("NaN position", np.where(np.arange(len(points))[:, None] == 3, nan, points), LEFT_FRAME),
        ("inf position", np.where(np.arange(len(points))[:, None] == 0, inf, points), LEFT_FRAME),
        ("all NaN", np.full_like(points, nan), LEFT_FRAME),
        ("frame_id ''", points, ""),
        ("frame_id 'base'", points, "base"),
        ("frame_id 'world'", points, "world"),
        ("frame_id of the right camera", points, RIGHT_FRAME),
        ("20000 NaN poses", np.full((20_000, 3), nan), LEFT_FRAME),
    ]
    for what, xyz, frame in path_defects:
        for stamp in (stamps(), STAMP_ZERO, FAR_FUTURE):
            cases.append(
                Case(EXECUTOR, f"path: {what}, stamp {stamp}", [Send(topics.PATH, path(xyz, stamp, frame))])
            )
    for _ in range(30):  # a random part of the path with a NaN or inf, or in another frame
        xyz = points[: int(rng.integers(0, len(points)))].copy()
        if len(xyz) and rng.random() < 0.5:
            xyz[int(rng.integers(0, len(xyz))), int(rng.integers(0, 3))] = float(rng.choice([nan, inf, -inf]))
            frame = LEFT_FRAME
        else:
            frame = str(rng.choice(["", "base", LEFT_FRAME + "_", "map"]))
        cases.append(Case(EXECUTOR, "path: random defects", [Send(topics.PATH, path(xyz, stamps(), frame))]))
    return cases


def last_cases(rng: np.random.Generator, stamps: Stamps, sample: Sample) -> list[Case]:
    """Inputs that are well-formed but for their stamp, or costly: sent last, each in its own burst.

    A stamp before the epoch or past builtin_interfaces/Time's range (the node may process the
    input and then fail to stamp its output), a speckled mask pair (random 0/255 pixels) and
    100k points scattered over the image as a sequence. By the time a node meets these it has
    met everything else.
    """
    cases = []
    for stamp in (NEGATIVE, NANOSEC_OVERFLOW):
        left, right = (
            image(64, 48, "rgb8", _bytes(rng, 64 * 48 * 3), stamp),
            image(64, 48, "rgb8", _bytes(rng, 64 * 48 * 3), stamp),
        )
        cases.append(
            Case(
                SEGMENTATION,
                f"well-formed images stamped {stamp}",
                [Send(topics.LEFT_IMAGE, left), Send(topics.RIGHT_IMAGE, right)],
            )
        )
        sends = [
            *good_camera_info(sample, stamps()),
            Send(topics.TIP_HINT, restamped(sample.hint, stamp), True, 0.05),
            Send(topics.LEFT_MASK, restamped(sample.left_mask, stamp)),
            Send(topics.RIGHT_MASK, restamped(sample.right_mask, stamp)),
        ]
        cases.append(Case(ORDERING, f"true masks stamped {stamp}", sends))
        sends = [
            *good_camera_info(sample, stamps()),
            Send(topics.LEFT_SEQUENCE, restamped(sample.left_sequence, stamp)),
            Send(topics.RIGHT_SEQUENCE, restamped(sample.right_sequence, stamp)),
        ]
        cases.append(Case(RECONSTRUCTION, f"true sequences stamped {stamp}", sends))
    s = stamps()
    w, h = sample.size
    speckle = [np.where(rng.random((h, w)) < 0.5, 255, 0) for _ in range(2)]
    sends = [
        Send(topics.TIP_HINT, restamped(sample.hint, s), False, 0.05),
        Send(topics.LEFT_MASK, mono8(speckle[0], s)),
        Send(topics.RIGHT_MASK, mono8(speckle[1], s)),
    ]
    cases.append(Case(ORDERING, "speckle masks (random 0/255 pixels)", sends))
    s = stamps()
    scatter = rng.uniform((0, 0), (w, h), (100_000, 2))
    sends = [
        Send(topics.LEFT_SEQUENCE, polygon(scatter, s)),
        Send(topics.RIGHT_SEQUENCE, polygon(scatter - (20, 0), s)),
    ]
    cases.append(Case(RECONSTRUCTION, "100k points scattered over the image", sends))
    return cases


# --------------------------------------------------------------------------- bursts and barriers


BARRIER_REPLY = {
    SEGMENTATION: topics.LEFT_MASK,
    ORDERING: topics.LEFT_SEQUENCE,
    RECONSTRUCTION: topics.GRASP_POSE,
    EXECUTOR: topics.TARGET_POSE,
}
"""Where a node's answer to a barrier appears, with the barrier's stamp."""


def barrier(node: str, stamp: int, sample: Sample, rng: np.random.Generator) -> list[Send]:
    """A well-formed input of ``node`` that it answers on BARRIER_REPLY[node]."""
    if node == SEGMENTATION:
        return [
            Send(topics.LEFT_IMAGE, image(64, 48, "rgb8", _bytes(rng, 64 * 48 * 3), stamp), False),
            Send(topics.RIGHT_IMAGE, image(64, 48, "rgb8", _bytes(rng, 64 * 48 * 3), stamp), False),
        ]
    if node == ORDERING:
        return [
            *good_camera_info(sample, stamp),
            Send(topics.TIP_HINT, restamped(sample.hint, stamp), False, 0.05),
            Send(topics.LEFT_MASK, restamped(sample.left_mask, stamp), False),
            Send(topics.RIGHT_MASK, restamped(sample.right_mask, stamp), False),
        ]
    if node == RECONSTRUCTION:
        return [
            *good_camera_info(sample, stamp),
            Send(topics.LEFT_SEQUENCE, restamped(sample.left_sequence, stamp), False),
            Send(topics.RIGHT_SEQUENCE, restamped(sample.right_sequence, stamp), False),
        ]
    return [Send(topics.GRASP_POSE, restamped(sample.grasp_pose, stamp), False)]


def bursts(cases: list[Case]) -> Iterator[list[Case]]:
    """Runs of cases of one node with at most BURST_PER_TOPIC messages on any topic."""
    burst: list[Case] = []
    load: Counter[str] = Counter()
    for case in cases:
        need = Counter(send.topic for send in case.sends)
        if burst and (
            case.node != burst[0].node or any(load[t] + n > BURST_PER_TOPIC for t, n in need.items())
        ):
            yield burst
            burst, load = [], Counter()
        burst.append(case)
        load.update(need)
    if burst:
        yield burst


@dataclass
class Fuzzer:
    """Sends the cases burst by burst, each burst followed by a barrier; records what went wrong."""

    pipeline: Any  # node_processes.Pipeline
    driver: Any  # node_processes.Driver
    sample: Sample
    rng: np.random.Generator = field(default_factory=lambda: np.random.default_rng(SEED + 1))
    malformed: Counter[tuple[str, str]] = field(default_factory=Counter)
    """Malformed messages sent, by (node, topic)."""
    seconds: Counter[str] = field(default_factory=Counter)
    """Time spent on each node's bursts and barriers."""
    carriers: int = 0
    barriers: int = 0
    malformed_pose_stamps: set[int] = field(default_factory=set)
    sent_pose_stamps: set[int] = field(default_factory=set)
    """Stamps of every grasp pose this test published itself."""
    barrier_stamps: set[int] = field(default_factory=set)
    problems: list[str] = field(default_factory=list)
    _stamps: Stamps = field(default_factory=lambda: Stamps(BARRIER_BASE_NS))

    def send(self, node: str, sends: list[Send]) -> None:
        for item in sends:
            self.driver.publish(item.topic, item.message)
            if item.topic == topics.GRASP_POSE:
                stamp = harness.raw_stamp_ns(item.message.header.stamp)
                self.sent_pose_stamps.add(stamp)
                if item.malformed:
                    self.malformed_pose_stamps.add(stamp)
            if item.malformed:
                self.malformed[(node, item.topic)] += 1
            else:
                self.carriers += 1
            if item.spin_after:
                self.driver.spin(item.spin_after)

    def run(self, cases: list[Case]) -> None:
        for burst in bursts(cases):
            began = time.monotonic()
            for case in burst:
                self.send(case.node, case.sends)
            self.drain(burst[0].node, [case.what for case in burst])
            self.seconds[burst[0].node] += time.monotonic() - began

    def drain(self, node: str, after: list[str]) -> bool:
        """Barriers to ``node`` until one is answered; a node that died or stalled is logged and restarted."""
        process, reply = self.pipeline[node], BARRIER_REPLY[node]
        sent: set[int] = set()
        began = time.monotonic()
        while time.monotonic() - began < BARRIER_TIMEOUT_S and process.alive():
            stamp = self._stamps()
            sent.add(stamp)
            self.barrier_stamps.add(stamp)
            self.barriers += 1
            for item in barrier(node, stamp, self.sample, self.rng):
                self.driver.publish(item.topic, item.message)
                self.driver.spin(item.spin_after)
                if item.topic == topics.GRASP_POSE:
                    self.sent_pose_stamps.add(stamp)

            def answered() -> bool:
                return bool(sent & self.driver.stamps(reply)) or not process.alive()

            if self.driver.spin_until(answered, BARRIER_RESEND_S) and process.alive():
                return True
        inputs = "; ".join(after)
        if process.alive():
            self.problems.append(
                f"{node} stopped serving: no answer on {reply} to well-formed input for "
                f"{BARRIER_TIMEOUT_S:.0f} s after: {inputs}\n{node} log tail:\n{process.log_tail(15)}"
            )
            process.kill()
        else:
            self.problems.append(
                f"{node} died (exit status {process.returncode}) on one of: {inputs}\n"
                f"{node} log tail:\n{process.log_tail(40)}"
            )
        process.start()  # so that the rest of the test runs and reports everything
        if not process.wait_started(START_TIMEOUT_S, lambda: self.driver.spin(0.1)):
            self.problems.append(f"{node} did not start again\n{process.log_tail(15)}")
        elif not self.reconnect():
            self.problems.append(f"after {node} was restarted, no frame went through the graph")
        return False

    def reconnect(self) -> bool:
        """Send a bags/sample frame (fresh stamps) until its target pose shows the graph is whole again."""
        frame = self.sample.frames[REFERENCE_FRAME]
        sent: set[int] = set()
        began = time.monotonic()
        while time.monotonic() - began < RECONNECT_TIMEOUT_S:
            stamp = self._stamps()
            sent.add(stamp)
            self.barrier_stamps.add(stamp)
            self.driver.publish_frame(frame, stamp)
            if self.driver.spin_until(lambda: bool(sent & self.driver.target_stamps()), 3.0):
                return True
        return False

    def summary(self) -> str:
        """Malformed messages by node and topic, and the time each node took."""
        lines = [
            f"malformed messages: {sum(self.malformed.values())} "
            f"({self.carriers} well-formed carriers, {self.barriers} barriers)"
        ]
        for node in harness.PIPELINE:
            mine = sorted((t, c) for (n, t), c in self.malformed.items() if n == node)
            lines.append(
                f"  {node}: {sum(c for _, c in mine)} in {self.seconds[node]:.1f} s: "
                + ", ".join(f"{t} {c}" for t, c in mine)
            )
        by_topic: Counter[str] = Counter()
        for (_, topic), count in self.malformed.items():
            by_topic[topic] += count
        lines.append("  by topic: " + ", ".join(f"{t} {c}" for t, c in sorted(by_topic.items())))
        return "\n".join(lines)


# --------------------------------------------------------------------------- the graph


@dataclass
class Graph:
    pipeline: Any  # node_processes.Pipeline
    driver: Any  # node_processes.Driver
    started_in_s: float


@pytest.fixture
def graph(tmp_path: Path, ros_domain_id: int) -> Iterator[Graph]:
    """The four nodes as processes and the test's driver node; all stopped however the test ends."""
    began = time.monotonic()
    # The bursts must reach the node: segmentation_node keeps only the newest image per camera
    # by default (queue_depth 1); the sensor-data depth of 5 queues a whole burst.
    queues = {"segmentation_node": ["-p", "queue_depth:=5"]}
    with harness.pipeline(tmp_path / "logs", ros_domain_id, ros_args=queues) as pipeline:
        driver = harness.Driver(ros_domain_id)
        try:
            expected = harness.graph_inputs()
            assert driver.wait_for_graph(expected, START_TIMEOUT_S), (
                f"the graph did not come up in {START_TIMEOUT_S:.0f} s: matched subscriptions "
                f"{ {t: driver.matched(t) for t in expected} }, expected {expected}{pipeline.report()}"
            )
            driver.spin(SETTLE_S)
            yield Graph(pipeline, driver, time.monotonic() - began)
        finally:
            driver.close()


# --------------------------------------------------------------------------- tests


WARNING_WORDS = {
    SEGMENTATION: ("encoding", "size"),
    ORDERING: ("tip hint", "camera_info"),
    RECONSTRUCTION: ("NaN", "camera_info"),
    EXECUTOR: (topics.GRASP_POSE, topics.PATH),
}
"""What each node's warnings name somewhere (warnings are throttled per problem, the executor's per topic)."""


@pytest.fixture
def malformed_cases(sample: Sample) -> list[Case]:
    """Every malformed case in the order sent (built before the nodes start)."""
    rng, stamps = np.random.default_rng(SEED), Stamps(FUZZ_BASE_NS)
    return [
        *executor_cases(rng, stamps, sample),
        *segmentation_cases(rng, stamps),
        *ordering_cases(rng, stamps, sample),
        *reconstruction_cases(rng, stamps, sample),
        *last_cases(rng, stamps, sample),
    ]


def test_nodes_survive_malformed_input_and_serve_the_next_frames(
    malformed_cases: list[Case], graph: Graph, sample: Sample
) -> None:
    driver, pipeline = graph.driver, graph.pipeline
    for topic in BARRIER_REPLY.values():
        driver.watch(topic)
    fuzzer = Fuzzer(pipeline, driver, sample)
    began = time.monotonic()
    for node in harness.PIPELINE:  # each node answers before the first malformed input
        if not fuzzer.drain(node, ["nothing yet: the graph has just started"]):
            pytest.fail("\n\n".join(fuzzer.problems) + pipeline.report())
    fuzzer.run(malformed_cases)
    fuzz_s = time.monotonic() - began
    problems = fuzzer.problems
    problems += [f"{name} is not running after the malformed input" for name in pipeline.dead()]

    began = time.monotonic()
    valid = {sample.frames[i].stamp_ns for i in VALID_FRAMES}
    for i in VALID_FRAMES:
        driver.publish_frame(sample.frames[i])
        driver.spin(1.0)
    driver.spin_until(
        lambda: valid <= driver.grasp_stamps() and valid <= driver.target_stamps(), GRASP_TIMEOUT_S
    )
    valid_s = time.monotonic() - began
    if missing := sorted(valid - driver.grasp_stamps()):
        problems.append(f"no {topics.GRASP_POSE} in {GRASP_TIMEOUT_S:.0f} s for the valid frames {missing}")
    elif missing := sorted(valid - driver.target_stamps()):
        problems.append(f"no {topics.TARGET_POSE} in {GRASP_TIMEOUT_S:.0f} s for the valid frames {missing}")

    targets = driver.target_stamps()
    if commanded := sorted(targets & fuzzer.malformed_pose_stamps):
        problems.append(f"executor_node published target poses for malformed grasp poses stamped {commanded}")
    made_by_pipeline = driver.grasp_stamps() - fuzzer.sent_pose_stamps
    if unexplained := sorted(targets - valid - fuzzer.barrier_stamps - made_by_pipeline):
        problems.append(f"target poses stamped {unexplained}: of no well-formed grasp pose")
    if reached := [r.message.data for r in driver.states if r.message.data.startswith(FORBIDDEN_STATES)]:
        problems.append(f"executor_node (dry_run, not armed) reached the states {reached}")

    for node in harness.PIPELINE:
        lines = pipeline[node].log_text().splitlines()
        warnings = [line for line in lines if "[WARN]" in line and "dropped" in line]
        if not warnings:
            problems.append(f"{node} logged no warning about dropped input")
        elif unnamed := [word for word in WARNING_WORDS[node] if not any(word in line for line in warnings)]:
            problems.append(f"{node}'s warnings never name {unnamed}")

    if (total := sum(fuzzer.malformed.values())) < MIN_MALFORMED:
        problems.append(f"only {total} malformed messages sent, fewer than {MIN_MALFORMED}")
    summary = (
        f"{fuzzer.summary()}\nstart {graph.started_in_s:.1f} s, malformed input {fuzz_s:.1f} s, "
        f"valid frames {valid_s:.1f} s"
    )
    print(summary)
    assert not problems, "\n\n".join(problems) + "\n\n" + summary + pipeline.report()


KILL_ORDER = (SEGMENTATION, ORDERING, RECONSTRUCTION, EXECUTOR)
UPSTREAM_OUTPUT = {
    ORDERING: topics.LEFT_MASK,
    RECONSTRUCTION: topics.LEFT_SEQUENCE,
    EXECUTOR: topics.GRASP_POSE,
}
"""What the nodes upstream of the killed one publish (the last of them): it must go on."""
PLAY_PERIOD_S = 0.7
"""One frame every 0.7 s: what segmentation_node keeps up with on two busy cores."""
RECOVERY_TIMEOUT_S = 30.0


def test_graph_recovers_when_each_node_is_killed_and_restarted(graph: Graph, sample: Sample) -> None:
    driver, pipeline = graph.driver, graph.pipeline
    outputs = {
        topics.LEFT_MASK: driver.watch(topics.LEFT_MASK),
        topics.RIGHT_MASK: driver.watch(topics.RIGHT_MASK),
        topics.LEFT_SEQUENCE: driver.watch(topics.LEFT_SEQUENCE),
        topics.RIGHT_SEQUENCE: driver.watch(topics.RIGHT_SEQUENCE),
        topics.GRASP_POSE: driver.grasp_poses,
        topics.TARGET_POSE: driver.target_poses,
    }
    player = driver.play(sample.frames, PLAY_PERIOD_S)
    timings = [f"start {graph.started_in_s:.1f} s"]

    def arrive(topic: str, since: float, count: int = 2) -> Callable[[], bool]:
        """Whether ``count`` frames published after ``since`` gave ``topic``."""
        return lambda: len({r.stamp_ns for r in outputs[topic]} & player.stamps_since(since)) >= count

    def context(since: float | None = None) -> str:
        """Timings, what each stage published for the frames played since ``since``, log tails."""
        lines = list(timings)
        if since is not None:
            played = player.stamps_since(since)
            counts = {topic: len({r.stamp_ns for r in got} & played) for topic, got in outputs.items()}
            answered = ", ".join(f"{topic} {count}" for topic, count in counts.items())
            lines.append(f"frames played since: {len(played)}; of them published on {answered}")
        return "\n" + "\n".join(lines) + pipeline.report(15)

    began = time.monotonic()
    assert driver.spin_until(arrive(topics.TARGET_POSE, began), RECOVERY_TIMEOUT_S), (
        f"no grasp and target poses for the frames played{context(began)}"
    )
    timings.append(f"first target poses {time.monotonic() - began:.1f} s after the first frame")

    for node in KILL_ORDER:
        process, others = pipeline[node], [name for name in KILL_ORDER if name != node]
        killed_at = time.monotonic()
        assert (status := process.kill()) == -9, f"{node} exited with {status}, not by SIGKILL{context()}"
        if topic := UPSTREAM_OUTPUT.get(node):  # the nodes upstream of the dead one go on working
            assert driver.spin_until(arrive(topic, killed_at), RECOVERY_TIMEOUT_S), (
                f"no {topic} for new frames while {node} was down{context(killed_at)}"
            )
        else:
            driver.spin(2 * PLAY_PERIOD_S)
        assert not (dead := [name for name in others if not pipeline[name].alive()]), (
            f"{dead} ended while {node} was down{context()}"
        )

        process.start()
        restarted_at = time.monotonic()
        assert process.wait_started(START_TIMEOUT_S, lambda: driver.spin(0.1)), (
            f"{node} did not start again{context()}"
        )
        for topic in (topics.GRASP_POSE, topics.TARGET_POSE):
            assert driver.spin_until(arrive(topic, restarted_at), RECOVERY_TIMEOUT_S), (
                f"no {topic} for new frames after {node} was restarted{context(restarted_at)}"
            )
        timings.append(
            f"{node}: killed, restarted {restarted_at - killed_at:.1f} s later, "
            f"poses again after {time.monotonic() - restarted_at:.1f} s"
        )
        assert not (dead := pipeline.dead()), f"{dead} ended after {node} was restarted{context()}"

    player.stop()
    played = player.stamps_since(began)
    answered = {r.stamp_ns for r in driver.target_poses} & played
    timings.append(f"{len(played)} frames played, {len(answered)} target poses")
    print("\n".join(timings))
