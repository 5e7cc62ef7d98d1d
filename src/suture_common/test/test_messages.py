# SPDX-License-Identifier: Apache-2.0
"""Round trips and error cases of suture_common.messages (no rclpy needed)."""

from __future__ import annotations

import array
from types import SimpleNamespace

import numpy as np
import pytest

from suture_common.camera import StereoCamera
from suture_common.messages import (
    TYPESTORE,
    MessageConversionError,
    camera_info_message,
    image_message,
    image_to_array,
    image_to_rgb,
    make_header,
    ns_from_stamp,
    path_message,
    path_to_array,
    point_message,
    point_to_array,
    polygon_message,
    polygon_to_array,
    pose_message,
    pose_to_arrays,
    stamp_from_ns,
    string_message,
)

STAMP = 1_700_000_123_456_789_012
RNG = np.random.default_rng(7)


def cdr_round_trip(msg):
    """The message after serialisation and deserialisation, as it comes out of a bag."""
    return TYPESTORE.deserialize_cdr(TYPESTORE.serialize_cdr(msg, msg.__msgtype__), msg.__msgtype__)


# --------------------------------------------------------------------------- stamps


@pytest.mark.parametrize("ns", [0, 1, 999_999_999, 1_000_000_000, STAMP, (2**31 - 1) * 10**9 + 999_999_999])
def test_stamp_round_trip(ns):
    stamp = stamp_from_ns(ns)
    assert 0 <= stamp.nanosec < 10**9
    assert ns_from_stamp(stamp) == ns


def test_stamp_fields():
    stamp = stamp_from_ns(STAMP)
    assert (stamp.sec, stamp.nanosec) == (1_700_000_123, 456_789_012)


@pytest.mark.parametrize("ns", [-1, 2**31 * 10**9, 1.5, "5", True])
def test_stamp_rejects(ns):
    with pytest.raises(MessageConversionError):
        stamp_from_ns(ns)


def test_header():
    header = make_header(STAMP, "left_camera_optical_frame")
    assert header.frame_id == "left_camera_optical_frame"
    assert ns_from_stamp(header.stamp) == STAMP
    with pytest.raises(MessageConversionError, match="frame_id"):
        make_header(STAMP, None)


def test_ns_from_stamp_duck_typed():
    assert ns_from_stamp(SimpleNamespace(sec=2, nanosec=5)) == 2_000_000_005


# --------------------------------------------------------------------------- images


@pytest.mark.parametrize(
    ("encoding", "shape"), [("mono8", (5, 7)), ("rgb8", (5, 7, 3)), ("bgr8", (4, 9, 3)), ("mono8", (1, 1))]
)
def test_image_round_trip(encoding, shape):
    pixels = RNG.integers(0, 256, shape, dtype=np.uint8)
    msg = image_message(pixels, encoding, STAMP, "cam")
    assert (msg.height, msg.width, msg.encoding, msg.is_bigendian) == (shape[0], shape[1], encoding, 0)
    assert msg.step == shape[1] * (1 if encoding == "mono8" else 3)
    assert msg.data.dtype == np.uint8 and msg.data.size == msg.step * msg.height
    assert ns_from_stamp(msg.header.stamp) == STAMP and msg.header.frame_id == "cam"
    for received in (msg, cdr_round_trip(msg)):
        out = image_to_array(received)
        assert out.dtype == np.uint8 and out.shape == shape
        np.testing.assert_array_equal(out, pixels)


def test_image_message_copies_the_array():
    pixels = np.zeros((3, 4), np.uint8)
    msg = image_message(pixels, "mono8", 0, "cam")
    pixels[:] = 9
    assert not image_to_array(msg).any()


def test_image_message_accepts_non_contiguous_array():
    base = RNG.integers(0, 256, (6, 8, 3), dtype=np.uint8)
    view = base[::2, ::-1]
    np.testing.assert_array_equal(image_to_array(image_message(view, "rgb8", 0, "c")), view)


@pytest.mark.parametrize("channels", [1, 3])
def test_image_step_padding(channels):
    height, width, pad = 4, 5, 3
    encoding = "mono8" if channels == 1 else "rgb8"
    shape = (height, width) if channels == 1 else (height, width, 3)
    pixels = RNG.integers(1, 256, shape, dtype=np.uint8)
    step = width * channels + pad
    padded = np.zeros((height, step), np.uint8)
    padded[:, : width * channels] = pixels.reshape(height, -1)
    msg = image_message(pixels, encoding, 0, "c")
    msg.step = step
    msg.data = padded.reshape(-1)
    np.testing.assert_array_equal(image_to_array(msg), pixels)


