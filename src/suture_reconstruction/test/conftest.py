# SPDX-License-Identifier: Apache-2.0
"""Shared fixtures: synthetic stereo threads with exact ground truth, and the committed sample bag."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest

from suture_common import topics
from suture_common.bag_io import read_messages
from suture_common.camera import StereoCamera
from suture_common.grasp import point_at_arc_length
from suture_common.messages import image_to_array, path_to_array, polygon_to_array, pose_to_arrays

SAMPLE_BAG = Path(__file__).resolve().parents[3] / "bags" / "sample"


@dataclass
class Scene:
    """A thread seen by a stereo camera: noisy, independently sampled (N, 2) sequences and the truth."""

    camera: StereoCamera
    left: np.ndarray
    right: np.ndarray
    path: np.ndarray
    grasp: np.ndarray


def view_sequence(
    camera: StereoCamera, curve: np.ndarray, view: str, rng: np.random.Generator, noise: float
) -> np.ndarray:
    """The image sequence of a dense 3D ``curve`` in ``view``: every ~1 px from the tip, plus noise."""
    uv = camera.project(curve, view)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(uv, axis=0), axis=1))])
    step = rng.uniform(0.95, 1.05)
    s = np.concatenate([[0.0], np.arange(rng.uniform(0, step), arc[-1], step)])
    sequence = np.column_stack([np.interp(s, arc, uv[:, 0]), np.interp(s, arc, uv[:, 1])])
    return sequence + rng.normal(0.0, noise, sequence.shape)


def planar_thread(kind: str, rng: np.random.Generator) -> np.ndarray:
    """A dense (every 0.05 mm) 3D centreline (m) in the left optical frame, about 90 mm from the camera.

    kinds: 'curved' (an S bend), 'loop' (crosses itself, the later strand lifted 1 mm over
    the earlier one), 'rows' (a straight thread 1 degree off the image rows), 'short' (20 mm),
    'lifted' and 'lifted_steep' (a thread 5 or 30 degrees off the image rows, lifted 6 mm towards
    the camera over about 12 mm of its length, 25 mm from the tip, as over the other strand of a
    crossing).
    """
    if kind.startswith("lifted"):
        return lifted_thread(5.0 if kind == "lifted" else 30.0)
    step = 5e-5
    length = {"short": 0.02}.get(kind, 0.09)
    s = np.arange(0.0, length, step)
    if kind == "loop":
        bump = np.exp(-0.5 * ((s - length / 2) / 0.012) ** 2)
        curvature = bump * (2 * np.pi + 0.8) / (bump.sum() * step) + 8.0
    elif kind in ("rows", "short"):
        curvature = np.zeros_like(s)
    else:
        curvature = 40.0 * np.sin(2 * np.pi * s / length)
    heading = np.cumsum(curvature) * step + (np.radians(1.0) if kind == "rows" else rng.uniform(0, 2 * np.pi))
    xy = np.cumsum(np.column_stack([np.cos(heading), np.sin(heading)]) * step, axis=0)
    xy -= xy.mean(axis=0)
    z = 0.09 + 0.15 * xy[:, 0] + 0.002 * np.sin(2 * np.pi * s / length)
    if kind == "loop":
        far = np.abs(np.arange(0, len(s), 20)[:, None] - np.arange(0, len(s), 20)[None, :]) > 100
        sub = xy[::20]
        gaps = np.linalg.norm(sub[:, None] - sub[None, :], axis=2)
        i, j = np.unravel_index(np.argmin(np.where(far, gaps, np.inf)), gaps.shape)
        later = max(i, j) * 20
        z = z - 0.001 * np.exp(-0.5 * ((s - s[later]) / 0.003) ** 2)
    return np.column_stack([xy, z])


def lifted_thread(heading_deg: float, lift: float = 0.006, width: float = 0.003) -> np.ndarray:
    """A gently bent 90 mm thread ``heading_deg`` off the image rows, lifted by ``lift`` (m; a
    Gaussian of ``width`` m, 25 mm from the tip): 6 mm over 3 mm is a slope of 1.2, so the depth
    excursion is most of the arc length there (dense, every 0.05 mm, in metres)."""
    step = 5e-5
    s = np.arange(0.0, 0.09, step)
    heading = np.radians(heading_deg) + 0.05 * np.sin(2 * np.pi * s / 0.09)
    xy = np.cumsum(np.column_stack([np.cos(heading), np.sin(heading)]) * step, axis=0)
    xy -= xy.mean(axis=0)
    z = 0.095 + 0.1 * xy[:, 0] - lift * np.exp(-0.5 * ((s - 0.025) / width) ** 2)
    return np.column_stack([xy, z])


def exact_view_sequences(camera: StereoCamera, curve: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The left and right image sequences (N, 2) of a dense 3D ``curve`` (m): every 1 px from the
    tip, without noise."""
    sequences = []
    for view in ("left", "right"):
        uv = camera.project(curve, view)
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(uv, axis=0), axis=1))])
        t = np.arange(0.0, arc[-1], 1.0)
        sequences.append(np.column_stack([np.interp(t, arc, uv[:, 0]), np.interp(t, arc, uv[:, 1])]))
    return sequences[0], sequences[1]


