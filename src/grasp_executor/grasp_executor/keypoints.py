# SPDX-License-Identifier: Apache-2.0
"""Key-point mode: the paper's UR5 validation (Section III.B.2, Table II).

A touching tip visits N points evenly spaced by arc length along the
reconstructed path (both ends included; N = 1 gives the cut tip). At each
point the tool approaches along its own z axis from ``approach_offset`` back,
touches, dwells (so a person can measure the tip-to-thread distance, as the
paper did), the measured tool pose is recorded, and the tool retreats the same
way. The tool orientation is fixed for the whole run (the paper held the tip
vertical to the surface).

:class:`KeypointRecord` holds the commanded point and the measured tool pose of
one visit; :func:`append_keypoint_csv` writes them to a CSV file a lab can
extend with its own measured tip-to-thread errors.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from grasp_executor.geometry import Pose
from grasp_executor.planning import Dwell, Move, Plan, Step
from suture_common.parameters import described


def evenly_spaced_points(path: np.ndarray, count: int) -> np.ndarray:
    """(count, 3) points equally spaced by arc length along an (M, 3) polyline, first to last point.

    Raises ValueError for fewer than 2 points, NaN, a path of zero length or count < 1.
    """
    path = np.asarray(path, dtype=np.float64)
    if count < 1:
        raise ValueError(f"key-point count must be at least 1, got {count}")
    if path.ndim != 2 or path.shape[1] != 3 or len(path) < 2:
        raise ValueError(f"path needs at least 2 points of (x, y, z), got shape {path.shape}")
    if not np.isfinite(path).all():
        raise ValueError("path contains NaN or inf")
    steps = np.linalg.norm(np.diff(path, axis=0), axis=1)
    cumulative = np.concatenate([[0.0], np.cumsum(steps)])
    if cumulative[-1] <= 0:
        raise ValueError("path has zero length")
    wanted = np.linspace(0.0, cumulative[-1], count)
    index = np.clip(np.searchsorted(cumulative, wanted, side="right") - 1, 0, len(steps) - 1)
    segment = steps[index]
    fraction = np.divide(wanted - cumulative[index], segment, out=np.zeros(count), where=segment > 0)
    return path[index] + np.clip(fraction, 0.0, 1.0)[:, None] * (path[index + 1] - path[index])


@dataclass(frozen=True)
class KeypointConfig:
    """Parameters of key-point mode; metres, seconds, quaternion (x, y, z, w) in the base frame."""

    count: int = field(
        default=10,
        metadata=described(
            "number of key points visited along the path (a float with an integer value is accepted)",
            (1, 10_000),
        ),
    )
    approach_offset: float = field(
        default=0.01,
        metadata=described("key points: approach and retreat distance along the tool z axis (m)", (0.0, 0.5)),
    )
    dwell: float = field(
        default=1.0,
        metadata=described("key points: time at each touch point (s)", (0.0, 3600.0)),
    )
    orientation_from_robot: bool = field(
        default=True,
        metadata=described("key points: keep the tool orientation measured at the start"),
    )
    orientation: tuple[float, float, float, float] = field(
        default=(1.0, 0.0, 0.0, 0.0),
        metadata=described(
            "key points: tool orientation [x, y, z, w] in the base frame when not from the robot"
        ),
    )

    def __post_init__(self) -> None:
        if not (math.isfinite(self.count) and int(self.count) == self.count and self.count >= 1):
            raise ValueError(f"keypoints.count must be a positive integer, got {self.count}")
        object.__setattr__(self, "count", int(self.count))
        for name in ("approach_offset", "dwell"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"keypoints.{name} must be non-negative, got {value}")
        orientation = np.asarray(self.orientation, dtype=np.float64)
        norm = float(np.linalg.norm(orientation)) if orientation.shape == (4,) else float("nan")
        if not (np.isfinite(orientation).all() and abs(norm - 1.0) <= 1e-3):
            raise ValueError(
                f"keypoints.orientation must be a unit quaternion (x, y, z, w), got {self.orientation}"
            )
        object.__setattr__(self, "orientation", tuple((orientation / norm).tolist()))


def plan_keypoints(
    points: np.ndarray, orientation: np.ndarray, frame_id: str, approach_offset: float, dwell: float
) -> Plan:
    """Approach, touch, dwell (recording key point i) and retreat for each (N, 3) base-frame point."""
    points = np.asarray(points, dtype=np.float64)
    orientation = np.asarray(orientation, dtype=np.float64)
    approach = Pose(np.zeros(3), orientation).axis(2)
    steps: list[Step] = []
    for index, point in enumerate(points):
        label = f"key point {index + 1}/{len(points)}"
        touch = Pose(point, orientation, frame_id)
        above = touch.translated(-approach_offset * approach)
        steps += [
            Move(f"{label} approach", above),
            Move(f"{label} touch", touch, is_target=True),
            Dwell(f"{label} dwell", dwell, keypoint=index),
            Move(f"{label} retreat", above),
        ]
    first = Pose(points[0], orientation, frame_id)
    return Plan("keypoints", first, tuple(steps), keypoints=points.copy())


@dataclass(frozen=True)
class KeypointRecord:
    """One visited key point: commanded position and the measured tool pose after the dwell (base frame)."""

    index: int
    count: int
    commanded: np.ndarray
    commanded_camera: np.ndarray
    measured: Pose | None

    @property
    def deviation(self) -> float:
        """Distance in metres between measured and commanded tool positions (NaN without a measurement)."""
        if self.measured is None:
            return float("nan")
        return float(np.linalg.norm(self.measured.position - self.commanded))

    def describe(self) -> str:
        """One log line: commanded point, measured tool pose and their distance."""
        commanded = ", ".join(f"{v:.4f}" for v in self.commanded)
        if self.measured is None:
            return f"key point {self.index + 1}/{self.count}: commanded ({commanded}) m, no measured pose"
        measured = ", ".join(f"{v:.4f}" for v in self.measured.position)
        quaternion = ", ".join(f"{v:.4f}" for v in self.measured.quaternion)
        return (
            f"key point {self.index + 1}/{self.count}: commanded ({commanded}) m, measured tool "
            f"({measured}) m, quaternion ({quaternion}), deviation {self.deviation * 1000:.2f} mm"
        )


CSV_COLUMNS = (
    "index",
    "commanded_x",
    "commanded_y",
    "commanded_z",
    "camera_x",
    "camera_y",
    "camera_z",
    "measured_x",
    "measured_y",
    "measured_z",
    "measured_qx",
    "measured_qy",
    "measured_qz",
    "measured_qw",
    "deviation_mm",
    "frame_id",
)


def append_keypoint_csv(path: str | Path, record: KeypointRecord) -> None:
    """Append ``record`` as a row to the CSV file ``path`` (metres; a header row first in a new file)."""
    path = Path(path)
    new = not path.exists() or path.stat().st_size == 0
    measured = record.measured
    values = [
        *record.commanded,
        *record.commanded_camera,
        *(measured.position if measured is not None else [math.nan] * 3),
        *(measured.quaternion if measured is not None else [math.nan] * 4),
    ]
    row = [record.index + 1, *(f"{v:.6f}" for v in values), f"{record.deviation * 1000:.3f}"]
    row.append(measured.frame_id if measured is not None else "")
    with path.open("a", newline="") as handle:
        writer = csv.writer(handle)
        if new:
            writer.writerow(CSV_COLUMNS)
        writer.writerow(row)