@pytest.mark.parametrize("kind", ["bytes", "array", "list"])
def test_image_to_array_reads_rclpy_style_data(kind):
    """rclpy's Image.data is array.array('B') (bytes when assigned); lists appear in hand-made messages."""
    pixels = RNG.integers(0, 256, (3, 4, 3), dtype=np.uint8)
    raw = pixels.tobytes()
    data = {"bytes": raw, "array": array.array("B", raw), "list": list(raw)}[kind]
    msg = SimpleNamespace(height=3, width=4, step=12, encoding="bgr8", is_bigendian=0, data=data)
    np.testing.assert_array_equal(image_to_array(msg), pixels)


def test_image_expect():
    msg = image_message(np.zeros((2, 2, 3), np.uint8), "rgb8", 0, "c")
    assert image_to_array(msg, expect=("rgb8", "bgr8")).shape == (2, 2, 3)
    assert image_to_array(msg, expect="rgb8").shape == (2, 2, 3)
    with pytest.raises(MessageConversionError, match="expects 'mono8'"):
        image_to_array(msg, expect="mono8")


def _image(**fields):
    base = {"height": 2, "width": 3, "step": 3, "encoding": "mono8", "is_bigendian": 0, "data": bytes(6)}
    base.update(fields)
    return SimpleNamespace(**base)


@pytest.mark.parametrize(
    ("fields", "match"),
    [
        ({"encoding": "16UC1"}, "unsupported image encoding '16UC1'"),
        ({"encoding": "rgba8", "step": 12, "data": bytes(24)}, "unsupported image encoding"),
        ({"data": bytes(5)}, "5 bytes but step \\* height"),
        ({"data": bytes(7)}, "7 bytes"),
        ({"step": 2, "data": bytes(4)}, "step 2 is smaller than width"),
        ({"encoding": "rgb8", "step": 3, "data": bytes(6)}, "smaller than width \\* channels = 3 \\* 3"),
        ({"width": 0, "step": 0, "data": b""}, "zero size"),
        ({"height": 0, "data": b""}, "zero size"),
        ({"data": np.zeros(3, np.uint16)}, "uint8"),
    ],
)
def test_image_to_array_errors(fields, match):
    with pytest.raises(MessageConversionError, match=match):
        image_to_array(_image(**fields))


def test_image_to_array_error_is_value_error():
    with pytest.raises(ValueError):
        image_to_array(_image(encoding="yuv422"))


@pytest.mark.parametrize(
    ("pixels", "encoding", "match"),
    [
        (np.zeros((2, 2), np.float32), "mono8", "must be uint8"),
        (np.zeros((2, 2, 3), np.uint8), "mono8", "shape \\(H, W\\)"),
        (np.zeros((2, 2), np.uint8), "rgb8", "shape \\(H, W, 3\\)"),
        (np.zeros((2, 2, 4), np.uint8), "bgr8", "shape"),
        (np.zeros((0, 2), np.uint8), "mono8", "empty"),
        (np.zeros((2, 2), np.uint8), "mono16", "unsupported image encoding"),
    ],
)
def test_image_message_errors(pixels, encoding, match):
    with pytest.raises(MessageConversionError, match=match):
        image_message(pixels, encoding, 0, "c")


# --------------------------------------------------------------------------- camera info


@pytest.mark.parametrize("view", ["left", "right"])
def test_camera_info(view):
    camera = StereoCamera.default(64, 48, baseline=0.005)
    msg = camera_info_message(camera, view, STAMP, "left_camera_optical_frame")
    for received in (msg, cdr_round_trip(msg)):
        assert (received.width, received.height) == (64, 48)
        assert received.distortion_model == "plumb_bob"
        assert ns_from_stamp(received.header.stamp) == STAMP
        np.testing.assert_array_equal(np.asarray(received.k).reshape(3, 3), camera.K)
        np.testing.assert_array_equal(np.asarray(received.p).reshape(3, 4), camera.P(view))
        np.testing.assert_array_equal(received.d, np.zeros(5))
        np.testing.assert_array_equal(np.asarray(received.r).reshape(3, 3), np.eye(3))
    if view == "right":
        assert msg.p[3] == pytest.approx(-camera.fx * 0.005)