@pytest.fixture
def exact_views() -> Callable[[StereoCamera, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """:func:`exact_view_sequences`, for tests that build their own threads."""
    return exact_view_sequences


def textured_plane_views(
    camera: StereoCamera, surface_disparity: int, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """(left, right) uint8 (H, W, 3) images of a textured plane at ``surface_disparity`` px."""
    rng = np.random.default_rng(seed)
    width = camera.width + surface_disparity
    texture = cv2.GaussianBlur(rng.uniform(0, 255, (camera.height, width)).astype(np.float32), (0, 0), 2.0)
    texture = np.clip(128 + 4 * (texture - texture.mean()), 0, 255).astype(np.uint8)
    left = texture[:, : camera.width]
    right = texture[:, surface_disparity:]  # right(u) = left(u + d): the plane at disparity d
    return np.dstack([left] * 3), np.dstack([right] * 3)


@pytest.fixture
def textured_pair() -> Callable[..., tuple[np.ndarray, np.ndarray]]:
    """:func:`textured_plane_views`, for tests that give reconstruct images."""
    return textured_plane_views


@pytest.fixture
def make_scene() -> Callable[..., Scene]:
    def make(
        kind: str = "curved", seed: int = 0, noise: float = 0.3, width: int = 640, height: int = 480
    ) -> Scene:
        rng = np.random.default_rng(seed)
        camera = StereoCamera.default(width, height)
        curve = planar_thread(kind, rng)
        grasp = point_at_arc_length(curve, 0.05)[0] if kind != "short" else curve[-1]
        return Scene(
            camera,
            view_sequence(camera, curve, "left", rng, noise),
            view_sequence(camera, curve, "right", rng, noise),
            curve,
            grasp,
        )

    return make


@dataclass
class SampleFrame:
    """One frame of bags/sample: ground-truth sequences, camera_info messages, the true thread and
    the rectified (H, W, 3) uint8 images."""

    stamp_ns: int
    topology: str
    left: np.ndarray
    right: np.ndarray
    left_info: object
    right_info: object
    path: np.ndarray
    grasp: np.ndarray
    left_image: np.ndarray
    right_image: np.ndarray


@pytest.fixture(scope="session")
def sample_frames() -> list[SampleFrame]:
    wanted = [
        topics.GT_LEFT_SEQUENCE,
        topics.GT_RIGHT_SEQUENCE,
        topics.GT_PATH,
        topics.GT_GRASP_POSE,
        topics.GT_TOPOLOGY,
        topics.LEFT_CAMERA_INFO,
        topics.RIGHT_CAMERA_INFO,
        topics.LEFT_IMAGE,
        topics.RIGHT_IMAGE,
    ]
    by_stamp: dict[int, dict[str, object]] = {}
    for item in read_messages(SAMPLE_BAG, wanted):
        by_stamp.setdefault(item.timestamp_ns, {})[item.topic] = item.message
    frames = []
    for stamp, m in sorted(by_stamp.items()):
        frames.append(
            SampleFrame(
                stamp,
                m[topics.GT_TOPOLOGY].data,
                polygon_to_array(m[topics.GT_LEFT_SEQUENCE])[:, :2],
                polygon_to_array(m[topics.GT_RIGHT_SEQUENCE])[:, :2],
                m[topics.LEFT_CAMERA_INFO],
                m[topics.RIGHT_CAMERA_INFO],
                path_to_array(m[topics.GT_PATH]),
                pose_to_arrays(m[topics.GT_GRASP_POSE])[0],
                image_to_array(m[topics.LEFT_IMAGE]),
                image_to_array(m[topics.RIGHT_IMAGE]),
            )
        )
    return frames
