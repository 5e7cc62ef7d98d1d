# SPDX-License-Identifier: Apache-2.0
"""reconstruction_node: ordered sequences in, 3D thread and grasp pose out, through :func:`reconstruct`.

Subscribes ``/suture/left/sequence`` and ``/suture/right/sequence``
(geometry_msgs/PolygonStamped, reliable) and ``/stereo/{left,right}/camera_info``
(sensor_msgs/CameraInfo, sensor-data QoS, which also hears reliable publishers).
Sequences are paired by exact ``header.stamp`` (:class:`StampPairBuffer`) and
reconstructed with the latest camera_info pair. A sequence point's z is the not-seen flag
(1.0: interpolated across a gap in the mask, e.g. under an instrument; 0.0: seen), which
:func:`reconstruct` reads (:mod:`suture_reconstruction.not_seen`).

With ``use_images`` (default true) it also subscribes the rectified images
``/stereo/{left,right}/image_rect`` (sensor-data QoS; rgb8, bgr8 or mono8, the
same in both views), keeps the newest ``image_buffer_size`` stereo pairs of
them, and gives the pair with the sequences' stamp to :func:`reconstruct`,
which refines the disparity photometrically
(:mod:`suture_reconstruction.photometric`; the depth of a 5 mm-baseline
endoscope needs the tenth of a pixel that the masks cannot give), and at an end
far along the rows from any steep stretch by a window round its termination,
as it does an end of a thread steep nowhere that stands out from the tissue
where the masks' pairs put it 1-2 px off (:mod:`suture_reconstruction.ends`). The images
of a frame are published before its sequences can exist, so they are normally
waiting; if they are not (lost on a best-effort link, or malformed), the frame
is reconstructed from the sequences alone, with a throttled warning. Publishes, with the stamp of the
stereo pair and frame ``frame_id`` (``left_camera_optical_frame``), reliable:

* ``/suture/points`` (sensor_msgs/PointCloud2: fields x y z float32, the dense
  triangulated vertices in sequence order);
* ``/suture/path`` (nav_msgs/Path: the optimised centreline from the cut tip);
* ``/suture/grasp_pose`` (geometry_msgs/PoseStamped: ``grasp_arc_length`` from
  the tip; x along the thread, z the approach direction);
* ``/suture/markers`` (visualization_msgs/MarkerArray: the path as LINE_STRIP
  id 0, the grasp point as SPHERE id 1, namespace ``suture``).

Parameters (read at start-up; SI units): see :data:`PARAMETERS`. A frame that
cannot be reconstructed (too few points, no stereo overlap, thread shorter than
the reserve, NaN, missing or unusable camera_info) is dropped with one warning
per reason and ``log_throttle`` seconds, and the node serves the next one. So is a
frame whose grasp point is refused (:mod:`suture_reconstruction.uncertainty`): a
grasp point a view does not see (GraspNotSeenError; also where the thread runs under an
instrument before the grasp point, rather than ThreadTooShortError), one uncertain by more than
``max_grasp_uncertainty_mm`` (UncertainGraspError), one on a thread whose reconstruction
starts more than ``max_tip_gap_mm`` after the cut tip (TipNotReconstructedError), or one before
which a view's sequence holds more than ``max_unexplained_arc_mm`` of thread that the 3D thread
does not explain (UnexplainedArcError), or near which (from the cut tip to 10 mm past it) a
stretch of 20 mm of 3D arc is more than ``max_arc_image_ratio`` times the length its image
covers (ArcAlongViewError), or that lies, where the thread runs along the image rows, more than
``max_behind_surface_px`` of disparity behind the textured surface beside it
(ThreadBehindSurfaceError; :mod:`suture_reconstruction.surface`), or that lies on a thread
crossing the image rows nowhere steeply whose cut tip or far end the images place more than
``max_end_disparity_gap_px`` of disparity from the reconstruction (EndDisparityError;
:mod:`suture_reconstruction.ends`); nothing of it is published.
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np
from geometry_msgs.msg import Point, PolygonStamped, PoseStamped
from nav_msgs.msg import Path
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image, PointCloud2, PointField
from std_msgs.msg import Header
from visualization_msgs.msg import Marker, MarkerArray

from suture_common.camera import CameraInfoCache, CameraModelError, StereoCamera
from suture_common.messages import (
    MessageConversionError,
    image_to_array,
    path_message,
    polygon_to_array,
    pose_message,
)
from suture_common.parameters import ParameterSpec, field_parameter, spec_table
from suture_common.ros import (
    RELIABLE_QOS,
    SENSOR_DATA_QOS,
    ThrottledWarnings,
    declare_parameters,
    run_node,
    sensor_data_qos,
    serialized,
    stamp_or_drop,
    to_rclpy,
)
from suture_common.stamp_buffer import StampedPairs, StampPairBuffer
from suture_common.topics import (
    GRASP_POSE,
    LEFT_CAMERA_INFO,
    LEFT_FRAME,
    LEFT_IMAGE,
    LEFT_SEQUENCE,
    MARKERS,
    PATH,
    POINTS,
    RIGHT_CAMERA_INFO,
    RIGHT_IMAGE,
    RIGHT_SEQUENCE,
)
from suture_reconstruction.core import Reconstruction, ReconstructionParams, reconstruct
from suture_reconstruction.errors import ImagePairError, ReconstructionError
from suture_reconstruction.pairing import PairingParams
from suture_reconstruction.photometric import check_image_pair
from suture_reconstruction.shape_graph import ShapeGraphParams

NODE_NAME = "reconstruction_node"
IMAGE_ENCODINGS = ("rgb8", "bgr8", "mono8")

_CORE_PARAMETERS = (
    (ReconstructionParams, "grasp_arc_length"),
    (ReconstructionParams, "max_grasp_uncertainty_mm"),
    (ReconstructionParams, "refuse_unseen_grasp"),
    (ReconstructionParams, "image_evidence"),
    (ReconstructionParams, "max_tip_gap_mm"),
    (ReconstructionParams, "max_unexplained_arc_mm"),
    (ReconstructionParams, "max_arc_image_ratio"),
    (ReconstructionParams, "max_behind_surface_px"),
    (ReconstructionParams, "max_end_disparity_gap_px"),
    (ShapeGraphParams, "tau_l"),
    (ShapeGraphParams, "tau_step"),
    (ShapeGraphParams, "upsilon3"),
    (ShapeGraphParams, "sigma1"),
    (ShapeGraphParams, "nu1"),
    (ReconstructionParams, "vertex_step"),
    (PairingParams, "min_depth"),
    (PairingParams, "max_depth"),
    (ReconstructionParams, "min_points"),
    (ReconstructionParams, "curve_smoothing"),
    (ReconstructionParams, "arc_smoothing"),
    (ReconstructionParams, "path_step"),
)
"""The fields of the core's parameters the node exposes, each under its own name."""