def test_camera_info_pair_rebuilds_camera():
    camera = StereoCamera.default(64, 48, baseline=0.004)
    left = cdr_round_trip(camera_info_message(camera, "left", 0, "l"))
    right = cdr_round_trip(camera_info_message(camera, "right", 0, "r"))
    assert StereoCamera.from_camera_info(left, right) == camera


# --------------------------------------------------------------------------- polygon


def test_polygon_round_trip_2d():
    points = np.array([[10.5, 20.25], [11.0, 21.0], [640.0, 480.0]])
    msg = polygon_message(points, STAMP, "cam")
    assert ns_from_stamp(msg.header.stamp) == STAMP and msg.header.frame_id == "cam"
    for received in (msg, cdr_round_trip(msg)):
        out = polygon_to_array(received)
        assert out.dtype == np.float64 and out.shape == (3, 3)
        np.testing.assert_array_equal(out[:, :2], points)
        np.testing.assert_array_equal(out[:, 2], 0.0)


def test_polygon_round_trip_3d_float32_precision():
    points = RNG.normal(size=(20, 3))
    out = polygon_to_array(cdr_round_trip(polygon_message(points, 0, "c")))
    np.testing.assert_array_equal(out, points.astype(np.float32).astype(np.float64))


@pytest.mark.parametrize("empty", [[], np.zeros((0, 2)), np.zeros((0, 3))])
def test_polygon_empty(empty):
    assert polygon_to_array(cdr_round_trip(polygon_message(empty, 0, "c"))).shape == (0, 3)


@pytest.mark.parametrize(
    ("points", "match"),
    [
        (np.zeros((3, 4)), "shape \\(N, 2\\) or \\(N, 3\\)"),
        (np.zeros(3), "shape"),
        ([[1.0, np.nan]], "NaN or inf"),
        ([[1.0, 2.0], [np.inf, 0.0]], "first at row 1"),
        ([["a", "b"]], "numeric"),
    ],
)
def test_polygon_message_errors(points, match):
    with pytest.raises(MessageConversionError, match=match):
        polygon_message(points, 0, "c")


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_polygon_to_array_rejects_non_finite(bad):
    msg = polygon_message([[1.0, 2.0], [3.0, 4.0]], 0, "c")
    msg.polygon.points[1].y = bad
    with pytest.raises(MessageConversionError, match="polygon contains NaN or inf"):
        polygon_to_array(msg)


# --------------------------------------------------------------------------- path


def test_path_round_trip():
    points = RNG.normal(size=(15, 3)) * 0.01 + [0.0, 0.0, 0.1]
    msg = path_message(points, STAMP, "left_camera_optical_frame")
    assert len(msg.poses) == 15
    for pose in msg.poses:
        assert ns_from_stamp(pose.header.stamp) == STAMP
        assert pose.header.frame_id == "left_camera_optical_frame"
        q = pose.pose.orientation
        assert (q.x, q.y, q.z, q.w) == (0.0, 0.0, 0.0, 1.0)
    assert msg.poses[0].header is not msg.poses[1].header
    for received in (msg, cdr_round_trip(msg)):
        out = path_to_array(received)
        assert out.dtype == np.float64
        np.testing.assert_array_equal(out, points)


def test_path_empty():
    assert path_to_array(cdr_round_trip(path_message(np.zeros((0, 3)), 0, "c"))).shape == (0, 3)


@pytest.mark.parametrize(
    ("points", "match"), [(np.zeros((3, 2)), "shape \\(N, 3\\)"), ([[0, 0, np.nan]], "NaN")]
)
def test_path_message_errors(points, match):
    with pytest.raises(MessageConversionError, match=match):
        path_message(points, 0, "c")


def test_path_to_array_rejects_non_finite():
    msg = path_message(np.ones((3, 3)), 0, "c")
    msg.poses[2].pose.position.z = np.nan
    with pytest.raises(MessageConversionError, match="path contains NaN or inf .*row 2"):
        path_to_array(msg)


# --------------------------------------------------------------------------- pose, point, string


def test_pose_round_trip():
    position = np.array([0.01, -0.02, 0.15])
    quaternion = np.array([0.1, -0.2, 0.3, 0.9])
    quaternion /= np.linalg.norm(quaternion)
    msg = pose_message(position, quaternion, STAMP, "base")
    assert ns_from_stamp(msg.header.stamp) == STAMP and msg.header.frame_id == "base"
    for received in (msg, cdr_round_trip(msg)):
        p, q = pose_to_arrays(received)
        assert p.shape == (3,) and q.shape == (4,) and p.dtype == q.dtype == np.float64
        np.testing.assert_array_equal(p, position)
        np.testing.assert_allclose(q, quaternion, rtol=0, atol=1e-15)


