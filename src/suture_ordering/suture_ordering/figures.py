# SPDX-License-Identifier: Apache-2.0
"""``suture-order-figures``: the ordered sequence in gradient colour over the left image (paper Fig. 6).

For each topology in a simulator bag (``/ground_truth/topology``), the first
``--per-topology`` frames are ordered with :func:`suture_ordering.order_stereo` from
the bag's masks (ground truth by default, or ``/suture/*/mask`` with
``--masks predicted``) and tip hint, and drawn over ``/stereo/left/image_rect``:
the sequence runs from blue at the cut tip through green to red at its end
(stretches interpolated across a gap are dotted), the tip is circled. One PNG
per frame: ``OUT/<topology>_<index>.png``.

Example::

    suture-order-figures bags/sample --out /tmp/ordering_figures

Exit status 0 on success, 1 with one line on standard error when the bag cannot be read.
"""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from suture_common import messages, topics
from suture_common.bag_io import BagError, read_messages
from suture_common.camera import CameraModelError, StereoCamera
from suture_ordering.core import OrderingResult, order_stereo
from suture_ordering.errors import OrderingError

MASK_TOPICS = {
    "ground_truth": (topics.GT_LEFT_MASK, topics.GT_RIGHT_MASK),
    "predicted": (topics.LEFT_MASK, topics.RIGHT_MASK),
}


def draw_sequence(image: np.ndarray, result: OrderingResult, thickness: int = 2) -> np.ndarray:
    """A copy of ``image`` ((H, W, 3) uint8 RGB) with ``result``'s sequence in gradient colour.

    Colour goes from blue (cut tip) through green to red (end); interpolated (bridged)
    points are drawn as dots; the tip is circled in white.
    """
    canvas = np.ascontiguousarray(image.copy())
    points = result.points
    n = len(points)
    scale = max(1, round(canvas.shape[1] / 640))
    for i in range(n - 1):
        t = i / max(1, n - 2)
        colour = _gradient(t)
        p0 = tuple(round(float(x)) for x in points[i])
        p1 = tuple(round(float(x)) for x in points[i + 1])
        if result.bridged[i] or result.bridged[i + 1]:
            if i % 4 == 0:
                cv2.circle(canvas, p0, scale, colour, thickness=-1, lineType=cv2.LINE_AA)
        else:
            cv2.line(canvas, p0, p1, colour, thickness * scale, lineType=cv2.LINE_AA)
    tip = tuple(round(float(x)) for x in result.tip)
    cv2.circle(canvas, tip, 6 * scale, (255, 255, 255), thickness=scale, lineType=cv2.LINE_AA)
    return canvas


def _gradient(t: float) -> tuple[int, int, int]:
    """RGB colour at ``t`` in [0, 1]: blue -> green -> red."""
    if t < 0.5:
        s = t / 0.5
        return (0, int(255 * s), int(255 * (1 - s)))
    s = (t - 0.5) / 0.5
    return (int(255 * s), int(255 * (1 - s)), 0)


def write_figures(bag: Path, out: Path, per_topology: int = 1, masks: str = "ground_truth") -> list[Path]:
    """Order and draw the first ``per_topology`` frames of each topology of ``bag``; returns the PNGs."""
    left_topic, right_topic = MASK_TOPICS[masks]
    wanted = (
        topics.LEFT_IMAGE,
        left_topic,
        right_topic,
        topics.TIP_HINT,
        topics.LEFT_CAMERA_INFO,
        topics.RIGHT_CAMERA_INFO,
        topics.GT_TOPOLOGY,
    )
    frames: dict[int, dict[str, object]] = defaultdict(dict)
    for record in read_messages(bag, wanted):
        frames[record.timestamp_ns][record.topic] = record.message
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    counts: dict[str, int] = defaultdict(int)
    for index, (stamp, frame) in enumerate(sorted(frames.items())):
        topology = frame[topics.GT_TOPOLOGY].data if topics.GT_TOPOLOGY in frame else "unknown"  # type: ignore[attr-defined]
        if counts[topology] >= per_topology:
            continue
        needed = (
            topics.LEFT_IMAGE,
            left_topic,
            right_topic,
            topics.LEFT_CAMERA_INFO,
            topics.RIGHT_CAMERA_INFO,
        )
        if not all(topic in frame for topic in needed):
            continue
        image = messages.image_to_rgb(frame[topics.LEFT_IMAGE])
        camera = StereoCamera.from_camera_info(
            frame[topics.LEFT_CAMERA_INFO], frame[topics.RIGHT_CAMERA_INFO]
        )
        hint = frame.get(topics.TIP_HINT)
        tip = None if hint is None else messages.point_to_array(hint)[:2]
        left = messages.image_to_array(frame[left_topic], expect="mono8")
        right = messages.image_to_array(frame[right_topic], expect="mono8")
        try:
            result = order_stereo(left, right, tip, camera).left_result
        except OrderingError as exc:
            print(f"suture-order-figures: frame {index} ({stamp} ns, {topology}): {exc}", file=sys.stderr)
            continue
        canvas = draw_sequence(image, result)
        label = f"{topology}  {len(result.visible)} px  {result.status}"
        cv2.putText(canvas, label, (10, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 2, cv2.LINE_AA)
        path = out / f"{topology}_{index:04d}.png"
        if not cv2.imwrite(str(path), cv2.cvtColor(canvas, cv2.COLOR_RGB2BGR)):
            raise OSError(f"could not write {path}")
        written.append(path)
        counts[topology] += 1
    return written


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="suture-order-figures", description=__doc__.split("\n\n")[0])
    parser.add_argument("bag", type=Path, help="simulator bag (directory or .mcap)")
    parser.add_argument("--out", type=Path, required=True, help="directory for the PNGs (created)")
    parser.add_argument("--per-topology", type=int, default=1, help="frames per topology (default 1)")
    parser.add_argument(
        "--masks",
        choices=tuple(MASK_TOPICS),
        default="ground_truth",
        help="ground_truth (/ground_truth/*/mask, default) or predicted (/suture/*/mask)",
    )
    args = parser.parse_args(argv)
    try:
        written = write_figures(args.bag, args.out, args.per_topology, args.masks)
    except (BagError, OSError, CameraModelError, messages.MessageConversionError) as exc:
        print(f"suture-order-figures: error: {exc}", file=sys.stderr)
        return 1
    if not written:
        print(
            f"suture-order-figures: error: {args.bag} has no frame with an image and masks", file=sys.stderr
        )
        return 1
    for path in written:
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