PARAMETERS: dict[str, ParameterSpec] = spec_table(
    (
        *(field_parameter(cls, name) for cls, name in _CORE_PARAMETERS),
        ParameterSpec("frame_id", LEFT_FRAME, "frame of the outputs (the left camera optical frame)"),
        ParameterSpec(
            "buffer_size",
            30,
            "unmatched stamps kept per side while waiting for the other sequence",
            (1, 10_000),
        ),
        ParameterSpec(
            "use_images",
            True,
            "refine the disparity with the rectified images (subscribes /stereo/*/image_rect)",
        ),
        ParameterSpec(
            "image_buffer_size", 10, "stereo image pairs kept while their sequences are on the way", (1, 1000)
        ),
        ParameterSpec("log_throttle", 5.0, "seconds between two warnings for the same reason", (0.0, 3600.0)),
    )
)
"""Every parameter of the node, by name: the core's (descriptions and ranges beside their
dataclass fields) and the node's own."""


class ReconstructionNode(Node):
    """The rclpy adapter of :func:`suture_reconstruction.core.reconstruct` (module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        values = declare_parameters(self, PARAMETERS.values())
        core = {name: values[name] for _, name in _CORE_PARAMETERS}
        self.params = ReconstructionParams().replace(**core)  # ValueError on bad values
        self.frame_id = str(values["frame_id"])
        self._buffer: StampPairBuffer[np.ndarray] = StampPairBuffer(int(values["buffer_size"]))
        self.use_images = bool(values["use_images"])
        image_capacity = int(values["image_buffer_size"])
        self._images: StampedPairs[Image] = StampedPairs(image_capacity)  # ValueError below 1
        self._cameras = CameraInfoCache()
        log_throttle = float(values["log_throttle"])
        self._warnings = ThrottledWarnings(self.get_logger(), log_throttle)
        self.frames = 0
        """Stereo pairs reconstructed and published."""
        self.dropped: dict[str, int] = self._warnings.counts
        """Stereo pairs dropped, by reason."""
        self.refined = 0
        """Stereo pairs whose disparity the images refined."""
        self._image_warnings = ThrottledWarnings(self.get_logger(), log_throttle)
        self.without_images: dict[str, int] = self._image_warnings.counts
        """Stereo pairs reconstructed from the sequences alone although ``use_images`` is set, by reason."""

        self._points = self.create_publisher(PointCloud2, POINTS, RELIABLE_QOS)
        self._path = self.create_publisher(Path, PATH, RELIABLE_QOS)
        self._pose = self.create_publisher(PoseStamped, GRASP_POSE, RELIABLE_QOS)
        self._markers = self.create_publisher(MarkerArray, MARKERS, RELIABLE_QOS)
        self.create_subscription(
            PolygonStamped, LEFT_SEQUENCE, lambda m: self._on_sequence("left", m), RELIABLE_QOS
        )
        self.create_subscription(
            PolygonStamped, RIGHT_SEQUENCE, lambda m: self._on_sequence("right", m), RELIABLE_QOS
        )
        self.create_subscription(
            CameraInfo, LEFT_CAMERA_INFO, lambda m: self._cameras.update("left", m), SENSOR_DATA_QOS
        )
        self.create_subscription(
            CameraInfo, RIGHT_CAMERA_INFO, lambda m: self._cameras.update("right", m), SENSOR_DATA_QOS
        )
        if self.use_images:
            images_qos = sensor_data_qos(5)
            self.create_subscription(Image, LEFT_IMAGE, lambda m: self._on_image("left", m), images_qos)
            self.create_subscription(Image, RIGHT_IMAGE, lambda m: self._on_image("right", m), images_qos)
        refined = f", disparity refined with {LEFT_IMAGE} and {RIGHT_IMAGE}" if self.use_images else ""
        self.get_logger().info(f"reconstructing {LEFT_SEQUENCE} and {RIGHT_SEQUENCE} in 3D{refined}")

    # ------------------------------------------------------------------ callbacks

    def _on_sequence(self, side: str, message: PolygonStamped) -> None:
        stamp = stamp_or_drop(message, self._drop, f"{side} sequence")
        if stamp is None:
            return
        try:
            sequence = polygon_to_array(message)
        except MessageConversionError as exc:
            self._drop("bad_sequence", f"dropped {side} sequence at {stamp} ns: {exc}")
            return
        pair = self._buffer.add(side, stamp, sequence)
        if pair is not None:
            self.process(stamp, *pair)

    def _on_image(self, side: str, message: Image) -> None:
        stamp = stamp_or_drop(message, self._drop, f"{side} image")
        if stamp is None:
            return
        self._images.add(side, stamp, message)

    def process(self, stamp_ns: int, left: np.ndarray, right: np.ndarray) -> Reconstruction | None:
        """Reconstruct one stereo pair and publish it; returns None (and warns) when it is dropped."""
        camera = self._stereo_camera()
        if camera is None:
            return None
        images = self._images_of(stamp_ns, camera) if self.use_images else None
        try:
            result = reconstruct(left, right, camera, self.params, images)
        except ReconstructionError as exc:
            self._drop(type(exc).__name__, f"dropped stereo pair at {stamp_ns} ns: {exc}")
            return None
        except ValueError as exc:  # anything else the core rejects (e.g. a degenerate grasp frame)
            self._drop("invalid_input", f"dropped stereo pair at {stamp_ns} ns: {exc}")
            return None
        self._publish(stamp_ns, result)
        self.frames += 1
        self.refined += result.image_matches > 0
        return result

    def _images_of(self, stamp_ns: int, camera: StereoCamera) -> tuple[np.ndarray, np.ndarray] | None:
        """The stereo images of ``stamp_ns`` as arrays, or None (with a warning) if there are none."""
        pair = self._images.take(stamp_ns)
        if pair is None:
            self._image_warnings.warn(
                "no_images",
                f"no stereo images of stamp {stamp_ns} ns received before its sequences: reconstructed "
                "from the sequences alone (set use_images false if the images are not published)",
            )
            return None
        try:
            if pair[0].encoding != pair[1].encoding:
                raise ImagePairError(f"encodings differ: {pair[0].encoding}, {pair[1].encoding}")
            arrays = tuple(image_to_array(message, expect=IMAGE_ENCODINGS) for message in pair)
            return check_image_pair(arrays, camera.width, camera.height)
        except (MessageConversionError, ImagePairError) as exc:
            self._image_warnings.warn(
                "bad_image",
                f"stereo images at {stamp_ns} ns unusable ({exc}): reconstructed from the sequences",
            )
            return None

    def _stereo_camera(self) -> StereoCamera | None:
        missing = self._cameras.missing()
        if missing:
            sides = " and ".join(missing)
            self._drop("no_camera_info", f"dropped stereo pair: no {sides} camera_info received yet")
            return None
        try:
            return self._cameras.camera()
        except CameraModelError as exc:
            self._drop("camera_info", f"dropped stereo pair: unusable camera_info: {exc}")
            return None

    # ------------------------------------------------------------------ output

    def _publish(self, stamp_ns: int, result: Reconstruction) -> None:
        # The grasp pose first: the executor waits on it, while building the Path message of a
        # long thread alone takes several milliseconds.
        pose = to_rclpy(pose_message(result.grasp_position, result.grasp_quaternion, stamp_ns, self.frame_id))
        self._pose.publish(pose)
        self._points.publish(point_cloud(result.points, pose.header))
        self._path.publish(serialized(path_message(result.path, stamp_ns, self.frame_id)))
        self._markers.publish(markers(result.path, result.grasp_position, pose.header))

    def _drop(self, reason: str, text: str) -> None:
        self._warnings.warn(reason, text)


def point_cloud(points: np.ndarray, header: Header) -> PointCloud2:
    """sensor_msgs/PointCloud2 of (N, 3) points (m): fields x y z float32, little-endian, one row."""
    data = np.ascontiguousarray(points, dtype="<f4").reshape(-1, 3)
    return PointCloud2(
        header=header,
        height=1,
        width=len(data),
        fields=[
            PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1)
            for i, n in enumerate("xyz")
        ],
        is_bigendian=False,
        point_step=12,
        row_step=12 * len(data),
        data=data.tobytes(),
        is_dense=True,
    )


def point_cloud_to_array(message: PointCloud2) -> np.ndarray:
    """(N, 3) float64 of a cloud written by :func:`point_cloud` (for tests and tools)."""
    return np.frombuffer(bytes(message.data), dtype="<f4").reshape(-1, 3).astype(np.float64)


def markers(path: np.ndarray, grasp_position: np.ndarray, header: Header) -> MarkerArray:
    """The path as a LINE_STRIP (id 0, 0.5 mm wide, green), the grasp point as a SPHERE (id 1, 3 mm, red)."""
    line = Marker(header=header, ns="suture", id=0, type=Marker.LINE_STRIP, action=Marker.ADD)
    line.pose.orientation.w = 1.0
    line.scale.x = 0.0005
    line.color.g, line.color.a = 1.0, 1.0
    line.points = [Point(x=x, y=y, z=z) for x, y, z in np.asarray(path, dtype=float).tolist()]
    sphere = Marker(header=header, ns="suture", id=1, type=Marker.SPHERE, action=Marker.ADD)
    x, y, z = np.asarray(grasp_position, dtype=float).tolist()
    sphere.pose.position = Point(x=x, y=y, z=z)
    sphere.pose.orientation.w = 1.0
    sphere.scale.x = sphere.scale.y = sphere.scale.z = 0.003
    sphere.color.r, sphere.color.a = 1.0, 1.0
    return MarkerArray(markers=[line, sphere])


def main(args: list[str] | None = None) -> int:
    """``ros2 run suture_reconstruction reconstruction_node``: spin until Ctrl-C or shutdown."""
    return run_node(ReconstructionNode, NODE_NAME, args)


if __name__ == "__main__":
    sys.exit(main())
