# SPDX-License-Identifier: Apache-2.0
"""ordering_node: thread masks in, ordered centreline sequences out, through :func:`order_stereo`.

Subscribes ``/suture/{left,right}/mask`` (sensor_msgs/Image mono8, sensor-data QoS),
``/suture/tip_hint`` (geometry_msgs/PointStamped, optional, matched by stamp as below) and
``/stereo/{left,right}/camera_info``; pairs the masks by exact ``header.stamp``
(:class:`suture_common.stamp_buffer.StampPairBuffer`) and publishes
``/suture/{left,right}/sequence`` (geometry_msgs/PolygonStamped, header = that mask's header,
reliable QoS) for each pair: x = u, y = v from the cut tip, and z the not-seen flag, 0.0 for a
point seen in the mask (or, across a gap, in the low mask) and 1.0 for one the search
interpolated across a gap in it (e.g. under an instrument shaft lying across the thread;
``StereoOrdering.left_sequence``), so that the 3D stage takes depth there from the seen thread
on either side instead of matching it. A cut end that the mask lost (no thread within
``tip_radius_px`` of the hint, but a thread end pointing at it from at most ``tip_gap_max_px``)
starts the sequence at the hint with a straight stretch flagged 1.0; its depth is that of the
first point seen.

With ``use_low_masks`` (default true) it also subscribes ``/suture/{left,right}/mask_low``
(segmentation_node's low masks, the same format) and gives the pair of the masks' stamp to
:func:`order_stereo`, which takes their sequences where they reach farther or hold more of the
cut end (a hairpin's bend the mask lost: ``low_mask_tip_gain_px``). segmentation_node
publishes the low masks just before the masks; once low masks have been seen, a mask pair whose
low masks have not arrived waits for them up to ``low_mask_wait`` seconds, or until the next
mask pair is complete, then is ordered without them (``without_low_masks`` counts those). Until
then (a segmenter that publishes no low masks) every pair is ordered at once from the masks
alone. That timing is :class:`suture_ordering.schedule.MaskPairSchedule`; this module only
adapts messages to it. Low masks that do not fit their masks (encoding, size) are left out with
a throttled warning.

A sequence that turns at a crossing onto the other strand, where mask straight on shows its own
thread going on beyond a stretch the mask lost, is published cut at the crossing
(``strand_switch_turn``, :mod:`suture_ordering.strand_switch`): the 3D stage then refuses a
thread too short to grasp instead of grasping the other thread. So is a sequence that passes by
a loop the mask shows beside it, cut where the loop joins it (a loop that leaves the thread at a
small angle and comes back there counts too), where a loop that the mask broke off at its
crossing comes near it, or where a bridge across a stretch the mask lost starts that goes past
what is left of a loop (``skipped_loop_cut``,
:mod:`suture_ordering.skipped_loop`): a grasp beyond would lie the loop's arc too far along.

Parameters (read at start-up): :data:`PARAMETERS`, every field of
:class:`suture_ordering.OrderingParams` under its own name (pixel lengths for a 640 px wide
image, scaled with the mask width; ``reference_width_px`` 0 means "use the pixel values
unscaled"; the ε ranges as ``[low, high]``) and the node's own :data:`NODE_PARAMETERS`.

Tip hints are kept by stamp (the last :data:`HINTS_KEPT`): masks use the hint with their own
stamp, else the newest hint not newer than them (a hint clicked once serves the frames
after it), else none (the automatic tip). The latest hint alone would be wrong whenever
segmentation lags behind a stream: the hint of a newer frame would apply to older masks.

Mask pairs that arrive before camera_info of both views (a camera driver started after the
graph, or camera_info lost during discovery) are held, the newest ``max_pending``, and ordered
when it arrives (:class:`suture_common.camera.CameraInfoCache` keeps it). A malformed input
(wrong encoding, size mismatch, unusable camera_info, empty mask, tip hint outside the image
or NaN, a thread without free end...) drops that frame with one throttled warning naming the
problem; the node keeps serving. So does an ordering it cannot trust: mask pixels near either
view's cut tip, or in line with the thread beyond it, that the sequence does not explain (a hook or
loop the search skipped, or one whose arms the mask lost, ``UnexplainedTipError``, parameters
``tip_unexplained_radius_px`` and ``tip_unexplained_max_px``).
"""

