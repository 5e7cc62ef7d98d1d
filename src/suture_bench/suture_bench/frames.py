"""Simulator bags as frames of numpy arrays, for every offline tool of suture_bench.

``find_bags`` expands paths into bags; ``read_frames`` joins a bag's input and
ground-truth topics by stamp into :class:`Frame` objects (DESIGN.md's topics,
converted with ``suture_common.messages``). The evaluator and the stage benchmarks
all read bags through here.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from suture_common import messages, topics
from suture_common.bag_io import read_messages
from suture_common.camera import StereoCamera

FRAME_TOPICS = (*topics.INPUT_TOPICS, *topics.GROUND_TRUTH_TOPICS)
IMAGE_TOPICS = (topics.LEFT_IMAGE, topics.RIGHT_IMAGE)


class EvaluationError(ValueError):
    """The evaluation cannot start (no bags, unknown source...)."""


@dataclass
class Frame:
    """One stereo frame of a bag with its ground truth, as numpy arrays (see DESIGN.md).

    Images are (H, W, 3) uint8, or None when read with ``images=False``; masks (H, W)
    bool; sequences (N, 3) (u, v, visible); path (M, 3) m; grasp point (3,) m.
    """

    stamp_ns: int
    topology: str
    camera: StereoCamera
    left_image: np.ndarray | None
    right_image: np.ndarray | None
    tip_hint: np.ndarray | None
    true_left_mask: np.ndarray
    true_right_mask: np.ndarray
    true_left_sequence: np.ndarray
    true_right_sequence: np.ndarray
    true_path: np.ndarray
    true_grasp: np.ndarray


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


def read_frames(bag: Path, images: bool = True) -> Iterator[Frame]:
    """Frames of one bag in stamp order; frames missing a needed topic are skipped.

    ``images=False`` skips decoding the camera images (the stages after segmentation
    start from the ground-truth masks or sequences and do not need them).
    """
    wanted = FRAME_TOPICS if images else tuple(t for t in FRAME_TOPICS if t not in IMAGE_TOPICS)
    pending: dict[int, dict[str, Any]] = defaultdict(dict)
    for record in read_messages(bag, wanted):
        pending[record.timestamp_ns][record.topic] = record.message
    for stamp in sorted(pending):
        got = pending.pop(stamp)
        if not all(t in got for t in wanted if t != topics.TIP_HINT):
            continue
        yield Frame(
            stamp_ns=stamp,
            topology=got[topics.GT_TOPOLOGY].data,
            camera=StereoCamera.from_camera_info(got[topics.LEFT_CAMERA_INFO], got[topics.RIGHT_CAMERA_INFO]),
            left_image=messages.image_to_array(got[topics.LEFT_IMAGE]) if images else None,
            right_image=messages.image_to_array(got[topics.RIGHT_IMAGE]) if images else None,
            tip_hint=messages.point_to_array(got[topics.TIP_HINT])[:2] if topics.TIP_HINT in got else None,
            true_left_mask=messages.image_to_array(got[topics.GT_LEFT_MASK], expect="mono8") > 0,
            true_right_mask=messages.image_to_array(got[topics.GT_RIGHT_MASK], expect="mono8") > 0,
            true_left_sequence=messages.polygon_to_array(got[topics.GT_LEFT_SEQUENCE]),
            true_right_sequence=messages.polygon_to_array(got[topics.GT_RIGHT_SEQUENCE]),
            true_path=messages.path_to_array(got[topics.GT_PATH]),
            true_grasp=messages.pose_to_arrays(got[topics.GT_GRASP_POSE])[0],
        )
