# SPDX-License-Identifier: Apache-2.0
"""Conversion between ROS 2 messages and numpy arrays, without rclpy.

Builders (``*_message``) return message instances of the ``rosbags`` ROS 2
Jazzy typestore (:data:`TYPESTORE`), ready for :class:`suture_common.bag_io.BagWriter`
or, through :func:`suture_common.ros.to_rclpy`, for an rclpy publisher.

Readers (``*_to_array``, ``*_to_arrays``, :func:`ns_from_stamp`) are duck-typed:
they only read fields by name, so they accept both rosbags dataclasses and rclpy
messages. (rclpy ``Image.data`` is an ``array.array``/``bytes``, rosbags' a numpy
uint8 array; both expose the buffer protocol.)

Conventions: stamps are integer nanoseconds since the epoch; positions are metres
(float64 arrays); quaternions are (x, y, z, w); pixels are (u, v) = (column, row).
A malformed message or argument raises :class:`MessageConversionError`, a
``ValueError`` whose text names the problem, so that a node can drop the message
with one log line.
"""

from __future__ import annotations

from collections.abc import Collection
from typing import TYPE_CHECKING, Any

import numpy as np
from rosbags.typesys import Stores, get_typestore

if TYPE_CHECKING:
    from suture_common.camera import StereoCamera

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
"""The rosbags typestore of ROS 2 Jazzy's standard messages; builders use its classes."""

ENCODING_CHANNELS: dict[str, int] = {"mono8": 1, "rgb8": 3, "bgr8": 3}
"""Image encodings this pipeline reads and writes, with their channel counts (all 8-bit)."""

_NS_PER_S = 1_000_000_000
_INT32_MAX = 2**31 - 1

_Time = TYPESTORE.types["builtin_interfaces/msg/Time"]
_Header = TYPESTORE.types["std_msgs/msg/Header"]
_Image = TYPESTORE.types["sensor_msgs/msg/Image"]
_CameraInfo = TYPESTORE.types["sensor_msgs/msg/CameraInfo"]
_RegionOfInterest = TYPESTORE.types["sensor_msgs/msg/RegionOfInterest"]
_Point = TYPESTORE.types["geometry_msgs/msg/Point"]
_Point32 = TYPESTORE.types["geometry_msgs/msg/Point32"]
_Polygon = TYPESTORE.types["geometry_msgs/msg/Polygon"]
_PolygonStamped = TYPESTORE.types["geometry_msgs/msg/PolygonStamped"]
_PointStamped = TYPESTORE.types["geometry_msgs/msg/PointStamped"]
_Quaternion = TYPESTORE.types["geometry_msgs/msg/Quaternion"]
_Pose = TYPESTORE.types["geometry_msgs/msg/Pose"]
_PoseStamped = TYPESTORE.types["geometry_msgs/msg/PoseStamped"]
_Path = TYPESTORE.types["nav_msgs/msg/Path"]
_String = TYPESTORE.types["std_msgs/msg/String"]

_QUATERNION_NORM_TOLERANCE = 1e-3


class MessageConversionError(ValueError):
    """A message or array cannot be converted; the text says which field is wrong and how."""


# --------------------------------------------------------------------------- stamps and headers


def stamp_from_ns(ns: int) -> Any:
    """builtin_interfaces/Time for ``ns`` integer nanoseconds since the epoch.

    Raises MessageConversionError for negative stamps or stamps past 2038 (int32 seconds).
    """
    if isinstance(ns, bool) or not isinstance(ns, (int, np.integer)):
        raise MessageConversionError(f"stamp must be integer nanoseconds, got {type(ns).__name__} {ns!r}")
    ns = int(ns)
    if ns < 0:
        raise MessageConversionError(f"stamp must be >= 0 ns, got {ns}")
    sec, nanosec = divmod(ns, _NS_PER_S)
    if sec > _INT32_MAX:
        raise MessageConversionError(f"stamp {ns} ns does not fit builtin_interfaces/Time (int32 seconds)")
    return _Time(sec=sec, nanosec=nanosec)


