# SPDX-License-Identifier: Apache-2.0
"""``suture-order-bench``: ordering success per topology and milliseconds per mask, on simulator bags.

Runs :func:`suture_ordering.order_stereo` on the ground-truth masks and tip hints
of the given bags (``/ground_truth/{left,right}/mask``, ``/suture/tip_hint``,
camera_info), scores both views with
:func:`suture_bench.ordering_metrics.ordering_success` against
``/ground_truth/{left,right}/sequence``, and prints per resolution and topology
the success rate and the median milliseconds per mask (one view: cleaning, tip
and search). Timing runs on one CPU core: the process is pinned to one core and
OpenCV to one thread (set ``OMP_NUM_THREADS=1 MKL_NUM_THREADS=1`` in the
environment as well if NumPy's BLAS is multithreaded; the search makes no large
BLAS calls).

Example::

    suture-order-bench /tmp/ord_crossed /tmp/ord_occluded --failures

Exit status 0 when it ran (whatever the success rate), 1 with one line on
standard error when a bag cannot be read.
"""

from __future__ import annotations

import argparse
import itertools
import os
import sys
from collections import defaultdict
from collections.abc import Sequence

import cv2
import numpy as np

from suture_bench.frames import find_bags, read_frames
from suture_bench.ordering_metrics import ordering_success
from suture_common.bag_io import BagError
from suture_ordering import OrderingError, OrderingParams, order_stereo


def single_core() -> str:
    """Pin this process to one CPU core and OpenCV to one thread; returns a description."""
    cv2.setNumThreads(1)
    for name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(name, "1")
    try:
        core = min(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {core})
        return f"pinned to CPU core {core}, cv2 threads 1"
    except (AttributeError, OSError):
        return "cv2 threads 1 (could not pin to one core on this OS)"


def _parse_set(items: Sequence[str]) -> dict[str, float | int | bool]:
    changes: dict[str, float | int | bool] = {}
    names = OrderingParams.field_names()
    for item in items:
        name, _, value = item.partition("=")
        if name not in names or not value:
            raise argparse.ArgumentTypeError(f"--set expects NAME=VALUE with NAME one of {', '.join(names)}")
        if name == "curvature_prediction":
            changes[name] = value.lower() in ("1", "true", "yes")
        elif name in ("grid_size", "zone_margin_px", "max_steps"):
            changes[name] = int(value)
        else:
            changes[name] = float(value)
    return changes


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="suture-order-bench", description=__doc__.split("\n\n")[0])
    parser.add_argument("bags", nargs="+", help="simulator bags (directories or .mcap), or folders of bags")
    parser.add_argument("--limit", type=int, default=None, help="at most this many frames per bag")
    parser.add_argument("--failures", action="store_true", help="print every failed frame and why")
    parser.add_argument(
        "--set", action="append", default=[], metavar="NAME=VALUE", help="override an OrderingParams field"
    )
    args = parser.parse_args(argv)
    try:
        params = OrderingParams().with_updates(**_parse_set(args.set))
    except (argparse.ArgumentTypeError, ValueError) as exc:
        print(f"suture-order-bench: error: {exc}", file=sys.stderr)
        return 2
    print(f"suture-order-bench: {single_core()}")

    success: dict[tuple[str, str, str], list[bool]] = defaultdict(list)
    timing: dict[str, list[float]] = defaultdict(list)
    try:
        for path in find_bags(args.bags):
            for frame in itertools.islice(read_frames(path, images=False), args.limit):
                resolution = f"{frame.camera.width}x{frame.camera.height}"
                try:
                    result = order_stereo(
                        frame.true_left_mask, frame.true_right_mask, frame.tip_hint, frame.camera, params
                    )
                except OrderingError as exc:
                    for view in ("left", "right"):
                        success[(resolution, frame.topology, view)].append(False)
                    if args.failures:
                        print(f"FAIL {path.name} {frame.stamp_ns} {frame.topology}: {exc}")
                    continue
                for view, predicted, truth, view_result in (
                    ("left", result.left, frame.true_left_sequence, result.left_result),
                    ("right", result.right, frame.true_right_sequence, result.right_result),
                ):
                    score = ordering_success(predicted, truth)
                    success[(resolution, frame.topology, view)].append(score.success)
                    timing[resolution].append(view_result.elapsed_ms)
                    if args.failures and not score.success:
                        print(
                            f"FAIL {path.name} {frame.stamp_ns} {frame.topology} {view}: {score.reason} "
                            f"(status {view_result.status}, {view_result.bridges} bridges, "
                            f"{view_result.forks} forks)"
                        )
    except BagError as exc:
        print(f"suture-order-bench: error: {exc}", file=sys.stderr)
        return 1

    print(f"{'resolution':<11} {'topology':<17} {'frames':>6} {'left %':>7} {'right %':>8}")
    for resolution, topology in sorted({(r, t) for r, t, _ in success}):
        left = success[(resolution, topology, "left")]
        right = success[(resolution, topology, "right")]
        print(
            f"{resolution:<11} {topology:<17} {len(left):>6} "
            f"{100 * np.mean(left):>7.1f} {100 * np.mean(right):>8.1f}"
        )
    for resolution, values in sorted(timing.items()):
        print(
            f"{resolution}: median {np.median(values):.2f} ms per mask, "
            f"p90 {np.percentile(values, 90):.2f} ms, "
            f"max {np.max(values):.2f} ms over {len(values)} masks (one core)"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