from __future__ import annotations

import dataclasses
import sys
from typing import Any

import cv2
import numpy as np
from geometry_msgs.msg import PointStamped, PolygonStamped
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image

from suture_common.camera import CameraInfoCache, CameraModelError, StereoCamera
from suture_common.messages import MessageConversionError, image_to_array, polygon_message
from suture_common.parameters import ParameterSpec, dataclass_parameters, spec_table
from suture_common.ros import (
    RELIABLE_QOS,
    SENSOR_DATA_QOS,
    ThrottledWarnings,
    declare_parameters,
    run_node,
    serialized,
    stamp_or_drop,
)
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
from suture_ordering.schedule import MaskPairSchedule, ReadyPair

NODE_NAME = "ordering_node"
WARN_PERIOD_S = 2.0
HINTS_KEPT = 100

NODE_PARAMETERS = (
    ParameterSpec(
        "max_pending",
        10,
        "unmatched masks kept per side; also the mask pairs held while camera_info is missing",
        (1, 10_000),
    ),
    ParameterSpec(
        "hint_max_age",
        0.0,
        "a tip hint older than this relative to the masks is ignored (s; 0: any age)",
        (0.0, 86_400.0),
    ),
    ParameterSpec(
        "use_low_masks",
        True,
        "also order the low masks (/suture/*/mask_low) and take their sequences where they reach farther",
    ),
    ParameterSpec(
        "low_mask_wait",
        0.1,
        "seconds a mask pair waits for its low masks, once low masks have been seen",
        (0.0, 60.0),
    ),
)
"""The node's own parameters, beside those of OrderingParams."""


def _ros_default(field: dataclasses.Field[Any]) -> Any:
    """The parameter default of an OrderingParams field: tuples as lists, None as 0.0."""
    value = field.default
    if isinstance(value, tuple):
        return [float(x) for x in value]
    return 0.0 if value is None else value


PARAMETERS: dict[str, ParameterSpec] = spec_table(
    (*dataclass_parameters(OrderingParams, _ros_default), *NODE_PARAMETERS)
)
"""Every parameter of the node, by name."""

MaskPair = tuple[Image, Image]


