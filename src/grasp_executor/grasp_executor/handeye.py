# SPDX-License-Identifier: Apache-2.0
"""The hand-eye transform T_base_camera: camera-frame grasp poses into the robot base frame.

Convention (docs/executor.md has a worked example): ``translation`` (metres) and
``quaternion`` (x, y, z, w) describe the camera frame *in* the robot base frame,
so that a point maps as

    p_base = R(quaternion) @ p_camera + translation

and an orientation as R_base = R(quaternion) @ R_camera. ``translation`` is the
camera's optical centre in base coordinates; the columns of R are the camera's
x (right), y (down), z (forward) axes in base coordinates. This is the paper's
``_C T^R`` (GS_R = T . GS_C), ``tf2``'s transform from ``camera_frame`` into
``base_frame``, and what ``static_transform_publisher --frame-id base_frame
--child-frame-id camera_frame`` takes.

A YAML file holds the same, either as ``translation`` + ``quaternion`` or as a
4x4 ``matrix`` (row-major, last row 0 0 0 1), optionally under a ``hand_eye:`` key::

    camera_frame: left_camera_optical_frame
    base_frame: PSM1_base
    translation: [0.10, -0.02, 0.35]
    quaternion: [1.0, 0.0, 0.0, 0.0]
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from grasp_executor.geometry import Pose, quaternion_multiply
from suture_common.grasp import quaternion_to_rotation, rotation_to_quaternion

QUATERNION_NORM_TOLERANCE = 1e-3
"""A hand-eye quaternion whose norm differs from 1 by more is rejected (a typo, not rounding)."""


class HandEyeError(ValueError):
    """The hand-eye transform is malformed; the text says which value and how to fix it."""


class FrameMismatchError(ValueError):
    """A pose or path is in another frame than the hand-eye transform's camera frame."""