def test_pose_message_renormalises_nearly_unit_quaternion():
    q = np.array([0.0, 0.0, 0.70710, 0.70710])  # norm 0.99999..., as typed by hand
    _, out = pose_to_arrays(pose_message([0, 0, 0], q, 0, "c"))
    assert np.linalg.norm(out) == pytest.approx(1.0, abs=1e-15)


@pytest.mark.parametrize(
    ("position", "quaternion", "match"),
    [
        ([0, 0], [0, 0, 0, 1], "position must have shape \\(3,\\)"),
        ([0, 0, 0], [0, 0, 1], "quaternion must have shape \\(4,\\)"),
        ([0, np.nan, 0], [0, 0, 0, 1], "position contains NaN"),
        ([0, 0, 0], [0, 0, 0, np.inf], "quaternion contains NaN or inf"),
        ([0, 0, 0], [0, 0, 0, 0], "norm 0"),
        ([0, 0, 0], [1, 1, 1, 1], "norm 2"),
    ],
)
def test_pose_message_errors(position, quaternion, match):
    with pytest.raises(MessageConversionError, match=match):
        pose_message(position, quaternion, 0, "c")


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [
        ("position.x", np.nan, "position contains NaN"),
        ("orientation.w", np.inf, "quaternion contains NaN"),
        ("orientation.w", 0.0, "norm 0"),  # an all-zero (uninitialised) orientation
    ],
)
def test_pose_to_arrays_errors(field, value, match):
    msg = pose_message([0.1, 0.2, 0.3], [0, 0, 0, 1], 0, "c")
    part, name = field.split(".")
    setattr(getattr(msg.pose, part), name, value)
    with pytest.raises(MessageConversionError, match=match):
        pose_to_arrays(msg)


def test_point_round_trip():
    msg = point_message(np.array([320.5, 240.25, 0.0]), STAMP, "left_camera_optical_frame")
    assert ns_from_stamp(msg.header.stamp) == STAMP
    for received in (msg, cdr_round_trip(msg)):
        np.testing.assert_array_equal(point_to_array(received), [320.5, 240.25, 0.0])


def test_point_errors():
    with pytest.raises(MessageConversionError, match="shape \\(3,\\)"):
        point_message([1.0, 2.0], 0, "c")
    with pytest.raises(MessageConversionError, match="NaN"):
        point_message([1.0, np.nan, 0.0], 0, "c")
    msg = point_message([1.0, 2.0, 0.0], 0, "c")
    msg.point.x = -np.inf
    with pytest.raises(MessageConversionError, match="point contains NaN or inf"):
        point_to_array(msg)


def test_string_round_trip():
    for text in ("refused: workspace box", "", "naïve ✓"):
        assert cdr_round_trip(string_message(text)).data == text
    with pytest.raises(MessageConversionError, match="str"):
        string_message(b"bytes")


@pytest.mark.parametrize(("sec", "nanosec"), [(-1, 0), (5, 1_000_000_000), (2147483647, 4294967295)])
def test_stamps_no_output_could_carry_are_refused(sec, nanosec):
    with pytest.raises(MessageConversionError, match="header stamp out of range"):
        ns_from_stamp(SimpleNamespace(sec=sec, nanosec=nanosec))


def test_image_to_rgb_reorders_bgr8_and_repeats_mono8():
    blue_bgr = np.zeros((2, 3, 3), np.uint8)
    blue_bgr[..., 0] = 255
    rgb = image_to_rgb(image_message(blue_bgr, "bgr8", 1, "cam"))
    assert rgb.shape == (2, 3, 3) and np.all(rgb[..., 2] == 255) and not rgb[..., :2].any()
    grey = np.arange(6, dtype=np.uint8).reshape(2, 3)
    np.testing.assert_array_equal(image_to_rgb(image_message(grey, "mono8", 1, "cam")), np.dstack([grey] * 3))
    red = np.zeros((2, 3, 3), np.uint8)
    red[..., 0] = 255
    np.testing.assert_array_equal(image_to_rgb(image_message(red, "rgb8", 1, "cam")), red)
