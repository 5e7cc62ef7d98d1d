# SPDX-License-Identifier: Apache-2.0
"""``suture-bag-info BAG [--contact-sheet PNG]``: what a simulated (or recorded) bag holds.

Prints each topic with its type and message count, then one line per frame
with the ground truth a user checks first: topology, thread length, grasp
point (camera frame, mm) and the tip hint. ``--contact-sheet`` also writes one
PNG with a row per frame: left image, right image and left ground-truth mask,
at half size.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

import cv2
import numpy as np

from suture_common import messages, topics
from suture_common.bag_io import BagError, bag_summary, read_messages


def describe(path: str) -> str:
    """The text that ``suture-bag-info`` prints for the bag at ``path``."""
    lines = [f"bag: {path}", "topics:"]
    for topic, (msgtype, count) in sorted(bag_summary(path).items()):
        lines.append(f"  {topic:34s} {msgtype:32s} {count:5d}")
    wanted = (topics.GT_TOPOLOGY, topics.GT_PATH, topics.GT_GRASP_POSE, topics.TIP_HINT, topics.LEFT_IMAGE)
    frames: dict[int, dict] = {}
    for record in read_messages(path, wanted):
        stamp = record.timestamp_ns
        entry = frames.setdefault(stamp, {})
        message = record.message
        if record.topic == topics.GT_TOPOLOGY:
            entry["topology"] = message.data
        elif record.topic == topics.GT_PATH:
            path_points = messages.path_to_array(message)
            entry["length_mm"] = 1000 * np.linalg.norm(np.diff(path_points, axis=0), axis=1).sum()
        elif record.topic == topics.GT_GRASP_POSE:
            entry["grasp_mm"] = 1000 * messages.pose_to_arrays(message)[0]
        elif record.topic == topics.TIP_HINT:
            entry["tip_px"] = messages.point_to_array(message)[:2]
        else:
            entry["size"] = f"{message.width}x{message.height} {message.encoding}"
    if frames:
        lines.append(
            "frames (stamp ns, topology, image, thread length, grasp point in left optical frame, tip hint):"
        )
    for stamp, entry in sorted(frames.items()):
        grasp = entry.get("grasp_mm")
        tip = entry.get("tip_px")
        lines.append(
            f"  {stamp}  {entry.get('topology', '?'):16s} {entry.get('size', '-'):16s} "
            f"{entry.get('length_mm', float('nan')):6.1f} mm  "
            + (f"grasp ({grasp[0]:6.1f}, {grasp[1]:6.1f}, {grasp[2]:6.1f}) mm  " if grasp is not None else "")
            + (f"tip ({tip[0]:5.1f}, {tip[1]:5.1f}) px" if tip is not None else "")
        )
    return "\n".join(lines)


def contact_sheet(path: str, output: str, scale: float = 0.5) -> int:
    """Write the stereo pairs and left masks of the bag at ``path`` as one PNG; returns the row count."""
    wanted = (topics.LEFT_IMAGE, topics.RIGHT_IMAGE, topics.GT_LEFT_MASK)
    frames: dict[int, dict[str, np.ndarray]] = {}
    for record in read_messages(path, wanted):
        array = messages.image_to_array(record.message)
        if array.ndim == 2:
            array = np.repeat(array[..., None], 3, axis=2)
        elif record.message.encoding == "rgb8":
            array = array[..., ::-1]  # OpenCV writes BGR
        frames.setdefault(record.timestamp_ns, {})[record.topic] = cv2.resize(
            array, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA
        )
    rows = [np.hstack([f[t] for t in wanted]) for _, f in sorted(frames.items()) if len(f) == len(wanted)]
    if not rows:
        raise BagError(f"{path} has no frame with {', '.join(wanted)}")
    if not cv2.imwrite(output, np.vstack(rows)):
        raise OSError(f"could not write {output}")
    return len(rows)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="suture-bag-info", description=__doc__.split("\n\n")[0])
    parser.add_argument("bag", help="bag directory or .mcap file")
    parser.add_argument("--contact-sheet", metavar="PNG", help="also write the frames as one PNG here")
    args = parser.parse_args(argv)
    try:
        print(describe(args.bag))
        if args.contact_sheet:
            rows = contact_sheet(args.bag, args.contact_sheet)
            print(f"contact sheet: {rows} frames (left, right, left mask) in {args.contact_sheet}")
    except (OSError, messages.MessageConversionError) as error:
        print(f"suture-bag-info: error: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