@dataclass(frozen=True)
class HandEye:
    """T_base_camera: maps ``camera_frame`` coordinates into ``base_frame`` (see module docstring)."""

    translation: np.ndarray
    quaternion: np.ndarray
    camera_frame: str = "left_camera_optical_frame"
    base_frame: str = "base"

    def __post_init__(self) -> None:
        translation = _vector(self.translation, 3, "hand-eye translation")
        quaternion = _vector(self.quaternion, 4, "hand-eye quaternion")
        norm = float(np.linalg.norm(quaternion))
        if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
            raise HandEyeError(
                f"hand-eye quaternion (x, y, z, w) = {quaternion.tolist()} has norm {norm:.6g}; "
                "give a unit quaternion in x, y, z, w order (identity is [0, 0, 0, 1])"
            )
        if not self.camera_frame or not self.base_frame:
            raise HandEyeError("hand-eye camera_frame and base_frame must be non-empty frame ids")
        quaternion = quaternion / norm
        translation.flags.writeable = False
        quaternion.flags.writeable = False
        object.__setattr__(self, "translation", translation)
        object.__setattr__(self, "quaternion", quaternion)

    @classmethod
    def identity(cls, camera_frame: str = "left_camera_optical_frame", base_frame: str = "base") -> HandEye:
        """The base frame coincides with the camera frame."""
        return cls(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]), camera_frame, base_frame)

    @classmethod
    def from_matrix(
        cls, matrix: np.ndarray, camera_frame: str = "left_camera_optical_frame", base_frame: str = "base"
    ) -> HandEye:
        """From a 4x4 homogeneous T_base_camera; its rotation must be orthonormal with det +1."""
        m = np.asarray(matrix, dtype=np.float64)
        if m.shape != (4, 4) or not np.isfinite(m).all():
            raise HandEyeError(f"hand-eye matrix must be a finite 4x4 array, got shape {m.shape}")
        if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
            raise HandEyeError(f"hand-eye matrix last row must be [0, 0, 0, 1], got {m[3].tolist()}")
        rotation = m[:3, :3]
        error = float(np.abs(rotation.T @ rotation - np.eye(3)).max())
        if error > 1e-4 or np.linalg.det(rotation) < 0:
            raise HandEyeError(
                "hand-eye matrix rotation part is not a proper rotation (orthonormal, det +1); "
                f"R^T R deviates from identity by {error:.2g}"
            )
        return cls(m[:3, 3], rotation_to_quaternion(rotation), camera_frame, base_frame)

    @property
    def rotation(self) -> np.ndarray:
        """3x3 rotation R of the camera frame in the base frame."""
        return quaternion_to_rotation(self.quaternion)

    @property
    def matrix(self) -> np.ndarray:
        """4x4 homogeneous T_base_camera."""
        m = np.eye(4)
        m[:3, :3] = self.rotation
        m[:3, 3] = self.translation
        return m

    def transform_points(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) camera-frame points -> (N, 3) base-frame points (a (3,) point gives (3,))."""
        points = np.asarray(points, dtype=np.float64)
        return points @ self.rotation.T + self.translation

    def transform_pose(self, pose: Pose) -> Pose:
        """A camera-frame pose -> the same pose in the base frame.

        Raises FrameMismatchError when ``pose.frame_id`` is not ``camera_frame``.
        """
        self.check_frame(pose.frame_id, "pose")
        position = self.transform_points(pose.position)
        quaternion = quaternion_multiply(self.quaternion, pose.quaternion)
        return Pose(position, quaternion, self.base_frame)

    def check_frame(self, frame_id: str, what: str) -> None:
        """Raise FrameMismatchError unless ``frame_id`` is the camera frame."""
        if frame_id != self.camera_frame:
            raise FrameMismatchError(
                f"{what} is in frame {frame_id!r}, but the hand-eye transform maps {self.camera_frame!r} "
                f"to {self.base_frame!r}; publish it in {self.camera_frame!r} or set camera_frame"
            )


def load_hand_eye(
    path: str | Path, camera_frame: str = "left_camera_optical_frame", base_frame: str = "base"
) -> HandEye:
    """Read a hand-eye YAML file (see module docstring).

    ``camera_frame``/``base_frame`` are used where the file names no frames.
    Raises HandEyeError naming the file and the problem.
    """
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise HandEyeError(f"cannot read hand-eye file {path}: {exc.strerror or exc}") from exc
    except yaml.YAMLError as exc:
        raise HandEyeError(f"hand-eye file {path} is not valid YAML: {exc}") from exc
    if isinstance(data, dict) and isinstance(data.get("hand_eye"), dict):
        data = data["hand_eye"]
    if not isinstance(data, dict):
        raise HandEyeError(f"hand-eye file {path} must hold a mapping (translation/quaternion or matrix)")
    camera_frame = str(data.get("camera_frame", camera_frame))
    base_frame = str(data.get("base_frame", base_frame))
    try:
        if "matrix" in data:
            if "translation" in data or "quaternion" in data:
                raise HandEyeError("give either matrix or translation + quaternion, not both")
            return HandEye.from_matrix(_numbers(data["matrix"], "matrix"), camera_frame, base_frame)
        missing = [key for key in ("translation", "quaternion") if key not in data]
        if missing:
            raise HandEyeError(f"missing {' and '.join(missing)} (or give a 4x4 matrix)")
        return HandEye(
            _numbers(data["translation"], "translation"),
            _numbers(data["quaternion"], "quaternion"),
            camera_frame,
            base_frame,
        )
    except HandEyeError as exc:
        raise HandEyeError(f"hand-eye file {path}: {exc}") from None


def _numbers(values: Any, what: str) -> np.ndarray:
    try:
        return np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise HandEyeError(f"{what} must be numbers, got {values!r}") from None


def _vector(values: Any, size: int, what: str) -> np.ndarray:
    array = _numbers(values, what)
    if array.shape != (size,):
        raise HandEyeError(f"{what} needs {size} values, got shape {array.shape}")
    if not np.isfinite(array).all():
        raise HandEyeError(f"{what} contains NaN or inf: {array.tolist()}")
    return array.copy()
