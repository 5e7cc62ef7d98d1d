# SPDX-License-Identifier: Apache-2.0
"""Rectified stereo pinhole camera: projection, triangulation and CameraInfo fields.

Conventions (REP-103, ``image_pipeline``):

* Points are in the left camera optical frame (x right, y down, z forward), in
  metres, as arrays of shape (N, 3), dtype float64.
* Pixels are (u, v) = (column, row) with the centre of the top-left pixel at
  (0, 0), as arrays of shape (N, 2).
* The right camera sits at x = +baseline in the left optical frame. Its
  projection matrix P holds Tx = -fx * baseline (the ROS CameraInfo rule), so a
  point at depth z has disparity d = u_left - u_right = fx * baseline / z > 0.
* Both views share K (rectified pair); distortion is zero.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


class CameraModelError(ValueError):
    """A camera model or CameraInfo is unusable (not rectified, zero baseline...)."""


@dataclass(frozen=True)
class StereoCamera:
    """A rectified stereo pair with shared intrinsics.

    Attributes are in pixels except ``baseline`` (metres).
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    baseline: float

    def __post_init__(self) -> None:
        values = (self.fx, self.fy, self.cx, self.cy, self.baseline)
        if not all(np.isfinite(values)):
            raise CameraModelError(f"camera parameters must be finite, got {values}")
        if self.width <= 0 or self.height <= 0:
            raise CameraModelError(f"image size must be positive, got {self.width}x{self.height}")
        if self.fx <= 0 or self.fy <= 0:
            raise CameraModelError(f"focal lengths must be positive, got fx={self.fx} fy={self.fy}")
        if self.baseline <= 0:
            raise CameraModelError(f"stereo baseline must be positive, got {self.baseline} m")

    @classmethod
    def default(cls, width: int, height: int, baseline: float = 0.005) -> StereoCamera:
        """An endoscope-like pair: 63 degree horizontal field of view, centred principal point."""
        focal = 0.8125 * width  # 520 px at 640 wide, 1040 px at 1280 wide
        return cls(width, height, focal, focal, (width - 1) / 2.0, (height - 1) / 2.0, baseline)

    @property
    def K(self) -> np.ndarray:  # noqa: N802 - the name used by CameraInfo
        """3x3 intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def P(self, view: str) -> np.ndarray:  # noqa: N802 - the name used by CameraInfo
        """3x4 projection matrix of ``view`` ('left' or 'right'), Tx = -fx * baseline on the right."""
        tx = 0.0 if _check_view(view) == "left" else -self.fx * self.baseline
        return np.array([[self.fx, 0.0, self.cx, tx], [0.0, self.fy, self.cy, 0.0], [0.0, 0.0, 1.0, 0.0]])

    def optical_centre(self, view: str) -> np.ndarray:
        """Position (3,) of the view's optical centre in the left optical frame, metres."""
        return np.array([0.0 if _check_view(view) == "left" else self.baseline, 0.0, 0.0])

    def project(self, points: np.ndarray, view: str) -> np.ndarray:
        """Project (N, 3) points in the left optical frame to (N, 2) pixels of ``view``.

        Points at or behind the camera (z <= 0) project to NaN.
        """
        points = np.asarray(points, dtype=np.float64)
        x = points[..., 0] - self.optical_centre(view)[0]
        z = np.where(points[..., 2] > 0, points[..., 2], np.nan)
        u = self.fx * x / z + self.cx
        v = self.fy * points[..., 1] / z + self.cy
        return np.stack([u, v], axis=-1)

    def rays(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Normalised ray slopes (x/z, y/z) of pixels (u, v); the same for both views."""
        return (np.asarray(u) - self.cx) / self.fx, (np.asarray(v) - self.cy) / self.fy

    def disparity(self, depth: np.ndarray) -> np.ndarray:
        """Disparity in pixels (u_left - u_right) of points at ``depth`` metres."""
        return self.fx * self.baseline / np.asarray(depth, dtype=np.float64)

    def triangulate(self, left_uv: np.ndarray, right_u: np.ndarray) -> np.ndarray:
        """(N, 3) points from left pixels (N, 2) and right columns (N,) on the same rows."""
        left_uv = np.asarray(left_uv, dtype=np.float64)
        disparity = left_uv[:, 0] - np.asarray(right_u, dtype=np.float64)
        z = self.fx * self.baseline / disparity
        x = (left_uv[:, 0] - self.cx) * z / self.fx
        y = (left_uv[:, 1] - self.cy) * z / self.fy
        return np.stack([x, y, z], axis=-1)

    def camera_info_fields(self, view: str) -> dict[str, Any]:
        """The sensor_msgs/CameraInfo fields of ``view`` (without the header)."""
        return {
            "height": self.height,
            "width": self.width,
            "distortion_model": "plumb_bob",
            "d": np.zeros(5),
            "k": self.K.ravel(),
            "r": np.eye(3).ravel(),
            "p": self.P(view).ravel(),
        }

    @classmethod
    def from_camera_info(cls, left: Any, right: Any) -> StereoCamera:
        """Build the pair from two CameraInfo messages (rclpy or rosbags; fields k, p, d...).

        Raises CameraModelError when the pair is not a rectified, aligned stereo pair.
        """
        p_left = np.asarray(left.p, dtype=np.float64).reshape(3, 4)
        p_right = np.asarray(right.p, dtype=np.float64).reshape(3, 4)
        if (left.width, left.height) != (right.width, right.height):
            raise CameraModelError(
                f"left and right camera_info sizes differ: {left.width}x{left.height} "
                f"vs {right.width}x{right.height}"
            )
        if not (np.all(np.isfinite(p_left)) and np.all(np.isfinite(p_right))):
            raise CameraModelError("camera_info projection matrix P contains NaN or inf")
        if not np.allclose(p_left[:, :3], p_right[:, :3], rtol=1e-6, atol=1e-6):
            raise CameraModelError(
                "left and right P differ in their 3x3 part: the pair is not rectified "
                "(use the rectified camera_info from image_proc/stereo calibration)"
            )
        if p_left[0, 3] != 0.0 or p_right[1, 3] != 0.0:
            raise CameraModelError("left P must have Tx = 0 and right P Ty = 0 (horizontal stereo)")
        fx = p_left[0, 0]
        if fx <= 0:
            raise CameraModelError(f"camera_info has non-positive fx = {fx}")
        baseline = -p_right[0, 3] / fx
        if not baseline > 0:
            raise CameraModelError(
                f"right camera_info P has Tx = {p_right[0, 3]}: expected -fx * baseline < 0 "
                "(zero or negative baseline)"
            )
        return cls(
            int(left.width),
            int(left.height),
            fx,
            p_left[1, 1],
            p_left[0, 2],
            p_left[1, 2],
            float(baseline),
        )


def _check_view(view: str) -> str:
    if view not in ("left", "right"):
        raise ValueError(f"view must be 'left' or 'right', got {view!r}")
    return view


class CameraInfoCache:
    """The latest camera_info of each view and the :class:`StereoCamera` they make, built once.

    The nodes give it every CameraInfo message they receive (:meth:`update`); :meth:`camera`
    builds the stereo camera again only when a field it is made of changed.
    """

    SIDES = ("left", "right")

    def __init__(self) -> None:
        self._messages: dict[str, Any] = {}
        self._camera: tuple[tuple[Any, ...], StereoCamera] | None = None

    def update(self, side: str, message: Any) -> None:
        """Keep ``message`` as the camera_info of ``side`` ('left' or 'right')."""
        if side not in self.SIDES:
            raise ValueError(f"side must be 'left' or 'right', got {side!r}")
        self._messages[side] = message

    def missing(self) -> list[str]:
        """The sides without camera_info yet."""
        return [side for side in self.SIDES if side not in self._messages]

    def camera(self) -> StereoCamera | None:
        """The stereo camera of the latest pair, or None while a side has none.

        Raises CameraModelError (from :meth:`StereoCamera.from_camera_info`) when the pair is
        unusable; it is tried again on the next call.
        """
        if self.missing():
            return None
        left, right = self._messages["left"], self._messages["right"]
        key = (tuple(left.p), tuple(right.p), left.width, left.height, right.width, right.height)
        if self._camera is None or self._camera[0] != key:
            self._camera = (key, StereoCamera.from_camera_info(left, right))
        return self._camera[1]