def _parameter_defaults() -> dict[str, Any]:
    """ROS parameter names and defaults (see :data:`PARAMETERS`)."""
    return {name: spec.default for name, spec in PARAMETERS.items()}


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
        values = declare_parameters(self, PARAMETERS.values())
        self.params = params_from_values(values)  # raises ValueError on a bad value
        self.hint_max_age_ns = int(float(values["hint_max_age"]) * 1e9)
        self.use_low_masks = bool(values["use_low_masks"])
        self.schedule: MaskPairSchedule[Image] = MaskPairSchedule(
            int(values["max_pending"]), float(values["low_mask_wait"])
        )
        self._cameras = CameraInfoCache()
        self._hints: dict[int, PointStamped] = {}  # by stamp (ns), insertion order
        self._warnings = ThrottledWarnings(self.get_logger(), WARN_PERIOD_S)
        self.dropped: dict[str, int] = self._warnings.counts
        """Mask pairs dropped, by problem."""
        self._notes = ThrottledWarnings(self.get_logger(), WARN_PERIOD_S)  # published, with a caveat
        self.frames_cut = 0
        """Mask pairs published with a sequence cut (``StereoOrdering.cut``)."""
        self.frames_published = 0
        self._left_pub = self.create_publisher(PolygonStamped, LEFT_SEQUENCE, RELIABLE_QOS)
        self._right_pub = self.create_publisher(PolygonStamped, RIGHT_SEQUENCE, RELIABLE_QOS)
        self.create_subscription(Image, LEFT_MASK, lambda m: self._on_mask("left", m), SENSOR_DATA_QOS)
        self.create_subscription(Image, RIGHT_MASK, lambda m: self._on_mask("right", m), SENSOR_DATA_QOS)
        # Runs only while a pair waits for its low masks (see _arm_low_mask_timer).
        self._low_mask_timer = self.create_timer(1.0, self._order_overdue)
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

    @property
    def without_low_masks(self) -> int:
        """Mask pairs ordered without their low masks after low masks had been seen."""
        return self.schedule.without_low_masks

    @property
    def low_masks_seen(self) -> bool:
        return self.schedule.low_masks_seen

    # ------------------------------------------------------------------ callbacks

    def _on_camera_info(self, side: str, message: CameraInfo) -> None:
        self._cameras.update(side, message)
        if not self._cameras.missing():
            self._order(self.schedule.release_held())

    def _on_hint(self, message: PointStamped) -> None:
        stamp_ns = stamp_or_drop(message, self._warnings.warn, "tip hint")
        if stamp_ns is None:
            return
        self._hints[stamp_ns] = message
        if len(self._hints) > HINTS_KEPT:
            del self._hints[next(iter(self._hints))]

    def _on_mask(self, side: str, message: Image) -> None:
        stamp_ns = stamp_or_drop(message, self._warnings.warn, f"{side} mask")
        if stamp_ns is None:
            return
        self._order(self.schedule.add_mask(side, stamp_ns, message))
        self._arm_low_mask_timer()

    def _order_overdue(self) -> None:
        """Order, without their low masks, the pairs that waited for them long enough."""
        self._order(self.schedule.overdue())
        self._arm_low_mask_timer()

    def _arm_low_mask_timer(self) -> None:
        """Fire at the deadline of the oldest pair waiting for its low masks; idle when none waits."""
        remaining_s = self.schedule.seconds_to_deadline()
        if remaining_s is None:
            self._low_mask_timer.cancel()
        else:
            self._low_mask_timer.timer_period_ns = max(1000, int(remaining_s * 1e9))
            self._low_mask_timer.reset()

    def _on_low_mask(self, side: str, message: Image) -> None:
        stamp_ns = stamp_or_drop(message, self._warnings.warn, f"{side} low mask")
        if stamp_ns is None:
            return
        self._order(self.schedule.add_low_mask(side, stamp_ns, message))
        self._arm_low_mask_timer()

    # ------------------------------------------------------------------ one stereo pair

    def _order(self, pairs: list[ReadyPair[Image]]) -> None:
        for pair in pairs:
            self._process(pair)

    def _stereo_camera(self) -> StereoCamera | None:
        try:
            return self._cameras.camera()
        except CameraModelError as exc:
            self._warnings.warn("camera_info", f"dropped masks: unusable camera_info: {exc}")
            return None

    def _tip_hint(self, stamp_ns: int) -> np.ndarray | None:
        earlier = [stamp for stamp in self._hints if stamp <= stamp_ns]
        if not earlier:
            return None
        hint_stamp = max(earlier)
        if self.hint_max_age_ns > 0 and stamp_ns - hint_stamp > self.hint_max_age_ns:
            return None
        point = self._hints[hint_stamp].point
        return np.array([point.x, point.y], dtype=np.float64)  # NaN is reported by order_stereo

    def _process(self, pair: ReadyPair[Image]) -> None:
        stamp_ns, left, right, low = pair.stamp_ns, pair.left, pair.right, pair.low
        missing = self._cameras.missing()
        if missing:  # a camera driver may start after us: hold the newest pairs until it speaks
            self.schedule.hold(pair)
            self._warnings.warn(
                "camera_info",
                f"holding masks: no {' or '.join(missing)} camera_info received yet "
                f"({LEFT_CAMERA_INFO}, {RIGHT_CAMERA_INFO}); the newest {self.schedule.capacity} pairs "
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
        if any(result.cut):
            self.frames_cut += 1
            self._notes.warn(
                "strand_switch",
                f"masks at {stamp_ns} ns: sequences cut where they turned onto the other strand at a "
                f"crossing or passed by a loop the mask shows ({result.cut[0]} left, {result.cut[1]} right "
                "points; strand_switch_turn, skipped_loop_cut)",
            )
        for publisher, points, header in (
            (self._left_pub, result.left_sequence, left.header),
            (self._right_pub, result.right_sequence, right.header),
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
