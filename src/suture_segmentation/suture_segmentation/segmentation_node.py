# SPDX-License-Identifier: Apache-2.0
"""segmentation_node: rectified stereo images in, suture masks out (:meth:`Segmenter.segment_pair_with_low`).

Subscribes ``/stereo/left/image_rect`` and ``/stereo/right/image_rect`` (sensor_msgs/Image,
rgb8, bgr8 or mono8, sensor-data QoS keeping the last ``queue_depth`` images: by default only
the newest, so that a node slower than the camera segments the current frame, not a queue of
stale ones), pairs them by exact ``header.stamp``
(:class:`suture_common.stamp_buffer.StampPairBuffer`), segments both views as one batch and
publishes ``/suture/left/mask`` and ``/suture/right/mask`` (sensor_msgs/Image mono8, 0 or 255,
the header of the input image of that side, sensor-data QoS). By default each view's suture
probability is the mean of the model's on the image and on its mirror image
(``flip_average``). bgr8 images are reordered to RGB
before they reach the model; mono8 images are segmented as grey. Just before them it publishes
the pair's *low masks*, ``/suture/{left,right}/mask_low`` (the same format: the mask plus the
pixels above ``low_threshold`` connected to it, :meth:`Segmenter.segment_pair_with_low`), which
ordering_node follows where the thread is faint; ``low_threshold`` 0 publishes none.

Parameters (read at start-up): see :data:`PARAMETERS`. ``weights`` "" is the shipped on-site
model ``m_onsite_half``: its int8 export (``suture_segmentation/weights/m_onsite_half_int8.onnx``)
with the onnx backend on the CPU, ``m_onsite_half.pt`` otherwise; "m_ost"/"m_ost_hard"/
"m_onsite_half"/"m_onsite"/"m_tosot"/"m_general" name a shipped model and the same names with
"_int8" its int8 ONNX export (backend onnx); anything else is a ``.pt`` checkpoint or an ``.onnx``
file. ``m_ost`` is the legacy camera's model (the paper's M-oST), ``m_ost_hard`` the same continued
on hooks, wide shafts and threads along the rows, ``m_tosot`` the paper's transfer to the on-site camera
from 40 labelled images, ``m_onsite`` the same camera's model from 800, and ``m_onsite_half`` its
half-resolution variant (as accurate, about 0.6 of the time per pair); ``m_general`` (trained on
domain-randomised frames) is meant for a camera that none of the models has seen.

Weights that cannot be loaded (missing, corrupt, not a suture U-Net) stop the node at
start-up: ``ros2 run`` prints one line, ``segmentation_node: cannot load weights: ...``, on
standard error and exits with status 1, as for any bad parameter value
(:func:`suture_common.ros.run_node`). The weights are configuration, not a message: a node that
kept running without a model would publish nothing, forever, and look alive to a launch file
or a supervisor, while a process that exits at once is seen and restarted or fixed.

A malformed input pair (an encoding other than rgb8, bgr8 or mono8, a 0-pixel image, data
shorter or longer than ``step * height``, left and right of different sizes) is dropped with
one warning per problem and ``log_throttle`` seconds that names it, and the node serves the
next pair; no mask is published for that stamp. So is a pair on which the inference runtime
itself fails (e.g. out of memory for a huge image), with the runtime's error in the warning.
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import Image

from suture_common.messages import (
    ENCODING_CHANNELS,
    MessageConversionError,
    image_message,
    image_to_array,
)
from suture_common.parameters import ParameterSpec, spec_table
from suture_common.ros import (
    SENSOR_DATA_QOS,
    ThrottledWarnings,
    declare_parameters,
    run_node,
    sensor_data_qos,
    serialized,
    stamp_or_drop,
)
from suture_common.stamp_buffer import StampPairBuffer
from suture_common.topics import LEFT_IMAGE, LEFT_MASK, LEFT_MASK_LOW, RIGHT_IMAGE, RIGHT_MASK, RIGHT_MASK_LOW
from suture_segmentation.checkpoint import WeightsError
from suture_segmentation.core import (
    LOW_THRESHOLD,
    SegmentationInputError,
    Segmenter,
    StereoSizeMismatchError,
)

NODE_NAME = "segmentation_node"

PARAMETERS: dict[str, ParameterSpec] = spec_table(
    (
        ParameterSpec(
            "weights",
            "",
            'model weights: "" = shipped m_onsite_half, "m_ost"/"m_ost_hard"/"m_onsite_half"/"m_onsite"/'
            '"m_tosot"/"m_general"[_int8], or a .pt/.onnx file',
        ),
        ParameterSpec("backend", "onnx", "inference backend: onnx (ONNX Runtime) or torch"),
        ParameterSpec("device", "cpu", "cpu or cuda[:N]"),
        ParameterSpec(
            "threshold", 0.5, "suture probability above which a pixel is suture, in (0, 1)", (0.0, 1.0)
        ),
        ParameterSpec(
            "low_threshold",
            LOW_THRESHOLD,
            "lower threshold of the low masks (mask_low topics: pixels above it connected to the mask), "
            "in (0, threshold]; 0: no low masks",
            (0.0, 1.0),
        ),
        ParameterSpec(
            "flip_average",
            True,
            "average each image's suture probability with its mirror image's (about twice the "
            "inference time; fewer broken threads and false positives on a noisy camera)",
        ),
        ParameterSpec(
            "input_width",
            0,
            "width the images are resized to for inference (0 with input_height 0: own size)",
            (0, 16_384),
        ),
        ParameterSpec(
            "input_height",
            0,
            "height the images are resized to for inference (0 with input_width 0: own size)",
            (0, 16_384),
        ),
        ParameterSpec("threads", 0, "CPU threads of the backend (0: the runtime's default)", (0, 1024)),
        ParameterSpec(
            "max_pending", 10, "unmatched images kept per side while waiting for the other view", (1, 10_000)
        ),
        ParameterSpec(
            "queue_depth",
            1,
            "images queued per camera while the node is busy: 1 = always the newest frame (bounded "
            "latency when images come faster than they are segmented); more = every frame, later",
            (1, 1000),
        ),
        ParameterSpec(
            "log_throttle", 2.0, "seconds between two warnings for the same problem", (0.0, 3600.0)
        ),
    )
)
"""Every parameter of the node, by name."""


def segmenter_from_values(values: dict[str, Any]) -> Segmenter:
    """The :class:`Segmenter` of the parameter ``values``; ValueError names a bad value.

    Weights that cannot be loaded are a ValueError too (with the file and the problem), so
    that :func:`run_node` reports them as one line and exit status 1.
    """
    width, height = int(values["input_width"]), int(values["input_height"])
    if (width, height) == (0, 0):
        input_size = None
    elif width > 0 and height > 0:
        input_size = (width, height)
    else:
        raise ValueError(
            f"input_width and input_height must both be 0 (the image's own size) or both positive, "
            f"got {width} and {height}"
        )
    threads = int(values["threads"])
    if threads < 0:
        raise ValueError(f"threads must be >= 0 (0: the runtime's default), got {threads}")
    weights = str(values["weights"])
    try:
        return Segmenter(
            weights=weights or None,
            backend=str(values["backend"]),
            device=str(values["device"]),
            threshold=float(values["threshold"]),
            input_size=input_size,
            threads=threads or None,
            low_threshold=float(values["low_threshold"]) or None,  # 0: no low masks
            flip_average=bool(values["flip_average"]),
        )
    except WeightsError as exc:
        hint = "" if weights else " (the shipped m_onsite_half; set the parameter weights to a .pt or .onnx)"
        raise ValueError(f"cannot load weights{hint}: {exc}") from exc


class SegmentationNode(Node):
    """Thin adapter between ROS topics and :meth:`Segmenter.segment_pair_with_low` (module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        values = declare_parameters(self, PARAMETERS.values())
        self.segmenter = segmenter_from_values(values)  # ValueError on bad values or weights
        self.pairer: StampPairBuffer[Image] = StampPairBuffer(int(values["max_pending"]))
        self._warnings = ThrottledWarnings(self.get_logger(), float(values["log_throttle"]))
        self.frames = 0
        """Stereo pairs segmented and published."""
        self.dropped: dict[str, int] = self._warnings.counts
        """Stereo pairs dropped, by problem."""

        self._left_pub = self.create_publisher(Image, LEFT_MASK, SENSOR_DATA_QOS)
        self._right_pub = self.create_publisher(Image, RIGHT_MASK, SENSOR_DATA_QOS)
        self._low_pubs = None
        if self.segmenter.low_threshold is not None:
            self._low_pubs = (
                self.create_publisher(Image, LEFT_MASK_LOW, SENSOR_DATA_QOS),
                self.create_publisher(Image, RIGHT_MASK_LOW, SENSOR_DATA_QOS),
            )
        images_qos = sensor_data_qos(int(values["queue_depth"]))  # ValueError below 1
        self.create_subscription(Image, LEFT_IMAGE, lambda m: self._on_image("left", m), images_qos)
        self.create_subscription(Image, RIGHT_IMAGE, lambda m: self._on_image("right", m), images_qos)
        self.get_logger().info(
            f"segmenting {LEFT_IMAGE} and {RIGHT_IMAGE} with {self.segmenter.weights} "
            f"({self.segmenter.backend} on {self.segmenter.device})"
        )

    # ------------------------------------------------------------------ callbacks

    def _on_image(self, side: str, message: Image) -> None:
        stamp_ns = stamp_or_drop(message, self._warnings.warn, f"{side} image")
        if stamp_ns is None:
            return
        paired = self.pairer.add(side, stamp_ns, message)
        if paired is not None:
            self.process(stamp_ns, *paired)

    # ------------------------------------------------------------------ one stereo pair

    def process(self, stamp_ns: int, left: Image, right: Image) -> tuple[np.ndarray, np.ndarray] | None:
        """Segment one stereo pair and publish its masks; returns None (and warns) when it is dropped."""
        images = []
        for side, message in (("left", left), ("right", right)):
            try:
                images.append(rgb_or_grey(message))
            except MessageConversionError as exc:
                self._warnings.warn(
                    image_problem(message), f"dropped stereo pair at {stamp_ns} ns: {side} image: {exc}"
                )
                return None
        try:
            (left_mask, right_mask), low_masks = self.segmenter.segment_pair_with_low(*images)
        except StereoSizeMismatchError as exc:
            self._warnings.warn("size_mismatch", f"dropped stereo pair at {stamp_ns} ns: {exc}")
            return None
        except SegmentationInputError as exc:
            self._warnings.warn("bad_image", f"dropped stereo pair at {stamp_ns} ns: {exc}")
            return None
        except Exception as exc:  # the runtime failed on this input (e.g. out of memory): keep serving
            self._warnings.warn(
                "inference_failed",
                f"dropped stereo pair at {stamp_ns} ns: inference failed: {type(exc).__name__}: {exc}",
            )
            return None
        outputs = [(self._left_pub, left_mask, left.header), (self._right_pub, right_mask, right.header)]
        if self._low_pubs is not None and low_masks is not None:  # first: ordering_node waits for them
            outputs[:0] = zip(self._low_pubs, low_masks, (left.header, right.header), strict=True)
        for publisher, mask, header in outputs:
            publisher.publish(serialized(image_message(mask, "mono8", stamp_ns, header.frame_id)))
        self.frames += 1
        return left_mask, right_mask


def rgb_or_grey(message: Any) -> np.ndarray:
    """(H, W, 3) RGB or (H, W) grey uint8 pixels of an rgb8, bgr8 or mono8 image message.

    Raises MessageConversionError (from :func:`image_to_array`) for anything else.
    """
    array = image_to_array(message, expect=tuple(ENCODING_CHANNELS))
    return array[..., ::-1] if message.encoding == "bgr8" else array


def image_problem(message: Any) -> str:
    """The throttling key of an image that :func:`image_to_array` rejected."""
    if str(message.encoding) not in ENCODING_CHANNELS:
        return "encoding"
    if int(message.width) <= 0 or int(message.height) <= 0:
        return "empty_image"
    return "malformed_image"  # step or data length


def main(args: list[str] | None = None) -> int:
    """``ros2 run suture_segmentation segmentation_node``: spin until Ctrl-C or shutdown."""
    return run_node(SegmentationNode, NODE_NAME, args)


if __name__ == "__main__":
    sys.exit(main())
