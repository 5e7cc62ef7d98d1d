"""ordering_node: thread masks in, ordered centreline sequences out, through :func:`order_stereo`.

Subscribes ``/suture/{left,right}/mask`` (sensor_msgs/Image mono8, sensor-data QoS),
``/suture/tip_hint`` (geometry_msgs/PointStamped, optional, matched by stamp as below) and
``/stereo/{left,right}/camera_info``; pairs the masks by exact ``header.stamp``
(:class:`suture_common.stamp_buffer.StampPairBuffer`) and publishes
``/suture/{left,right}/sequence`` (geometry_msgs/PolygonStamped, x = u, y = v, z = 0,
header = that mask's header, reliable QoS) for each pair.

With ``use_low_masks`` (default true) it also subscribes ``/suture/{left,right}/mask_low``
(segmentation_node's low masks, the same format) and gives the pair of the masks' stamp to
:func:`order_stereo`, which takes their sequences where they reach farther. segmentation_node
publishes the low masks just before the masks; once low masks have been seen, a mask pair whose
low masks have not arrived waits for them up to ``low_mask_wait`` seconds (default 0.1), or until
the next mask pair is complete, then is ordered without them (``without_low_masks`` counts
those). Until then (a segmenter that publishes no low masks) every pair is ordered at once from
the masks alone. Low masks that do not fit their masks (encoding, size) are left out with a
throttled warning.

Parameters: every field of :class:`suture_ordering.OrderingParams` under its own name
(pixel lengths for a 640 px wide image, scaled with the mask width;
``reference_width_px`` 0 means "use the pixel values unscaled"; the ε ranges as
``[low, high]``), plus ``use_low_masks`` and ``low_mask_wait`` (above), ``max_pending`` (unmatched
masks kept per side, and pairs held for camera_info, default 10) and
``hint_max_age`` (s; a tip hint older than this relative to the masks is ignored, 0 =
any age, default 0). They are read at start-up.

Tip hints are kept by stamp (the last :data:`HINTS_KEPT`): masks use the hint with their own
stamp, else the newest hint not newer than them (a hint clicked once serves the frames
after it), else none (the automatic tip). Taking simply the latest hint went wrong whenever
segmentation lags behind a stream: the hint of a newer frame was applied to older masks.

Mask pairs that arrive before camera_info of both views (a camera driver started after the
graph, or camera_info lost during discovery) are held, the newest ``max_pending``, and ordered
when it arrives. A malformed input (wrong encoding, size mismatch, unusable camera_info, empty
mask, tip hint outside the image or NaN, a thread without free end...) drops that frame with
one throttled warning naming the problem; the node keeps serving.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from collections import OrderedDict, deque
from typing import Any

import cv2
import numpy as np
from geometry_msgs.msg import PointStamped, PolygonStamped
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image

from suture_common.camera import CameraModelError, StereoCamera
from suture_common.messages import MessageConversionError, image_to_array, polygon_message
from suture_common.ros import (
    RELIABLE_QOS,
    SENSOR_DATA_QOS,
    ThrottledWarnings,
    run_node,
    serialized,
    stamp_or_drop,
)
from suture_common.stamp_buffer import StampedPairs, StampPairBuffer
from suture_common.topics import (
    LEFT_CAMERA_INFO,
    LEFT_MASK,
    LEFT_MASK_LOW,
    LEFT_SEQUENCE,
    RIGHT_CAMERA_INFO,
    RIGHT_MASK,
    RIGHT_MASK_LOW,
    RIGHT_SEQUENCE,
    TIP_HINT,
)
from suture_ordering.core import order_stereo
from suture_ordering.errors import OrderingError
from suture_ordering.params import OrderingParams

NODE_NAME = "ordering_node"
WARN_PERIOD_S = 2.0
HINTS_KEPT = 100

NODE_DEFAULTS: dict[str, Any] = {
    "max_pending": 10,
    "hint_max_age": 0.0,
    "use_low_masks": True,
    "low_mask_wait": 0.1,
}

MaskPair = tuple[Image, Image]


def _parameter_defaults() -> dict[str, Any]:
    """ROS parameter names and defaults: OrderingParams fields (tuples as lists, None as 0.0)."""
    defaults: dict[str, Any] = {}
    for field in dataclasses.fields(OrderingParams):
        value = field.default
        if isinstance(value, tuple):
            value = [float(x) for x in value]
        elif value is None:
            value = 0.0
        elif isinstance(value, float):
            value = float(value)
        defaults[field.name] = value
    return {**defaults, **NODE_DEFAULTS}


def params_from_values(values: dict[str, Any]) -> OrderingParams:
    """OrderingParams from ROS parameter values (see :func:`_parameter_defaults`)."""
    kwargs: dict[str, Any] = {}
    for field in dataclasses.fields(OrderingParams):
        value = values[field.name]
        if isinstance(field.default, tuple):
            value = tuple(float(x) for x in value)
        elif field.name == "reference_width_px":
            value = None if float(value) <= 0 else float(value)
        elif isinstance(field.default, bool):
            value = bool(value)
        elif isinstance(field.default, int):
            value = int(value)
        else:
            value = float(value)
        kwargs[field.name] = value
    return OrderingParams(**kwargs)


class OrderingNode(Node):
    """Thin adapter between ROS topics and :func:`suture_ordering.order_stereo`."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        for name, default in _parameter_defaults().items():
            self.declare_parameter(name, default)
        values = {name: self.get_parameter(name).value for name in _parameter_defaults()}
        self.params = params_from_values(values)  # raises ValueError on a bad value
        self.hint_max_age_ns = int(float(values["hint_max_age"]) * 1e9)
        self.pairer: StampPairBuffer[Image] = StampPairBuffer(int(values["max_pending"]))
        self._waiting: deque[tuple[int, Image, Image, MaskPair | None]] = deque(
            maxlen=int(values["max_pending"])
        )
        """Mask pairs (with their low masks) that arrived before camera_info of both views."""
        self.use_low_masks = bool(values["use_low_masks"])
        self._low_mask_pairs: StampedPairs[Image] = StampedPairs(int(values["max_pending"]))
        """Low mask pairs by stamp, waiting for their masks (the newest ``max_pending``)."""
        self._awaiting_low: OrderedDict[int, tuple[MaskPair, float]] = OrderedDict()
        """Mask pairs waiting for their low masks, with the monotonic time they wait until."""
        self.low_mask_wait_s = float(values["low_mask_wait"])
        if not self.low_mask_wait_s >= 0:
            raise ValueError(f"low_mask_wait must be >= 0 s, got {self.low_mask_wait_s}")
        self.low_masks_seen = False
        self.without_low_masks = 0
        """Mask pairs ordered without their low masks after low masks had been seen."""
        self._camera_info: dict[str, CameraInfo] = {}
        self._camera: StereoCamera | None = None
        self._hints: dict[int, PointStamped] = {}  # by stamp (ns), insertion order
        self._warnings = ThrottledWarnings(self.get_logger(), WARN_PERIOD_S)
        self.dropped: dict[str, int] = self._warnings.counts
        """Mask pairs dropped, by problem."""
        self.frames_published = 0
        self._left_pub = self.create_publisher(PolygonStamped, LEFT_SEQUENCE, RELIABLE_QOS)
        self._right_pub = self.create_publisher(PolygonStamped, RIGHT_SEQUENCE, RELIABLE_QOS)
        self.create_subscription(Image, LEFT_MASK, lambda m: self._on_mask("left", m), SENSOR_DATA_QOS)
        self.create_subscription(Image, RIGHT_MASK, lambda m: self._on_mask("right", m), SENSOR_DATA_QOS)
        # Runs only while a pair waits for its low masks (reset then, cancelled when none waits).
        self._low_mask_timer = self.create_timer(max(self.low_mask_wait_s, 0.001), self._order_overdue)
        self._low_mask_timer.cancel()
        if self.use_low_masks:
            self.create_subscription(
                Image, LEFT_MASK_LOW, lambda m: self._on_low_mask("left", m), SENSOR_DATA_QOS
            )
            self.create_subscription(
                Image, RIGHT_MASK_LOW, lambda m: self._on_low_mask("right", m), SENSOR_DATA_QOS
            )
        self.create_subscription(PointStamped, TIP_HINT, self._on_hint, SENSOR_DATA_QOS)
        self.create_subscription(
            CameraInfo, LEFT_CAMERA_INFO, lambda m: self._on_camera_info("left", m), SENSOR_DATA_QOS
        )
        self.create_subscription(
            CameraInfo, RIGHT_CAMERA_INFO, lambda m: self._on_camera_info("right", m), SENSOR_DATA_QOS
        )
        self.get_logger().info(f"ordering {LEFT_MASK} and {RIGHT_MASK} from the cut tip")

    # ------------------------------------------------------------------ callbacks

    def _on_camera_info(self, side: str, message: CameraInfo) -> None:
        self._camera_info[side] = message
        self._camera = None  # rebuilt on the next frame
        while self._waiting and not self._missing_camera_info():
            self._process(*self._waiting.popleft())

    def _on_hint(self, message: PointStamped) -> None:
        stamp_ns = stamp_or_drop(message, self._warnings.warn, "tip hint")
        if stamp_ns is None:
            return
        self._hints[stamp_ns] = message
        if len(self._hints) > HINTS_KEPT:
            del self._hints[next(iter(self._hints))]

    def _paired(
        self, pairer: StampPairBuffer[Image] | StampedPairs[Image], side: str, message: Image, what: str
    ) -> tuple[int, MaskPair] | None:
        """The stamp and the (left, right) pair ``message`` completes, or None."""
        stamp_ns = stamp_or_drop(message, self._warnings.warn, f"{side} {what}")
        if stamp_ns is None:
            return None
        paired = pairer.add(side, stamp_ns, message)
        return None if paired is None else (stamp_ns, paired)

    def _on_mask(self, side: str, message: Image) -> None:
        completed = self._paired(self.pairer, side, message, "mask")
        if completed is None:
            return
        stamp_ns, paired = completed
        self._order_overdue(everything=True)  # a newer pair is complete: the older ones waited enough
        low = self._low_mask_pairs.take(stamp_ns)
        if low is not None or not self.low_masks_seen:
            self._process(stamp_ns, *paired, low)
            return
        self._awaiting_low[stamp_ns] = (paired, time.monotonic() + self.low_mask_wait_s)
        self._low_mask_timer.reset()

    def _order_overdue(self, everything: bool = False) -> None:
        """Order, without their low masks, the pairs that waited for them until now (or all)."""
        now = time.monotonic()
        while self._awaiting_low:
            stamp_ns, (paired, deadline) = next(iter(self._awaiting_low.items()))
            if not everything and deadline > now:
                return
            del self._awaiting_low[stamp_ns]
            self.without_low_masks += 1
            self._process(stamp_ns, *paired, None)
        self._low_mask_timer.cancel()

    def _on_low_mask(self, side: str, message: Image) -> None:
        completed = self._paired(self._low_mask_pairs, side, message, "low mask")
        if completed is None:
            return
        stamp_ns, _ = completed
        self.low_masks_seen = True
        waiting = self._awaiting_low.pop(stamp_ns, None)
        if waiting is not None:
            self._process(stamp_ns, *waiting[0], self._low_mask_pairs.take(stamp_ns))

    # ------------------------------------------------------------------ one stereo pair

    def _missing_camera_info(self) -> list[str]:
        return [side for side in ("left", "right") if side not in self._camera_info]

    def _stereo_camera(self) -> StereoCamera | None:
        if self._camera is None:
            try:
                self._camera = StereoCamera.from_camera_info(
                    self._camera_info["left"], self._camera_info["right"]
                )
            except CameraModelError as exc:
                self._warnings.warn("camera_info", f"dropped masks: unusable camera_info: {exc}")
                return None
        return self._camera

    def _tip_hint(self, stamp_ns: int) -> np.ndarray | None:
        earlier = [stamp for stamp in self._hints if stamp <= stamp_ns]
        if not earlier:
            return None
        hint_stamp = max(earlier)
        if self.hint_max_age_ns > 0 and stamp_ns - hint_stamp > self.hint_max_age_ns:
            return None
        point = self._hints[hint_stamp].point
        return np.array([point.x, point.y], dtype=np.float64)  # NaN is reported by order_stereo

    def _process(self, stamp_ns: int, left: Image, right: Image, low: MaskPair | None = None) -> None:
        missing = self._missing_camera_info()
        if missing:  # a camera driver may start after us: hold the newest pairs until it speaks
            self._waiting.append((stamp_ns, left, right, low))
            self._warnings.warn(
                "camera_info",
                f"holding masks: no {' or '.join(missing)} camera_info received yet "
                f"({LEFT_CAMERA_INFO}, {RIGHT_CAMERA_INFO}); the newest {self._waiting.maxlen} pairs "
                "are ordered when it arrives",
            )
            return
        camera = self._stereo_camera()
        if camera is None:
            return
        try:
            left_mask = image_to_array(left, expect="mono8")
            right_mask = image_to_array(right, expect="mono8")
        except MessageConversionError as exc:
            self._warnings.warn("mask", f"dropped masks at {stamp_ns} ns: {exc}")
            return
        low_masks = self._low_masks(stamp_ns, low, left_mask.shape)
        try:
            result = order_stereo(
                left_mask, right_mask, self._tip_hint(stamp_ns), camera, self.params, low_masks
            )
        except OrderingError as exc:
            self._warnings.warn(type(exc).__name__, f"dropped masks at {stamp_ns} ns: {exc}")
            return
        for publisher, points, header in (
            (self._left_pub, result.left, left.header),
            (self._right_pub, result.right, right.header),
        ):
            publisher.publish(serialized(polygon_message(points, stamp_ns, header.frame_id)))
        self.frames_published += 1

    def _low_masks(
        self, stamp_ns: int, low: MaskPair | None, shape: tuple[int, ...]
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """The low masks as arrays of the masks' ``shape``, or None (with a warning when unusable)."""
        if low is None:
            return None
        try:
            arrays = image_to_array(low[0], expect="mono8"), image_to_array(low[1], expect="mono8")
        except MessageConversionError as exc:
            problem = str(exc)
        else:
            if arrays[0].shape == arrays[1].shape == shape:
                return arrays
            problem = f"sizes {arrays[0].shape} and {arrays[1].shape}, masks {shape}"
        self._warnings.warn("low_mask", f"masks at {stamp_ns} ns ordered without their low masks: {problem}")
        return None


def main(args: list[str] | None = None) -> int:
    """``ros2 run suture_ordering ordering_node``: spin until Ctrl-C or shutdown."""
    # The ordering's OpenCV calls are small; a pool of OpenCV workers only spun beside them,
    # 13 % of a core in the node graph at 5 frames/s, taken from the other nodes.
    cv2.setNumThreads(1)
    return run_node(OrderingNode, NODE_NAME, args)


if __name__ == "__main__":
    sys.exit(main())