def ns_from_stamp(stamp: Any) -> int:
    """Integer nanoseconds since the epoch of a builtin_interfaces/Time (fields ``sec``, ``nanosec``).

    Raises MessageConversionError for a stamp no output could carry (negative seconds, nanosec
    outside [0, 1e9)), so that nodes drop such input instead of failing when they publish.
    """
    sec, nanosec = int(stamp.sec), int(stamp.nanosec)
    if not (0 <= sec <= _INT32_MAX and 0 <= nanosec < _NS_PER_S):
        raise MessageConversionError(
            f"header stamp out of range (sec {sec}, nanosec {nanosec}): need sec >= 0 and nanosec < 1e9"
        )
    return sec * _NS_PER_S + nanosec


def make_header(stamp_ns: int, frame_id: str) -> Any:
    """std_msgs/Header with the stamp ``stamp_ns`` (integer ns) and ``frame_id``."""
    if not isinstance(frame_id, str):
        raise MessageConversionError(f"frame_id must be a str, got {type(frame_id).__name__}")
    return _Header(stamp=stamp_from_ns(stamp_ns), frame_id=frame_id)


# --------------------------------------------------------------------------- images


def image_message(array: np.ndarray, encoding: str, stamp_ns: int, frame_id: str) -> Any:
    """sensor_msgs/Image holding a copy of ``array``.

    ``array`` is (H, W) uint8 for ``mono8`` or (H, W, 3) uint8 for ``rgb8``/``bgr8``
    (channel order as the encoding says; nothing is reordered). ``step`` is
    ``W * channels`` (no padding), ``is_bigendian`` 0.
    """
    channels = _channels(encoding)
    array = np.asarray(array)
    if array.dtype != np.uint8:
        raise MessageConversionError(
            f"{encoding} image must be uint8, got {array.dtype} (scale and cast with .astype(np.uint8))"
        )
    expected = "(H, W)" if channels == 1 else "(H, W, 3)"
    if (channels == 1 and array.ndim != 2) or (channels == 3 and (array.ndim != 3 or array.shape[2] != 3)):
        raise MessageConversionError(f"{encoding} image must have shape {expected}, got {array.shape}")
    height, width = array.shape[:2]
    if height == 0 or width == 0:
        raise MessageConversionError(f"image must not be empty, got shape {array.shape}")
    return _Image(
        header=make_header(stamp_ns, frame_id),
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=0,
        step=width * channels,
        data=np.array(array, dtype=np.uint8, order="C", copy=True).reshape(-1),
    )


def image_to_array(msg: Any, expect: str | Collection[str] | None = None) -> np.ndarray:
    """The pixels of a sensor_msgs/Image as (H, W) (mono8) or (H, W, 3) (rgb8, bgr8) uint8.

    ``expect`` optionally restricts the accepted encodings (one name or a collection),
    e.g. ``expect="mono8"`` for masks. Row padding (``step > W * channels``) is
    dropped. The result is a view into the message's buffer where possible (it may
    be read-only or non-contiguous); call ``.copy()`` before writing to it.

    Raises MessageConversionError for an unsupported or unexpected encoding, zero
    width or height, ``step < W * channels`` or ``len(data) != step * height``.
    """
    encoding = str(msg.encoding)
    channels = _channels(encoding)
    if expect is not None:
        allowed = (expect,) if isinstance(expect, str) else tuple(expect)
        if encoding not in allowed:
            raise MessageConversionError(
                f"image encoding is {encoding!r} but this input expects {' or '.join(map(repr, allowed))}"
            )
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    if height <= 0 or width <= 0:
        raise MessageConversionError(f"image has zero size: width={width} height={height}")
    row_bytes = width * channels
    if step < row_bytes:
        raise MessageConversionError(
            f"image step {step} is smaller than width * channels = {width} * {channels} = {row_bytes} "
            f"for {encoding}"
        )
    data = _as_uint8(msg.data)
    if data.size != step * height:
        raise MessageConversionError(
            f"image data has {data.size} bytes but step * height = {step} * {height} = {step * height}"
        )
    rows = data.reshape(height, step)[:, :row_bytes]
    return rows.reshape(height, width) if channels == 1 else rows.reshape(height, width, 3)


def image_to_rgb(msg: Any) -> np.ndarray:
    """(H, W, 3) uint8 RGB pixels of an rgb8, bgr8 or mono8 sensor_msgs/Image.

    bgr8 is reordered (a copy), mono8 repeated into three channels; rgb8 is
    :func:`image_to_array`'s view. Raises MessageConversionError as :func:`image_to_array`.
    """
    array = image_to_array(msg, expect=("rgb8", "bgr8", "mono8"))
    if array.ndim == 2:
        return np.repeat(array[..., None], 3, axis=2)
    return np.ascontiguousarray(array[..., ::-1]) if msg.encoding == "bgr8" else array


