# SPDX-License-Identifier: Apache-2.0
"""Writing simulated frames: one MCAP bag message set per frame, and PNG training folders.

Bag topics and frames follow docs/interfaces.md (``suture_common.topics``). Every message
of a frame carries the frame's stamp, and is logged at that time. Ground-truth
sequences are PolygonStamped with x = u, y = v and z = 1.0 where the target's
own surface is visible at that point, 0.0 where something covers it (see
``suture_sim.scene``).

PNG folders (for ``suture-seg finetune --images DIR --masks DIR``)::

    DIR/images/000012_left.png   RGB, 8 bit
    DIR/masks/000012_left.png    single channel, 0 = background, 255 = suture

Image and mask of a pair share one file name.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from suture_common import messages, topics
from suture_common.bag_io import BagWriter
from suture_sim.scene import SimFrame


def write_frame(writer: BagWriter, frame: SimFrame) -> None:
    """Write all input and ground-truth topics of ``frame`` into an open bag."""
    stamp = frame.stamp_ns
    left, right = topics.LEFT_FRAME, topics.RIGHT_FRAME
    records = [
        (topics.LEFT_IMAGE, messages.image_message(frame.left_image, "rgb8", stamp, left)),
        (topics.RIGHT_IMAGE, messages.image_message(frame.right_image, "rgb8", stamp, right)),
        (topics.LEFT_CAMERA_INFO, messages.camera_info_message(frame.camera, "left", stamp, left)),
        (topics.RIGHT_CAMERA_INFO, messages.camera_info_message(frame.camera, "right", stamp, right)),
        (topics.TIP_HINT, messages.point_message(np.r_[frame.tip_hint, 0.0], stamp, left)),
        (topics.GT_LEFT_MASK, messages.image_message(frame.left_mask, "mono8", stamp, left)),
        (topics.GT_RIGHT_MASK, messages.image_message(frame.right_mask, "mono8", stamp, right)),
        (topics.GT_LEFT_SEQUENCE, messages.polygon_message(frame.left_sequence, stamp, left)),
        (topics.GT_RIGHT_SEQUENCE, messages.polygon_message(frame.right_sequence, stamp, right)),
        (topics.GT_PATH, messages.path_message(frame.path, stamp, left)),
        (
            topics.GT_GRASP_POSE,
            messages.pose_message(frame.grasp_position, frame.grasp_quaternion, stamp, left),
        ),
        (topics.GT_TOPOLOGY, messages.string_message(frame.topology)),
    ]
    for topic, message in records:
        writer.write(topic, message, stamp)


def export_png(frame: SimFrame, directory: str | Path) -> list[Path]:
    """Write the frame's two images and two masks under ``directory``; returns the paths."""
    directory = Path(directory)
    written = []
    for view, image, mask in (
        ("left", frame.left_image, frame.left_mask),
        ("right", frame.right_image, frame.right_mask),
    ):
        name = f"{frame.index:06d}_{view}.png"
        for sub, array in (("images", cv2.cvtColor(image, cv2.COLOR_RGB2BGR)), ("masks", mask)):
            path = directory / sub / name
            path.parent.mkdir(parents=True, exist_ok=True)
            if not cv2.imwrite(str(path), array):
                raise OSError(f"could not write {path}")
            written.append(path)
    return written
