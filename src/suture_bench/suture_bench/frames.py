# SPDX-License-Identifier: Apache-2.0
"""Bags as frames of numpy arrays, for every offline tool of suture_bench.

``find_bags`` expands paths into bags; ``read_frames`` joins a bag's input and
ground-truth topics by stamp into :class:`Frame` objects (docs/interfaces.md's topics,
converted with ``suture_common.messages``). The evaluator and the stage benchmarks
all read bags through here.

Simulator bags carry every ground-truth topic. Bags from elsewhere may carry less (true
masks only, or nothing): with ``complete=False`` a frame needs only its two camera_info
messages, and what it lacks is None. Their true sequences may carry z = 0 everywhere
(the contract defines no visibility flag): the visibility of each point then comes from
the true mask of its view (a point is visible where the mask is within 1 px), or, without
a mask, every point counts as visible.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from suture_common import messages, topics
from suture_common.bag_io import BagDamage, read_messages
from suture_common.camera import StereoCamera

FRAME_TOPICS = (*topics.INPUT_TOPICS, *topics.GROUND_TRUTH_TOPICS)
IMAGE_TOPICS = (topics.LEFT_IMAGE, topics.RIGHT_IMAGE)
#: The topology of a frame whose bag has no /ground_truth/topology.
UNLABELLED = "unlabelled"


class EvaluationError(ValueError):
    """The evaluation cannot start (no bags, unknown source...)."""


@dataclass
class Frame:
    """One stereo frame of a bag with its ground truth, as numpy arrays (see docs/interfaces.md).

    Images are (H, W, 3) uint8, or None when read with ``images=False``; masks (H, W)
    bool; sequences (N, 3) (u, v, visible); path (M, 3) m; grasp point (3,) m. Ground truth
    the bag lacks is None (only with ``read_frames(..., complete=False)``).
    ``visibility``: where the sequences' visible column comes from: 'flag' (the bag's z),
    'mask' (the true masks) or 'assumed' (no flag and no mask: all visible).
    """

    stamp_ns: int
    topology: str
    camera: StereoCamera
    left_image: np.ndarray | None
    right_image: np.ndarray | None
    tip_hint: np.ndarray | None
    true_left_mask: np.ndarray | None
    true_right_mask: np.ndarray | None
    true_left_sequence: np.ndarray | None
    true_right_sequence: np.ndarray | None
    true_path: np.ndarray | None
    true_grasp: np.ndarray | None
    visibility: str = "flag"


def find_bags(paths: Iterable[str | Path]) -> list[Path]:
    """Bag directories (with metadata.yaml) or .mcap files named by, or found under, ``paths``."""
    bags: list[Path] = []
    for path in map(Path, paths):
        if not path.exists():
            raise EvaluationError(f"{path} does not exist")
        if path.is_file() or (path / "metadata.yaml").exists():
            bags.append(path)
            continue
        found = sorted({p.parent for p in path.rglob("metadata.yaml")})
        found += sorted(p for p in path.rglob("*.mcap") if not (p.parent / "metadata.yaml").exists())
        if not found:
            raise EvaluationError(f"no bags (metadata.yaml or .mcap) under {path}")
        bags.extend(found)
    return bags


def read_frames(
    bag: Path,
    images: bool = True,
    complete: bool = True,
    skipped: Counter | None = None,
    damage: BagDamage | None = None,
) -> Iterator[Frame]:
    """Frames of one bag in stamp order.

    ``images=False`` skips decoding the camera images (the stages after segmentation
    start from the ground-truth masks or sequences and do not need them).
    ``complete=True`` yields only frames with every input and ground-truth topic (a
    simulator bag's frames); ``complete=False`` every stamp with both camera_info messages
    (and both images, when ``images``). A stamp left out is counted in ``skipped`` by
    reason. ``damage``: read what can be read of a damaged bag (``suture_common.bag_io``).
    """
    wanted = FRAME_TOPICS if images else tuple(t for t in FRAME_TOPICS if t not in IMAGE_TOPICS)
    needed = [t for t in wanted if t != topics.TIP_HINT]
    if not complete:
        needed = [topics.LEFT_CAMERA_INFO, topics.RIGHT_CAMERA_INFO, *(IMAGE_TOPICS if images else ())]
    pending: dict[int, dict[str, Any]] = defaultdict(dict)
    for record in read_messages(bag, wanted, damage):
        pending[record.timestamp_ns][record.topic] = record.message
    for stamp in sorted(pending):
        got = pending.pop(stamp)
        missing = [t for t in needed if t not in got]
        if missing:
            if skipped is not None:
                skipped[f"no {', '.join(missing)}"] += 1
            continue
        yield _frame(stamp, got, images)


def _frame(stamp: int, got: dict[str, Any], images: bool) -> Frame:
    def convert(topic: str, how: Any, *args: Any) -> Any:
        return how(got[topic], *args) if topic in got else None

    left_mask = convert(topics.GT_LEFT_MASK, _mask)
    right_mask = convert(topics.GT_RIGHT_MASK, _mask)
    left_sequence = convert(topics.GT_LEFT_SEQUENCE, messages.polygon_to_array)
    right_sequence = convert(topics.GT_RIGHT_SEQUENCE, messages.polygon_to_array)
    visibility = "flag"
    if left_sequence is not None and not np.any(left_sequence[:, 2]):
        visibility = "mask" if left_mask is not None else "assumed"
        left_sequence = with_visibility(left_sequence, left_mask)
        if right_sequence is not None:
            right_sequence = with_visibility(right_sequence, right_mask)
    grasp = convert(topics.GT_GRASP_POSE, messages.pose_to_arrays)
    return Frame(
        stamp_ns=stamp,
        topology=got[topics.GT_TOPOLOGY].data if topics.GT_TOPOLOGY in got else UNLABELLED,
        camera=StereoCamera.from_camera_info(got[topics.LEFT_CAMERA_INFO], got[topics.RIGHT_CAMERA_INFO]),
        left_image=convert(topics.LEFT_IMAGE, messages.image_to_rgb) if images else None,
        right_image=convert(topics.RIGHT_IMAGE, messages.image_to_rgb) if images else None,
        tip_hint=messages.point_to_array(got[topics.TIP_HINT])[:2] if topics.TIP_HINT in got else None,
        true_left_mask=left_mask,
        true_right_mask=right_mask,
        true_left_sequence=left_sequence,
        true_right_sequence=right_sequence,
        true_path=convert(topics.GT_PATH, messages.path_to_array),
        true_grasp=None if grasp is None else grasp[0],
        visibility=visibility,
    )


def _mask(message: Any) -> np.ndarray:
    return messages.image_to_array(message, expect="mono8") > 0


def with_visibility(sequence: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    """(N, 3) ``sequence`` with its visible column from ``mask``: 1 where the mask is within 1 px
    of the point, else 0; all 1 without a mask."""
    sequence = np.array(sequence, dtype=np.float64)
    if mask is None:
        sequence[:, 2] = 1.0
        return sequence
    near = cv2.dilate(mask.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    height, width = near.shape
    u = np.clip(np.rint(sequence[:, 0]).astype(int), 0, width - 1)
    v = np.clip(np.rint(sequence[:, 1]).astype(int), 0, height - 1)
    sequence[:, 2] = near[v, u].astype(np.float64)
    return sequence
