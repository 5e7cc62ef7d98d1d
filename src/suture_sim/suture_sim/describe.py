"""``suture-bag-info BAG``: what a simulated (or recorded) bag holds.

Prints each topic with its type and message count, then one line per frame
with the ground truth a user checks first: topology, thread length, grasp
point (camera frame, mm) and the tip hint.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

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


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="suture-bag-info", description=__doc__.split("\n\n")[0])
    parser.add_argument("bag", help="bag directory or .mcap file")
    args = parser.parse_args(argv)
    try:
        print(describe(args.bag))
    except (BagError, messages.MessageConversionError) as error:
        print(f"suture-bag-info: error: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