def _channels(encoding: str) -> int:
    try:
        return ENCODING_CHANNELS[encoding]
    except (KeyError, TypeError):
        raise MessageConversionError(
            f"unsupported image encoding {encoding!r}; use one of {', '.join(ENCODING_CHANNELS)} "
            "(convert e.g. with image_proc or cv2.cvtColor before publishing)"
        ) from None


def _as_uint8(data: Any) -> np.ndarray:
    """A flat uint8 view of an image data field (numpy array, bytes, array.array or list)."""
    if isinstance(data, np.ndarray):
        if data.dtype != np.uint8:
            raise MessageConversionError(f"image data must be uint8 bytes, got a {data.dtype} array")
        return data.reshape(-1)
    try:
        return np.frombuffer(data, dtype=np.uint8)
    except TypeError:  # a list of ints, as some hand-written messages carry
        return np.asarray(data, dtype=np.uint8).reshape(-1)


# --------------------------------------------------------------------------- camera info


def camera_info_message(camera: StereoCamera, view: str, stamp_ns: int, frame_id: str) -> Any:
    """Rectified sensor_msgs/CameraInfo of ``view`` ('left' or 'right') of ``camera``.

    Fields from :meth:`StereoCamera.camera_info_fields` (plumb_bob, zero distortion,
    identity R, right P with Tx = -fx * baseline); binning 0 and an empty ROI.
    """
    fields = camera.camera_info_fields(view)
    return _CameraInfo(
        header=make_header(stamp_ns, frame_id),
        height=int(fields["height"]),
        width=int(fields["width"]),
        distortion_model=str(fields["distortion_model"]),
        d=np.asarray(fields["d"], dtype=np.float64).copy(),
        k=np.asarray(fields["k"], dtype=np.float64).copy(),
        r=np.asarray(fields["r"], dtype=np.float64).copy(),
        p=np.asarray(fields["p"], dtype=np.float64).copy(),
        binning_x=0,
        binning_y=0,
        roi=_RegionOfInterest(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
    )


# --------------------------------------------------------------------------- geometry


def polygon_message(points: np.ndarray, stamp_ns: int, frame_id: str) -> Any:
    """geometry_msgs/PolygonStamped from (N, 2) or (N, 3) float points (z = 0 for (N, 2)).

    For image sequences x = u, y = v in pixels. Point32 is float32, so values are
    rounded to float32 precision. N = 0 gives an empty polygon.
    """
    points = _finite_points(points, "polygon", (2, 3))
    if points.shape[1] == 2:
        points = np.column_stack([points, np.zeros(len(points))])
    values = points.astype(np.float32).tolist()
    return _PolygonStamped(
        header=make_header(stamp_ns, frame_id),
        polygon=_Polygon(points=[_Point32(x=x, y=y, z=z) for x, y, z in values]),
    )


def polygon_to_array(msg: Any) -> np.ndarray:
    """(N, 3) float64 vertices of a geometry_msgs/PolygonStamped (N may be 0).

    Raises MessageConversionError if a vertex is NaN or infinite.
    """
    points = np.array([(p.x, p.y, p.z) for p in msg.polygon.points], dtype=np.float64).reshape(-1, 3)
    return _check_finite(points, "polygon")


def path_message(points: np.ndarray, stamp_ns: int, frame_id: str) -> Any:
    """nav_msgs/Path through (N, 3) points in metres, in order (N may be 0).

    Every PoseStamped carries a copy of the path's header; orientations are identity.
    """
    points = _finite_points(points, "path", (3,))
    return _Path(
        header=make_header(stamp_ns, frame_id),
        poses=[
            _PoseStamped(
                header=make_header(stamp_ns, frame_id),
                pose=_Pose(
                    position=_Point(x=x, y=y, z=z), orientation=_Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
                ),
            )
            for x, y, z in points.tolist()
        ],
    )


def path_to_array(msg: Any) -> np.ndarray:
    """(N, 3) float64 positions (metres) of a nav_msgs/Path; orientations are ignored.

    Raises MessageConversionError if a position is NaN or infinite.
    """
    points = np.array(
        [(p.pose.position.x, p.pose.position.y, p.pose.position.z) for p in msg.poses], dtype=np.float64
    ).reshape(-1, 3)
    return _check_finite(points, "path")


def pose_message(position: np.ndarray, quaternion_xyzw: np.ndarray, stamp_ns: int, frame_id: str) -> Any:
    """geometry_msgs/PoseStamped from a (3,) position in metres and a (4,) unit quaternion (x, y, z, w).

    The quaternion is renormalised; one whose norm differs from 1 by more than 1e-3
    (or a NaN/inf value anywhere) raises MessageConversionError.
    """
    position = _finite_vector(position, 3, "pose position")
    quaternion = _unit_quaternion(_finite_vector(quaternion_xyzw, 4, "pose quaternion"))
    x, y, z = position.tolist()
    qx, qy, qz, qw = quaternion.tolist()
    return _PoseStamped(
        header=make_header(stamp_ns, frame_id),
        pose=_Pose(position=_Point(x=x, y=y, z=z), orientation=_Quaternion(x=qx, y=qy, z=qz, w=qw)),
    )


def pose_to_arrays(msg: Any) -> tuple[np.ndarray, np.ndarray]:
    """(position (3,) metres, quaternion (4,) x y z w) float64 of a geometry_msgs/PoseStamped.

    The quaternion is renormalised. Raises MessageConversionError for NaN/inf values
    or a quaternion whose norm differs from 1 by more than 1e-3 (e.g. all zeros).
    """
    p, q = msg.pose.position, msg.pose.orientation
    position = _check_finite(np.array([p.x, p.y, p.z], dtype=np.float64), "pose position")
    quaternion = _check_finite(np.array([q.x, q.y, q.z, q.w], dtype=np.float64), "pose quaternion")
    return position, _unit_quaternion(quaternion)


def point_message(xyz: np.ndarray, stamp_ns: int, frame_id: str) -> Any:
    """geometry_msgs/PointStamped from a (3,) float array (for the tip hint: u, v, 0 in pixels)."""
    x, y, z = _finite_vector(xyz, 3, "point").tolist()
    return _PointStamped(header=make_header(stamp_ns, frame_id), point=_Point(x=x, y=y, z=z))


def point_to_array(msg: Any) -> np.ndarray:
    """(3,) float64 of a geometry_msgs/PointStamped; raises MessageConversionError on NaN/inf."""
    p = msg.point
    return _check_finite(np.array([p.x, p.y, p.z], dtype=np.float64), "point")


def string_message(text: str) -> Any:
    """std_msgs/String holding ``text``."""
    if not isinstance(text, str):
        raise MessageConversionError(f"string message needs a str, got {type(text).__name__}")
    return _String(data=text)


# --------------------------------------------------------------------------- validation helpers


def _finite_points(points: Any, what: str, widths: tuple[int, ...]) -> np.ndarray:
    try:
        array = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise MessageConversionError(f"{what} points must be numeric, got {exc}") from None
    if array.ndim == 1 and array.size == 0:  # [] means no points
        array = array.reshape(0, widths[-1])
    if array.ndim != 2 or array.shape[1] not in widths:
        shapes = " or ".join(f"(N, {w})" for w in widths)
        raise MessageConversionError(f"{what} points must have shape {shapes}, got {array.shape}")
    return _check_finite(array, what)


def _finite_vector(values: Any, size: int, what: str) -> np.ndarray:
    try:
        array = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise MessageConversionError(f"{what} must be numeric, got {exc}") from None
    if array.shape != (size,):
        raise MessageConversionError(f"{what} must have shape ({size},), got {array.shape}")
    return _check_finite(array, what)


def _check_finite(array: np.ndarray, what: str) -> np.ndarray:
    bad = ~np.isfinite(array)
    if bad.any():
        index = np.argwhere(bad)[0]
        where = f"row {index[0]}" if array.ndim == 2 else f"element {index[0]}"
        raise MessageConversionError(
            f"{what} contains NaN or inf ({int(bad.sum())} values, first at {where})"
        )
    return array


def _unit_quaternion(quaternion: np.ndarray) -> np.ndarray:
    norm = float(np.linalg.norm(quaternion))
    if abs(norm - 1.0) > _QUATERNION_NORM_TOLERANCE:
        raise MessageConversionError(
            f"quaternion (x, y, z, w) = {quaternion.tolist()} has norm {norm:.6g}, expected a unit "
            "quaternion (identity is (0, 0, 0, 1))"
        )
    return quaternion / norm
