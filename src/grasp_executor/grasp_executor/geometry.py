# SPDX-License-Identifier: Apache-2.0
"""Poses and rotations for the executor: the :class:`Pose` value, quaternion <-> rotation vector, slerp.

Conventions: positions in metres, quaternions (x, y, z, w) as in ROS messages,
rotation vectors (rx, ry, rz) = unit axis * angle in radians as Universal Robots
controllers use them. Rotation matrices come from :mod:`suture_common.grasp`.

The conversions accept one value (shape (4,) or (3,)) or a batch (shape (N, 4)
or (N, 3)) and are written with numpy only; ``scipy.spatial.transform`` is the
test oracle, not a dependency.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from suture_common.grasp import quaternion_to_rotation

_SMALL_ANGLE = 1e-6


@dataclass(frozen=True)
class Pose:
    """A tool or target pose: position (3,) metres and quaternion (4,) x y z w in ``frame_id``.

    The arrays are stored as read-only float64 copies. A Pose may hold NaN or a
    non-unit quaternion (a bad message, a bad sensor value): it is a value, and
    :class:`grasp_executor.safety.SafetyGate` decides whether it may be commanded.
    """

    position: np.ndarray
    quaternion: np.ndarray
    frame_id: str = ""

    def __post_init__(self) -> None:
        position = np.array(self.position, dtype=np.float64).reshape(-1)
        quaternion = np.array(self.quaternion, dtype=np.float64).reshape(-1)
        if position.shape != (3,) or quaternion.shape != (4,):
            raise ValueError(
                f"a pose needs 3 position and 4 quaternion values, got {position.size} and {quaternion.size}"
            )
        position.flags.writeable = False
        quaternion.flags.writeable = False
        object.__setattr__(self, "position", position)
        object.__setattr__(self, "quaternion", quaternion)

    def is_finite(self) -> bool:
        """True when no position or quaternion value is NaN or infinite."""
        return bool(np.isfinite(self.position).all() and np.isfinite(self.quaternion).all())

    def rotation(self) -> np.ndarray:
        """3x3 rotation matrix (columns: the pose's x, y, z axes in ``frame_id``)."""
        return quaternion_to_rotation(self.quaternion)

    def axis(self, index: int) -> np.ndarray:
        """Unit x (0), y (1) or z (2) axis of the pose, expressed in ``frame_id``."""
        return self.rotation()[:, index]

    def translated(self, offset: np.ndarray) -> Pose:
        """The same orientation and frame at ``position + offset``."""
        return Pose(self.position + np.asarray(offset, dtype=np.float64), self.quaternion, self.frame_id)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Pose):
            return NotImplemented
        return (
            self.frame_id == other.frame_id
            and np.array_equal(self.position, other.position, equal_nan=True)
            and np.array_equal(self.quaternion, other.quaternion, equal_nan=True)
        )

    __hash__ = None  # type: ignore[assignment]  # holds arrays


def quaternion_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` of (..., 4) quaternions (x, y, z, w): rotate by ``b``, then by ``a``."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    av, aw = a[..., :3], a[..., 3:]
    bv, bw = b[..., :3], b[..., 3:]
    vector = aw * bv + bw * av + np.cross(av, bv)
    scalar = aw * bw - np.sum(av * bv, axis=-1, keepdims=True)
    return np.concatenate([vector, scalar], axis=-1)


def quaternion_to_rotvec(quaternion: np.ndarray) -> np.ndarray:
    """Rotation vector(s) (..., 3) of (..., 4) quaternion(s) (x, y, z, w); angle in [0, pi].

    The quaternion need not be normalised; q and -q give the same vector. Raises
    ValueError for a zero or non-finite quaternion.
    """
    q = np.asarray(quaternion, dtype=np.float64)
    if q.shape[-1:] != (4,):
        raise ValueError(f"quaternions must have shape (..., 4), got {q.shape}")
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if not np.isfinite(q).all() or (norm == 0).any():
        raise ValueError("quaternion is zero, NaN or infinite; it has no rotation vector")
    q = q / norm
    q = np.where(q[..., 3:] < 0, -q, q)  # w >= 0, so the angle is in [0, pi]
    vector, w = q[..., :3], q[..., 3:]
    sin_half = np.linalg.norm(vector, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(sin_half, w)
    # angle / sin(angle / 2), with its series 2 + angle^2 / 12 near zero
    safe = np.where(sin_half > _SMALL_ANGLE, sin_half, 1.0)
    scale = np.where(sin_half > _SMALL_ANGLE, angle / safe, 2.0 + angle**2 / 12.0)
    return vector * scale


def rotvec_to_quaternion(rotvec: np.ndarray) -> np.ndarray:
    """Unit quaternion(s) (..., 4) (x, y, z, w), w >= 0, of (..., 3) rotation vector(s).

    Raises ValueError for NaN or infinite values.
    """
    r = np.asarray(rotvec, dtype=np.float64)
    if r.shape[-1:] != (3,):
        raise ValueError(f"rotation vectors must have shape (..., 3), got {r.shape}")
    if not np.isfinite(r).all():
        raise ValueError("rotation vector contains NaN or inf")
    angle = np.linalg.norm(r, axis=-1, keepdims=True)
    # sin(angle / 2) / angle, with its series 1/2 - angle^2 / 48 near zero
    safe = np.where(angle > _SMALL_ANGLE, angle, 1.0)
    scale = np.where(angle > _SMALL_ANGLE, np.sin(angle / 2.0) / safe, 0.5 - angle**2 / 48.0)
    q = np.concatenate([r * scale, np.cos(angle / 2.0)], axis=-1)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:] < 0, -q, q)


def rotation_angle(a: np.ndarray, b: np.ndarray) -> float:
    """Angle in radians [0, pi] of the rotation between unit quaternions ``a`` and ``b``."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    dot = abs(float(np.dot(a / np.linalg.norm(a), b / np.linalg.norm(b))))
    return 2.0 * float(np.arccos(min(1.0, dot)))


def slerp(a: np.ndarray, b: np.ndarray, fraction: float) -> np.ndarray:
    """Spherical linear interpolation between unit quaternions: ``a`` at 0, ``b`` (or -b) at 1.

    Takes the shorter way round; the result is a unit quaternion.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    dot = float(np.dot(a, b))
    if dot < 0.0:
        b, dot = -b, -dot
    if dot > 1.0 - 1e-9:
        q = a + fraction * (b - a)
    else:
        theta = np.arccos(dot)
        q = (np.sin((1.0 - fraction) * theta) * a + np.sin(fraction * theta) * b) / np.sin(theta)
    return q / np.linalg.norm(q)
